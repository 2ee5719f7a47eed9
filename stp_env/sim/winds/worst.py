"""``worst``: the HJ games' worst-case wind, re-evaluated at every inner step of the core. A vehicle avoiding the
intruder gets the minimising wind of the avoid game (intruder paper eq. 14) and the intruder the matching one; a
vehicle tracking its plan gets the wind that grows its tracking error most (SPP eq. 25). Heading disturbances are
zero in this model."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from stp_env.sim import tables
from stp_env.sim.physics import relative_state, rotate
from stp_env.sim.reference import nominal_reference
from stp_env.sim.types import AVOIDING, FLYING, PRESENT
from stp_env.sim.winds import register
from stp_env.sim.winds.base import StateFeedbackWind, radii


def worst_winds(state, params):
    """The worst-case winds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    n = params.vehicles.n
    r = radii(params)
    tau = state.t - state.t_appear
    x = params.vehicles.model.pose(state.x)
    rel = relative_state(x, state.intruder_x[None, :])
    game = jax.vmap(lambda x: tables.pursuit_input(params, tau, x))(rel)          # (N, 4)
    wc = game[:, 2:4]
    wc_dir = wc / jnp.maximum(jnp.linalg.norm(wc, axis=1, keepdims=True), 1e-12)
    # combined wind R(-theta_i)(d_I - d_i): the vehicle takes -R(theta_i) wc_dir d_r, the intruder +R(theta_i) ...
    w_avoid = -rotate(x[:, 2], wc_dir) * r[:n, None]
    x_ref, _ = nominal_reference(params, state.t)
    err = relative_state(x, x_ref)
    d_err = jax.vmap(lambda e: tables.tracking_control(params, e)[1])(err)       # (N, 2) body frame
    d_dir = d_err / jnp.maximum(jnp.linalg.norm(d_err, axis=1, keepdims=True), 1e-12)
    # The error dynamics see minus the vehicle's wind, rotated into its frame: the vehicle takes -R(theta) d.
    w_track = -rotate(x[:, 2], d_dir) * r[:n, None]
    present = state.intruder_status == PRESENT
    avoiding = (state.status == FLYING) & (state.mode == AVOIDING) & present
    w_veh = jnp.where(avoiding[:, None], w_avoid, w_track)
    vals = jnp.where((state.status == FLYING) & present,
                     jax.vmap(lambda x: tables.avoid_value(params, tau, x))(rel), jnp.inf)
    j = jnp.argmin(vals)
    w_int = rotate(x[j, 2], wc_dir[j]) * r[n]
    w_int = jnp.where(jnp.isfinite(vals[j]), w_int, jnp.zeros(2))
    return jnp.concatenate([w_veh, w_int[None]], axis=0)


@register
@dataclasses.dataclass(frozen=True)
class Worst(StateFeedbackWind):
    name = "worst"
    help = "the HJ games' worst-case wind"
    order = 3

    def inner(self, state, params, held):
        del held
        return worst_winds(state, params)
