"""The mission as a single-agent Gymnasium environment: at each decision point the agent picks one of the motion
primitives; the environment runs the rest of the receding-horizon loop of :mod:`stp_env.survivability.mission`
(conflicts reveal intruders, ``Omega`` widens to the alternative sites once the goal is out of reach).

==============  ===================================================================================================
action          ``Discrete(A)``: primitive ``a`` = ``Network.primitives[a]`` (heading change, speed change); ``A = 25``
                on the paper's mission. A primitive that is not *valid* (its segment is known to be blocked, its
                speed leaves the range, or its successor cannot reach ``Omega``) ends the episode as an emergency
                landing.
observation     ``Box(-1, 1, (12 + 5 A,), float32)``:
                ``[0]`` window ``k / K``; ``[1:3]`` position ``(x, y) / n``; ``[3:5]`` ``cos h, sin h``;
                ``[5]`` speed ``v / v_max``; ``[6]`` 1 once ``Omega`` includes the alternative sites;
                ``[7:9]`` goal minus position ``/ n``; ``[9]`` ``log10(1 + N_goal(s)) / 13``;
                ``[10]`` ``log10(1 + N(s)) / 13``; ``[11]`` survivability ``R(s)``;
                then for each primitive ``a`` (5 values each, in primitive order): valid flag, the first
                segment's robustness ``p(s, a)``, ``log10(1 + N_Omega(s')) / 13``, ``R(s')``, and ``pi_S``'s future
                term ``J(s') / K`` (0 when not valid). ``N`` counts feasible trajectories to any site,
                ``N_Omega`` to ``Omega``; ``R`` and ``J`` are those of :mod:`stp_env.survivability.dp`.
reward          on landing: ``reward_goal`` at the goal, ``reward_alternate`` at an alternative site,
                ``reward_failure`` on an emergency landing (no valid primitive left, or an invalid one chosen);
                0 otherwise.
episode         one mission through a fresh traffic instance; a decision whose segment conflicts with the
                actual traffic reveals the intruders and is asked again (same window). Truncated after
                ``max_steps`` decisions. With ``PlannerConfig(reveal="step")`` or ``"radius"`` only the segment's
                first time step is checked at the decision; a conflict found later in the segment ends the
                episode as an emergency landing (the reveal models of :mod:`stp_env.survivability.mission`).
info            ``outcome`` (``G``, ``A``, ``L`` or ``None``), ``window``, ``revealed`` (count), ``omega``,
                ``scenario`` ``(N_p, N_u)``, ``valid`` (the action mask, numpy bool)
==============  ===================================================================================================

Random primitives are mostly invalid (from the origin at speed 0 only the primitives that keep the speed in range
and the goal in reach are valid), so an unmasked agent rarely lives long enough to land anywhere: a plain PPO run of
60,000 steps ended every one of its 16,285 episodes in an emergency landing. :meth:`SurvivabilityEnv.action_masks`
gives the valid primitives to agents that mask (sb3-contrib's ``MaskablePPO``).

With ``pool`` (a list of ``(scenario, Instance)``, prepared once: faster resets for training), each reset picks
one of them at random. Otherwise each reset draws the scenario uniformly from ``scenarios`` (or
``options={"scenario": (N_p, N_u)}``) and the instance from the environment's generator as seed ``(1, n)`` (or
``options={"instance_seed": ...}``, or a prepared :class:`stp_env.survivability.mission.Instance` as
``options={"instance": ...}``, for evaluation on given instances).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import ClassVar

import gymnasium as gym
import numpy as np

from stp_env.arguments import check_int
from stp_env.seeds import check_seed
from stp_env.survivability import dp
from stp_env.survivability.config import MissionConfig, PlannerConfig, TrafficConfig
from stp_env.survivability.graph import Graph, build_graph
from stp_env.survivability.mission import Instance, Knowledge, check_before, fly, make_instance, sense_here
from stp_env.survivability.network import build_network

COUNT_SCALE = 13.0       # log10 of the largest count on the paper's mission is about 8.5
N_STATE_FEATURES = 12
N_ACTION_FEATURES = 5


def observation_size(n_actions: int) -> int:
    return N_STATE_FEATURES + N_ACTION_FEATURES * n_actions


class SurvivabilityEnv(gym.Env):
    """See the module docstring."""

    metadata: ClassVar[dict] = {"render_modes": []}

    def __init__(self, scenarios=((100, 100),), *, mission: MissionConfig | None = None,
                 traffic: TrafficConfig | None = None, planner: PlannerConfig | None = None,
                 reward_goal: float = 1.0, reward_alternate: float = 0.5, reward_failure: float = 0.0,
                 max_steps: int = 200, graph: Graph | None = None, pool=None):
        scenarios = tuple((int(p), int(u)) for p, u in scenarios)
        if not scenarios or any(p < 0 or u < 0 for p, u in scenarios):
            raise ValueError(f"scenarios must be a non-empty list of (N_p, N_u) >= 0; got {scenarios!r}.")
        self.scenarios = scenarios
        self.graph = graph if graph is not None else build_graph(build_network(mission))
        self.traffic = TrafficConfig() if traffic is None else traffic
        self.planner = PlannerConfig() if planner is None else planner
        self.rewards = (float(reward_goal), float(reward_alternate), float(reward_failure))
        self.max_steps = int(max_steps)
        A = self.graph.net.n_actions
        self.action_space = gym.spaces.Discrete(A)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (observation_size(A),), np.float32)
        self.pool = None if pool is None else list(pool)
        if self.pool is not None and not self.pool:
            raise ValueError("pool must be None or a non-empty list of (scenario, Instance).")

    # ---- Gymnasium API -------------------------------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        # Everything is checked, and the episode drawn, before anything changes (the reset contract of every
        # environment, docs/threat-model.md): a reset that raises leaves the generator, the instance and the
        # episode as they were. Seeds: stp_env.seeds.check_seed, [0, 2**63 - 1].
        if seed is not None:
            check_seed(seed)
        scenario, instance, instance_seed = self._check_options(options)
        if seed is not None:
            rng, rng_seed = gym.utils.seeding.np_random(seed)
        else:
            rng, rng_seed = copy.deepcopy(self.np_random), self.np_random_seed
        if instance is None and self.pool is not None and instance_seed is None:
            scenario, instance = self.pool[int(rng.integers(len(self.pool)))]
        elif instance is None:
            if scenario is None:
                scenario = self.scenarios[int(rng.integers(len(self.scenarios)))]
            if instance_seed is None:
                instance_seed = (1, int(rng.integers(2**62)))
            traffic = self.traffic.with_overrides(n_partial=int(scenario[0]), n_unknown=int(scenario[1]))
            instance = make_instance(self.graph, traffic, self.planner, instance_seed)
        if scenario is None:
            scenario = (instance.traffic.n_partial, instance.traffic.n - instance.traffic.n_partial)
        know = Knowledge(self.graph, instance)
        sense_here(self.graph, know, self.graph.origin, self.planner)
        self._np_random, self._np_random_seed = rng, rng_seed
        self.instance, self.scenario, self.know = instance, tuple(scenario), know
        self.g, self.omega, self.steps, self.outcome = self.graph.origin, "goal", 0, None
        self.tables = None
        self._refresh()
        return self._observation(), self._info()

    def _check_options(self, options):
        """``(scenario, instance, instance_seed)`` of the options (``None`` where not given), checked."""
        if options is None:
            return None, None, None
        if not isinstance(options, Mapping):
            raise ValueError(f"options must be a dict or None; got {type(options).__name__}.")
        unknown = sorted(map(repr, set(options) - {"scenario", "instance", "instance_seed"}))
        if unknown:
            gym.logger.warn(f"ignoring unknown reset option(s) {', '.join(unknown)}; known: scenario, instance, "
                            "instance_seed.")
        scenario, instance, instance_seed = (options.get(k) for k in ("scenario", "instance", "instance_seed"))
        if scenario is not None:
            if not isinstance(scenario, (tuple, list)) or len(scenario) != 2:
                raise ValueError(f"options['scenario'] must be a pair (N_p, N_u); got {scenario!r}.")
            scenario = tuple(check_int(v, "options['scenario'] (N_p, N_u)", 0, 100_000) for v in scenario)
        if instance is not None and not isinstance(instance, Instance):
            raise ValueError(f"options['instance'] must be a stp_env.survivability.mission.Instance; got "
                             f"{type(instance).__name__}.")
        if instance_seed is not None:
            parts = instance_seed if isinstance(instance_seed, (tuple, list)) else (instance_seed,)
            if not parts:
                raise ValueError("options['instance_seed'] must be a seed or a non-empty tuple of seeds.")
            for v in parts:
                check_seed(v, "options['instance_seed']")
        return scenario, instance, instance_seed

    def step(self, action):
        if self.outcome is not None:
            raise RuntimeError("step() after the episode ended; call reset().")
        a = int(action)
        if not self.action_space.contains(a):
            raise ValueError(f"action must be an integer in [0, {self.action_space.n}); got {action!r}.")
        self.steps += 1
        g = self.graph
        if not self.valid[a]:
            return self._end("L")
        hit, minute = check_before(g, self.know, self.g, a, self.planner)
        if hit.size:
            self.know.reveal(hit, minute)
            self.tables = None
            self._refresh()
        else:
            conflict, changed = fly(g, self.know, self.g, a, self.planner)
            if conflict is not None:
                return self._end("L")
            self.g = int(g.succ[self.g, a])
            if g.term_goal[self.g] or (self.omega == "all" and g.term_alt[self.g]):
                return self._end("G" if g.term_goal[self.g] else "A")
            if sense_here(g, self.know, self.g, self.planner) or changed:
                self.tables = None
            self._refresh()
        if not self.valid.any():
            return self._end("L")
        return self._observation(), 0.0, False, self.steps >= self.max_steps, self._info()

    def action_masks(self) -> np.ndarray:
        """The valid primitives at the current decision, ``(A,)`` bool (the ``valid`` info; the observation's
        per-primitive flags): what sb3-contrib's ``MaskablePPO`` reads to sample only valid actions."""
        return self.valid.copy()

    # ---- internals ---------------------------------------------------------------------------------------------
    def _refresh(self):
        """Tables (recomputed only when the knowledge or ``Omega`` changed) and the valid primitives."""
        g = self.graph
        if self.tables is None:
            self.tables = self._compute()
        if self.omega == "goal" and self.tables.n_goal[self.g] == 0:
            self.omega = "all"
            self.tables = self._compute()
        succ, seg = g.succ[self.g], g.seg[self.g]
        ok = succ >= 0
        s = np.where(ok, succ, 0)
        n_om = self.tables.n_goal if self.omega == "goal" else self.tables.n_all
        self.valid = ok & self.know.feasible[np.where(ok, seg, 0)] & (n_om[s] > 0)

    def _compute(self) -> dp.Tables:
        t = dp.tables(self.graph, self.know.feasible, self.instance.robustness, "S", self.omega,
                      blocked_bits=self.instance.blocked_bits)
        return dp.Tables(*(np.asarray(x) for x in t))

    def _end(self, outcome):
        self.outcome = outcome
        reward = self.rewards[("G", "A", "L").index(outcome)]
        return self._observation(), reward, True, False, self._info()

    def _info(self):
        return {"outcome": self.outcome, "window": self.graph.window_of(self.g), "revealed": len(self.know.revealed),
                "omega": self.omega, "scenario": self.scenario, "valid": self.valid.copy()}

    def _observation(self) -> np.ndarray:
        g, net, t = self.graph, self.graph.net, self.tables
        x, y, h, v = g.states[self.g]
        k = g.window_of(self.g)
        ang = 2 * np.pi * h / net.n_headings
        gx, gy = net.goal
        head = [k / net.n_windows, x / net.n, y / net.n, np.cos(ang), np.sin(ang), v / max(net.n_speeds - 1, 1),
                float(self.omega == "all"), (gx - x) / net.n, (gy - y) / net.n,
                np.log10(1.0 + t.n_goal[self.g]) / COUNT_SCALE, np.log10(1.0 + t.n_all[self.g]) / COUNT_SCALE,
                t.value[self.g]]
        succ, seg = g.succ[self.g], g.seg[self.g]
        s = np.where(succ >= 0, succ, 0)
        n_om = t.n_goal if self.omega == "goal" else t.n_all
        valid = self.valid
        per = np.stack([valid.astype(np.float64),
                        np.where(valid, self.instance.robustness[np.where(succ >= 0, seg, 0)], 0.0),
                        np.where(valid, np.log10(1.0 + n_om[s]) / COUNT_SCALE, 0.0),
                        np.where(valid, t.value[s], 0.0),
                        np.where(valid, t.future[s] / net.n_windows, 0.0)], axis=1)
        obs = np.concatenate([np.asarray(head, np.float64), per.reshape(-1)])
        return np.clip(np.nan_to_num(obs, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0).astype(np.float32)
