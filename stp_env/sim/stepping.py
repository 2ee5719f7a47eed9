"""The programs a one-episode adapter (:mod:`stp_env.env`) calls: a reset and a step of the core with everything the
adapter turns into observations, rewards and infos, in one jitted call each.

A step's outputs come back as one packed ``int32`` array, and the key and state it carries to the next step stay
packed on the device as another (:mod:`stp_env.sim.packing` says why: each array in or out of a call has its own
cost, larger than the step's own work on a CPU). :data:`TRACE_COUNTS` counts the traces of the step (the tests check
that an episode, replanning included, traces it once).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from stp_env.sim import core, observations
from stp_env.sim.jit import sim_jit
from stp_env.sim.packing import pack
from stp_env.sim.rollout import intruder_decision


class StepInfo(NamedTuple):
    """What the infos are made of, read on the device after each step (arrays ``(N,)`` per vehicle, scalars
    ``()``)."""

    status: jax.Array               # (N,) STATUS_NAMES index after the step
    prev_status: jax.Array          # (N,) before it (a collision is new when it was not COLLIDED)
    mode: jax.Array                 # (N,) MODE_NAMES index
    avoid_start: jax.Array          # (N,) [s] t_i (inf: never forced)
    guarantee_violation: jax.Array  # (N,) bool
    used_filter: jax.Array          # (N,) bool
    min_separation: jax.Array       # (N,) [m]
    t: jax.Array                    # () [s]
    intruder_status: jax.Array      # () INTRUDER_STATUS_NAMES index
    tracking_error: jax.Array       # (N,) [m] distance to the nominal position
    max_tracking_error: jax.Array   # (N,) [m] largest while tracking the plan (never forced)
    tracked: jax.Array              # (N,) bool: applied the tracker at every inner step while flying its plan
    tracking_violation: jax.Array   # (N,) bool: tracked, and max_tracking_error exceeded r_e


class StepOutput(NamedTuple):
    """Everything the adapter converts to numpy after a ``reset`` or ``step`` (one ``device_get``)."""

    obs_vehicles: jax.Array   # (N, vehicle observation size)
    obs_intruder: jax.Array   # (intruder observation size,)
    rewards: jax.Array        # (N + 1,)
    info: StepInfo
    terminated: jax.Array     # ()
    truncated: jax.Array      # ()


def step_info(prev, new) -> StepInfo:
    return StepInfo(status=new.status, prev_status=prev.status, mode=new.mode, avoid_start=new.avoid_start,
                    guarantee_violation=new.guarantee_violation, used_filter=new.used_filter,
                    min_separation=new.min_separation, t=new.t, intruder_status=new.intruder_status,
                    tracking_error=new.tracking_error, max_tracking_error=new.max_tracking_error,
                    tracked=new.tracked, tracking_violation=new.tracking_violation)


def advance(key, state, actions, params):
    """One adapter step: ``step``, then everything the adapter converts to numpy."""
    key, sub = jax.random.split(key)
    new, rewards = core.step(sub, state, actions, params)
    obs_v, obs_i = observations.observe(new, params)
    term, trunc = core.episode_over(new, params)
    return key, new, StepOutput(obs_v, obs_i, rewards, step_info(state, new), term, trunc)


def start(key, params):
    key, sub = jax.random.split(key)
    state = core.reset(sub, params)
    obs_v, obs_i = observations.observe(state, params)
    no = jnp.zeros((), bool)
    return key, state, StepOutput(obs_v, obs_i, jnp.zeros((params.vehicles.n + 1,), jnp.float32),
                                  step_info(state, state), no, no)


start_jit = sim_jit(start)


observe_jit = sim_jit(observations.observe)
global_state_jit = sim_jit(observations.global_state)

TRACE_COUNTS = {"step": 0}  # incremented when the step function is traced (tests check it stays at 1)


def advance_scripted(key, state, actions, params, vehicle_policy=None, intruder_policy=None):
    """:func:`advance` with the vehicles and/or the intruder flown by scripted policies (their actions ignored):
    the intruder's action once per step from its own key (as in :func:`stp_env.sim.rollout`), the vehicles' policy
    as the feedback law of every inner control step."""
    key, sub = jax.random.split(key)
    if intruder_policy is not None:
        k_i, sub = jax.random.split(sub)
        a_i = intruder_decision(intruder_policy, k_i, state, params)
        actions = actions.at[params.vehicles.n, :2].set(a_i.astype(actions.dtype))
    new, rewards = core.step(sub, state, actions, params, vehicle_policy=vehicle_policy)
    obs_v, obs_i = observations.observe(new, params)
    term, trunc = core.episode_over(new, params)
    return key, new, StepOutput(obs_v, obs_i, rewards, step_info(state, new), term, trunc)


def advance_carry(carry, actions, params, layout, vehicle_policy=None, intruder_policy=None, with_state=False):
    """One adapter step on the packed carry: ``(carry, actions, params) -> (carry, packed output)``, where the carry
    is :func:`pack` of ``(key, state)`` laid out as ``layout``; :func:`advance` or, with a scripted policy,
    :func:`advance_scripted`. ``with_state``: also ``(key, state)`` unpacked, for a user who reads ``env_state``
    after every step (one more output per array, instead of a second call that unpacks the carry)."""
    TRACE_COUNTS["step"] += 1
    key, state = layout.unpack_traced(carry)
    if vehicle_policy is None and intruder_policy is None:
        key, new, out = advance(key, state, actions, params)
    else:
        key, new, out = advance_scripted(key, state, actions, params, vehicle_policy=vehicle_policy,
                                          intruder_policy=intruder_policy)
    if with_state:
        return pack((key, new)), pack(out), (key, new)
    return pack((key, new)), pack(out)


advance_carry_jit = sim_jit(advance_carry, static_argnames=("layout", "vehicle_policy", "intruder_policy",
                                                               "with_state"))
