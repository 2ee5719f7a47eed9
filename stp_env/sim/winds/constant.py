"""``constant``: one wind per agent and episode, uniform in its disk."""

from __future__ import annotations

import dataclasses

from stp_env.sim.fleet import agent_rows
from stp_env.sim.winds import register
from stp_env.sim.winds.base import WindModel, uniform_in_fleet_disks


@register
@dataclasses.dataclass(frozen=True)
class Constant(WindModel):
    name = "constant"
    help = "one per episode"
    order = 1

    def initial(self, key, params):
        return uniform_in_fleet_disks(key, params)

    def draw(self, key, state, params):
        del key
        return agent_rows(params, state.wind), state.wind
