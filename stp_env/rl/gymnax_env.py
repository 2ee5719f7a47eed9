"""The intruder's view of the game as a gymnax ``Environment`` (gymnax 1.x): learners written for gymnax (PureJaxRL
style PPO, this package's :mod:`stp_env.rl.jax_ppo`) train on it inside one compiled program, with no host round
trip per step.

``IntruderGymnaxEnv(params, horizon=..., vehicle_policy=..., observation=...)`` subclasses gymnax's own
``gymnax.environments.environment.Environment``, so its ``reset(key, params)`` and ``step(key, state, action,
params)`` are gymnax's: ``step`` splits ``key`` into a step key and a reset key, advances with :meth:`step_env`,
and resets the episode in the same call when it ended (``terminated | truncated``), returning ``(obs, state,
reward, terminated, truncated, info)`` with ``info["final_observation"]`` the observation the step reached. gymnax's
wrappers (``LogWrapper``, ``FlattenObservationWrapper``) take it as any gymnax env (``tests/test_jax_rl.py``).

What one episode is, the rewards and the observations are those of the Gymnasium and SB3 views
(:mod:`stp_env.rl.functional`): the environment's state is the core's :class:`stp_env.sim.EnvState`, ``params``
are the core's :class:`stp_env.sim.EnvParams` (``default_params`` the ones the env was made with), and

* :meth:`reset_env` ``(key, params)`` is :func:`stp_env.rl.functional.reset_one` (with ``horizon="episode"``,
  :func:`stp_env.sim.reset` itself, so that an episode keyed as the evaluator keys one is the evaluator's episode);
* :meth:`step_env` ``(key, state, action, params)`` is one :func:`stp_env.sim.step` with the vehicles on their
  baseline policy and the intruder's ``action`` ``(2,)`` in ``[-1, 1]`` (clipped by the core);
* ``info`` holds the episode's numbers so far (``n_forced`` = ``|N^RP|`` of eq. 39, ``collisions``,
  ``intruder_collisions``, ``guarantee_violations``, ``time``) and ``discount`` (0 at a termination), besides the
  three entries gymnax's ``step`` adds.

:meth:`IntruderGymnaxEnv.batch_step` is ``jax.vmap(env.step)`` over a batch of envs (the same transitions, floats
to their last bits) for trainers: it computes the resets only when some env of the batch (of a device's share)
ended, where gymnax's ``step`` under ``vmap`` computes every env's reset at every step (a reset at the intruder's
appearance costs several steps: it places the vehicles on their plans and draws the spawn).

Needs the ``jax-rl`` extra (``pip install 'stp-env[jax-rl]'``: gymnax, which brings flax).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from gymnax.environments import environment, spaces

from stp_env.baselines.observations import check_observation, observation_size
from stp_env.rl import functional as F
from stp_env.sim import engine
from stp_env.sim.types import EnvParams, EnvState

OBS_BOUND = 2.0
"""Every entry of an intruder observation is in ``[-2, 2]`` (:mod:`stp_env.baselines.observations`)."""


class IntruderGymnaxEnv(environment.Environment):
    """The intruder's gymnax environment (see the module docstring).

    Args:
        params: the core's parameters (:func:`stp_env.rl.train.build_params`, or
            :func:`stp_env.assembly.params_for`); ``default_params``.
        horizon: ``"intruder"`` (the episode runs from the intruder's appearance to its departure) or
            ``"episode"`` (the core's whole episode).
        vehicle_policy: a name of :data:`stp_env.baselines.VEHICLE_POLICIES` (``"switching"``: ``u*`` with the HJ
            filter; ``"worst"``: the buffer game's worst vehicles, which read ``V^B``).
        observation: the intruder's observation set (``"core"`` or ``"game"``, which reads ``V^B``).
    """

    def __init__(self, params: EnvParams, *, horizon: str = "intruder", vehicle_policy: str = "switching",
                 observation: str = "core"):
        super().__init__()
        if not isinstance(params, EnvParams):
            raise ValueError(f"params must be the core's EnvParams; got {type(params).__name__}.")
        self.horizon = F.check_horizon(horizon)
        self.vehicle_policy_name = vehicle_policy
        self._vehicle_policy = F.check_vehicle_policy(vehicle_policy)
        self.observation = check_observation(observation)
        self._params = params
        self._obs_size = observation_size(params, observation)  # reads V^B's presence: ValueError if missing

    @property
    def default_params(self) -> EnvParams:
        return self._params

    @property
    def name(self) -> str:
        return "stp-env/Intruder"

    @property
    def num_actions(self) -> int:
        return 2

    def action_space(self, params: EnvParams | None = None) -> spaces.Box:
        """``Box(-1, 1, (2,))``: speed and turn rate, mapped linearly onto the intruder's bounds."""
        return spaces.Box(-1.0, 1.0, (2,), jnp.float32)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        return spaces.Box(-OBS_BOUND, OBS_BOUND, (self._obs_size,), jnp.float32)

    def reset_env(self, key, params: EnvParams):
        state = F.reset_one(key, params, self.horizon)
        return self.get_obs(state, params), state

    def step_env(self, key, state: EnvState, action, params: EnvParams):
        state, reward = F.step_one(key, state, action, params, self._vehicle_policy)
        terminated, _ = F.episode_end(state, params, self.horizon)
        info = {**F.episode_stats(state), "discount": jnp.where(terminated, 0.0, 1.0).astype(jnp.float32)}
        return self.get_obs(state, params), state, reward.astype(jnp.float32), terminated, info

    def get_obs(self, state: EnvState, params: EnvParams | None = None, key=None):
        return F.intruder_obs(state, self._params if params is None else params, self.observation)

    def is_terminated(self, state: EnvState, params: EnvParams):
        return F.episode_end(state, params, self.horizon)[0]

    def is_truncated(self, state: EnvState, params: EnvParams):
        return F.episode_end(state, params, self.horizon)[1]

    # ------------------------------------------------------------------------------------------- for trainers
    def batch_step(self, keys, states: EnvState, actions, params: EnvParams | None = None):
        """``jax.vmap(self.step, in_axes=(0, 0, 0, None))(keys, states, actions, params)``, with each env's reset
        computed only in a step where some env of the batch ended; the batch is shared among the devices of JAX's
        default backend (:func:`stp_env.sim.engine.across_devices`). The same transitions, ends and resets; being
        another compiled program, floats may differ in their last bits (``docs/numerics.md``). Jittable; call it
        inside the trainer's compiled program."""
        params = self._params if params is None else params
        return engine.across_devices(lambda batch, p: self._batch_step(*batch, p), (keys, states, actions),
                                     shared=params)

    def _batch_step(self, keys, states, actions, params):
        split = jax.vmap(jax.random.split)(keys)
        obs_st, st, reward, terminated, info = jax.vmap(self.step_env, in_axes=(0, 0, 0, None))(
            split[:, 0], states, actions, params)
        truncated = jax.vmap(self.is_truncated, in_axes=(0, None))(st, params)
        done = terminated | truncated

        def with_resets(operand):
            obs, st = operand
            obs_re, st_re = jax.vmap(self.reset_env, in_axes=(0, None))(split[:, 1], params)

            def pick(a, b):
                return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

            return pick(obs_re, obs), jax.tree.map(pick, st_re, st)

        obs, st_out = jax.lax.cond(jnp.any(done), with_resets, lambda operand: operand, (obs_st, st))
        info = {**info, "terminated": terminated, "truncated": truncated, "final_observation": obs_st}
        return obs, st_out, reward, terminated, truncated, info
