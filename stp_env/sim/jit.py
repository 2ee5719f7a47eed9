"""How the simulator's programs are compiled.

A simulator program (a batch of episodes, one adapter step, a falsifier's objective) is large: a town rollout is
about 27,000 lines of optimised HLO in several hundred fusions, and most of its compile time is LLVM turning that
into machine code (see ``docs/numerics.md``, "Compiling the simulator"). At backend optimisation level 2 that takes
0.6 times as long as at XLA's default (3), while the compiled program runs about as fast and its outputs were the
same bit for bit on the measured programs. Tests, evaluations and short
training runs are dominated by compiles, so the simulator's programs use :data:`SIM_COMPILER_OPTIONS`.

The HJ solver and the planner keep XLA's defaults: their outputs are shipped artifacts (tables, bounds, plans) that
must reproduce bit for bit, and at levels below 3 some of them do not (a tracking bound of 6.081 m came out 6.087 m).

Every simulator program is jitted with :func:`sim_jit`, so that this choice is made in one place.
"""

from __future__ import annotations

import jax

SIM_COMPILER_OPTIONS: dict[str, int] = {"xla_backend_optimization_level": 2}
"""XLA options of every simulator program (a debug-options field accepted by every backend)."""


def sim_jit(fun, **jit_kwargs):
    """``jax.jit(fun, **jit_kwargs)`` compiled with :data:`SIM_COMPILER_OPTIONS`; the same signature, so it can
    decorate like ``jax.jit`` (``functools.partial(sim_jit, static_argnames=...)``)."""
    if "compiler_options" in jit_kwargs:
        raise TypeError("sim_jit sets compiler_options itself (SIM_COMPILER_OPTIONS)")
    return jax.jit(fun, compiler_options=dict(SIM_COMPILER_OPTIONS), **jit_kwargs)
