"""``uniform``: a new wind uniformly in each agent's disk every step (the papers' simulations)."""

from __future__ import annotations

import dataclasses

from stp_env.sim.winds import register
from stp_env.sim.winds.base import WindModel, uniform_in_disks


@register
@dataclasses.dataclass(frozen=True)
class Uniform(WindModel):
    name = "uniform"
    help = "a new wind in the disk every step (the papers)"
    order = 0

    def draw(self, key, state, params):
        return uniform_in_disks(key, params), state.wind
