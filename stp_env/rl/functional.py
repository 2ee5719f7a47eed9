"""The intruder's single-agent view of the simulation core, as pure JAX functions (one env and a batch).

The vehicles are driven by a baseline policy (:data:`stp_env.policies.VEHICLE_POLICIES`, ``switching`` =
``u*`` of eq. 38 by default) inside the step; the only action from outside is the intruder's ``(2,)``.

Horizons (what one intruder episode is):

* ``"intruder"`` (default, for training): the episode starts when the intruder appears and ends (terminated) when
  it leaves, ``t_IAT`` later (Assumption 1). The appearance time ``t_`` is drawn uniformly on the core's step grid
  within ``params.intruder.appear_window``, and the core is reset *at* ``t_`` (:func:`stp_env.sim.reset` with
  ``t_start = t_``): vehicles already in the air start on their nominal trajectories. This skips the steps in
  which the intruder's actions are ignored (before it appears and after it leaves), which are 90 % of a core
  episode for ``town``. Collisions after the intruder has left are not part of its return.
* ``"episode"``: the core's episode (``t_start`` to ``t_end``, see :class:`stp_env.sim.EnvConfig`); terminated
  when every vehicle is done and the intruder gone, truncated at ``t_end`` (``TimeLimit.truncated``).

Keys: each env carries one ``jax.random`` key. A reset splits it into ``(key, k_reset)``, a step into
``(key, k_step)``; seeding an env with ``seed`` sets its key to :func:`key_for_seed` ``(seed)``. The Gymnasium env and
the batched VecEnv follow the same rule, so a VecEnv seeded with ``s`` reproduces ``n`` Gymnasium envs seeded
with ``s, s + 1, ..., s + n - 1`` (SB3's convention).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from stp_env import sim
from stp_env.policies import vehicle_policy
from stp_env.policies.observations import intruder_observation
from stp_env.seeds import check_seed
from stp_env.sim import core, engine
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import COLLIDED, GONE, EnvParams, EnvState

HORIZONS = ("intruder", "episode")


def key_for_seed(seed: int):
    """The env key of an integer seed in ``[0, 2**63 - 1]`` (checked: ``ValueError`` otherwise): a raw ``uint32``
    key, so that batches of keys and states can be selected with ``jnp.where``. Its data are those of
    :func:`stp_env.seeds.prng_key` (``(seed >> 32, seed & 0xFFFFFFFF)``; for seeds below ``2**32`` the key
    ``jax.random.PRNGKey(seed)``), so distinct seeds give distinct keys: nothing is truncated."""
    value = check_seed(seed)
    return jnp.asarray([value >> 32, value & 0xFFFFFFFF], jnp.uint32)


def check_horizon(horizon: str) -> str:
    if horizon not in HORIZONS:
        raise ValueError(f"horizon {horizon!r} is not known; allowed: {', '.join(HORIZONS)}.")
    return horizon


check_vehicle_policy = vehicle_policy  # the one lookup by name (stp_env.policies.vehicles)


def reset_one(key, params: EnvParams, horizon: str) -> EnvState:
    """A new intruder episode (see the module docstring for the horizons)."""
    if horizon == "episode":
        return core.reset(key, params)
    k_time, k_reset = jax.random.split(key)
    lo, hi = params.intruder.appear_window[0], params.intruder.appear_window[1]
    first = jnp.ceil((lo - params.episode.t_start) / params.episode.dt - 1e-4)
    last = jnp.maximum(jnp.floor((hi - params.episode.t_start) / params.episode.dt + 1e-4), first)
    k = first + jnp.floor(jax.random.uniform(k_time, ()) * (last - first + 1.0))
    t_appear = params.episode.t_start + jnp.minimum(k, last) * params.episode.dt
    at_appear = params.replace(episode=dict(t_start=t_appear), intruder=dict(appear_window=jnp.stack([t_appear,
                                                                                                      t_appear])))
    return core.reset(k_reset, at_appear)


def step_one(key, state: EnvState, action, params: EnvParams, vehicle_policy):
    """One core step: the vehicles' baseline policy as the feedback law of every inner control step, and the
    intruder's ``action`` ``(2,)``. Returns ``(state, intruder_reward)``."""
    action = jnp.asarray(action, state.x.dtype)
    actions = jnp.concatenate([jnp.zeros((params.vehicles.n, 2), action.dtype), action[None, :]], axis=0)
    state, rewards = core.step(key, state, actions, params, vehicle_policy=vehicle_policy)
    return state, rewards[-1]


def episode_end(state: EnvState, params: EnvParams, horizon: str):
    """``(terminated, truncated)`` of the intruder's episode."""
    terminated, truncated = core.episode_over(state, params)
    if horizon == "intruder":
        terminated = terminated | (state.intruder_status == GONE)
        truncated = truncated & ~terminated
    return terminated, truncated


def episode_stats(state: EnvState):
    """Numbers reported in the infos: ``|N^RP|`` (eq. 39), collisions, guarantee violations so far, time [s]."""
    return {
        "n_forced": sim.n_forced(state).astype(jnp.int32),
        "collisions": jnp.sum(state.status == COLLIDED).astype(jnp.int32),
        "intruder_collisions": jnp.sum(state.collided_with_intruder).astype(jnp.int32),
        "guarantee_violations": jnp.sum(state.guarantee_violation).astype(jnp.int32),
        "time": state.t,
    }


def intruder_obs(state: EnvState, params: EnvParams, observation: str = "core"):
    """The intruder's observation of set ``observation`` (:mod:`stp_env.policies.observations`)."""
    return intruder_observation(state, params, observation)


# ------------------------------------------------------------------------------------------------ one env
@functools.partial(sim_jit, static_argnames=("horizon", "observation"))
def env_reset(key, params: EnvParams, horizon: str, observation: str = "core"):
    """``(key, state, obs)``: the env key after the reset split, the new state, the intruder's observation."""
    key, k_reset = jax.random.split(key)
    state = reset_one(k_reset, params, horizon)
    return key, state, intruder_obs(state, params, observation)


@functools.partial(sim_jit, static_argnames=("horizon", "vehicle_policy", "observation"))
def env_step(key, state: EnvState, action, params: EnvParams, horizon: str, vehicle_policy,
             observation: str = "core"):
    """``(key, state, obs, reward, terminated, truncated, stats)`` without auto-reset (Gymnasium API)."""
    key, k_step = jax.random.split(key)
    state, reward = step_one(k_step, state, action, params, vehicle_policy)
    terminated, truncated = episode_end(state, params, horizon)
    return (key, state, intruder_obs(state, params, observation), reward, terminated, truncated,
            episode_stats(state))


# ------------------------------------------------------------------------------------------------ batch
@functools.partial(sim_jit, static_argnames=("horizon", "observation"))
def batch_reset(keys, params: EnvParams, horizon: str, observation: str = "core"):
    """:func:`env_reset` for a batch of keys ``(n,)`` (shared among the devices:
    :func:`stp_env.sim.engine.vmap_across_devices`, ``params`` whole to each)."""
    return engine.vmap_across_devices(lambda k, p: env_reset.__wrapped__(k, p, horizon, observation),
                                      shared=params)(keys)


@functools.partial(sim_jit, static_argnames=("horizon", "vehicle_policy", "observation"))
def batch_step(keys, states: EnvState, actions, params: EnvParams, horizon: str, vehicle_policy,
               observation: str = "core"):
    """One step of ``n`` envs with auto-reset, in one compiled program.

    Returns ``(keys, states, obs, rewards, terminated, truncated, terminal_obs, stats)``: ``obs`` are the
    observations after the auto-reset of the finished envs, ``terminal_obs`` and ``stats`` those of the state
    the step reached (before the reset). The reset branch runs only when some env finished (of the device's share,
    when the batch is shared among devices: :func:`stp_env.sim.engine.across_devices`).
    """
    return engine.across_devices(lambda batch, p: _batch_step(*batch, p, horizon, vehicle_policy, observation),
                                 (keys, states, actions), shared=params)


def _batch_step(keys, states: EnvState, actions, params: EnvParams, horizon: str, vehicle_policy, observation: str):
    step = jax.vmap(env_step.__wrapped__, in_axes=(0, 0, 0, None, None, None, None))
    keys, states, obs, rewards, terminated, truncated, stats = step(keys, states, actions, params, horizon,
                                                                    vehicle_policy, observation)
    done = terminated | truncated

    def reset_done(operand):
        keys, states, obs = operand
        new_keys, new_states, new_obs = jax.vmap(lambda k: env_reset.__wrapped__(k, params, horizon, observation))(keys)

        def pick(a, b):
            return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

        return pick(new_keys, keys), jax.tree.map(pick, new_states, states), pick(new_obs, obs)

    keys, next_states, next_obs = jax.lax.cond(jnp.any(done), reset_done, lambda operand: operand,
                                               (keys, states, obs))
    return keys, next_states, next_obs, rewards, terminated, truncated, obs, stats
