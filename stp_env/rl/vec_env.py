"""A native Stable-Baselines3 ``VecEnv`` of ``n`` intruder envs backed by the batched JAX core.

One call of :func:`stp_env.rl.functional.batch_step` (one compiled program: ``vmap`` of the core step, the
vehicles' baseline policy, the observations, and the auto-reset of the finished envs) per ``step``; no
subprocesses, no per-env Python loop.

SB3 conventions kept (as in ``DummyVecEnv`` over :class:`stp_env.rl.IntruderEnv`, which it reproduces step for
step for the same seeds):

* ``seed(s)`` gives env ``i`` the seed ``s + i`` at the next ``reset()``; envs without a seed keep their key stream
  (the first ``reset()`` without any seed draws seeds from ``np.random``, as ``VecEnv.seed(None)`` does).
* A finished env is reset inside the step: its ``info`` holds ``terminal_observation`` and
  ``TimeLimit.truncated`` (truncated and not terminated), and ``reset_infos[i]`` the new episode's reset info.
* Every info has ``n_forced`` (``|N^RP|``), ``kbar``, ``collisions``, ``intruder_collisions``,
  ``guarantee_violations`` and ``time`` [s] (the values of the state the step reached).
* The envs share one :class:`stp_env.sim.EnvParams`: attributes as for every batched JAX ``VecEnv`` of the
  project (:class:`stp_env.rl.jax_vec_env.JaxVecEnv`), the per-env ones being :attr:`IntruderVecEnv.PER_ENV_ATTRS`.
"""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from stp_env import sim
from stp_env.policies.observations import check_observation, observation_size
from stp_env.rl import functional as F
from stp_env.rl.gym_env import build_params
from stp_env.rl.jax_vec_env import JaxVecEnv

STAT_NAMES = ("n_forced", "collisions", "intruder_collisions", "guarantee_violations")
INFO_NAMES = (*STAT_NAMES, "time")


class IntruderVecEnv(JaxVecEnv):
    """``n_envs`` intruder envs in one batched JAX state (see the module docstring).

    Args:
        n_envs: batch size.
        scenario, config, horizon, vehicle_policy, params, store, observation: as for
            :class:`stp_env.rl.IntruderEnv`.
    """

    PER_ENV_ATTRS = ("n_forced", "time", "intruder_status")

    def __init__(self, n_envs: int, scenario="town", config: sim.EnvConfig | None = None, *,
                 horizon: str = "intruder", vehicle_policy: str = "switching", params: sim.EnvParams | None = None,
                 store=None, observation: str = "core"):
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise ValueError(f"n_envs must be an integer >= 1; got {n_envs!r}.")
        self.horizon = F.check_horizon(horizon)
        self.vehicle_policy_name = vehicle_policy
        self._vehicle_policy = F.check_vehicle_policy(vehicle_policy)
        self.params = build_params(scenario, config, params=params, store=store)
        self.kbar = int(self.params.intruder.kbar)
        self.observation = check_observation(observation)
        size = observation_size(self.params, self.observation)
        super().__init__(n_envs, gym.spaces.Box(-2.0, 2.0, (size,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self._keys = None

    # ---------------------------------------------------------------------------------------------- core API
    def reset(self) -> np.ndarray:
        keys = jnp.asarray(self._keys_for_reset())
        self._keys, self._states, obs = F.batch_reset(keys, self._on_devices("params"), self.horizon,
                                                      self.observation)
        obs = np.asarray(obs)
        times = np.asarray(self._states.t).tolist()
        self.reset_infos = [{"kbar": self.kbar, "time": t} for t in times]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_wait(self):
        if self._states is None:
            raise RuntimeError("Call reset() before step().")
        if self._actions is None:
            raise RuntimeError("Call step_async() before step_wait().")
        out = F.batch_step(self._keys, self._states, self._actions, self._on_devices("params"), self.horizon,
                           self._vehicle_policy, self.observation)
        self._keys, self._states = out[0], out[1]
        self._actions = None
        obs, rewards, terminated, truncated, terminal_obs, stats, new_times = jax.device_get(
            (out[2], out[3], out[4], out[5], out[6], out[7], self._states.t))
        dones = terminated | truncated
        columns = [stats[name].tolist() for name in STAT_NAMES] + [stats["time"].tolist()]
        infos = [dict(zip(INFO_NAMES, values)) for values in zip(*columns)]
        for info in infos:
            info["kbar"] = self.kbar
        for i in np.flatnonzero(dones).tolist():
            infos[i]["terminal_observation"] = terminal_obs[i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            self.reset_infos[i] = {"kbar": self.kbar, "time": float(new_times[i])}
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self._keys = None
        super().close()

    def _per_env(self, name: str) -> np.ndarray:
        if name == "n_forced":
            return np.asarray(jax.vmap(sim.n_forced)(self._states))
        if name == "time":
            return np.asarray(self._states.t)
        return np.asarray(self._states.intruder_status)
