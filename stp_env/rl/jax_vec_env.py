"""The base of the project's Stable-Baselines3 ``VecEnv``s whose envs are one batched JAX state.

Subclasses (:class:`stp_env.rl.vec_env.IntruderVecEnv`, the co-observation attacker's
:class:`stp_env.coobservation.learned.AttackerVecEnv`) hold the batch and implement ``reset()`` and ``step_wait()``
(one compiled call each); this base gives them the rest of SB3's ``VecEnv`` contract the same way:

* ``step_async`` checks the actions (shape ``(n_envs, action_dim)``, finite) before anything is stored;
* the envs share one set of attributes: ``get_attr(name)`` returns the shared attribute once per index, except
  the per-env values a subclass lists in ``PER_ENV_ATTRS`` (read by its ``_per_env(name)``, an array over envs);
  ``set_attr`` sets a shared attribute on every env at once (``indices=None``) and refuses the per-env and the
  private ones; ``env_method`` calls the shared method once per index;
* ``env_is_wrapped`` is ``False`` (no Gymnasium wrappers inside), ``get_images`` ``None`` per env, and ``close``
  drops the batch;
* ``_on_devices(name)``: the attribute ``name`` (the environment's parameters) on every device the batch is shared
  among (:func:`stp_env.sim.engine.replicate`), copied once and again only when the attribute is replaced, so that
  a step does not copy the tables to the other devices.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from stp_env.rl.gym_env import check_action


class JaxVecEnv(VecEnv):
    """See the module docstring. Subclasses set ``self._states`` (``None`` before the first reset) and read
    ``self._actions`` in ``step_wait``."""

    PER_ENV_ATTRS: ClassVar[tuple[str, ...]] = ()
    render_mode = None

    def __init__(self, num_envs: int, observation_space: gym.spaces.Space, action_space: gym.spaces.Box):
        super().__init__(num_envs, observation_space, action_space)
        self._states = None
        self._actions = None

    def _keys_for_reset(self) -> np.ndarray:
        """The env keys ``(n_envs, 2)`` a ``reset()`` starts from, by SB3's seeding rule: env ``i`` seeded with
        ``s`` gets :func:`stp_env.rl.functional.key_for_seed` ``(s)``; an unseeded env keeps its key stream (its
        current key in ``self._keys``); before the first reset, unseeded envs draw seeds as ``VecEnv.seed(None)``
        does."""
        from stp_env.rl.functional import key_for_seed

        current = getattr(self, "_keys", None)
        if current is None and any(s is None for s in self._seeds):
            drawn = self.seed(None)
            self._seeds = [s if s is not None else d for s, d in zip(self._seeds, drawn)]
        keys = np.array(current) if current is not None else np.zeros((self.num_envs, 2), np.uint32)
        for i, seed in enumerate(self._seeds):
            if seed is not None:
                keys[i] = np.asarray(key_for_seed(seed))
        return keys

    def _on_devices(self, name: str):
        """The attribute ``name`` on every device a shared batch runs on (see the module docstring)."""
        from stp_env.sim import engine

        value = getattr(self, name)
        cache = self.__dict__.setdefault("_replicas", {})
        if name not in cache or cache[name][0] is not value:
            cache[name] = (value, engine.replicate(value))
        return cache[name][1]

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = check_action(actions, (self.num_envs, *self.action_space.shape))

    def close(self) -> None:
        self._states = None

    def _per_env(self, name: str) -> np.ndarray:
        raise AttributeError(name)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        idx = list(self._get_indices(indices))
        if attr_name in self.PER_ENV_ATTRS:
            if self._states is None:
                raise AttributeError(f"{attr_name!r} is known after reset().")
            values = self._per_env(attr_name)
            return [values[i].item() for i in idx]
        value = getattr(self, attr_name)
        return [value for _ in idx]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        idx = list(self._get_indices(indices))
        if sorted(idx) != list(range(self.num_envs)):
            raise ValueError(f"{type(self).__name__} envs share their attributes: set_attr applies to every env at "
                             f"once (indices=None); got indices {indices!r}.")
        if attr_name in self.PER_ENV_ATTRS or attr_name.startswith("_"):
            raise ValueError(f"{attr_name!r} cannot be set.")
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list:
        method = getattr(self, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
