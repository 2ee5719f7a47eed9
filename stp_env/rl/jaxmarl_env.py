"""The whole game as a JaxMARL ``MultiAgentEnv``: every vehicle and the intruder are agents of one jittable
environment, for multi-agent learners written in JAX (JaxMARL's IPPO/MAPPO style).

``GameJaxMARLEnv(params)`` subclasses ``jaxmarl.environments.multi_agent_env.MultiAgentEnv``; its ``reset(key)`` and
``step(key, state, actions)`` are JaxMARL's (``step`` advances with :meth:`step_env` and resets in the same call when
``dones["__all__"]``). JaxMARL's own ``LogWrapper`` takes it (``tests/test_jax_rl.py``).

* **Agents**: ``vehicle_0 .. vehicle_{N-1}`` (every vehicle of ``params``, scenario order) and ``intruder``: a fixed
  set, as JaxMARL's learners expect (arrays over agents). An agent's ``done`` says when it no longer takes part: a
  vehicle when it arrived, collided or left the domain (one that arrived before the episode is done from the
  reset; one still on the ground is not done, and its actions are ignored until it departs), the intruder when it
  has left (``t_IAT`` after appearing, Assumption 1); ``"__all__"`` when the core's episode is over
  (:func:`stp_env.sim.episode_over`: every vehicle done and the intruder gone, or the time limit). To train on the
  vehicles that can take part in a window only, build ``params`` for them (:mod:`stp_env.sim.fleet`).
* **Actions**: ``Box(-1, 1, (2,))`` for every agent, as the PettingZoo env: speed and turn rate, held over the
  step; a forced vehicle's action is replaced by the avoidance control ``u^A`` (eq. 15) while the intruder is
  present (eq. 38, the safety filter of :func:`stp_env.sim.step`).
* **Observations**: the rows of :func:`stp_env.sim.observe` (vehicles ``20 + 5K``, the intruder ``8 + 7K``; every
  entry in ``[-2, 2]``).
* **Rewards**: the core's (:class:`stp_env.sim.RewardConfig`).
* **Infos**: numbers only, one ``(N + 1,)`` array per key in agent order (JaxMARL's convention): ``n_forced``
  (``|N^RP|`` of eq. 39, the same for every agent), ``forced`` (the vehicle was forced to avoid), ``collided``,
  ``guarantee_violation``, ``tracking_violation`` (0 for the intruder).

Needs the ``jax-rl`` extra on Python 3.11 or newer (JaxMARL's own floor).
Importing this module imports ``jaxmarl``, and gymnax (which JaxMARL imports) makes a JAX array at import, which
starts JAX's backend: choose the CPU device count (:func:`stp_env.set_cpu_devices`) before importing it.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxmarl.environments import spaces
from jaxmarl.environments.multi_agent_env import MultiAgentEnv

from stp_env.sim import core, observations, status
from stp_env.sim.observations import observation_sizes
from stp_env.sim.types import COLLIDED, GONE, EnvParams, EnvState

INTRUDER = "intruder"


class GameJaxMARLEnv(MultiAgentEnv):
    """The game with every vehicle and the intruder as agents (see the module docstring)."""

    def __init__(self, params: EnvParams):
        if not isinstance(params, EnvParams):
            raise ValueError(f"params must be the core's EnvParams; got {type(params).__name__}.")
        n = int(params.vehicles.n)
        super().__init__(num_agents=n + 1)
        self.params = params
        self.n_vehicles = n
        self.vehicles = [f"vehicle_{i}" for i in range(n)]
        self.agents = [*self.vehicles, INTRUDER]
        vehicle_size, intruder_size = observation_sizes(params)
        action_dim = params.vehicles.model.action_dim
        self.observation_spaces = {a: spaces.Box(-2.0, 2.0, (vehicle_size,)) for a in self.vehicles}
        self.observation_spaces[INTRUDER] = spaces.Box(-2.0, 2.0, (intruder_size,))
        self.action_spaces = {a: spaces.Box(-1.0, 1.0, (action_dim,)) for a in self.vehicles}
        self.action_spaces[INTRUDER] = spaces.Box(-1.0, 1.0, (2,))

    @property
    def name(self) -> str:
        return "stp-env/Game"

    @property
    def agent_classes(self) -> dict:
        return {"vehicles": list(self.vehicles), "intruder": [INTRUDER]}

    def reset(self, key):
        state = core.reset(key, self.params)
        return self.get_obs(state), state

    def get_obs(self, state: EnvState) -> dict:
        vehicle_obs, intruder_obs = observations.observe(state, self.params)
        obs = {a: vehicle_obs[i].astype(jnp.float32) for i, a in enumerate(self.vehicles)}
        obs[INTRUDER] = intruder_obs.astype(jnp.float32)
        return obs

    def step_env(self, key, state: EnvState, actions: dict):
        dim = self.params.vehicles.model.action_dim
        rows = [jnp.zeros((2,), jnp.float32).at[:dim].set(jnp.asarray(actions[a], jnp.float32).reshape(dim))
                for a in self.vehicles]
        rows.append(jnp.asarray(actions[INTRUDER], jnp.float32).reshape(2))
        state, rewards = core.step(key, state, jnp.stack(rows), self.params)
        terminated, truncated = core.episode_over(state, self.params)
        over = terminated | truncated
        vehicle_done = status.done_vehicles(state) | over
        dones = {a: vehicle_done[i] for i, a in enumerate(self.vehicles)}
        dones[INTRUDER] = (state.intruder_status == GONE) | over
        dones["__all__"] = over
        rewards = {a: rewards[i].astype(jnp.float32) for i, a in enumerate(self.agents)}
        return self.get_obs(state), state, rewards, dones, self.infos(state)

    def infos(self, state: EnvState) -> dict:
        forced = jnp.isfinite(state.avoid_start)
        n_forced = jnp.sum(forced).astype(jnp.int32)

        def with_intruder(vehicles, intruder=False):
            return jnp.concatenate([vehicles, jnp.asarray([intruder], vehicles.dtype)])

        return {
            "n_forced": jnp.full((self.num_agents,), n_forced, jnp.int32),
            "forced": with_intruder(forced),
            "collided": with_intruder(state.status == COLLIDED, jnp.any(state.collided_with_intruder)),
            "guarantee_violation": with_intruder(state.guarantee_violation),
            "tracking_violation": with_intruder(state.tracking_violation),
        }

    def get_avail_actions(self, state: EnvState) -> dict:
        """Continuous actions: every agent may always act (an ignored action does nothing)."""
        return {a: jnp.ones((2,), bool) for a in self.agents}
