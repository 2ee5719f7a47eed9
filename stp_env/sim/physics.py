"""Kinematics of the simulation: exact Dubins motion under zero-order-hold control and wind, frames (re-exported
from :mod:`stp_env.kinematics`, which every layer shares), actions.

All functions are pure and jittable; shapes broadcast over leading axes.
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.angles import wrap_angle
from stp_env.kinematics import dubins_step, relative_state, rotate
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN

__all__ = ["action_to_control", "control_to_action", "disk_sample", "dubins_step", "relative_state", "rotate",
           "wrap_angle"]


def action_to_control(action, bounds):
    """Map ``[-1, 1]^2`` (clipped) to ``(v, omega)`` in ``[v_min, v_max] x [-omega_max, omega_max]``. ``bounds``:
    ``(v_min, v_max, omega_max, ...)``."""
    a = jnp.clip(action, -1.0, 1.0)
    v = bounds[V_MIN] + 0.5 * (a[..., 0] + 1.0) * (bounds[V_MAX] - bounds[V_MIN])
    return v, a[..., 1] * bounds[OMEGA_MAX]


def control_to_action(v, omega, bounds):
    """Inverse of :func:`action_to_control` (clipped to ``[-1, 1]``)."""
    span = jnp.maximum(bounds[V_MAX] - bounds[V_MIN], 1e-9)
    a0 = 2.0 * (v - bounds[V_MIN]) / span - 1.0
    a1 = omega / jnp.maximum(bounds[OMEGA_MAX], 1e-9)
    return jnp.clip(jnp.stack([a0, a1], axis=-1), -1.0, 1.0)


def disk_sample(key_uniform_pair, radius):
    """A point uniform in the disk of ``radius`` from two U[0, 1) numbers (last axis 2)."""
    u = key_uniform_pair
    r = radius * jnp.sqrt(u[..., 0])
    a = 2 * jnp.pi * u[..., 1]
    return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], axis=-1)
