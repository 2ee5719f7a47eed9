"""A PettingZoo environment of the compromised-vehicle threat: a UAV formation under a co-observation schedule,
one of whose vehicles an attacker takes over.

Quick start::

    from stp_env.coobservation.env import parallel_env

    env = parallel_env(schedule="unsecured")
    observations, infos = env.reset(seed=0, options={"compromised": 0, "compromise_time": 100.0})
    while env.agents:
        actions = {"attacker": env.action_space("attacker").sample()}   # vehicles left out fly their plans
        observations, rewards, terminations, truncations, infos = env.step(actions)
    print(infos["attacker"])       # entered a forbidden zone? detected? when?

A thin adapter of :func:`stp_env.coobservation.threat.step` (the core's step by composition; one jitted call per
step).

Agents
------
===============  ==========================================================================================
``vehicle_<i>``  A UAV of the formation (:class:`stp_env.coobservation.uav.FormationScenario`). Its action is
                 applied unless it is the compromised vehicle and the attack has begun. A vehicle missing from
                 the action dict flies its plan (the project's tracker, ``nominal_tracking``).
``attacker``     Controls the compromised vehicle from ``compromise_time`` on; its actions are ignored before
                 (and when nobody is compromised). Missing from the action dict: the vehicle flies its plan.
===============  ==========================================================================================

Actions: ``Box(-1, 1, (2,))`` for every agent (speed in ``[0, 25] m/s`` and turn rate in ``[-2, 2] rad/s``,
clipped; NaN, booleans, strings, wrong shapes and unknown or finished agents raise ``ValueError`` before anything
changes).
Observations: vehicles get the core's vehicle row (:func:`stp_env.sim.observations.observe`); the attacker gets
:func:`stp_env.coobservation.attackers.attacker_observation` (zeros until it is active).

Rewards: the attacker gets ``+1`` when the compromised vehicle first enters a forbidden zone and ``-2`` when it
is detected (the learned attacker's objective: enter without missing an observation); vehicles get 0.

Episode: from ``t = 0`` (take-off) until one step after the last scheduled observation; every agent is
terminated then (a vehicle earlier, when it lands, collides or leaves the airspace).

Infos (fresh dicts every step)
------------------------------
Vehicles: ``status``, ``in_forbidden``, ``entered_forbidden``, ``observations`` (the scheduled observations of this
vehicle that fell due in this step: ``time``, ``observer`` (``"vehicle_<j>"`` or the fixed point), ``distance``
[m], ``seen``), ``time`` [s].
Attacker: ``compromised`` (an agent name, or ``None``), ``active``, ``compromise_time``, ``entered``,
``entry_time``, ``detected``, ``detection_time`` (the first missed observation of the compromised vehicle at or
after the compromise), ``success`` (entered and not detected so far), ``missed_observations`` (all misses so
far), ``time``.

Arguments
---------
``parallel_env(scenario=None, schedule="secured", *, compromised=None, compromise_time=None, params=None,
max_cycles=None)``: ``scenario`` a :class:`~stp_env.coobservation.uav.FormationScenario` (default one);
``schedule`` ``"secured"`` (the fewest observation times whose reachability ellipses miss the zones),
``"unsecured"`` (every 90 s) or a sequence of times [s] starting at 0 and ending at the flight's end;
``compromised`` a vehicle index (``None``: drawn per episode) and ``compromise_time`` [s] in ``[0, duration]``
(``None``: uniform over the flight); ``reset(options={"compromised": i, "compromise_time": t})`` overrides both for
one episode (``"compromised": -1``: nobody). ``params`` prebuilt :class:`stp_env.sim.EnvParams` of the scenario.

``reset(seed=s)``: ``s`` an integer in ``[0, 2**63 - 1]`` (:func:`stp_env.seeds.prng_key`, the seed function of
every environment: each seed its own episode stream, no truncation to 32 bits); booleans, floats, strings, negative
or larger seeds raise ``ValueError``, as do options that are not a dict and bad values of ``compromised`` or
``compromise_time``. A reset that raises changes nothing: the key, the state and the agents are what they were.

Version history: v0 (``coobservation_v0``), first release. Seeds of ``2**32`` and more now give their own episodes
(they were reduced to their low 32 bits), and seeds that are not integers in ``[0, 2**63 - 1]`` raise.
"""

from __future__ import annotations

import functools
import reprlib
from collections.abc import Mapping
from typing import ClassVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import ParallelEnv

from stp_env.arguments import check_int, check_real, contains_bool
from stp_env.coobservation import attackers, threat
from stp_env.coobservation.uav import FormationScenario
from stp_env.policies import nominal_tracking
from stp_env.seeds import prng_key
from stp_env.sim.observations import observe, vehicle_observation_size
from stp_env.sim.packing import DeviceCarry, Layout, pack
from stp_env.sim.types import STATUS_NAMES

UNSECURED_PERIOD = 90.0  # [s]
ATTACKER_REWARDS = (1.0, -2.0)  # entry, detection


@functools.lru_cache(maxsize=4)
def _params(scenario: FormationScenario):
    return scenario.params()


@functools.lru_cache(maxsize=8)
def schedule_times(scenario: FormationScenario, schedule: str) -> tuple[float, ...]:
    """The named schedules' observation times [s]."""
    from stp_env.coobservation.checkpoints import ellipse_test

    if schedule == "secured":
        secure = ellipse_test(scenario.forbidden, scenario.attacker_speed, scenario.ellipse_radius)
        return tuple(scenario.secured_times(secure))
    if schedule == "unsecured":
        return tuple(scenario.uniform_times(UNSECURED_PERIOD))
    raise ValueError(f"schedule {schedule!r} is not known; allowed: 'secured', 'unsecured' or a sequence of times.")


def _step(key, ts, actions, given, attacker_action, attacker_given, params, tp):
    key, k_track, k_step = jax.random.split(key, 3)
    track = nominal_tracking(k_track, ts.sim, params)
    a = jnp.where(given[:, None], actions, track)
    c = jnp.maximum(ts.compromised, 0)
    a_att = jnp.where(attacker_given, attacker_action, threat.FLY_PLAN)
    entered_before = ts.entered[c]
    detected_before = jnp.isfinite(ts.detect_time)
    checked_before = ts.checked
    new = threat.step(k_step, ts, a, a_att, params, tp, feedback=~given)
    reward = ATTACKER_REWARDS[0] * (new.entered[c] & ~entered_before & (ts.compromised >= 0)) + \
        ATTACKER_REWARDS[1] * (jnp.isfinite(new.detect_time) & ~detected_before)
    return key, new, _outputs(new, params, tp), reward, new.checked & ~checked_before


def _outputs(ts, params, tp):
    return {"vehicle_obs": observe(ts.sim, params)[0].astype(jnp.float32),
            "attacker_obs": attackers.attacker_observation(ts, params, tp),
            "done": threat.episode_done(ts, params)}


def _reset(key, params, tp, compromised, t_compromise):
    key, k_reset = jax.random.split(key)
    ts = threat.reset(k_reset, params, tp, compromised, t_compromise)
    return key, ts, _outputs(ts, params, tp)


def _info_fields(ts):
    """What the infos are made of (host side, :meth:`CoObservationParallelEnv._infos`)."""
    return {"t": ts.sim.t, "status": ts.sim.status, "inside": ts.inside, "entered": ts.entered,
            "obs_distance": ts.obs_distance, "compromised": ts.compromised, "entry_time": ts.entry_time,
            "detect_time": ts.detect_time, "t_compromise": ts.t_compromise, "missed": ts.missed}


def _step_host(key, ts, *args):
    """:func:`_step` with what the host reads after it: ``(key, ts, (outputs, reward, newly checked observations,
    the infos' fields))``."""
    key, new, out, reward, newly = _step(key, ts, *args)
    return key, new, (out, reward, newly, _info_fields(new))


def _step_packed(words, *args, layout):
    """:func:`_step_host` on the packed ``(key, threat state)`` (:mod:`stp_env.sim.packing`): the new carry and
    what the host reads, each packed into one array."""
    key, new, host = _step_host(*layout.unpack_traced(words), *args)
    return pack((key, new)), pack(host)


_step_jit = jax.jit(_step)
_step_packed_jit = jax.jit(_step_packed, static_argnames=("layout",))
_reset_jit = jax.jit(_reset)


class CoObservationParallelEnv(ParallelEnv):
    """See the module docstring (the user's manual)."""

    metadata: ClassVar[dict] = {"name": "coobservation_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, scenario: FormationScenario | None = None, schedule="secured", *, compromised=None,
                 compromise_time=None, params=None, max_cycles: int | None = None):
        scenario = FormationScenario() if scenario is None else scenario
        if not isinstance(scenario, FormationScenario):
            raise ValueError(f"scenario must be a FormationScenario; got {type(scenario).__name__}.")
        self.scenario = scenario
        times = schedule_times(scenario, schedule) if isinstance(schedule, str) else tuple(float(t) for t in schedule)
        self.schedule = scenario.schedule(times)
        self.times = times
        self.params = _params(scenario) if params is None else params
        self.threat = threat.threat_params(self.schedule, scenario.forbidden, scenario.observation_radius)
        n = scenario.n_vehicles
        self.compromised, self.compromise_time = self._check_compromise(compromised, compromise_time)
        self.possible_agents = [f"vehicle_{i}" for i in range(n)] + ["attacker"]
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        steps = threat.steps_for(self.params)
        if max_cycles is not None and (isinstance(max_cycles, bool) or not isinstance(max_cycles, int)
                                       or max_cycles < 1):
            raise ValueError(f"max_cycles must be a positive integer; got {max_cycles!r}.")
        self.max_cycles = steps if max_cycles is None else max_cycles
        self._dv = vehicle_observation_size(self.params)
        self._observation_spaces: dict[str, gymnasium.spaces.Box] = {}
        self._action_spaces: dict[str, gymnasium.spaces.Box] = {}
        self.agents: list[str] = []
        self._carry = DeviceCarry()  # (key, threat state), packed on the device (stp_env.sim.packing)
        self._out_layout = None
        self._steps = 0
        self.render_mode = None

    @property
    def _key(self):
        tree = self._carry.unpacked()
        return None if tree is None else tree[0]

    @property
    def _ts(self):
        tree = self._carry.unpacked()
        return None if tree is None else tree[1]

    def _check_compromise(self, compromised, compromise_time):
        """``(compromised, compromise_time)`` checked (``None`` stays ``None``: drawn per episode)."""
        n = self.scenario.n_vehicles
        if compromised is not None:
            compromised = check_int(compromised, "compromised (a vehicle index, -1 for nobody, or None for random)",
                                    -1, n - 1)
        if compromise_time is not None:
            compromise_time = check_real(compromise_time, "compromise_time [s] (or None for random)", 0.0,
                                         float(self.scenario.duration))
        return compromised, compromise_time

    def observation_space(self, agent):
        """One space object per agent, made on first use and kept by the env."""
        self._known(agent)
        if agent not in self._observation_spaces:
            size = attackers.OBS_SIZE if agent == "attacker" else self._dv
            self._observation_spaces[agent] = gymnasium.spaces.Box(-2.0, 2.0, (size,), np.float32)
        return self._observation_spaces[agent]

    def action_space(self, agent):
        """One space object per agent, made on first use and kept by the env."""
        self._known(agent)
        if agent not in self._action_spaces:
            self._action_spaces[agent] = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        return self._action_spaces[agent]

    def _known(self, agent):
        if agent not in self._index:
            raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}.")

    # ------------------------------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        # Everything is checked before anything changes (the contract of stp_env.env's reset): a failed reset leaves
        # the key, the state and the agents as they were. Seeds: stp_env.seeds.prng_key, [0, 2**63 - 1].
        key = prng_key(seed) if seed is not None else self._key
        c, t_c = self._check_options(options)
        if key is None:
            key = prng_key(int(np.random.SeedSequence().entropy % (2**63)))
        key, k_draw = jax.random.split(key)
        c_draw, t_draw = threat.draw_attack(k_draw, self.params, 0.0, self.scenario.duration)
        c = int(c_draw) if c is None else c
        t_c = float(t_draw) if t_c is None else t_c
        key, ts, out = _reset_jit(key, self.params, self.threat, c, t_c)
        out, checked, fields = jax.device_get((out, ts.checked, _info_fields(ts)))
        self._carry.set((key, ts))
        self._steps = 0
        self.agents = list(self.possible_agents)
        obs = self._observations(out)
        # the observations checked at the start (the base stations at t = 0) are the reset's events
        checked = np.asarray(checked)[:len(self.schedule)]
        infos = self._infos(checked & (np.asarray(self.threat.obs_time)[:len(self.schedule)] < threat.NEVER),
                            fields)
        return obs, infos

    def _check_options(self, options):
        """``(compromised, compromise_time)`` of this episode: the options' values, else the env's; checked."""
        if options is None:
            options = {}
        if not isinstance(options, Mapping):
            raise ValueError(f"options must be a dict (e.g. {{'compromised': 0, 'compromise_time': 100.0}}) or None; "
                             f"got {type(options).__name__}.")
        unknown = sorted(map(repr, set(options) - {"compromised", "compromise_time"}))
        if unknown:  # PettingZoo's API test passes arbitrary options and expects them to be ignored
            gymnasium.logger.warn(f"ignoring unknown reset option(s) {', '.join(unknown)}; known: compromised, "
                                  "compromise_time.")
        return self._check_compromise(options.get("compromised", self.compromised),
                                      options.get("compromise_time", self.compromise_time))

    def step(self, actions):
        if self._carry.words is None:
            raise RuntimeError("call reset() before step().")
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict {{agent: action}}; got {type(actions).__name__}.")
        n = self.scenario.n_vehicles
        arr = np.zeros((n, 2), np.float32)
        given = np.zeros(n, bool)
        att, att_given = np.zeros(2, np.float32), False
        for agent, a in actions.items():
            self._known(agent)
            if agent not in self.agents:
                raise ValueError(f"action for {agent!r}, which has finished; live agents: {self.agents}.")
            if a is None:
                continue
            raw = a
            try:
                kind = np.asarray(raw).dtype.kind
            except (TypeError, ValueError):
                kind = "O"
            if kind not in "iuf" or contains_bool(raw):  # NumPy reads True as 1.0 and "1" as 1.0 without a word
                raise ValueError(f"action for {agent!r} must be 2 real numbers (speed, turn rate in [-1, 1]), not "
                                 f"booleans or strings; got {reprlib.repr(raw)}.")
            a = np.asarray(raw, np.float64)
            if a.shape != (2,) or not np.all(np.isfinite(a)):
                raise ValueError(f"action for {agent!r} must be 2 finite numbers (speed, turn rate in [-1, 1]); got "
                                 f"{a.tolist() if a.size < 10 else a.shape}.")
            if agent == "attacker":
                att, att_given = np.clip(a, -1, 1).astype(np.float32), True
            else:
                i = self._index[agent]
                arr[i], given[i] = np.clip(a, -1, 1), True
        args = (arr, given, att, att_given, self.params, self.threat)
        if self._out_layout is None:  # the shapes are fixed for the env's life
            self._out_layout = Layout.of(jax.eval_shape(_step_host, *self._carry.unpacked(), *args)[2])
        words = self._carry.advance(_step_packed_jit, *args)
        self._steps += 1
        out, reward, newly, fields = self._out_layout.unpack(np.asarray(words))
        obs = self._observations(out)
        infos = self._infos(newly, fields)
        status = fields["status"]
        end = bool(out["done"]) or self._steps >= self.max_cycles
        live = list(self.agents)
        terms, truncs, rews = {}, {}, {}
        for a in live:
            vehicle_done = a != "attacker" and status[self._index[a]] >= 2
            terms[a] = bool(out["done"]) or vehicle_done
            truncs[a] = end and not terms[a]
            rews[a] = float(reward) if a == "attacker" else 0.0
        self.agents = [a for a in live if not (terms[a] or truncs[a])]
        return ({a: obs[a] for a in live}, rews, terms, truncs, {a: infos[a] for a in live})

    # ------------------------------------------------------------------------------------------ conversions
    def _observations(self, out):
        n = self.scenario.n_vehicles
        vo = np.asarray(out["vehicle_obs"], np.float32)
        obs = {f"vehicle_{i}": vo[i] for i in range(n)}
        obs["attacker"] = np.asarray(out["attacker_obs"], np.float32)
        return obs

    def _infos(self, newly, fields):
        """The infos from the host copy of :func:`_info_fields` and the newly checked observations."""
        t = float(fields["t"])
        n = self.scenario.n_vehicles
        inside = np.asarray(fields["inside"])
        entered = np.asarray(fields["entered"])
        events = {i: [] for i in range(n)}
        dist = np.asarray(fields["obs_distance"])
        radius = self.scenario.observation_radius
        for m in np.flatnonzero(newly):
            ob = self.schedule[m]
            seen = bool(dist[m] <= radius)
            observer = f"vehicle_{ob.partner}" if ob.partner is not None else ob.point
            events[ob.agent].append({"time": float(ob.time), "observer": observer, "distance": float(dist[m]),
                                     "seen": seen})
            if ob.partner is not None:
                events[ob.partner].append({"time": float(ob.time), "observer": f"vehicle_{ob.agent}",
                                           "distance": float(dist[m]), "seen": seen})
        infos = {}
        status = np.asarray(fields["status"])
        for i in range(n):
            infos[f"vehicle_{i}"] = {"status": STATUS_NAMES[int(status[i])], "in_forbidden": bool(inside[i]),
                                     "entered_forbidden": bool(entered[i]), "observations": events[i], "time": t}
        c = int(fields["compromised"])
        entry = float(fields["entry_time"][c]) if c >= 0 else float("inf")
        det = float(fields["detect_time"])
        infos["attacker"] = {
            "compromised": f"vehicle_{c}" if c >= 0 else None,
            "active": c >= 0 and t >= float(fields["t_compromise"]) - 1e-6,
            "compromise_time": float(fields["t_compromise"]), "entered": bool(c >= 0 and entered[c]),
            "entry_time": entry if np.isfinite(entry) else None, "detected": bool(np.isfinite(det)),
            "detection_time": det if np.isfinite(det) else None,
            "success": bool(c >= 0 and entered[c] and not np.isfinite(det)),
            "missed_observations": int(np.asarray(fields["missed"]).sum()), "time": t}
        return infos

    @property
    def threat_state(self) -> threat.ThreatState:
        """The wrapper's :class:`~stp_env.coobservation.threat.ThreatState` (for analysis; unpacked from the device
        on the first read after a step)."""
        tree = self._carry.tree
        return None if tree is None else tree[1]

    def render(self):
        gymnasium.logger.warn("coobservation_v0 has no render mode.")

    def close(self):
        pass


def parallel_env(scenario: FormationScenario | None = None, schedule="secured", **kwargs) -> CoObservationParallelEnv:
    """The ParallelEnv (see the module docstring)."""
    return CoObservationParallelEnv(scenario, schedule, **kwargs)
