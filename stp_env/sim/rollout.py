"""Batched rollouts: a ``lax.scan`` over steps of the step ``vmap``-ed over episode keys (one compiled program), on
the episode engine (:mod:`stp_env.sim.engine`)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from stp_env.sim import core, engine, gates, status
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import EnvParams


def episode_step(key, state, params: EnvParams, vehicle_policy, intruder_policy):
    """One step: the intruder's action once (the decision rate, :func:`intruder_decision`), the vehicle policy as
    the feedback law of every inner control step (:func:`stp_env.sim.core.step`); returns ``(state, rewards)``."""
    k_i, k_s = jax.random.split(key)
    a_i = intruder_decision(intruder_policy, k_i, state, params)
    actions = jnp.concatenate([jnp.zeros((params.vehicles.n, 2), a_i.dtype), a_i[None, :]], axis=0)
    return core.step(k_s, state, actions, params, vehicle_policy=vehicle_policy)


def intruder_decision(intruder_policy, key, state, params: EnvParams):
    """The scripted intruder's action ``intruder_policy(key, state, params)``, computed only while the intruder is
    present in some episode of the batch (:func:`stp_env.sim.gates.when_any`): the core ignores an absent
    intruder's action, so the zero action of the skip changes nothing."""
    shape = jax.eval_shape(intruder_policy, key, state, params)
    return gates.when_any(status.intruder_present(state), lambda k: intruder_policy(k, state, params),
                          lambda k: jnp.zeros(shape.shape, shape.dtype), key)


@functools.partial(sim_jit, static_argnames=("vehicle_policy", "intruder_policy", "n_envs", "n_steps", "record"))
def rollout(key, params: EnvParams, vehicle_policy, intruder_policy, n_envs: int, n_steps: int,
            record: bool = False):
    """Run ``n_envs`` episodes of ``n_steps`` steps.

    Returns ``(final_state, trajectory)``: the final :class:`EnvState` batched over episodes, and with
    ``record=True`` a dict of per-step arrays ``(n_envs, n_steps, ...)``: ``t``, ``x`` (vehicle states), ``status``,
    ``mode``, ``intruder_x``, ``intruder_status``, ``rewards`` (``None`` otherwise). Episode ``i`` uses
    ``jax.random.fold_in(key, i)``; steps after the episode ends (every vehicle done and the intruder gone, or
    ``t_end``) leave the state unchanged.
    """
    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(n_envs))
    return rollout_keys(keys, params, vehicle_policy, intruder_policy, n_steps, record)


def rollout_keys(episode_keys, params: EnvParams, vehicle_policy, intruder_policy, n_steps: int,
                 record: bool = False):
    """:func:`rollout` of one episode per key of ``episode_keys`` ``(B,)``: the episode keyed ``k`` resets with the
    first half of ``split(k)`` and steps with ``split(second half, n_steps)`` (:func:`stp_env.sim.engine.episodes`:
    a ``lax.scan`` over steps of the step ``vmap``-ed over episodes). Steps after the episode is over
    (:func:`~stp_env.sim.core.episode_over`) leave the state unchanged and earn nothing."""
    return engine.episodes(episode_keys, lambda k: core.reset(k, params),
                           lambda state, k: episode_step(k, state, params, vehicle_policy, intruder_policy), n_steps,
                           stop=lambda state: over(state, params), record=record_step if record else None)


def over(state, params: EnvParams):
    """The rollouts' stop rule: every vehicle done and the intruder gone, or the time limit
    (:func:`~stp_env.sim.core.episode_over`)."""
    term, trunc = core.episode_over(state, params)
    return term | trunc


def record_step(state, rewards) -> dict:
    """What a recorded rollout keeps of each step: ``t``, ``x``, ``status``, ``mode``, ``intruder_x``,
    ``intruder_status`` of the state after it, and its ``rewards``."""
    return {"t": state.t, "x": state.x, "status": state.status, "mode": state.mode, "intruder_x": state.intruder_x,
            "intruder_status": state.intruder_status, "rewards": rewards}


def steps_for(params: EnvParams) -> int:
    """Steps from ``t_start`` to ``t_end``."""
    return round(float((params.episode.t_end - params.episode.t_start) / params.episode.dt)) + 1
