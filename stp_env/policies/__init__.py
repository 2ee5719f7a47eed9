"""Baseline policies: jittable functions ``policy(key, state, params) -> actions`` of the simulation core.

Vehicle policies return ``(N, 2)`` actions in ``[-1, 1]`` (see :mod:`stp_env.policies.vehicles`); intruder
policies return ``(2,)`` (see :mod:`stp_env.policies.intruders`). They read the full
:class:`~stp_env.sim.EnvState` (the papers' controllers assume full state information), so they run inside
``lax.scan`` and ``vmap`` with the core (:func:`stp_env.sim.rollout`).
"""

from stp_env.policies.intruders import (
    BUFFER_GAME_INTRUDERS,
    INTRUDERS,
    bezier_intruder,
    greedy_pursuit,
    hj_pursuit,
    hover,
    intruder_policy,
    max_k,
    mixture,
    mixture_index,
    optimal_max_k,
    ordered_max_k,
    random_intruder,
)
from stp_env.policies.vehicles import (
    BUFFER_GAME_VEHICLE_POLICIES,
    VEHICLE_POLICIES,
    fallback_control,
    hj_filter,
    nominal_tracking,
    safety_filter,
    switching,
    tube_keeping,
    vehicle_policy,
    worst,
)

__all__ = [
    "BUFFER_GAME_INTRUDERS",
    "BUFFER_GAME_VEHICLE_POLICIES",
    "INTRUDERS",
    "VEHICLE_POLICIES",
    "bezier_intruder",
    "fallback_control",
    "greedy_pursuit",
    "hj_filter",
    "hj_pursuit",
    "hover",
    "intruder_policy",
    "max_k",
    "mixture",
    "mixture_index",
    "nominal_tracking",
    "optimal_max_k",
    "ordered_max_k",
    "random_intruder",
    "safety_filter",
    "switching",
    "tube_keeping",
    "vehicle_policy",
    "worst",
]
