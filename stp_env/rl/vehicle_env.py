"""The after-avoidance vehicle's view for Stable-Baselines3: a single-agent ``VecEnv`` for learning a vehicle policy
under the HJ filters. The episode (reset, step, reward, observation, ends) and the evaluation of vehicle policies
(:func:`stp_env.rl.ego.evaluate_ego`) are :mod:`stp_env.rl.ego`'s.
"""

from __future__ import annotations

import functools

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from stp_env.rl.ego import (
    STAT_NAMES,
    check_params,
    ego_done,
    ego_obs,
    ego_reset,
    ego_stats,
    ego_step,
)
from stp_env.rl.jax_vec_env import JaxVecEnv
from stp_env.sim import engine, observations
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import EnvParams


# ------------------------------------------------------------------------------------------------ batched env
@functools.partial(sim_jit, static_argnames=("intruder",))
def batch_reset(keys, params: EnvParams, intruder):
    def one(key, params):
        key, k_reset = jax.random.split(key)
        s, ego = ego_reset(k_reset, params, intruder)
        return key, s, ego, ego_obs(s, ego, params)

    return engine.vmap_across_devices(one, shared=params)(keys)


@functools.partial(sim_jit, static_argnames=("intruder",))
def batch_step(keys, states, egos, actions, params: EnvParams, intruder, energy, late_limit):
    """One step of ``n`` ego envs with auto-reset: ``(keys, states, egos, obs, rewards, terminated, truncated,
    terminal_obs, stats)``."""
    def one(key, s, ego, a, params):
        key, k = jax.random.split(key)
        s, r = ego_step(k, s, ego, a, params, energy)
        term, trunc = ego_done(s, ego, params, late_limit)
        return key, s, r, term, trunc, ego_obs(s, ego, params), ego_stats(s, ego, params)

    step = engine.vmap_across_devices(one, shared=params)
    keys, states, rewards, term, trunc, obs, stats = step(keys, states, egos, actions)
    done = term | trunc

    def reset_done(operand):
        keys, states, egos, obs = operand
        new_keys, new_states, new_egos, new_obs = batch_reset.__wrapped__(keys, params, intruder)

        def pick(a, b):
            return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

        return (pick(new_keys, keys), jax.tree.map(pick, new_states, states), pick(new_egos, egos),
                pick(new_obs, obs))

    keys, next_states, next_egos, next_obs = jax.lax.cond(jnp.any(done), reset_done, lambda o: o,
                                                          (keys, states, egos, obs))
    return keys, next_states, next_egos, next_obs, rewards, term, trunc, obs, stats


class EgoVehicleVecEnv(JaxVecEnv):
    """``n_envs`` ego-vehicle envs in one batched JAX state (module docstring); SB3's ``VecEnv`` conventions as
    :class:`stp_env.rl.IntruderVecEnv` (seeding, auto-reset with ``terminal_observation``).

    Args:
        n_envs: batch size.
        params: the environment (:func:`stp_env.assembly.params_for`; with ``V^B`` if the intruder reads it).
        intruder: a jittable intruder policy (``stp_env.evaluation.resolve_intruder(name)``).
        energy: weight of the energy term per second at full speed.
        late_limit: seconds after the ego's STA at which its episode is truncated.
    """

    def __init__(self, n_envs: int, params: EnvParams, intruder, *, energy: float = 0.002, late_limit: float = 60.0):
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise ValueError(f"n_envs must be an integer >= 1; got {n_envs!r}.")
        for name, value in (("energy", energy), ("late_limit", late_limit)):
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0; got {value!r}.")
        self.params, self.intruder = check_params(params), intruder
        self.energy, self.late_limit = float(energy), float(late_limit)
        size = observations.vehicle_observation_size(params)
        super().__init__(n_envs, gym.spaces.Box(-2.0, 2.0, (size,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self._keys = self._egos = None

    def reset(self) -> np.ndarray:
        keys = jnp.asarray(self._keys_for_reset())
        self._keys, self._states, self._egos, obs = batch_reset(keys, self._on_devices("params"), self.intruder)
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return np.asarray(obs)

    def step_wait(self):
        if self._states is None:
            raise RuntimeError("Call reset() before step().")
        if self._actions is None:
            raise RuntimeError("Call step_async() before step_wait().")
        out = batch_step(self._keys, self._states, self._egos, jnp.asarray(self._actions),
                         self._on_devices("params"), self.intruder, self.energy, self.late_limit)
        self._keys, self._states, self._egos = out[0], out[1], out[2]
        self._actions = None
        obs, rewards, term, trunc, terminal_obs, stats = jax.device_get(out[3:])
        dones = term | trunc
        columns = [np.asarray(stats[name]).tolist() for name in STAT_NAMES]
        infos = [dict(zip(STAT_NAMES, values)) for values in zip(*columns)]
        for i in np.flatnonzero(dones).tolist():
            infos[i]["terminal_observation"] = terminal_obs[i]
            infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self._keys = self._egos = None
        super().close()
