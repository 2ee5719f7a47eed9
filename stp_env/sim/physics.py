"""Kinematics of the simulation: exact Dubins motion under zero-order-hold control and wind, frames, actions.

All functions are pure and jittable; shapes broadcast over leading axes.
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.angles import wrap_angle
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN

__all__ = ["action_to_control", "control_to_action", "disk_sample", "dubins_step", "relative_state", "rotate",
           "wrap_angle"]


def rotate(theta, v):
    """``R(theta) v`` for ``v`` of shape ``(..., 2)``."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def dubins_step(x, v, omega, wind, dt):
    """Exact solution of eq. (43) over ``dt`` with ``(v, omega)`` and wind ``(d_x, d_y)`` held constant:

        p(t + dt) = p + v/omega (sin(theta + omega dt) - sin theta, cos theta - cos(theta + omega dt)) + d dt,

    written with ``sinc`` so that ``omega -> 0`` is the straight line. ``x``: ``(..., 3)``."""
    theta = x[..., 2]
    half = 0.5 * omega * dt
    # chord length v dt sinc(half) along the mean heading theta + half
    chord = v * dt * jnp.sinc(half / jnp.pi)
    mid = theta + half
    px = x[..., 0] + chord * jnp.cos(mid) + wind[..., 0] * dt
    py = x[..., 1] + chord * jnp.sin(mid) + wind[..., 1] * dt
    return jnp.stack([px, py, wrap_angle(theta + omega * dt)], axis=-1)


def relative_state(x_own, x_other):
    """The other agent's state in the own agent's body frame (eq. 44's state): ``(..., 3)``."""
    p = rotate(-x_own[..., 2], x_other[..., :2] - x_own[..., :2])
    return jnp.concatenate([p, wrap_angle(x_other[..., 2] - x_own[..., 2])[..., None]], axis=-1)


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
