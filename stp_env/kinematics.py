"""Planar kinematics shared by every layer: rotations, exact Dubins motion under a held control and wind, and
relative states in a body frame (intruder paper eq. 44). Pure and jittable; shapes broadcast over leading axes.

The simulator (:mod:`stp_env.sim.physics`), the planner and the closed-loop certification of the reachability
sets (:mod:`stp_env.reach.closed_loop`) all move vehicles with these functions, so that what is certified is what
is flown.
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.angles import wrap_angle

__all__ = ["dubins_step", "relative_state", "rotate"]


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
