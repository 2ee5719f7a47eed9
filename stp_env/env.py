"""STP under an intruder: a PettingZoo environment of Dubins vehicles in wind, planned by sequential trajectory
planning, and one adversarial intruder (Bansal, Chen, Fisac, Tomlin: the STP papers of docs/references.md).

Quick start::

    import stp_env

    env = stp_env.parallel_env()               # the "town" scenario, k̄ = 2, 7 vehicles + 1 intruder
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)
    print(env.episode["n_forced"], "vehicles were forced to avoid; bound k̄ =", env.episode["kbar"])

The manual (agents, actions, observations, rewards, seeds, infos, arguments, versions): docs/environment.md,
"Reference". ``stp_env.parallel_env`` is :func:`parallel_env`; ``stp_env.env`` is this module, callable as :func:`env`.

This module is the adapter: PettingZoo's agents, spaces and dicts around the pure JAX core :mod:`stp_env.sim`, one
jitted call per step (:mod:`stp_env.sim.stepping`). What it accepts is checked in :mod:`stp_env.env_checks`, its
infos are built by :mod:`stp_env.env_infos` (the evaluator's episode metrics, :mod:`stp_env.sim.metrics`), and
``replan=True`` runs Algorithm 4 through :mod:`stp_env.replanning`. The tables its policies read beyond the
scenario's (the buffer table ``V^B`` of a buffer-game policy, a plug-in's table) are built by
:func:`stp_env.requirements.with_required_tables`.
"""

from __future__ import annotations

import contextvars
import functools
import sys
import types
from typing import ClassVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.wrappers import OrderEnforcingWrapper

from stp_env import assembly, sim
from stp_env.env_checks import (
    ActionChecker,
    check_appear_window,
    check_flags,
    check_max_cycles,
    check_reset_options,
    check_vehicle_policy,
    env_config,
)
from stp_env.env_infos import InfoBuilder
from stp_env.progress import compile_note
from stp_env.replanning import Replanner
from stp_env.seeds import prng_key
from stp_env.sim import fleet, observations
from stp_env.sim.packing import DeviceCarry, Layout
from stp_env.sim.stepping import advance, advance_carry_jit, advance_scripted, global_state_jit, start_jit
from stp_env.sim.types import GONE, INTRUDER_STATUS_NAMES, MODE_NAMES, STATUS_NAMES

DEFAULT_SCENARIO = "town"
INFO_CODES = {"status": STATUS_NAMES, "mode": MODE_NAMES, "intruder_status": INTRUDER_STATUS_NAMES}
"""What the integer codes of the infos name: ``INFO_CODES["status"][info["status"]]`` is a vehicle's status
(``"waiting"``, ``"flying"``, ...); the intruder's ``status`` and ``stp_episode_intruder_status`` are
``INFO_CODES["intruder_status"]`` codes."""


_BUILD_PROGRESS = contextvars.ContextVar("stp_env_build_progress", default=False)


@functools.lru_cache(maxsize=8)
def _cached_params(scenario, config):
    return assembly.params_for(scenario, config, progress=_BUILD_PROGRESS.get())


class STPParallelEnv(ParallelEnv):
    """PettingZoo ParallelEnv of STP vehicles and an intruder; see the module docstring (the user's manual)."""

    metadata: ClassVar[dict] = {"name": "stp_v1", "render_modes": ["human", "rgb_array"], "render_fps": 10,
                                "is_parallelizable": True}

    def __init__(self, scenario=DEFAULT_SCENARIO, config: sim.EnvConfig | None = None, *,
                 max_cycles: int | None = None, render_mode: str | None = None, params: sim.EnvParams | None = None,
                 render_avoid_regions: bool = False, store=None, replan: bool = False,
                 vehicle_policy=None, intruder=None, backend: str | None = None,
                 progress: bool | None = None, keep_finished: bool = False, **config_overrides):
        from stp_env import progress as progress_mod
        from stp_env import requirements
        from stp_env.policies import vehicle_policy as resolve_vehicle_policy
        from stp_env.policies.intruders import capabilities, resolve_intruder
        from stp_env.scenarios import Scenario, make

        vehicle_policy_fn = None
        if callable(vehicle_policy):  # the user's own jittable policy (its outputs are checked below)
            vehicle_policy_fn = vehicle_policy
        elif vehicle_policy is not None:  # a name or learned:NAME_OR_PATH; ValueError before anything is built
            vehicle_policy_fn = resolve_vehicle_policy(vehicle_policy)

        check_flags(keep_finished=keep_finished, render_mode=render_mode, modes=self.metadata["render_modes"])
        intruder_policy = resolve_intruder(intruder) if isinstance(intruder, str) else intruder
        if intruder_policy is not None and not callable(intruder_policy):
            raise ValueError(f"intruder must be None (the agent acts), an intruder spec or a policy; got {intruder!r}.")
        intruder_caps = None if intruder_policy is None else capabilities(intruder_policy)
        # every table the policies read (ValueError for an unknown one before anything is loaded)
        tables = requirements.required_tables(vehicle_policy_fn, intruder_caps)
        config = env_config(config, config_overrides, spawn=None if intruder_caps is None else intruder_caps.spawn,
                            backend=backend)
        if isinstance(scenario, str):
            scenario = make(scenario)
        if not isinstance(scenario, Scenario):
            raise ValueError(f"scenario must be a registry name or a Scenario; got {type(scenario).__name__}.")
        self.scenario = scenario
        self.config = config
        if replan and params is not None:
            raise ValueError("replan=True replans from the scenario's own plan; it cannot be combined with params= "
                             "(pass the scenario and config instead).")
        self._progress = progress_mod.enabled(progress)
        if params is None:
            progress_mod.note(f"loading the reachability artifacts and plan of {scenario.name!r} (computed and "
                              "cached on first use)", self._progress)
            token = _BUILD_PROGRESS.set(self._progress)
            try:
                params = _cached_params(scenario, config) if store is None else assembly.params_for(
                    scenario, config, store=store, progress=self._progress)
            finally:
                _BUILD_PROGRESS.reset(token)
        elif backend is not None:
            params = params.replace(vehicles=dict(model=config.vehicle_model))
        check_appear_window(params)
        params = requirements.with_required_tables(params, scenario, tables=tables, store=store,
                                                   progress=self._progress)
        if callable(vehicle_policy):
            check_vehicle_policy(vehicle_policy_fn, params)
        self._vehicle_policy = vehicle_policy_fn
        self._vehicle_policy_name = (vehicle_policy if vehicle_policy is None or isinstance(vehicle_policy, str)
                                     else getattr(vehicle_policy, "__name__", "custom policy"))
        self._intruder_policy = intruder_policy
        self._intruder_name = None if intruder is None else (intruder if isinstance(intruder, str)
                                                             else intruder_caps.__name__)
        self._step_layout = None  # Layout of the packed step output, found at the first step
        self._noted_with_state = False  # the step variant returning env_state announced (it compiles on first use)
        self.params = params
        self._base_params = params
        self.replan = bool(replan)
        self._replanner = Replanner(scenario, params, enabled=self.replan, store=store, progress=self._progress)
        n = params.vehicles.n
        # The agents of an episode are the vehicles still to fly at its first instant (those that arrived before it
        # are out of the airspace for the whole episode) and the intruder unless a script flies it: the same agents
        # for every seed, all of them present at reset, as PettingZoo's clients expect of possible_agents.
        self._vehicle_names = [f"vehicle_{i}" for i in range(n)]
        self._in_episode = ~np.asarray(jax.device_get(fleet.arrived_at_start(params)), bool)
        self.possible_agents = [a for a, take in zip(self._vehicle_names, self._in_episode) if take]
        if intruder_policy is None:
            self.possible_agents.append("intruder")
        self._index = {**{a: i for i, a in enumerate(self._vehicle_names)}, "intruder": n}
        self._actions = ActionChecker(self.possible_agents, self._index, n, params.vehicles.model.action_dim)
        self.keep_finished = keep_finished
        self._finished: set[str] = set()  # agents done before the episode's end (kept as agents: keep_finished)
        self.max_cycles = check_max_cycles(sim.steps_for(params) if max_cycles is None else max_cycles)
        self.render_mode = render_mode
        self.render_avoid_regions = render_avoid_regions
        self._dv, self._di = observations.observation_sizes(params)
        self._state_size = observations.global_state_size(params)
        self._info_builder = InfoBuilder(self._vehicle_names, self._in_episode, int(params.intruder.kbar),
                                         float(params.tables.tracking_bound))
        self.episode: dict | None = None  # the episode-level results after the last reset or step (see Infos)
        self._observation_spaces: dict[str, gymnasium.spaces.Box] = {}
        self._action_spaces: dict[str, gymnasium.spaces.Box] = {}
        self._carry = DeviceCarry()  # (key, state), packed on the device
        self._steps = 0
        self.agents: list[str] = []
        self._fig = None

    # ------------------------------------------------------------------------------------------ spaces
    def observation_space(self, agent):
        """One space object per agent (as PettingZoo recommends), made on first use and kept by the env."""
        self._check_known(agent)
        if agent not in self._observation_spaces:
            size = self._di if agent == "intruder" else self._dv
            self._observation_spaces[agent] = gymnasium.spaces.Box(-2.0, 2.0, (size,), np.float32)
        return self._observation_spaces[agent]

    def action_space(self, agent):
        """One space object per agent, made on first use and kept by the env."""
        self._check_known(agent)
        if agent not in self._action_spaces:
            self._action_spaces[agent] = gymnasium.spaces.Box(-1.0, 1.0, (self._action_dim(agent),), np.float32)
        return self._action_spaces[agent]

    @property
    def state_space(self):
        return gymnasium.spaces.Box(-2.0, 2.0, (self._state_size,), np.float32)

    def _action_dim(self, agent) -> int:
        return self._actions.action_dim(agent)

    def _check_known(self, agent):
        if agent not in self.possible_agents:
            raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}.")

    # ------------------------------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        # Everything is checked before anything changes: a failed reset leaves the key, state and agents as they
        # were (the next episode is the one it would have been without the failed call).
        key = prng_key(seed) if seed is not None else self._key
        appear_time = check_reset_options(options, self._base_params)
        if key is None:
            key = prng_key(int(np.random.SeedSequence().entropy % (2 ** 31)))
        params = self._base_params
        start_params = params
        if appear_time is not None:
            start_params = params.replace(intruder=dict(appear_window=jnp.asarray([appear_time, appear_time],
                                                                                  jnp.float32)))
        compile_note("the environment's reset", key, start_params, progress=self._progress)
        key, state, out = start_jit(key, start_params)
        self._carry.set((key, state))
        self.params = params
        self._replanner.reset(params)
        self._steps = 0
        out = jax.device_get(out)
        obs, info = self._observations(out.obs_vehicles, out.obs_intruder), out.info
        self.agents = list(self.possible_agents)  # every agent of the episode (possible_agents, built with it)
        self._finished = set()
        infos = self._infos(info, self.agents)
        obs = {a: obs[a] for a in self.agents}
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def _check_action(self, agent, a) -> np.ndarray | None:
        return self._actions.check(agent, a, self.agents)

    def step(self, actions):
        if self._carry.words is None:
            raise RuntimeError("call reset() before step().")
        if not self.agents:
            raise RuntimeError("the episode is over (every agent has terminated or been truncated); call reset() "
                               "before step().")
        arr = self._actions.parse(actions, self.agents)  # raises before anything changes
        scripted = not (self._vehicle_policy is None and self._intruder_policy is None)
        if self._step_layout is None:  # traced once per environment, not compiled
            step = (functools.partial(advance_scripted, vehicle_policy=self._vehicle_policy,
                                      intruder_policy=self._intruder_policy) if scripted else advance)
            self._step_layout = Layout.of(jax.eval_shape(step, *self._carry.unpacked(), arr, self.params)[2])
            # the shapes of the step's arguments are fixed for the environment's life (a new plan keeps them), so
            # the compilation is announced here, at its first step, and not looked up at every step
            flown = ", ".join(f"{name} {who}" for name, who in ((self._vehicle_policy_name, "vehicles"),
                                                                (self._intruder_name, "intruder")) if name)
            compile_note(f"the environment's step ({flown})" if scripted else "the environment's step",
                         self._carry.words, arr, self.params, progress=self._progress)
        # a user who read env_state since the last step (e.g. to compute the vehicles' actions) gets the state
        # with this one's outputs; otherwise it stays packed until asked for
        with_state = self._carry.was_read
        if with_state and not self._noted_with_state:  # once per environment, not looked up at every step
            self._noted_with_state = True
            compile_note("the environment's step (returning env_state)", self._carry.words, arr, self.params,
                         progress=self._progress)
        words = self._carry.advance(advance_carry_jit, arr, self.params, vehicle_policy=self._vehicle_policy,
                                    intruder_policy=self._intruder_policy, with_state=with_state)
        self._steps += 1
        out = self._step_layout.unpack(np.asarray(words))
        obs, rewards, info = self._observations(out.obs_vehicles, out.obs_intruder), out.rewards, out.info
        if self.replan:
            self.params, new_obs, new_info = self._replanner.after_step(self._carry, self.params, self._observations,
                                                                        info)
            if new_obs is not None:
                obs, info = new_obs, new_info
        done_v = info.status >= sim.ARRIVED
        intruder_done = int(info.intruder_status) == GONE
        truncated_all = bool(out.truncated) or self._steps >= self.max_cycles
        live = self.agents
        infos = self._infos(info, live)
        rewards, done = rewards.tolist(), [*done_v.tolist(), intruder_done]  # Python scalars, indexed per agent
        index = self._index
        rew = {a: rewards[index[a]] for a in live}
        terms = {a: done[index[a]] for a in live}
        truncs = {a: truncated_all and not terms[a] for a in live}
        obs = {a: obs[a] for a in live}
        ending = truncated_all or all(terms.values())  # no agent of the episode is left after this step
        if self.keep_finished:
            # a finished agent stays an agent until the episode ends (reward 0 after the step it finished in, its
            # actions ignored by the core), so that every agent ends in the same step: what clients without agent
            # death need (SuperSuit's vector envs, TorchRL)
            rew.update(dict.fromkeys(self._finished, 0.0))
            if not ending:
                self._finished.update(a for a in live if terms[a])
                terms, truncs = dict.fromkeys(live, False), dict.fromkeys(live, False)
        if ending and any(truncs.values()):
            # the last step of a truncated episode truncates every agent (one that also terminates in it is both):
            # a client that ends an episode when all its agents are truncated (RLlib) sees the end
            truncs = dict.fromkeys(live, True)
        self.agents = [] if ending else [a for a in live if not (terms[a] or truncs[a])]
        if self.render_mode == "human":
            self.render()
        return obs, rew, terms, truncs, infos

    # ------------------------------------------------------------------------------------------ conversions
    def _observations(self, obs_vehicles, obs_intruder) -> dict[str, np.ndarray]:
        """Every agent's observation, an array of its own (writable; a client may change it in place)."""
        obs = {name: row.copy() for name, row in zip(self._vehicle_names, obs_vehicles)}
        obs["intruder"] = np.array(obs_intruder)
        return obs

    def _infos(self, info, live) -> dict:
        """The infos of the agents ``live`` (in that order) from the step's ``StepInfo``; sets ``episode``."""
        episode = self._info_builder.episode(info)
        self.episode = InfoBuilder.readable(episode)
        return self._info_builder.infos(info, live, episode, self._replanner.replanned, self._replanner.sta)

    def state(self) -> np.ndarray:
        """The global state (``state_space``): per vehicle ``(x, y)`` scaled, ``cos, sin``, flying / finished /
        waiting / avoiding / after flags; the intruder's ``(x, y, cos, sin)``, present flag, ``tau / t_IAT``; and
        the time since the episode start over its length."""
        if self._carry.words is None:
            raise RuntimeError("call reset() before state().")
        return np.array(global_state_jit(self._state, self.params))  # an array of the caller's own (writable)

    # ------------------------------------------------------------------------------------------ render
    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        if self._carry.words is None:
            raise RuntimeError("call reset() before render().")
        from stp_env.render import show_frame

        self._fig, frame = show_frame(self, self._fig, self.render_mode, fps=self.metadata["render_fps"])
        return frame

    def close(self):
        if self._fig is not None:
            from stp_env.render import close_figure

            self._fig = close_figure(self._fig)

    @property
    def env_state(self) -> sim.EnvState:
        """The core's :class:`~stp_env.sim.EnvState` (read-only use; for parity checks and custom analysis);
        ``None`` before the first ``reset``. Read between two steps, it comes with the next step's outputs (a loop
        that reads it after every step makes one call per step, not two)."""
        tree = self._carry.tree
        return None if tree is None else tree[1]

    @property
    def replan_log(self) -> list[dict]:
        """Algorithm 4's events of the episode (``replan=True``): time, vehicles, new and old STAs, seconds."""
        return self._replanner.log

    @property
    def _key(self):
        return None if self._carry.words is None else self._carry.unpacked()[0]

    @property
    def _state(self):
        return None if self._carry.words is None else self._carry.unpacked()[1]


def parallel_env(scenario=DEFAULT_SCENARIO, config: sim.EnvConfig | None = None, **kwargs) -> STPParallelEnv:
    """The ParallelEnv (see the module docstring for arguments)."""
    return STPParallelEnv(scenario, config, **kwargs)


class STPAECEnv(parallel_to_aec_wrapper):
    """PettingZoo's ``parallel_to_aec`` conversion that checks each action when its agent steps.

    The conversion buffers the actions of one cycle and steps the parallel env when the last agent has acted; a bad
    action of an earlier agent would only be rejected then, and every later call would fail on the same buffered
    action. Here a bad action raises ``ValueError`` at its agent's own ``step`` and is not buffered: the agent is
    still the one to act, and nothing else changed."""

    def step(self, action):
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if action is not None:
                raise ValueError(f"{agent!r} has finished (terminated or truncated): its step takes None; got "
                                 f"{action!r}.")
        elif action is None:
            raise ValueError(f"{agent!r} is live: its step takes an action (real numbers in [-1, 1]); None is the "
                             "step of a finished agent only.")
        else:
            action = self.env._check_action(agent, action)
        super().step(action)


def raw_env(scenario=DEFAULT_SCENARIO, config: sim.EnvConfig | None = None, **kwargs):
    """The AEC form without the order-enforcing wrapper."""
    return STPAECEnv(parallel_env(scenario, config, **kwargs))


def env(scenario=DEFAULT_SCENARIO, config: sim.EnvConfig | None = None, **kwargs):
    """The AEC form (``parallel_to_aec`` of :func:`parallel_env`, with PettingZoo's order enforcing)."""
    return OrderEnforcingWrapper(raw_env(scenario, config, **kwargs))


class _CallableModule(types.ModuleType):
    """This module, callable: ``stp_env.env(...)`` is :func:`env` (the package exports ``env`` and
    ``parallel_env`` at the top level, and ``stp_env.env`` is this module's name)."""

    def __call__(self, *args, **kwargs):
        return env(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
