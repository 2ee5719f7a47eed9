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

(``stp_env.parallel_env`` is :func:`parallel_env` of this module; ``stp_env.env`` is this module, and calling it is
:func:`env`.) The first ``parallel_env()`` of a machine computes the scenario's reachability artifacts into the
artifact cache and says so on the terminal (``progress=False`` silences it); the first ``reset`` and ``step`` of a
machine compile the simulator, later processes load the compiled programs (:mod:`stp_env.compilation_cache`).

The environment is a thin adapter around the pure JAX core :mod:`stp_env.sim` (``reset``, ``step``, ``observe``;
one jitted call per step); batched rollouts of thousands of episodes use the core directly
(:func:`stp_env.sim.rollout`). A loop over one environment on a CPU runs faster with XLA's CPU runtime on one
thread (1.06-1.2x on an idle 2-core machine, 1.24-1.73x on a busy one): ``stp_env.set_cpu_threads(1)`` before the first
environment or array of the process (or ``PJRT_NPROC=1`` in the environment; :mod:`stp_env.cpu_threads`, which
also says why batches want every core).

Agents
------
================  ==========================================================================================
``vehicle_<i>``   STP vehicle ``i`` (scenario order). Dubins kinematics under wind (intruder paper eq. 43).
                  Waits on the ground until its departure time ``t_LDT`` (outside the airspace: cannot
                  collide, its actions are ignored), leaves the airspace when it reaches its target disk
                  (terminated), or when it collides or leaves the domain (terminated).
``intruder``      Appears at ``t_`` (random in ``EnvConfig.appear_window``, or ``reset(options=
                  {"appear_time": t})``) outside every vehicle's avoid region (Assumption 3), and is removed
                  ``t_IAT`` later (terminated). Its actions are ignored before it appears. Not an agent when
                  a script flies it (``intruder=...``).
================  ==========================================================================================

``possible_agents`` are the agents of the episode the configuration defines, the same for every seed: the
vehicles still to fly at its first instant (those that arrived earlier are out of the airspace for the whole
episode) and the intruder; ``reset`` makes every one of them an agent. An agent leaves ``agents`` when it is done
(PettingZoo's convention); with ``keep_finished=True`` it stays until the episode ends, with reward 0 and its
actions ignored, so that every agent ends in the same step (for clients without agent death: SuperSuit's vector
envs, TorchRL; docs/training.md). The last step of a truncated episode truncates every agent left (one that
terminates in it too is both).

Actions
-------
``Box(-1, 1, (2,), float32)`` for every agent (for the vehicles: their vehicle model's action size, 2 for the
papers' Dubins vehicle): ``a[0]`` maps linearly to the speed ``[v_min, v_max]`` [m/s], ``a[1]`` to the turn rate
``[-omega_max, omega_max]`` [rad/s]. Out-of-range actions are clipped. NaN or inf, anything but real numbers
(strings, booleans, complex), wrong shapes, and actions for unknown or finished agents raise ``ValueError`` naming
the agent and leave the state unchanged; the AEC form checks each action at its agent's own ``step`` (the agent is
still to act after the error), where ``None`` is the action of a finished agent only (PettingZoo's rule): a live
agent's ``step(None)`` raises ``ValueError`` naming it. ``step`` after every agent has finished raises
``RuntimeError``: call ``reset``. A live agent missing from the action dict applies the zero action. With
``EnvConfig(safety_filter=True)`` (the default), a vehicle forced by the intruder (its relative state reached the
boundary of ``V^A``, eqs. 17-18) has its action replaced by the avoidance control ``u^A`` (eq. 15) until the intruder
leaves (eq. 38); the info ``used_filter`` says when. ``vehicle_policy="worst"`` (or any name of
:data:`stp_env.baselines.VEHICLE_POLICIES`) flies the vehicles by that scripted policy instead of their actions
(which are still checked, then ignored): ``"worst"`` is the buffer game's worst vehicle, under which an optimal
intruder can reach the k̄ bound (the intruder paper's Fig. 6; scenario ``"fig6"``). ``vehicle_policy`` may also be
the user's own jittable function ``(key, state, params) -> actions`` ``(N, action_dim)`` in ``[-1, 1]`` (clipped;
checked once, abstractly, when the env is made), evaluated inside the step at every inner control step like the
named ones (the papers' controllers are in ``state.track_action`` and ``state.avoid_action``): one jitted call
per step instead of the user's call plus the step's. Define it once: the step compiles per function object.
``intruder="max-k"`` (a name of :data:`stp_env.baselines.INTRUDERS`, ``"learned:NAME_OR_PATH"``, a plug-in
``"package.module:policy"``, or the policy itself) flies the intruder by that policy the same way (there is then
no ``intruder`` agent); its record's capabilities apply
(:class:`stp_env.baselines.intruders.Intruder`): the buffer table is loaded for one that reads ``V^B``, and
without a ``config`` or a ``spawn_mode`` it appears where it spawns by default (``"boundary"`` for ``max-k``).

Observations
------------
``Box(-2, 2, (20 + 5K,))`` for vehicles and ``Box(-2, 2, (8 + 7K,))`` for the intruder (``K = n_nearest``, 4 by
default; the sizes are read from :func:`stp_env.sim.core.observe` itself, :func:`stp_env.sim.observation_sizes`):
own state, time to the STA, target, tracking error, the intruder within the sensing range ``d_sense`` (>= ``d^A``,
eq. 16) with its avoid-region value, and the ``K`` nearest flying vehicles, in the body frame. The table of entries
is in :func:`stp_env.sim.core.observe`. ``state()`` is the global state (:func:`stp_env.sim.global_state`): every
vehicle's ``(x, y, cos, sin)`` scaled by the domain, status and mode flags (the first entries of its observation),
the intruder's, and the time.

Rewards
-------
:class:`stp_env.sim.RewardConfig`: vehicles get progress toward the target, an arrival bonus (smaller after the
STA) and a collision penalty; the intruder gets ``+forced`` per vehicle newly forced to avoid, a large bonus per
collision it causes, and optional shaping by the avoid-region value.

Seeds and options
-----------------
``reset(seed=s)``: ``s`` an integer in ``[0, 2**63 - 1]`` (:func:`stp_env.seeds.prng_key`: every seed its own
episode stream, no truncation); booleans, floats, negative or larger seeds raise ``ValueError``. ``options``: a
dict; ``{"appear_time": t}`` fixes the intruder's appearance time ``t`` [s, plan time], a real number within the
episode ``[t_start, t_end]``; other keys are ignored with a warning. Everything is checked before anything
changes: after a failed ``reset`` the key, state and agents are as before. An ``EnvConfig.appear_window`` that
falls outside the episode raises ``ValueError`` when the environment is built. Observations and ``state()`` are
arrays of the caller's own (writable).

Infos (fresh dicts every step)
------------------------------
Numbers only (ints, floats, bools; no NaN), the same keys for every vehicle at every step, so that tensors can
hold them. Vehicles: ``status`` (an index of ``INFO_CODES["status"]``: waiting / flying / arrived / collided /
out_of_bounds), ``mode`` (of ``INFO_CODES["mode"]``: nominal / avoiding / after_avoidance), ``avoid_start_time``
(``t_i`` [s], ``inf`` if never forced), ``forced``, ``n_forced``
(``|N^RP|``, eq. 39), ``kbar``, ``collision``, ``guarantee_violation`` (a collision although the intruder
appeared outside its avoid region and it applied ``u^A`` from ``t_i`` on; not one in which a vehicle flying the
after-avoidance fallback takes part, see :mod:`stp_env.sim.core`), ``tracking_error`` [m] (distance to its
nominal position), ``max_tracking_error`` [m] (the largest at an inner control step while it flew its plan in the
nominal mode, never forced), ``tracked`` (it applied the tracker ``kappa`` at every inner step meanwhile: a
vehicle policy flew it, or its actions were the tracker's), ``tracking_violation`` (it tracked its plan and
``max_tracking_error`` exceeded the robust-tracking bound ``r_e``: a guarantee violation of the planner, as
``stp-env evaluate`` counts it), ``used_filter``, ``min_separation`` [m], ``cost`` (1.0 in the step of a
collision: the safety-gymnasium convention), ``time`` [s], ``sta`` (the current STA [s]: a new one after
replanning), ``replanned``.
Intruder: ``status`` (of ``INFO_CODES["intruder_status"]``: pending / present / gone), ``n_forced``, ``kbar``,
``kbar_exceeded``, ``collisions``, ``guarantee_violations``, ``tracking_violations``, ``cost`` (0.0), ``time``.
Every agent's info also holds the episode-level results so far (the same for every agent), each an entry
``stp_episode_<name>`` of its own (flat, so that every value is a number: no nested dict, and not ``episode``, the
key Stable-Baselines3's monitors own): ``n_forced``, ``kbar``, ``kbar_exceeded``, ``collisions``,
``guarantee_violations``, ``tracking_violations``, ``max_tracking_error`` [m] (over the vehicles of the episode
that flew and tracked their plan, as ``stp-env evaluate`` reports it; ``-inf`` if none did), ``tracking_bound``
(``r_e`` [m]), ``intruder_status`` (a code), ``time``. ``env.episode`` is the same record to
read, with names (``intruder_status`` ``"gone"``) and ``None`` (no tracked vehicle), after every ``reset`` and
``step``: at the end of an episode it is there whichever agents are left.

Arguments
---------
``parallel_env(scenario="town", config=None, *, max_cycles=None, render_mode=None, params=None, store=None,
backend=None, progress=None, keep_finished=False, **config_fields)``:
``scenario`` is a registry name or a :class:`stp_env.scenarios.Scenario`; ``config`` an
:class:`stp_env.sim.EnvConfig` (``dt`` [s], the inner control period ``control_dt`` [s], wind model, spawn mode,
safety filter, episode window, rewards); any field of it can also be given by name and replaces the config's
(``parallel_env("town", control_dt=0.01, wind_model="gusts")``). Settings outside what the guarantees certify (an
inner period outside 0.005-0.02 s, a smaller avoid margin, a plan that is not a flight of ``U^p``) are refused
unless ``allow_uncertified=True``;
``max_cycles`` caps the steps (default: the episode window ``t_end - t_start`` over ``dt``); ``params``
bypasses the scenario (prebuilt :class:`stp_env.sim.EnvParams`). ``replan=True`` runs Algorithm 4 when the
intruder leaves: every vehicle that was forced to avoid gets a new STA and plan
(:func:`stp_env.planning.replan.replan`, level-set solves on the host, about 15-25 s per event on ``town`` on 2
cores; ``env.replan_log`` records each) and tracks it in the nominal mode; without it (the default, and in the
batched core) it flies the jittable fallback of eq. 40 with no new STA. Use it with
``EnvConfig(episode="full")``: the default episode window ends 10 s after the intruder leaves.
``backend``: ``None`` (the config's plant: the papers' Dubins model in the jitted core by default), ``"jax"``,
``"pymunk"`` (the same Dubins motion stepped by the pymunk physics engine) or ``"pymunk-dynamic[:param=value,...]"``
(rigid bodies with mass, drag, actuator lag and wind as a force; :mod:`stp_env.sim.backends`).
``progress``: ``True`` shows the artifact builds (bars) and announces the compilation of reset and step on standard
error, ``False`` never; ``None`` (the default) when standard error is a terminal or ``$STP_ENV_PROGRESS=1``
(:mod:`stp_env.progress`).
``env(...)`` is the AEC form (``parallel_to_aec``), ``raw_env(...)`` the same without the order-enforcing wrapper.
Render modes: ``"rgb_array"`` (a top-down map: buildings, targets, vehicles with headings and danger zones,
the intruder, avoid-region footprints when ``render_avoid_regions=True``) and ``"human"`` (the same in a window).

Version history
---------------
* v1 (``stp_v1``, this version): with the same dynamics for the same actions as v0: the ``replan`` argument and
  the ``sta`` and ``replanned`` infos; ``guarantee_violation`` no longer counts a collision that a vehicle flying the
  after-avoidance fallback takes part in (it still counts as a collision). Seeds of ``2**32`` and more give their
  own episodes (they were reduced to their low 32 bits); negative seeds, and actions that are not real numbers,
  raise ``ValueError``. Vehicles may fly another plant than Dubins (``EnvConfig(vehicle_model=...)``; the action
  space is the model's). Added since, with the same dynamics: the infos ``tracking_error``, ``max_tracking_error``,
  ``tracked``, ``tracking_violation``, ``tracking_violations`` and ``episode``, and ``env.episode``.
* v0 (``stp_v0``): first release.
"""

from __future__ import annotations

import contextvars
import dataclasses
import functools
import math
import numbers
import reprlib
import sys
import time
import types
import warnings
from typing import ClassVar, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.wrappers import OrderEnforcingWrapper

from stp_env import assembly, sim
from stp_env.angles import wrap_angle
from stp_env.arguments import contains_bool
from stp_env.progress import compile_note
from stp_env.seeds import prng_key
from stp_env.sim import core, fleet
from stp_env.sim.backends import with_backend
from stp_env.sim.jit import sim_jit
from stp_env.sim.packing import DeviceCarry, Layout, pack
from stp_env.sim.rollout import intruder_decision
from stp_env.sim.types import (
    AFTER_AVOIDANCE,
    COLLIDED,
    FLYING,
    GONE,
    INTRUDER_STATUS_NAMES,
    MODE_NAMES,
    NOMINAL,
    STATUS_NAMES,
    WAITING,
    replace,
)

DEFAULT_SCENARIO = "town"
INFO_CODES = {"status": STATUS_NAMES, "mode": MODE_NAMES, "intruder_status": INTRUDER_STATUS_NAMES}
"""What the integer codes of the infos name: ``INFO_CODES["status"][info["status"]]`` is a vehicle's status
(``"waiting"``, ``"flying"``, ...); the intruder's ``status`` and ``stp_episode_intruder_status`` are
``INFO_CODES["intruder_status"]`` codes."""


_BUILD_PROGRESS = contextvars.ContextVar("stp_env_build_progress", default=False)


@functools.lru_cache(maxsize=8)
def _cached_params(scenario, config):
    return assembly.params_for(scenario, config, progress=_BUILD_PROGRESS.get())


class StepInfo(NamedTuple):
    """What the infos are made of, read on the device after each step (arrays ``(N,)`` per vehicle, scalars
    ``()``)."""

    status: jax.Array               # (N,) STATUS_NAMES index after the step
    prev_status: jax.Array          # (N,) before it (a collision is new when it was not COLLIDED)
    mode: jax.Array                 # (N,) MODE_NAMES index
    avoid_start: jax.Array          # (N,) [s] t_i (inf: never forced)
    guarantee_violation: jax.Array  # (N,) bool
    used_filter: jax.Array          # (N,) bool
    min_separation: jax.Array       # (N,) [m]
    t: jax.Array                    # () [s]
    intruder_status: jax.Array      # () INTRUDER_STATUS_NAMES index
    tracking_error: jax.Array       # (N,) [m] distance to the nominal position
    max_tracking_error: jax.Array   # (N,) [m] largest while tracking the plan (never forced)
    tracked: jax.Array              # (N,) bool: applied the tracker at every inner step while flying its plan
    tracking_violation: jax.Array   # (N,) bool: tracked, and max_tracking_error exceeded r_e


class StepOutput(NamedTuple):
    """Everything the adapter converts to numpy after a ``reset`` or ``step`` (one ``device_get``)."""

    obs_vehicles: jax.Array   # (N, vehicle observation size)
    obs_intruder: jax.Array   # (intruder observation size,)
    rewards: jax.Array        # (N + 1,)
    info: StepInfo
    terminated: jax.Array     # ()
    truncated: jax.Array      # ()


def _step_info(prev, new) -> StepInfo:
    return StepInfo(status=new.status, prev_status=prev.status, mode=new.mode, avoid_start=new.avoid_start,
                    guarantee_violation=new.guarantee_violation, used_filter=new.used_filter,
                    min_separation=new.min_separation, t=new.t, intruder_status=new.intruder_status,
                    tracking_error=new.tracking_error, max_tracking_error=new.max_tracking_error,
                    tracked=new.tracked, tracking_violation=new.tracking_violation)


def _advance(key, state, actions, params):
    """One adapter step: ``step``, then everything the adapter converts to numpy."""
    key, sub = jax.random.split(key)
    new, rewards = core.step(sub, state, actions, params)
    obs_v, obs_i = core.observe(new, params)
    term, trunc = core.episode_over(new, params)
    return key, new, StepOutput(obs_v, obs_i, rewards, _step_info(state, new), term, trunc)


def _start(key, params):
    key, sub = jax.random.split(key)
    state = core.reset(sub, params)
    obs_v, obs_i = core.observe(state, params)
    no = jnp.zeros((), bool)
    return key, state, StepOutput(obs_v, obs_i, jnp.zeros((params.vehicles.n + 1,), jnp.float32),
                                  _step_info(state, state), no, no)


_start_jit = sim_jit(_start)


_observe_jit = sim_jit(core.observe)
_global_state_jit = sim_jit(core.global_state)

TRACE_COUNTS = {"step": 0}  # incremented when the step function is traced (tests check it stays at 1)


def _advance_scripted(key, state, actions, params, vehicle_policy=None, intruder_policy=None):
    """:func:`_advance` with the vehicles and/or the intruder flown by scripted policies (their actions ignored):
    the intruder's action once per step from its own key (as in :func:`stp_env.sim.rollout`), the vehicles' policy
    as the feedback law of every inner control step."""
    key, sub = jax.random.split(key)
    if intruder_policy is not None:
        k_i, sub = jax.random.split(sub)
        a_i = intruder_decision(intruder_policy, k_i, state, params)
        actions = actions.at[params.vehicles.n, :2].set(a_i.astype(actions.dtype))
    new, rewards = core.step(sub, state, actions, params, vehicle_policy=vehicle_policy)
    obs_v, obs_i = core.observe(new, params)
    term, trunc = core.episode_over(new, params)
    return key, new, StepOutput(obs_v, obs_i, rewards, _step_info(state, new), term, trunc)


# ------------------------------------------------------------------------------------------------ one transfer
# A step's outputs are fetched as one packed int32 array, and the key and state it carries to the next step stay
# packed on the device as another (stp_env.sim.packing says why: each array in or out of a call has its own
# cost, larger than the step's own work on a CPU).


def _advance_carry(carry, actions, params, layout, vehicle_policy=None, intruder_policy=None, with_state=False):
    """One adapter step on the packed carry: ``(carry, actions, params) -> (carry, packed output)``, where the carry
    is :func:`pack` of ``(key, state)`` laid out as ``layout``; :func:`_advance` or, with a scripted policy,
    :func:`_advance_scripted`. ``with_state``: also ``(key, state)`` unpacked, for a user who reads ``env_state``
    after every step (one more output per array, instead of a second call that unpacks the carry)."""
    TRACE_COUNTS["step"] += 1
    key, state = layout.unpack_traced(carry)
    if vehicle_policy is None and intruder_policy is None:
        key, new, out = _advance(key, state, actions, params)
    else:
        key, new, out = _advance_scripted(key, state, actions, params, vehicle_policy=vehicle_policy,
                                          intruder_policy=intruder_policy)
    if with_state:
        return pack((key, new)), pack(out), (key, new)
    return pack((key, new)), pack(out)


_advance_carry_jit = sim_jit(_advance_carry, static_argnames=("layout", "vehicle_policy", "intruder_policy",
                                                               "with_state"))


def _clip_unit(x: np.ndarray) -> np.ndarray:
    """``np.clip(x, -1, 1)`` of finite ``x`` as two ufuncs (the same values; ``np.clip``'s Python wrapper cost a
    third of parsing the town's actions)."""
    return np.minimum(np.maximum(x, -1.0), 1.0)


def _check_vehicle_policy(policy, params) -> None:
    """A vehicle policy passed as a function: traced once abstractly on the env's state (nothing computed), it
    must return the vehicles' actions ``(N, action_dim)`` as floats; ``ValueError`` saying what it returned."""
    key = jax.random.key(0)
    name = getattr(policy, "__name__", repr(policy))
    try:
        out = jax.eval_shape(policy, key, jax.eval_shape(core.reset, key, params), params)
    except Exception as err:  # anything the trace raises: the message says which policy and why
        raise ValueError(f"vehicle_policy {name!r} is not a jittable function (key, state, params) -> actions: "
                         f"{type(err).__name__}: {err}") from err
    want = (params.vehicles.n, params.vehicles.model.action_dim)
    shape, dtype = getattr(out, "shape", None), getattr(out, "dtype", None)
    if shape is None or tuple(shape) != want or not jnp.issubdtype(dtype, jnp.floating):
        got = f"shape {tuple(shape)}, dtype {dtype}" if shape is not None else type(out).__name__
        raise ValueError(f"vehicle_policy {name!r} must return the vehicles' actions, floats of shape {want} (one "
                         f"row per vehicle, in [-1, 1]); it returned {got}.")


def _check_appear_window(params) -> None:
    """The intruder's appearance window must lie within the episode ``[t_start, t_end]``."""
    lo, hi = (float(v) for v in np.asarray(params.intruder.appear_window))
    t0, t1 = float(params.episode.t_start), float(params.episode.t_end)
    if not (np.isfinite(lo) and np.isfinite(hi) and t0 - 1e-3 <= lo <= hi <= t1 + 1e-3):
        raise ValueError(f"the intruder's appearance window [{lo:.2f}, {hi:.2f}] s (plan time; "
                         "EnvConfig.appear_window is relative to the first departure) is not within the episode "
                         f"[{t0:.2f}, {t1:.2f}] s: the intruder would appear before the episode starts or after it "
                         "ends.")


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
        from stp_env.baselines import BUFFER_GAME_VEHICLE_POLICIES, VEHICLE_POLICIES
        from stp_env.baselines import vehicle_policy as resolve_vehicle_policy
        from stp_env.baselines.intruders import capabilities, resolve_intruder
        from stp_env.scenarios import Scenario, make

        vehicle_policy_fn = None
        if callable(vehicle_policy):  # the user's own jittable policy (its outputs are checked below)
            vehicle_policy_fn = vehicle_policy
        elif vehicle_policy is not None:  # a name or learned:NAME_OR_PATH; ValueError before anything is built
            vehicle_policy_fn = resolve_vehicle_policy(vehicle_policy)

        if not isinstance(keep_finished, bool):
            raise ValueError(f"keep_finished must be True or False; got {keep_finished!r}.")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} is not supported; allowed: "
                             f"{self.metadata['render_modes']} or None.")
        if config is not None and not isinstance(config, sim.EnvConfig):
            raise ValueError(f"config must be a stp_env.sim.EnvConfig; got {type(config).__name__}.")
        intruder_policy = resolve_intruder(intruder) if isinstance(intruder, str) else intruder
        if intruder_policy is not None and not callable(intruder_policy):
            raise ValueError(f"intruder must be None (the agent acts), an intruder spec or a policy; got {intruder!r}.")
        intruder_caps = None if intruder_policy is None else capabilities(intruder_policy)
        if config is None and intruder_caps is not None and "spawn_mode" not in config_overrides:
            config = sim.EnvConfig(spawn_mode=intruder_caps.spawn)  # where the scripted intruder appears by default
        config = sim.EnvConfig() if config is None else config
        if config_overrides:
            fields = {f.name for f in dataclasses.fields(sim.EnvConfig)}
            unknown = sorted(set(config_overrides) - fields)
            if unknown:
                raise TypeError(f"parallel_env() got unexpected keyword argument(s) {unknown}; besides its own "
                                f"arguments it takes the fields of stp_env.sim.EnvConfig: {sorted(fields)}.")
            config = config.with_overrides(**config_overrides)
        config = with_backend(config, backend)
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
        _check_appear_window(params)
        buffer_policies = {VEHICLE_POLICIES[name] for name in BUFFER_GAME_VEHICLE_POLICIES}
        buffer_game = vehicle_policy_fn in buffer_policies or (intruder_caps is not None
                                                                and intruder_caps.needs_buffer)
        if buffer_game and params.tables.buffer_values is None:
            params = assembly.with_buffer(params, assembly.load_buffer(scenario, store=store,
                                                                         progress=self._progress))
        if callable(vehicle_policy):
            _check_vehicle_policy(vehicle_policy_fn, params)
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
        self._plan0 = None
        if self.replan:
            from stp_env.planning.replan import obstacle_pads

            plan0 = assembly.load_plan(scenario, tracking_bound=float(params.tables.tracking_bound), store=store,
                                  progress=self._progress)
            # the windows of the plan's disks (derived once here for plan files that do not record them)
            self._plan0 = dataclasses.replace(plan0, obstacle_pads=obstacle_pads(plan0, self.scenario, store=store))
        self._plan = self._plan0
        self._replan_tried = np.zeros(params.vehicles.n, bool)
        self._replanned = np.zeros(params.vehicles.n, bool)
        self._sta = np.asarray(params.vehicles.sta, np.float64)
        self.replan_log: list[dict] = []
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
        self.keep_finished = keep_finished
        self._finished: set[str] = set()  # agents done before the episode's end (kept as agents: keep_finished)
        default_cycles = sim.steps_for(params)
        if max_cycles is None:
            max_cycles = default_cycles
        if isinstance(max_cycles, bool) or not isinstance(max_cycles, (int, np.integer)) or max_cycles < 1:
            raise ValueError(f"max_cycles must be a positive integer; got {max_cycles!r}.")
        self.max_cycles = int(max_cycles)
        self.render_mode = render_mode
        self.render_avoid_regions = render_avoid_regions
        self._dv, self._di = core.observation_sizes(params)
        self._state_size = core.global_state_size(params)
        self._kbar = int(params.intruder.kbar)
        self._tracking_bound = float(params.tables.tracking_bound)
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
        """The intruder flies Dubins (speed, turn rate); the vehicles' action size is their model's."""
        return 2 if agent == "intruder" else self.params.vehicles.model.action_dim

    def _check_known(self, agent):
        if agent not in self.possible_agents:
            raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}.")

    # ------------------------------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        # Everything is checked before anything changes: a failed reset leaves the key, state and agents as they
        # were (the next episode is the one it would have been without the failed call).
        key = prng_key(seed) if seed is not None else self._key
        appear_time = self._check_options(options)
        if key is None:
            key = prng_key(int(np.random.SeedSequence().entropy % (2 ** 31)))
        params = self._base_params
        start_params = params
        if appear_time is not None:
            start_params = params.replace(intruder=dict(appear_window=jnp.asarray([appear_time, appear_time],
                                                                                  jnp.float32)))
        compile_note("the environment's reset", key, start_params, progress=self._progress)
        key, state, out = _start_jit(key, start_params)
        self._carry.set((key, state))
        self.params = params
        self._plan = self._plan0
        self._replan_tried = np.zeros(params.vehicles.n, bool)
        self._replanned = np.zeros(params.vehicles.n, bool)
        self._sta = np.asarray(params.vehicles.sta, np.float64)
        self.replan_log = []
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

    def _check_options(self, options) -> float | None:
        """The ``appear_time`` option (``None`` if not given), checked; unknown options are warned about."""
        if options is None:
            return None
        if not isinstance(options, dict):
            raise ValueError(f"options must be a dict (e.g. {{'appear_time': seconds}}) or None; got "
                             f"{type(options).__name__}.")
        unknown = sorted(map(repr, set(options) - {"appear_time"}))
        if unknown:  # PettingZoo's API test passes arbitrary options and expects them to be ignored
            gymnasium.logger.warn(f"ignoring unknown reset option(s) {', '.join(unknown)}; known: 'appear_time' "
                                  "(seconds, plan time).")
        if "appear_time" not in options:
            return None
        t = options["appear_time"]
        if isinstance(t, (bool, np.bool_)) or not isinstance(t, numbers.Real):
            raise ValueError(f"appear_time must be a real number of seconds (plan time); got {t!r} "
                             f"({type(t).__name__}).")
        t = float(t)
        if not np.isfinite(t):
            raise ValueError(f"appear_time must be finite; got {t}.")
        lo, hi = float(self._base_params.episode.t_start), float(self._base_params.episode.t_end)
        if not lo <= t <= hi:
            raise ValueError(f"appear_time {t} s is outside the episode [{lo:.2f}, {hi:.2f}] s (plan time): the "
                             "intruder would appear before the episode starts or after it ends.")
        return t

    def _check_action(self, agent, a) -> np.ndarray | None:
        """The action of a live ``agent`` as a clipped float32 array (``None``: the zero action);
        ``ValueError`` naming the agent for anything else."""
        if agent not in self.possible_agents:
            raise ValueError(f"action for unknown agent {agent!r}; agents are {self.possible_agents}.")
        if agent not in self.agents:
            raise ValueError(f"action for {agent!r}, which has finished (terminated or truncated); "
                             f"live agents: {self.agents}.")
        if a is None:
            return None
        try:
            arr = np.asarray(a)
        except (TypeError, ValueError) as err:
            raise ValueError(f"action for {agent!r} is not an array of numbers ({err}).") from None
        if arr.dtype.kind not in "iuf" or contains_bool(a):  # [True, 0.5] reads as [1.0, 0.5] in NumPy
            raise ValueError(f"action for {agent!r} must be real numbers (speed, turn rate in [-1, 1]); got "
                             f"{reprlib.repr(a)} (dtype {arr.dtype}).")
        shape = (self._action_dim(agent),)
        if arr.shape != shape:
            raise ValueError(f"action for {agent!r} must have shape {shape} (in [-1, 1]; Dubins: speed, turn rate); "
                             f"got shape {arr.shape}.")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"action for {agent!r} is not finite: {arr.tolist()}; actions must be finite numbers "
                             "in [-1, 1] (out-of-range values are clipped).")
        return np.clip(arr, -1.0, 1.0).astype(np.float32)

    def _parse_actions(self, actions) -> np.ndarray:
        if self._carry.words is None:
            raise RuntimeError("call reset() before step().")
        if not self.agents:
            raise RuntimeError("the episode is over (every agent has terminated or been truncated); call reset() "
                               "before step().")
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict {{agent: action}}; got {type(actions).__name__}.")
        n = self.params.vehicles.n
        arr = np.zeros((n + 1, max(2, self.params.vehicles.model.action_dim)), np.float32)
        if self._parse_plain(actions, arr):
            return arr
        for agent, a in actions.items():  # the general path: every action checked on its own, errors named
            checked = self._check_action(agent, a)
            if checked is not None:
                arr[self._index[agent], :checked.shape[0]] = checked
        return arr

    def _parse_plain(self, actions, arr) -> bool:
        """The common case in one vectorised check: every action a finite float ``np.ndarray`` of its agent's
        shape, for a live agent; clipped into ``arr``. ``False`` (``arr`` untouched) for anything else, which the
        general path then accepts (lists, ``None``, ints) or rejects with a message naming the agent. The same
        result as the general path, with one finiteness check and one clip per action size instead of one per
        agent (the per-agent checks were a third of an adapter step for the city's 51 agents)."""
        live, index = set(self.agents), self._index
        vehicle_shape = (self.params.vehicles.model.action_dim,)
        rows, values = [], []
        for agent, a in actions.items():
            if type(a) is not np.ndarray or a.dtype.kind != "f" or agent not in live or \
                    a.shape != ((2,) if agent == "intruder" else vehicle_shape):
                return False
            rows.append(index[agent])
            values.append(a)
        if not values:
            return True
        if vehicle_shape == (2,):  # one action size for every agent (Dubins vehicles)
            stacked = np.asarray(values, np.float64)
            if not np.isfinite(stacked).all():
                return False
            arr[rows, :2] = _clip_unit(stacked)
            return True
        groups: dict[int, tuple[list, list]] = {}
        for row, a in zip(rows, values):
            group = groups.setdefault(a.shape[0], ([], []))
            group[0].append(row)
            group[1].append(a)
        stacked = {dim: np.asarray(group[1], np.float64) for dim, group in groups.items()}
        if not all(np.isfinite(v).all() for v in stacked.values()):
            return False
        for dim, (group_rows, _) in groups.items():
            arr[group_rows, :dim] = _clip_unit(stacked[dim])
        return True

    def step(self, actions):
        arr = self._parse_actions(actions)  # raises before anything changes
        scripted = not (self._vehicle_policy is None and self._intruder_policy is None)
        if self._step_layout is None:  # traced once per environment, not compiled
            advance = (functools.partial(_advance_scripted, vehicle_policy=self._vehicle_policy,
                                         intruder_policy=self._intruder_policy) if scripted else _advance)
            self._step_layout = Layout.of(jax.eval_shape(advance, *self._carry.unpacked(), arr, self.params)[2])
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
        words = self._carry.advance(_advance_carry_jit, arr, self.params, vehicle_policy=self._vehicle_policy,
                                    intruder_policy=self._intruder_policy, with_state=with_state)
        self._steps += 1
        out = self._step_layout.unpack(np.asarray(words))
        obs, rewards, info = self._observations(out.obs_vehicles, out.obs_intruder), out.rewards, out.info
        if self.replan:
            obs, info = self._maybe_replan(obs, info)
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

    # ------------------------------------------------------------------------------------------ replanning
    def _maybe_replan(self, obs, info: StepInfo):
        """Algorithm 4 after the intruder has left: every flying vehicle in the after-avoidance mode that has not
        been replanned gets a new STA and plan (:func:`stp_env.planning.replan.replan`, host side), the
        simulator's nominal tables are updated (:func:`stp_env.assembly.with_plan`; same shapes, no retrace) and the
        vehicle is back in the nominal mode, tracking its new plan. Returns the observations and info arrays of
        the updated state."""
        need = (info.mode == AFTER_AVOIDANCE) & (info.status == FLYING) & ~self._replan_tried
        if not need.any():
            return obs, info
        from stp_env.planning.replan import replan  # host-side level-set planning: imported on first use

        idx = [int(i) for i in np.nonzero(need)[0]]
        self._replan_tried[idx] = True  # one attempt per vehicle and episode
        x = np.asarray(self._state.x, np.float64)
        t_bar = float(self._state.t)
        affected = {i: (x[i, 0], x[i, 1], wrap_angle(float(x[i, 2]))) for i in idx}
        start = time.perf_counter()
        try:
            new_plan = replan(self._plan, self.scenario, affected, t_bar)
        except ValueError as err:
            warnings.warn(f"replanning vehicles {idx} at t = {t_bar:.1f} s failed ({err}); they keep the fallback "
                          "control of eq. 40.", stacklevel=3)
            self.replan_log.append({"time": t_bar, "vehicles": idx, "error": str(err)})
            return obs, info
        self._plan = new_plan
        self.params = assembly.with_plan(self.params, new_plan)
        key, state = self._carry.unpacked()
        self._carry.set((key, replace(state, mode=state.mode.at[jnp.asarray(idx)].set(NOMINAL))))
        self._replanned[idx] = True
        self._sta = np.asarray(self.params.vehicles.sta, np.float64)
        self.replan_log.append({"time": t_bar, "vehicles": idx,
                                "sta": [float(new_plan.vehicles[i].plan.sta) for i in idx],
                                "old_sta": [float(self._base_params.vehicles.sta[i]) for i in idx],
                                "seconds": round(time.perf_counter() - start, 2)})
        obs = self._observations(*jax.device_get(_observe_jit(self._state, self.params)))
        mode = np.array(info.mode)
        mode[idx] = NOMINAL
        return obs, info._replace(mode=mode)

    # ------------------------------------------------------------------------------------------ conversions
    def _observations(self, obs_vehicles, obs_intruder) -> dict[str, np.ndarray]:
        """Every agent's observation, an array of its own (writable; a client may change it in place)."""
        obs = {name: row.copy() for name, row in zip(self._vehicle_names, obs_vehicles)}
        obs["intruder"] = np.array(obs_intruder)
        return obs

    def _infos(self, info: StepInfo, live) -> dict:
        """The infos of the agents ``live`` (in that order) from the step's :class:`StepInfo`; sets ``episode``."""
        status, mode, avoid_start = info.status.astype(int), info.mode.astype(int), info.avoid_start
        forced = np.isfinite(avoid_start)
        n_forced = int(forced.sum())
        kbar = self._kbar
        collided = status == COLLIDED
        new_collision = collided & (info.prev_status != COLLIDED)
        t = float(info.t)
        violation, used, min_sep = info.guarantee_violation, info.used_filter, info.min_separation
        error, max_error, track_violation = info.tracking_error, info.max_tracking_error, info.tracking_violation
        # as the evaluator: vehicles of the episode that flew and tracked their plan (not one flown by the agent)
        flew_tracked = info.tracked & (status != WAITING) & self._in_episode
        episode = {
            "n_forced": n_forced,
            "kbar": kbar,
            "kbar_exceeded": bool(kbar > 0 and n_forced > kbar),
            "collisions": int(collided.sum()),
            "guarantee_violations": int(violation.sum()),
            "tracking_violations": int(track_violation.sum()),
            # no NaN in the infos (NaN != NaN: PettingZoo's seed tests compare infos): the maximum over no vehicle
            "max_tracking_error": float(np.max(max_error[flew_tracked])) if flew_tracked.any() else -math.inf,
            "tracking_bound": self._tracking_bound,
            "intruder_status": int(info.intruder_status),
            "time": t,
        }
        # env.episode: the same record to read (names, None), the infos' one to hold in tensors (numbers)
        self.episode = {**episode, "intruder_status": INTRUDER_STATUS_NAMES[episode["intruder_status"]],
                        "max_tracking_error": (None if episode["max_tracking_error"] == -math.inf
                                               else episode["max_tracking_error"])}
        # Only the live agents' dicts are built (the city's finished vehicles are most of its agents late in an
        # episode), each from Python lists (one tolist() per column): no per-element numpy scalars
        live_set = set(live)
        columns = zip(self._vehicle_names, status.tolist(), mode.tolist(), avoid_start.tolist(), forced.tolist(),
                      collided.tolist(), violation.tolist(), error.tolist(), max_error.tolist(),
                      info.tracked.tolist(), track_violation.tolist(), used.tolist(), self._replanned.tolist(),
                      self._sta.tolist(), min_sep.tolist(), new_collision.tolist())
        record = {f"stp_episode_{k}": v for k, v in episode.items()}  # flat: a tensor per entry
        built = {}
        for (agent, st, md, start, frc, col, viol, err, max_err, tracked, track_viol, used_i, replanned, sta,
             sep, new_col) in columns:
            if agent not in live_set:
                continue
            built[agent] = {
                "status": st,
                "mode": md,
                "avoid_start_time": start,  # inf: never forced (the core's own convention)
                "forced": frc,
                "n_forced": n_forced,
                "kbar": kbar,
                "collision": col,
                "guarantee_violation": viol,
                "tracking_error": err,
                "max_tracking_error": max_err,
                "tracked": tracked,
                "tracking_violation": track_viol,
                "used_filter": used_i,
                "replanned": replanned,
                "sta": sta,
                "min_separation": sep,
                "cost": float(new_col),
                "time": t,
                **record,
            }
        if "intruder" in live_set:
            built["intruder"] = {
                "status": episode["intruder_status"],
                "n_forced": n_forced,
                "kbar": kbar,
                "kbar_exceeded": episode["kbar_exceeded"],
                "collisions": episode["collisions"],
                "guarantee_violations": episode["guarantee_violations"],
                "tracking_violations": episode["tracking_violations"],
                "cost": 0.0,
                "time": t,
                **record,
            }
        return {agent: built[agent] for agent in live}

    def state(self) -> np.ndarray:
        """The global state (``state_space``): per vehicle ``(x, y)`` scaled, ``cos, sin``, flying / finished /
        waiting / avoiding / after flags; the intruder's ``(x, y, cos, sin)``, present flag, ``tau / t_IAT``; and
        the time since the episode start over its length."""
        if self._carry.words is None:
            raise RuntimeError("call reset() before state().")
        return np.array(_global_state_jit(self._state, self.params))  # an array of the caller's own (writable)

    # ------------------------------------------------------------------------------------------ render
    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        if self._carry.words is None:
            raise RuntimeError("call reset() before render().")
        from stp_env.render import draw_frame

        fig = draw_frame(self, self._fig)
        self._fig = fig
        if self.render_mode == "rgb_array":
            fig.canvas.draw()
            return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
        import matplotlib
        import matplotlib.pyplot as plt

        if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "ps", "cairo", "template"):
            plt.pause(1.0 / self.metadata["render_fps"])
        return None

    def close(self):
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None

    @property
    def env_state(self) -> sim.EnvState:
        """The core's :class:`~stp_env.sim.EnvState` (read-only use; for parity checks and custom analysis);
        ``None`` before the first ``reset``. Read between two steps, it comes with the next step's outputs (a loop
        that reads it after every step makes one call per step, not two)."""
        tree = self._carry.tree
        return None if tree is None else tree[1]

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
