"""The co-observation attacker's Stable-Baselines3 ``VecEnv``: ``n`` attacker episodes in one batched JAX state
(:mod:`stp_env.coobservation.learned` describes the episodes, the action and the reward). Imported on first use by
:func:`stp_env.coobservation.learned.make_vec_env` (Stable-Baselines3 is the optional ``rl`` extra)."""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from stp_env.coobservation import attackers
from stp_env.rl.jax_vec_env import JaxVecEnv


class AttackerVecEnv(JaxVecEnv):
    """``n_envs`` attacker episodes (the arguments of :func:`stp_env.coobservation.learned.make_vec_env`; ``base``
    the raw key data the envs' keys are folded from; ``programs`` the compiled ``(batch_reset, batch_step)`` of
    :mod:`stp_env.coobservation.learned`, which builds this env). Attributes as for every batched JAX ``VecEnv``
    (:class:`stp_env.rl.jax_vec_env.JaxVecEnv`); an env's ``info`` at the end of its episode holds ``entered``,
    ``detected`` and ``episode`` (return and length: SB3's ``Monitor`` convention, logged as
    ``rollout/ep_rew_mean``)."""

    def __init__(self, n_envs: int, params, tp, t_window, base, programs, *, action_repeat: int, gamma: float,
                 shaping: float, residual: bool, margin_reward: float = 0.0):
        super().__init__(n_envs, gym.spaces.Box(-2.0, 2.0, (attackers.OBS_SIZE,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self.params, self.tp = params, tp
        self._batch_reset, self._batch_step = programs
        self.action_repeat, self.gamma, self.shaping, self.residual = action_repeat, gamma, shaping, residual
        self.margin_reward = float(margin_reward)
        self._keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(n_envs))
        self.window = jnp.asarray(t_window, jnp.float32)
        self._returns = np.zeros(n_envs)
        self._lengths = np.zeros(n_envs, int)

    def reset(self):
        self._keys, self._states, obs = self._batch_reset(self._keys, self._on_devices("params"),
                                                          self._on_devices("tp"), self.window)
        return np.asarray(obs)

    def step_async(self, actions) -> None:
        super().step_async(actions)  # checked (shape, finite), then held to the action box
        self._actions = jnp.asarray(np.clip(self._actions, -1, 1))

    def step_wait(self):
        if self._states is None:
            raise RuntimeError("Call reset() before step().")
        out = self._batch_step(self._keys, self._states, self._actions, self._on_devices("params"),
                               self._on_devices("tp"), self.window, self.action_repeat, self.gamma, self.shaping,
                               self.residual, self.margin_reward)
        self._keys, self._states = out[0], out[1]
        obs, rew, done, term_obs, stats = jax.device_get(out[2:])
        self._returns += rew
        self._lengths += 1
        infos = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            infos[i] = {"terminal_observation": term_obs[i], "TimeLimit.truncated": False,
                        "entered": bool(stats[i, 0]), "detected": bool(stats[i, 1]),
                        "episode": {"r": float(self._returns[i]), "l": int(self._lengths[i])}}
            self._returns[i], self._lengths[i] = 0.0, 0
        return np.asarray(obs), rew.astype(np.float32), done.astype(bool), infos
