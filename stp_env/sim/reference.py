"""The nominal trajectories as continuous-time references (jittable).

A plan stores, per vehicle, samples ``x_k`` at ``t_k = t_0 + k dt`` and the control ``u_k`` in the planning set
``U^p`` held from ``t_k`` to ``t_{k+1}``, with ``x_{k+1}`` the exact Dubins motion of ``x_k`` under ``u_k``
(:func:`stp_env.planning.single.plan_single_with_slices`). Between samples the reference is that exact arc, so it is
a trajectory of the planning dynamics at every instant, which is what the robust-tracking bound of SPP eqs. (24)-(26)
assumes of a reference (a straight chord between samples cuts a turning arc by up to ``v dt^2 omega / 8``).
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.sim.physics import dubins_step
from stp_env.sim.types import EnvParams


def nominal_reference(params: EnvParams, t):
    """Every vehicle's nominal state and control at time ``t``: ``(N, 3)``, ``(N, 2)``. Before the first sample the
    reference waits at it; after the last it stays at the last sample."""
    s = (t - params.vehicles.nominal_t0) / params.vehicles.nominal_dt
    last = jnp.maximum(params.vehicles.nominal_len - 1, 0)
    s = jnp.clip(s, 0.0, last.astype(s.dtype))
    k0 = jnp.minimum(jnp.floor(s).astype(jnp.int32), last)
    tau = (s - k0) * params.vehicles.nominal_dt
    idx = jnp.arange(params.vehicles.n)
    x0, u0 = params.vehicles.nominal_states[idx, k0], params.vehicles.nominal_controls[idx, k0]
    x = dubins_step(x0, u0[:, 0], u0[:, 1], jnp.zeros_like(x0[:, :2]), tau)
    return x, u0
