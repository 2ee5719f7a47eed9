"""The pure JAX simulation core: arrays in, arrays out (see ``docs/architecture.md``).

* :mod:`~stp_env.sim.types`: ``EnvParams`` (constants), ``EnvState`` (per step), status and mode codes.
* :mod:`~stp_env.sim.config`: ``EnvConfig`` and ``RewardConfig`` (typed).
* :mod:`~stp_env.sim.core`: ``reset``, ``step``, ``observe`` and the events of a step.
* :mod:`~stp_env.sim.rollout`: ``rollout`` (a ``lax.scan`` over steps of the ``vmap``-ed step).
* :mod:`~stp_env.sim.fleet`: simulating only the vehicles that can fly in an episode window, with the whole
  fleet's random numbers.
* :mod:`~stp_env.sim.wind`, :mod:`~stp_env.sim.spawn`, :mod:`~stp_env.sim.tables`,
  :mod:`~stp_env.sim.physics`: wind models, intruder spawning, value-table reads, kinematics.

The core knows no scenario, plan or artifact: :mod:`stp_env.assembly`, the layer above it, makes ``EnvParams``
from them (``params_for``, ``make_params``, ``load_artifacts``, ``load_plan``, ``with_plan``, ``busiest_window``).
"""

from stp_env.sim.config import EnvConfig, RewardConfig
from stp_env.sim.core import episode_over, lifecycle, reset, step
from stp_env.sim.observations import global_state, observation_sizes, observe
from stp_env.sim.reference import nominal_reference
from stp_env.sim.rollout import rollout, steps_for
from stp_env.sim.types import (
    AFTER_AVOIDANCE,
    ARRIVED,
    AVOIDING,
    COLLIDED,
    FLYING,
    GONE,
    NOMINAL,
    OUT_OF_BOUNDS,
    PENDING,
    PRESENT,
    WAITING,
    EnvParams,
    EnvState,
    RewardWeights,
    n_forced,
)

__all__ = [
    "AFTER_AVOIDANCE", "ARRIVED", "AVOIDING", "COLLIDED", "FLYING", "GONE", "NOMINAL", "OUT_OF_BOUNDS", "PENDING",
    "PRESENT", "WAITING", "EnvConfig", "EnvParams", "EnvState", "RewardConfig", "RewardWeights", "episode_over",
    "global_state", "lifecycle", "n_forced", "nominal_reference", "observation_sizes", "observe", "reset", "rollout",
    "step", "steps_for",
]
