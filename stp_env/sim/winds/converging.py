"""``converging``: the winds of the buffer game (intruder paper eqs. 46-47, every player helping the intruder reach
the next vehicle), by line of sight, re-evaluated at every inner step of the core.

While the intruder is present, every flying vehicle that has not been forced gets its full wind toward the
intruder, and the intruder its full wind toward the nearest such vehicle: the winds that close each pair's distance
fastest (for a pair flying straight at each other they are the game's minimising disturbances exactly; the
game's value also weighs headings, which line of sight does not). Forced vehicles, and every vehicle while the
intruder is absent, get :func:`stp_env.sim.winds.worst.worst_winds` (the avoid game's and the tracking game's
worst). With ``--vehicle-policy worst`` and an intruder that hops between vehicles (``optimal-max-k``) this is the
premise of the buffer region ``V^B``, so it is the wind under which the k̄ bound can be reached. No heading
disturbance."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from stp_env.sim.types import FLYING, PRESENT
from stp_env.sim.winds import register
from stp_env.sim.winds.base import StateFeedbackWind, radii
from stp_env.sim.winds.worst import worst_winds


def converging_winds(state, params):
    """The line-of-sight helping winds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    n = params.vehicles.n
    r = radii(params)
    pos = params.vehicles.model.pose(state.x)[:, :2]
    gap = state.intruder_x[None, :2] - pos                                  # (N, 2) vehicle -> intruder
    dist = jnp.linalg.norm(gap, axis=1)
    toward = gap / jnp.maximum(dist, 1e-9)[:, None]
    helping = (state.status == FLYING) & ~jnp.isfinite(state.avoid_start) & (state.intruder_status == PRESENT)
    j = jnp.argmin(jnp.where(helping, dist, jnp.inf))
    base = worst_winds(state, params)
    w_veh = jnp.where(helping[:, None], toward * r[:n, None], base[:n])
    w_int = jnp.where(helping.any(), -toward[j] * r[n], base[n])
    return jnp.concatenate([w_veh, w_int[None]], axis=0)


@register
@dataclasses.dataclass(frozen=True)
class Converging(StateFeedbackWind):
    name = "converging"
    help = "the buffer game's helping winds by line of sight (unforced vehicles and intruder blow toward each other)"
    order = 5

    def inner(self, state, params, held):
        del held
        return converging_winds(state, params)
