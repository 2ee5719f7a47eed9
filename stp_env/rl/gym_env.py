"""The intruder as a single-agent Gymnasium environment (the vehicles run a baseline policy inside the core).

================  ==========================================================================================
observation       ``Box(-2, 2, (8 + 7K,), float32)``: :func:`stp_env.sim.observe`'s intruder row (present flag,
                  position, heading, ``tau / t_IAT``, time to appear, ``|N^RP| / N``, then the ``K`` nearest
                  flying vehicles in its body frame with their avoid values ``V^A`` and forced flags);
                  ``observation="game"`` appends the buffer game's features (31 more,
                  :mod:`stp_env.policies.observations`)
action            ``Box(-1, 1, (2,), float32)``: speed in ``[v_min, v_max]`` and turn rate in
                  ``[-omega_max, omega_max]`` of the intruder (clipped; NaN or a wrong shape is a ``ValueError``)
reward            the core's intruder reward (:class:`stp_env.sim.RewardConfig`: ``forced`` per vehicle newly
                  forced to avoid, ``intruder_collision`` per collision it causes, ``shaping`` by ``min V^A``)
episode           ``horizon="intruder"``: from its appearance until it leaves (``t_IAT``); ``"episode"``: the
                  core's episode. See :mod:`stp_env.rl.functional`.
info              ``n_forced`` (``|N^RP|``, eq. 39), ``kbar``, ``collisions``, ``intruder_collisions``,
                  ``guarantee_violations``, ``time`` [s]
================  ==========================================================================================

Seeding: ``reset(seed=s)`` sets the env's key to ``key_for_seed(s)``; later resets continue from it, so episodes
after a seeded reset are reproducible. ``reset()`` without a seed before any seeded reset draws the key from
Gymnasium's ``np_random``.
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import gymnasium as gym
import jax
import numpy as np

from stp_env import assembly, sim
from stp_env.policies.observations import check_observation, observation_size
from stp_env.rl import functional as F
from stp_env.sim.jit import sim_jit
from stp_env.sim.packing import DeviceCarry, Layout, pack


def build_params(scenario="town", config: sim.EnvConfig | None = None, *, params=None, store=None) -> sim.EnvParams:
    """``params`` if given, else :func:`stp_env.assembly.params_for` of the scenario and config."""
    if params is not None:
        if scenario != "town" or config is not None:
            raise ValueError("Pass either params or scenario/config, not both.")
        return params
    return assembly.params_for(scenario, sim.EnvConfig() if config is None else config, store=store, progress=False)


def check_action(action, shape) -> np.ndarray:
    action = np.asarray(action, dtype=np.float32)
    if action.shape != shape:
        raise ValueError(f"actions must have shape {shape}; got {action.shape}.")
    if not np.all(np.isfinite(action)):
        raise ValueError("actions must be finite (no NaN or inf).")
    return action


def _step_packed(words, action, params, layout, horizon, vehicle_policy, observation):
    """:func:`stp_env.rl.functional.env_step` on the packed ``(key, state)`` (:mod:`stp_env.sim.packing`): the new
    carry and the outputs ``(obs, reward, terminated, truncated, stats)``, each packed into one array."""
    key, state = layout.unpack_traced(words)
    key, state, *out = F.env_step.__wrapped__(key, state, action, params, horizon, vehicle_policy, observation)
    return pack((key, state)), pack(tuple(out))


_step_packed_jit = sim_jit(_step_packed, static_argnames=("layout", "horizon", "vehicle_policy", "observation"))


class IntruderEnv(gym.Env):
    """The intruder's view of a scenario (see the module docstring).

    Args:
        scenario: registry name or :class:`stp_env.scenarios.Scenario` (default ``"town"``).
        config: :class:`stp_env.sim.EnvConfig` (rewards, wind, spawn, safety filter).
        horizon: ``"intruder"`` or ``"episode"``.
        vehicle_policy: a name in :data:`stp_env.policies.VEHICLE_POLICIES` (``"switching"``: ``u*``, eq. 38).
        params: prebuilt :class:`stp_env.sim.EnvParams` (instead of scenario and config).
        observation: the intruder's observation set (:mod:`stp_env.policies.observations`: ``"core"``, or
            ``"game"`` with the buffer game's features, which needs ``V^B`` in the params).
    """

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, scenario="town", config: sim.EnvConfig | None = None, *, horizon: str = "intruder",
                 vehicle_policy: str = "switching", params: sim.EnvParams | None = None, store=None,
                 observation: str = "core"):
        self.horizon = F.check_horizon(horizon)
        self.vehicle_policy_name = vehicle_policy
        self._vehicle_policy = F.check_vehicle_policy(vehicle_policy)
        self.params = build_params(scenario, config, params=params, store=store)
        self.observation = check_observation(observation)
        size = observation_size(self.params, self.observation)
        self.observation_space = gym.spaces.Box(-2.0, 2.0, (size,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.render_mode = None
        self.kbar = int(self.params.intruder.kbar)
        self._carry = DeviceCarry()  # (key, state), packed on the device (stp_env.sim.packing)
        self._out_layout = None

    @property
    def state(self) -> sim.EnvState | None:
        """The core's state (``None`` before the first reset)."""
        tree = self._carry.tree
        return None if tree is None else tree[1]

    @property
    def _key(self):
        tree = self._carry.unpacked()
        return None if tree is None else tree[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if options:
            raise ValueError(f"IntruderEnv.reset takes no options; got {sorted(options)}.")
        key = F.key_for_seed(seed) if seed is not None else None  # checked before anything changes
        super().reset(seed=seed)
        if key is None:
            key = self._key
        if key is None:
            key = F.key_for_seed(int(self.np_random.integers(0, 2**32)))
        key, state, obs = F.env_reset(key, self.params, self.horizon, self.observation)
        self._carry.set((key, state))
        return np.array(obs), {"kbar": self.kbar, "time": float(state.t)}

    def step(self, action):
        if self._carry.words is None:
            raise RuntimeError("Call reset() before step().")
        action = check_action(action, (2,))
        static = {"horizon": self.horizon, "vehicle_policy": self._vehicle_policy, "observation": self.observation}
        if self._out_layout is None:  # the shapes are fixed for the env's life
            outputs = jax.eval_shape(functools.partial(F.env_step.__wrapped__, **static), *self._carry.unpacked(),
                                     action, self.params)[2:]
            self._out_layout = Layout.of(tuple(outputs))
        words = self._carry.advance(_step_packed_jit, action, self.params, **static)
        obs, reward, terminated, truncated, stats = self._out_layout.unpack(np.asarray(words))
        info = {name: (float(value) if name == "time" else int(value)) for name, value in stats.items()}
        info["kbar"] = self.kbar
        return np.array(obs), float(reward), bool(terminated), bool(truncated), info
