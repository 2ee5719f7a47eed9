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

:meth:`GameGymnaxEnv.batch_step` (of this env and of :class:`VehicleGymnaxEnv`, the ego vehicle's view) is
``jax.vmap(env.step)`` over a batch of envs (the same transitions, floats to their last bits) for trainers: it
computes the resets of the envs that ended only, where gymnax's ``step`` under ``vmap`` computes every env's reset
at every step (a reset costs several steps: the intruder's places the vehicles on their plans and draws the spawn;
the ego vehicle's flies a whole intruder episode).

Needs the ``jax-rl`` extra (``pip install 'stp-env[jax-rl]'``: gymnax, which brings flax).
Importing this module imports ``gymnax``, and gymnax makes a JAX array at import, which starts JAX's backend:
choose the CPU device count (:func:`stp_env.set_cpu_devices`) before importing it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from gymnax.environments import environment, spaces

from stp_env.policies.observations import check_observation, observation_size
from stp_env.rl import functional as F
from stp_env.sim import engine, observations
from stp_env.sim.types import EnvParams, EnvState

OBS_BOUND = 2.0
"""Every entry of an intruder observation is in ``[-2, 2]`` (:mod:`stp_env.policies.observations`)."""


RESET_SHARE = 8
"""The resets of a batch of ``n`` envs are computed ``ceil(n / RESET_SHARE)`` at a time, for the envs that ended."""


class GameGymnaxEnv(environment.Environment):
    """What this module's environments share: their parameters (``default_params``), a ``Box(-1, 1, (2,))`` action
    and a ``Box(-2, 2, (m,))`` observation (``m`` set by the subclass in ``_obs_size``), and the batched step
    trainers call."""

    _params: EnvParams
    _obs_size: int

    @property
    def default_params(self) -> EnvParams:
        return self._params

    @property
    def num_actions(self) -> int:
        return 2

    def action_space(self, params: EnvParams | None = None) -> spaces.Box:
        """``Box(-1, 1, (2,))``: speed and turn rate, mapped linearly onto the agent's bounds."""
        return spaces.Box(-1.0, 1.0, (2,), jnp.float32)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        return spaces.Box(-OBS_BOUND, OBS_BOUND, (self._obs_size,), jnp.float32)

    def batch_step(self, keys, states: EnvState, actions, params: EnvParams | None = None):
        """``jax.vmap(self.step, in_axes=(0, 0, 0, None))(keys, states, actions, params)``, with the resets computed
        for the envs that ended only (in chunks of ``ceil(n / RESET_SHARE)``, as many chunks as it takes; none in a
        step where no env ended), where gymnax's ``step`` under ``vmap`` computes every env's reset at every step;
        the batch is shared among the devices of JAX's default backend (:func:`stp_env.sim.engine.across_devices`).
        The same transitions, ends and resets (each env's reset from its own key); being another compiled program,
        floats may differ in their last bits (``docs/numerics.md``). Jittable; call it inside the trainer's compiled
        program."""
        params = self._params if params is None else params
        return engine.across_devices(lambda batch, p: self._batch_step(*batch, p), (keys, states, actions),
                                     shared=params)

    def _batch_step(self, keys, states, actions, params):
        split = jax.vmap(jax.random.split)(keys)
        obs_st, st, reward, terminated, info = jax.vmap(self.step_env, in_axes=(0, 0, 0, None))(
            split[:, 0], states, actions, params)
        truncated = jax.vmap(self.is_truncated, in_axes=(0, None))(st, params)
        done = terminated | truncated
        n = done.shape[0]
        chunk = -(-n // RESET_SHARE)
        # the ended envs' indices first, then n (no env), padded so that every chunk's slice is in range
        ended = jnp.concatenate([jnp.nonzero(done, size=n, fill_value=n)[0], jnp.full((chunk,), n)])
        reset_keys = split[:, 1]

        def reset_chunk(carry):
            first, obs, st = carry
            idx = jax.lax.dynamic_slice(ended, (first,), (chunk,))
            obs_re, st_re = jax.vmap(self.reset_env, in_axes=(0, None))(reset_keys[jnp.minimum(idx, n - 1)], params)

            def put(a, b):  # index n is out of range: dropped
                return a.at[idx].set(b, mode="drop")

            return first + chunk, put(obs, obs_re), jax.tree.map(put, st, st_re)

        _, obs, st_out = jax.lax.while_loop(lambda c: c[0] < jnp.sum(done), reset_chunk,
                                            (jnp.zeros((), jnp.int32), obs_st, st))
        info = {**info, "terminated": terminated, "truncated": truncated, "final_observation": obs_st}
        return obs, st_out, reward, terminated, truncated, info


class IntruderGymnaxEnv(GameGymnaxEnv):
    """The intruder's gymnax environment (see the module docstring).

    Args:
        params: the core's parameters (:func:`stp_env.rl.train.build_params`, or
            :func:`stp_env.assembly.params_for`); ``default_params``.
        horizon: ``"intruder"`` (the episode runs from the intruder's appearance to its departure) or
            ``"episode"`` (the core's whole episode).
        vehicle_policy: a name of :data:`stp_env.policies.VEHICLE_POLICIES` (``"switching"``: ``u*`` with the HJ
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
    def name(self) -> str:
        return "stp-env/Intruder"

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


# ------------------------------------------------------------------------------------------------ the ego vehicle
class EgoState(NamedTuple):
    """The ego vehicle env's state: the core's state and which vehicle is the ego (-1: none was forced)."""

    sim: EnvState
    ego: jax.Array


class VehicleGymnaxEnv(GameGymnaxEnv):
    """The after-avoidance vehicle's view (:mod:`stp_env.rl.ego`, as SB3's ``EgoVehicleVecEnv``) as a gymnax
    environment: a reset draws an intruder episode flown on ``u*`` until the intruder leaves and hands over the
    vehicle forced first; the agent's action, held over the step, flies it through the HJ filters; the others fly
    ``u*``. Reward, observation and ends as that module's (``info``: its :data:`~stp_env.rl.ego.STAT_NAMES`
    and ``discount``).

    Args:
        params: the core's parameters with the episode to the vehicles' targets
            (:func:`stp_env.rl.ego.ego_params`).
        intruder: a jittable intruder policy ``(key, state, params) -> (2,)`` (a learned one:
            :func:`stp_env.policies.learned.mlp_intruder`).
        energy: weight of the energy term per second at full speed; late_limit: seconds after the ego's STA at
            which its episode is truncated.
    """

    def __init__(self, params: EnvParams, intruder, *, energy: float = 0.002, late_limit: float = 60.0):
        super().__init__()
        from stp_env.rl import ego as V

        if not isinstance(params, EnvParams):
            raise ValueError(f"params must be the core's EnvParams; got {type(params).__name__}.")
        for name, value in (("energy", energy), ("late_limit", late_limit)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
                raise ValueError(f"{name} must be a finite number >= 0; got {value!r}.")
        self._v = V
        self._params = V.check_params(params)
        self.intruder = intruder
        self.energy, self.late_limit = float(energy), float(late_limit)

        self._obs_size = observations.vehicle_observation_size(params)

    @property
    def name(self) -> str:
        return "stp-env/EgoVehicle"

    def reset_env(self, key, params: EnvParams):
        state, ego = self._v.ego_reset(key, params, self.intruder)
        state = EgoState(state, ego)
        return self.get_obs(state, params), state

    def step_env(self, key, state: EgoState, action, params: EnvParams):
        sim_state, reward = self._v.ego_step(key, state.sim, state.ego, action, params, self.energy)
        state = EgoState(sim_state, state.ego)
        terminated, _ = self._v.ego_done(sim_state, state.ego, params, self.late_limit)
        info = {**self._v.ego_stats(sim_state, state.ego, params),
                "discount": jnp.where(terminated, 0.0, 1.0).astype(jnp.float32)}
        return self.get_obs(state, params), state, reward.astype(jnp.float32), terminated, info

    def get_obs(self, state: EgoState, params: EnvParams | None = None, key=None):
        return self._v.ego_obs(state.sim, state.ego, self._params if params is None else params)

    def is_terminated(self, state: EgoState, params: EnvParams):
        return self._v.ego_done(state.sim, state.ego, params, self.late_limit)[0]

    def is_truncated(self, state: EgoState, params: EnvParams):
        return self._v.ego_done(state.sim, state.ego, params, self.late_limit)[1]
