"""The simulator's programs are compiled with the simulator's options, and only they (``stp_env/sim/jit.py``)."""

from __future__ import annotations

import ast
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stp_env
from stp_env.sim.jit import SIM_COMPILER_OPTIONS, sim_jit

ROOT = pathlib.Path(stp_env.__file__).parent

# modules whose compiled programs run the simulator's step (every jit in them goes through sim_jit)
SIM_PROGRAM_MODULES = ("sim/rollout.py", "sim/stepping.py", "evaluation/runner.py", "evaluation/worst_case.py",
                       "rl/functional.py", "falsify/search.py", "coobservation/threat.py")
# modules whose outputs are shipped artifacts that must reproduce bit for bit: XLA's defaults only
DEFAULT_OPTION_MODULES = ("hj/solver.py", "planning/brs.py", "planning/single.py", "reach/tracking.py")


def _jit_calls(path: pathlib.Path) -> tuple[list[str], list[str]]:
    """The names of the jit functions this module calls or decorates with: ``(jax.jit uses, sim_jit uses)``."""
    bare, ours = [], []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and node.attr == "jit" and isinstance(node.value, ast.Name) \
                and node.value.id == "jax":
            bare.append(f"{path.name}:{node.lineno}")
        elif isinstance(node, ast.Name) and node.id == "sim_jit":
            ours.append(f"{path.name}:{node.lineno}")
    return bare, ours


@pytest.mark.parametrize("module", SIM_PROGRAM_MODULES)
def test_simulator_programs_compile_with_the_simulator_options(module):
    bare, ours = _jit_calls(ROOT / module)
    assert not bare, f"simulator programs jitted without SIM_COMPILER_OPTIONS: {bare}"
    assert ours, f"{module} defines no simulator program any more: update SIM_PROGRAM_MODULES"


@pytest.mark.parametrize("module", DEFAULT_OPTION_MODULES)
def test_artifact_programs_keep_the_default_options(module):
    bare, ours = _jit_calls(ROOT / module)
    assert not ours, f"{module} builds shipped artifacts; it must compile with XLA's defaults: {ours}"
    assert bare, f"{module} jits nothing any more: update DEFAULT_OPTION_MODULES"


def test_sim_jit_passes_its_options_to_the_compiler():
    x = jnp.linspace(-3.0, 3.0, 101)
    lowered = sim_jit(lambda x: jnp.sin(x) * 2.0).lower(x)
    # the options travel with the lowering to the compile (jax.stages internals; a JAX upgrade may move them)
    kvs = dict(lowered._lowering._compiler_options_kvs)
    assert kvs == SIM_COMPILER_OPTIONS
    assert dict(jax.jit(lambda x: x).lower(jnp.ones(3))._lowering._compiler_options_kvs or ()) == {}
    np.testing.assert_array_equal(np.asarray(lowered.compile()(x)), np.asarray(jnp.sin(x) * 2.0))


def test_sim_jit_decorates_like_jax_jit_and_refuses_other_options():
    import functools

    @functools.partial(sim_jit, static_argnames=("n",))
    def power(x, n):
        return x ** n

    assert float(power(jnp.float32(2.0), n=3)) == 8.0
    with pytest.raises(TypeError, match="SIM_COMPILER_OPTIONS"):
        sim_jit(lambda x: x, compiler_options={"xla_backend_optimization_level": 3})
