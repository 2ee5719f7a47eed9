"""Batched rollouts: a ``lax.scan`` over steps of the step ``vmap``-ed over episode keys (one compiled program)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from stp_env.sim import core
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import EnvParams


def episode_step(key, state, params: EnvParams, vehicle_policy, intruder_policy):
    """One step: the intruder's action once (the decision rate), the vehicle policy as the feedback law of every
    inner control step (:func:`stp_env.sim.core.step`); returns ``(state, rewards)``."""
    k_i, k_s = jax.random.split(key)
    a_i = intruder_policy(k_i, state, params)
    actions = jnp.concatenate([jnp.zeros((params.n_vehicles, 2), a_i.dtype), a_i[None, :]], axis=0)
    return core.step(k_s, state, actions, params, vehicle_policy=vehicle_policy)


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
    first half of ``split(k)`` and steps with ``split(second half, n_steps)``.

    The program is a ``lax.scan`` over steps of the step ``vmap``-ed over episodes, not a ``vmap`` of a scan: the
    same arithmetic, but tracing a batched scan re-batches its whole body until the batching of its carry settles,
    which made the rollout several times slower to trace and compile."""

    def split(ep_key):
        k_reset, k_run = jax.random.split(ep_key)
        return k_reset, jax.random.split(k_run, n_steps)

    k_reset, k_steps = jax.vmap(split)(episode_keys)
    s0 = jax.vmap(core.reset, in_axes=(0, None))(k_reset, params)

    def one(state, k):
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

    final, traj = jax.lax.scan(jax.vmap(one), s0, jnp.swapaxes(k_steps, 0, 1))
    return final, jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), traj)


def steps_for(params: EnvParams) -> int:
    """Steps from ``t_start`` to ``t_end``."""
    return round(float((params.t_end - params.t_start) / params.dt)) + 1
