"""Seeds to JAX PRNG keys, without truncation or collisions.

``jax.random.key(seed)`` without 64-bit mode keeps the low 32 bits of a seed (``2**32 + 5`` gives the same key as
``5``) and maps negative seeds onto large positive ones (``-1`` is ``2**32 - 1``). :func:`prng_key` accepts
exactly the integers it can represent without loss, ``0 <= seed <= 2**63 - 1``, and gives each its own key: the
key data ``(seed >> 32, seed & 0xFFFFFFFF)``, which for seeds below ``2**32`` is the key ``jax.random.key(seed)``
gives (so results of those seeds are unchanged) and for larger seeds the key that JAX gives in 64-bit mode.
Booleans, floats (even integral ones), strings and anything else are refused with a ``ValueError``.
"""

from __future__ import annotations

import numbers

import jax
import numpy as np

MAX_SEED = 2**63 - 1


def check_seed(seed, name: str = "seed") -> int:
    """``seed`` as a Python int if it is an integer in ``[0, 2**63 - 1]``; ``ValueError`` naming ``name``
    otherwise."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, numbers.Integral):
        raise ValueError(f"{name} must be an integer in [0, 2**63 - 1]; got {seed!r} ({type(seed).__name__}).")
    value = int(seed)
    if not 0 <= value <= MAX_SEED:
        raise ValueError(f"{name} must be an integer in [0, 2**63 - 1]; got {value}.")
    return value


def prng_key(seed, name: str = "seed"):
    """A typed JAX PRNG key for ``seed`` (checked by :func:`check_seed`): distinct seeds give distinct keys."""
    value = check_seed(seed, name)
    data = np.asarray([value >> 32, value & 0xFFFFFFFF], np.uint32)
    return jax.random.wrap_key_data(data)
