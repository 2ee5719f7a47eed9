"""Angles: the one heading-wrapping function of the package.

Every heading the package stores or compares is wrapped to ``[-pi, pi)`` by :func:`wrap_angle`, whatever holds it:
a Python number (scenario data), a NumPy array (host-side analysis) or a JAX array (the jitted core, traced values
included). Each kind is wrapped in its own arithmetic, so a Python float stays a float64 ``float`` and a JAX
``float32`` stays ``float32``.
"""

from __future__ import annotations

import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np


def wrap_angle(theta):
    """``theta`` [rad] wrapped to ``[-pi, pi)``: ``(theta + pi) mod 2 pi - pi`` (floored modulo)."""
    if isinstance(theta, jax.Array):
        return jnp.mod(theta + jnp.pi, 2 * jnp.pi) - jnp.pi
    if isinstance(theta, numbers.Real) and not isinstance(theta, np.generic):
        return (float(theta) + math.pi) % (2.0 * math.pi) - math.pi
    return np.mod(np.asarray(theta) + np.pi, 2 * np.pi) - np.pi
