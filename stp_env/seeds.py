"""Seeds to JAX PRNG keys, without truncation or collisions.

``jax.random.key(seed)`` without 64-bit mode keeps the low 32 bits of a seed (``2**32 + 5`` gives the same key as
``5``) and maps negative seeds onto large positive ones (``-1`` is ``2**32 - 1``). :func:`prng_key` accepts
exactly the integers it can represent without loss, ``0 <= seed <= 2**63 - 1``, and gives each its own key: the
key data ``(seed >> 32, seed & 0xFFFFFFFF)``, which for seeds below ``2**32`` is the key ``jax.random.key(seed)``
gives (so results of those seeds are unchanged) and for larger seeds the key that JAX gives in 64-bit mode.
Booleans, floats (even integral ones), strings and anything else are refused with a ``ValueError``.

This is the one seed function of the package: the environments (``reset(seed=...)``), the library's entry points
(evaluations, the falsifier, the co-observation evaluation and training) and every subcommand's ``--seed``
(:mod:`stp_env.cli_kit`) use it. :func:`check_seed` imports nothing heavy (JAX only when a key is made).
"""

from __future__ import annotations

import numbers

MAX_SEED = 2**63 - 1
MAX_SEED_32 = 2**32 - 1
"""The largest seed of the subcommands whose seed also seeds NumPy's legacy generator, which takes 32 bits
(``train-intruder``: Stable-Baselines3's ``set_random_seed``)."""


def check_seed(seed, name: str = "seed", maximum: int = MAX_SEED) -> int:
    """``seed`` as a Python int if it is an integer in ``[0, maximum]`` (default ``2**63 - 1``); ``ValueError``
    naming ``name`` otherwise."""
    from stp_env.arguments import show

    bound = "2**63 - 1" if maximum == MAX_SEED else "2**32 - 1" if maximum == MAX_SEED_32 else str(maximum)
    if isinstance(seed, bool) or type(seed).__name__ == "bool_" or not isinstance(seed, numbers.Integral):
        raise ValueError(f"{name} must be an integer in [0, {bound}]; got {show(seed)} ({type(seed).__name__}).")
    value = int(seed)
    if not 0 <= value <= maximum:
        raise ValueError(f"{name} must be an integer in [0, {bound}]; got {show(value)}.")
    return value


def prng_key(seed, name: str = "seed"):
    """A typed JAX PRNG key for ``seed`` (checked by :func:`check_seed`): distinct seeds give distinct keys."""
    import jax
    import numpy as np

    value = check_seed(seed, name)
    data = np.asarray([value >> 32, value & 0xFFFFFFFF], np.uint32)
    return jax.random.wrap_key_data(data)
