"""``tailwind``: every agent's wind at the full bound of its disk, blowing along the agent's current heading,
re-evaluated at every inner step of the core. It is the wind that makes every agent as fast over the ground as it
can ever be (``v + d``) in whatever direction it flies: the case a reachability bound built on the speed
``v_max + d`` (the co-observation ellipses, ``stp_env.coobservation``) has to cover, and the one an attacker would
pick. No heading disturbance."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from stp_env.sim.winds import register
from stp_env.sim.winds.base import StateFeedbackWind, radii


def tailwinds(state, params):
    """The tailwinds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    heading = jnp.concatenate([params.vehicles.model.pose(state.x)[:, 2], state.intruder_x[2:3]])
    return jnp.stack([jnp.cos(heading), jnp.sin(heading)], axis=1) * radii(params)[:, None]


@register
@dataclasses.dataclass(frozen=True)
class Tailwind(StateFeedbackWind):
    name = "tailwind"
    help = "full strength along each agent's heading (the fastest ground speed)"
    order = 4

    def inner(self, state, params, held):
        del held
        return tailwinds(state, params)
