"""Batched rollouts: ``vmap`` over episode keys of a ``lax.scan`` over steps (one compiled program)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from stp_env.sim import core
from stp_env.sim.types import EnvParams


def episode_step(key, state, params: EnvParams, vehicle_policy, intruder_policy):
    """One step: the intruder's action once (the decision rate), the vehicle policy as the feedback law of every
    inner control step (:func:`stp_env.sim.core.step`); returns ``(state, rewards)``."""
    k_i, k_s = jax.random.split(key)
    a_i = intruder_policy(k_i, state, params)
    actions = jnp.concatenate([jnp.zeros((params.n_vehicles, 2), a_i.dtype), a_i[None, :]], axis=0)
    return core.step(k_s, state, actions, params, vehicle_policy=vehicle_policy)


@functools.partial(jax.jit, static_argnames=("vehicle_policy", "intruder_policy", "n_envs", "n_steps", "record"))
def rollout(key, params: EnvParams, vehicle_policy, intruder_policy, n_envs: int, n_steps: int,
            record: bool = False):
    """Run ``n_envs`` episodes of ``n_steps`` steps.

    Returns ``(final_state, trajectory)``: the final :class:`EnvState` batched over episodes, and with
    ``record=True`` a dict of per-step arrays ``(n_envs, n_steps, ...)``: ``t``, ``x`` (vehicle states), ``status``,
    ``mode``, ``intruder_x``, ``intruder_status``, ``rewards`` (``None`` otherwise). Episode ``i`` uses
    ``jax.random.fold_in(key, i)``; steps after the episode ends (every vehicle done and the intruder gone, or
    ``t_end``) leave the state unchanged.
    """

    def one(ep_key):
        k_reset, k_run = jax.random.split(ep_key)
        s0 = core.reset(k_reset, params)

        def body(state, k):
            new, rewards = episode_step(k, state, params, vehicle_policy, intruder_policy)
            term, trunc = core.episode_over(state, params)
            over = term | trunc
            new = jax.tree.map(lambda a, b: jnp.where(over, a, b), state, new)
            rewards = jnp.where(over, 0.0, rewards)
            out = None
            if record:
                out = {"t": new.t, "x": new.x, "status": new.status, "mode": new.mode,
                       "intruder_x": new.intruder_x, "intruder_status": new.intruder_status, "rewards": rewards}
            return new, out

        return jax.lax.scan(body, s0, jax.random.split(k_run, n_steps))

    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(n_envs))
    return jax.vmap(one)(keys)


def steps_for(params: EnvParams) -> int:
    """Steps from ``t_start`` to ``t_end``."""
    return round(float((params.t_end - params.t_start) / params.dt)) + 1
