"""The assembly layer: from a scenario, its plan and the reachability artifacts to
:class:`~stp_env.sim.types.EnvParams` (host side, numpy; runs once per environment).

It sits above the simulation core (:mod:`stp_env.sim`), the planner, the scenarios and the artifact store, and is the
one place where they meet (docs/architecture.md, "Layers"): :func:`params_for` (a scenario or its registry name to
``EnvParams``: artifacts, plan, checks), :func:`make_params` (the same from given artifacts and plan, with every
check of what the proofs certify), :func:`load_artifacts`, :func:`load_plan` (the shipped plan when there is one,
:data:`SHIPPED_PLANS`, else the cached one), :func:`with_plan` (replanning), :func:`load_buffer` and
:func:`with_buffer` (the ``V^B`` table of the buffer-game policies). The core itself knows no scenario, plan or
artifact: it reads the arrays of ``EnvParams``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.params_checks import (
    PERIOD_DECIMALS,
    CheckedInputs,
    check_inputs,
    faults_message,
    plan_faults,
    plan_period,
    sample_period,
)
from stp_env.progress import enabled as progress_enabled
from stp_env.scenarios.catalog.city import CITY_CASES
from stp_env.sim.bounds import bounds_row
from stp_env.sim.config import EnvConfig
from stp_env.sim.margins import tube_free_level
from stp_env.sim.tables import pad_components, pad_periodic
from stp_env.sim.types import EnvParams, EpisodeParams, IntruderParams, TableParams, VehicleParams, WindParams


def flying_counts(plan, times: np.ndarray) -> np.ndarray:
    """How many vehicles of ``plan`` are in the air (departed, not yet arrived) at each of ``times``."""
    dep = np.asarray([v.plan.t_ldt for v in plan.vehicles])
    arr = np.asarray([v.plan.arrival_time if math.isfinite(v.plan.arrival_time) else v.plan.times[-1]
                      for v in plan.vehicles])
    return ((times[:, None] >= dep[None, :]) & (times[:, None] < arr[None, :])).sum(axis=1)


def busiest_window(plan, step: float = 0.5) -> tuple[float, float]:
    """The first longest time interval during which the most vehicles of ``plan`` are in the air [s]."""
    dep = min(v.plan.t_ldt for v in plan.vehicles)
    end = max(v.plan.times[-1] for v in plan.vehicles)
    times = np.arange(dep, end + step, step)
    counts = flying_counts(plan, times)
    best = counts == counts.max()
    # longest run of True
    runs, start = [], None
    for i, b in enumerate(best):
        if b and start is None:
            start = i
        if (not b or i == len(best) - 1) and start is not None:
            stop = i if b else i - 1
            runs.append((stop - start, start, stop))
            start = None
    _, a, b = max(runs)
    return float(times[a]), float(times[b])


def _plan_arrays(plan):
    vehicles = plan.vehicles
    dt = plan_period(plan)
    k = max(len(v.plan.times) for v in vehicles)
    n = len(vehicles)
    states = np.zeros((n, k, 3), np.float32)
    controls = np.zeros((n, k, 2), np.float32)
    for i, v in enumerate(vehicles):
        m = len(v.plan.times)
        states[i, :m], controls[i, :m] = v.plan.states, v.plan.controls
        states[i, m:], controls[i, m:] = v.plan.states[-1], v.plan.controls[-1]
    return {
        "nominal_t0": np.asarray([v.plan.times[0] for v in vehicles], np.float32),
        "nominal_dt": np.float32(dt),
        "nominal_states": states,
        "nominal_controls": controls,
        "nominal_len": np.asarray([len(v.plan.times) for v in vehicles], np.int32),
        "departure": np.asarray([v.plan.t_ldt for v in vehicles], np.float32),
        "sta": np.asarray([v.plan.sta for v in vehicles], np.float32),
        "arrival": np.asarray([v.plan.arrival_time for v in vehicles], np.float32),
        "starts": states[:, 0].copy(),
    }


def with_plan(params: EnvParams, plan, *, pad_to: int = 256, allow_uncertified: bool = False) -> EnvParams:
    """``params`` with the nominal trajectories, STAs and planned arrival times of ``plan`` (the departure times
    and start states stay: they belong to the episode's start), e.g. after replanning (Algorithm 4,
    :func:`stp_env.planning.replan.replan`), which changes only the affected vehicles' entries.

    The sample tables keep their length ``K`` when every trajectory fits, so the jitted step is not retraced;
    otherwise they grow to the next multiple of ``pad_to`` samples (one retrace). Raises ``ValueError`` if the
    plan has another number of vehicles or another sample period, or if a trajectory is not a flight of the
    planning dynamics (:func:`plan_faults`, dynamics only: replanned vehicles start in the air) unless
    ``allow_uncertified``, in which case those vehicles are no longer ``certified``."""
    n = params.vehicles.n
    if len(plan.vehicles) != n:
        raise ValueError(f"the plan has {len(plan.vehicles)} vehicles; these params have {n}.")
    arrays = _plan_arrays(plan)
    if not math.isclose(float(arrays["nominal_dt"]), float(params.vehicles.nominal_dt), rel_tol=1e-5):
        raise ValueError(f"the plan's sample period is {float(arrays['nominal_dt'])} s; the simulator's nominal "
                         f"tables use {float(params.vehicles.nominal_dt)} s.")
    dyn = params.tables.tracking_dynamics
    faults = plan_faults(plan, dt=float(arrays["nominal_dt"]), planning_v=(dyn.other_v_min, dyn.other_v_max),
                         planning_omega_max=dyn.other_omega_max, targets=np.asarray(params.vehicles.targets),
                         target_radii=np.asarray(params.vehicles.target_radii))
    if faults and not allow_uncertified:
        raise ValueError(faults_message(faults, "the new plan"))
    faulty = np.asarray([v.index in faults for v in plan.vehicles])
    k_old, k_new = params.vehicles.nominal_states.shape[1], arrays["nominal_states"].shape[1]
    k = k_old if k_new <= k_old else pad_to * math.ceil(k_new / pad_to)
    states, controls = arrays["nominal_states"], arrays["nominal_controls"]
    if k > k_new:  # pad with the last sample, as _plan_arrays does
        states = np.concatenate([states, np.repeat(states[:, -1:], k - k_new, axis=1)], axis=1)
        controls = np.concatenate([controls, np.repeat(controls[:, -1:], k - k_new, axis=1)], axis=1)
    return params.replace(vehicles=dict(
        nominal_t0=jnp.asarray(arrays["nominal_t0"]), nominal_states=jnp.asarray(states),
        nominal_controls=jnp.asarray(controls), nominal_len=jnp.asarray(arrays["nominal_len"]),
        sta=jnp.asarray(arrays["sta"]), nominal_arrival=jnp.asarray(arrays["arrival"]),
        certified=jnp.asarray(np.asarray(params.vehicles.certified) & ~faulty)))


def make_params(scenario, plan, avoid, tracking, config: EnvConfig | None = None) -> EnvParams:
    """Assemble the simulator's constants.

    Args:
        scenario: a :class:`stp_env.scenarios.Scenario`.
        plan: its :class:`stp_env.planning.Plan` (nominal trajectories and departure times).
        avoid: the :class:`stp_env.reach.avoid.AvoidRegion` for the scenario's vehicle, ``R_c`` and ``t_IAT``.
        tracking: the :class:`stp_env.reach.tracking.TrackingBound` of its planning set.
        config: :class:`EnvConfig` (default: ``EnvConfig()``).

    Everything is checked against what the proofs certify before anything is built: the avoid region and the
    tracking bound must be those of the scenario's vehicle, planning set, ``R_c`` and ``t_IAT``; the tracking bound
    must be certified in closed loop; the avoid margin must be at least the certified one; every trajectory of the
    plan must be a flight of the planning dynamics (:func:`plan_faults`); the decision step ``dt`` may not be longer
    than ``t_IAT`` (the intruder stays a whole step: Assumption 1). The last four are refused with one line unless
    ``config.allow_uncertified``; the vehicles concerned then have ``certified`` false. The checks are
    :func:`stp_env.params_checks.check_inputs`; each group of ``EnvParams`` is then built by its own function.
    """
    config = EnvConfig() if config is None else config
    checked = check_inputs(scenario, plan, avoid, tracking, config)
    arrays = _plan_arrays(plan)
    window = _appear_window(plan, arrays, config)
    return EnvParams(episode=_episode_params(scenario, plan, arrays, window, config),
                     vehicles=_vehicle_params(scenario, plan, avoid, arrays, checked, config),
                     intruder=_intruder_params(scenario, plan, avoid, window, checked, config),
                     tables=_table_params(scenario, avoid, tracking, checked, config),
                     wind=_wind_params(config))


def _appear_window(plan, arrays, config: EnvConfig) -> tuple[float, float]:
    """``(lo, hi)`` [s], the window in which the intruder appears: ``config.appear_window`` after the first
    departure, else the plan's :func:`busiest_window` (``arrays``: :func:`_plan_arrays` of ``plan``)."""
    if config.appear_window is None:
        return busiest_window(plan)
    first = float(arrays["departure"].min())
    return first + config.appear_window[0], first + config.appear_window[1]


def _episode_params(scenario, plan, arrays, window, config: EnvConfig) -> EpisodeParams:
    """When and where the episode runs: a ``"window"`` episode from ``lead`` before the appear ``window`` to
    ``tail`` after the intruder leaves (``t_IAT`` after its latest appearance, Assumption 1); a ``"full"`` one from
    the first departure to the last STA or plan sample (or the intruder's leaving) plus ``tail``; never starting more
    than a step before the first departure. The safety filter replaces actions by ``u^A`` (eq. 38)."""
    lo, hi = window
    t_iat = float(scenario.t_iat)
    if config.episode == "window":
        t_start, t_end = lo - config.lead, hi + t_iat + config.tail
    else:
        t_start = float(arrays["departure"].min())
        last = max(float(arrays["sta"].max()), max(float(v.plan.times[-1]) for v in plan.vehicles))
        t_end = max(last, hi + t_iat) + config.tail
    t_start = max(t_start, float(arrays["departure"].min()) - config.dt)
    f32 = np.float32
    return EpisodeParams(
        dt=jnp.asarray(config.dt, f32),
        t_start=jnp.asarray(t_start, f32),
        t_end=jnp.asarray(t_end, f32),
        domain_lo=jnp.asarray(scenario.domain_lo, f32),
        domain_hi=jnp.asarray(scenario.domain_hi, f32),
        collision_radius=jnp.asarray(scenario.collision_radius, f32),
        reward_weights=config.rewards.weights(),
        safety_filter=config.safety_filter,
        n_nearest=config.n_nearest,
        control_substeps=config.control_substeps,
    )


def _vehicle_params(scenario, plan, avoid, arrays, checked: CheckedInputs, config: EnvConfig) -> VehicleParams:
    """The vehicles: the HJ model's bounds (those of the avoid region's vehicle), the plan's nominal tables, the
    scenario's targets, and ``certified`` false for every vehicle under an uncertified setting and for those whose
    trajectories are not flights of ``U^p`` (``checked``)."""
    certified = np.asarray([not checked.uncertified and v.index not in checked.faults for v in plan.vehicles], bool)
    f32 = np.float32
    return VehicleParams(
        bounds=jnp.asarray(bounds_row(avoid.config.vehicle), f32),
        departure=jnp.asarray(arrays["departure"]),
        sta=jnp.asarray(arrays["sta"]),
        nominal_arrival=jnp.asarray(arrays["arrival"]),
        starts=jnp.asarray(arrays["starts"]),
        targets=jnp.asarray(scenario.targets(), f32),
        target_radii=jnp.asarray(scenario.target_radii(), f32),
        nominal_t0=jnp.asarray(arrays["nominal_t0"]),
        nominal_dt=jnp.asarray(arrays["nominal_dt"]),
        nominal_states=jnp.asarray(arrays["nominal_states"]),
        nominal_controls=jnp.asarray(arrays["nominal_controls"]),
        nominal_len=jnp.asarray(arrays["nominal_len"]),
        certified=jnp.asarray(certified),
        planning_v_max=jnp.asarray(scenario.planning_v[1], f32),
        n=scenario.n_vehicles,
        model=config.vehicle_model,
    )


def _intruder_params(scenario, plan, avoid, window, checked: CheckedInputs, config: EnvConfig) -> IntruderParams:
    """The intruder (Assumption 1): its bounds, ``t_IAT``, the appear ``window``, its spawns (``"outside"`` within
    ``spawn_radius``, 1.5 d^A by default (eq. 16), Assumption 3; ``"boundary"``, Observation 1), the k̄ under test
    (the plan's, else the scenario's, else -1) and the sensing range ``d_sense`` (``checked``)."""
    kbar = plan.kbar if plan.kbar is not None else (scenario.kbar if scenario.kbar is not None else -1)
    f32 = np.float32
    return IntruderParams(
        bounds=jnp.asarray(bounds_row(avoid.config.intruder), f32),
        t_iat=jnp.asarray(float(scenario.t_iat), f32),
        appear_window=jnp.asarray(list(window), f32),
        spawn_radius=jnp.asarray(1.5 * checked.detection_range if config.spawn_radius is None else
                                 config.spawn_radius, f32),
        spawn_boundary_probability=jnp.asarray({"outside": 0.0, "boundary": 1.0, "mixed": 0.5}[config.spawn_mode],
                                               f32),
        kbar=jnp.asarray(kbar, jnp.int32),
        d_sense=jnp.asarray(checked.d_sense, f32),
    )


def _table_params(scenario, avoid, tracking, checked: CheckedInputs, config: EnvConfig) -> TableParams:
    """The grid tables: the buildings' signed distance (a far-away constant without buildings); the avoid value
    ``V^A`` of the relative dynamics (eq. 44), with d^A (eq. 16) and the avoid margin (``checked``); the tracking
    table, the gradient of ``W = -V`` of the tracking-error game (3) on the SPP error dynamics (eqs. 24-25), which
    the tracker ``kappa`` reads (SPP eq. 26), and ``V`` itself, with ``r_e`` and the tube's free level
    (:func:`stp_env.sim.margins.tube_free_level`)."""
    acfg, tcfg = avoid.config, tracking.config
    if scenario.buildings:
        gx, gy = scenario.grid_points[:2]
        sdf_grid = hj.Grid.from_bounds(scenario.domain_lo, scenario.domain_hi, (gx, gy))
        sdf = np.asarray(scenario.static_obstacle())[:, :, 0].astype(np.float32)
    else:
        sdf_grid = hj.Grid.from_bounds(scenario.domain_lo, scenario.domain_hi, (5, 5))
        sdf = np.full((5, 5), 1.0e6, np.float32)
    grads = hj.interpolation.gradient_field(tcfg.grid, jnp.asarray(-np.asarray(tracking.value), jnp.float32))
    tracking_value = np.asarray(tracking.value, np.float32)
    box = tcfg.error_dynamics.control_space.blocks[0]
    error_states = np.stack([np.broadcast_to(np.asarray(x), tcfg.grid.shape) for x in tcfg.grid.broadcast_states()])
    free_level = tube_free_level(tracking_value, -np.stack([np.asarray(g) for g in grads]), error_states, box.lo,
                                 box.hi, config.control_dt, tracking.bound - tracking.raised)
    f32 = np.float32
    return TableParams(
        sdf=jnp.asarray(sdf),
        avoid_taus=jnp.asarray(avoid.taus, f32),
        avoid_values=jnp.asarray(pad_periodic(avoid.values, acfg.grid, lead=1), f32),
        detection_range=jnp.asarray(checked.detection_range, f32),
        avoid_margin=jnp.asarray(checked.avoid_margin, f32),
        avoid_fall_rate=jnp.asarray(avoid.fall_rate, f32),
        tracking_table=jnp.asarray(pad_components([*grads, tracking_value], tcfg.grid), f32),
        tracking_bound=jnp.asarray(tracking.bound, f32),
        tracking_free_level=jnp.asarray(free_level, f32),
        sdf_grid=sdf_grid,
        avoid_grid=acfg.grid,
        tracking_grid=tcfg.grid,
        avoid_dynamics=acfg.relative_dynamics,
        tracking_dynamics=tcfg.error_dynamics,
    )


def _wind_params(config: EnvConfig) -> WindParams:
    """The wind: the configured model (:mod:`stp_env.sim.winds`), bounded by the vehicles' wind bound."""
    return WindParams(model=config.wind_model)


def load_artifacts(scenario, *, store=None, progress: bool | None = None):
    """``(avoid region, tracking bound)`` for a scenario from the artifact cache (computed on first use: about
    20 s and 30 s on 2 cores for the city vehicle)."""
    progress = progress_enabled(progress)
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.avoid import compute_avoid_region
    from stp_env.reach.defaults import default_avoid_config
    from stp_env.reach.tracking import default_tracking_bound

    store = ArtifactStore() if store is None else store
    avoid = compute_avoid_region(default_avoid_config(scenario.vehicle, scenario.collision_radius, scenario.t_iat),
                                 store=store, progress=progress)
    tracking = default_tracking_bound(scenario.vehicle, tuple(scenario.planning_v), scenario.planning_omega_max,
                                      store=store, progress=progress)
    return avoid, tracking


def load_plan(scenario, *, tracking_bound: float, store=None, progress: bool | None = None):
    """The shipped plan when ``scenario`` is a registry default (at its ``kbar``) that ships one
    (:func:`stp_env.planning.stp.shipped_plan_for`) and that plan is valid for ``tracking_bound`` (made with a bound
    at least as large, at the scenario's sample period), else the cached plan (planned on first use)."""
    progress = progress_enabled(progress)
    from stp_env.planning.stp import cached_plan

    shipped = _shipped_plan(scenario)
    if shipped is not None:
        problem = plan_mismatch(shipped, scenario, tracking_bound)
        if problem is None:
            return shipped
        import warnings

        warnings.warn(f"The shipped plan of {scenario.name!r} does not fit this code ({problem}); planning anew "
                      "(a source checkout regenerates it with `stp-env data plans --ship`).", RuntimeWarning,
                      stacklevel=2)
    return cached_plan(scenario, tracking_bound=tracking_bound, store=store, progress=progress)


BOUND_TOLERANCE = 1e-3  # [m] a plan made with r_e this much smaller than the current one is still accepted


def plan_mismatch(plan, scenario, tracking_bound: float) -> str | None:
    """Why ``plan`` cannot serve ``scenario`` with the tracking bound ``tracking_bound`` (``None`` if it can): its
    obstacles and targets were grown and shrunk by the bound it was made with, so a smaller one voids its
    separation guarantees; its vehicles, k̄, STAs and sample period must be the scenario's."""
    if len(plan.vehicles) != len(scenario.vehicles):
        return f"it has {len(plan.vehicles)} vehicles, the scenario {len(scenario.vehicles)}"
    if plan.kbar != scenario.kbar:
        return f"it was planned for kbar = {plan.kbar}, the scenario has kbar = {scenario.kbar}"
    moved = [v.index for v in plan.vehicles if not math.isclose(v.plan.sta, scenario.vehicles[v.index].sta,
                                                                 abs_tol=1e-6)]
    if moved:
        return f"its STAs differ from the scenario's (vehicles {moved[:5]})"
    if plan.tracking_bound < tracking_bound - BOUND_TOLERANCE:
        return (f"it was made with the tracking-error bound r_e = {plan.tracking_bound:.3f} m, smaller than the "
                f"current {tracking_bound:.3f} m")
    periods = {sample_period(v.plan.times) for v in plan.vehicles if len(v.plan.times) > 1}
    if periods and periods != {round(float(scenario.time_step), PERIOD_DECIMALS)}:
        return f"its sample period is {sorted(periods)} s, the scenario's {scenario.time_step} s"
    return None


SHIPPED_PLANS: dict[str, tuple[str, dict]] = {
    "tiny": ("tiny", {}),
    "tiny-intruder": ("tiny-intruder", {}),
    **{f"town-kbar{k}": ("town", {"kbar": k}) for k in (1, 2, 3)},
    "fig6-kbar3": ("fig6", {}),
    "city": ("city", {}),  # BEACLS Case 0
    **{f"city-case{c}": ("city", dict(case)) for c, case in CITY_CASES.items() if c != 0},
    **{f"city-kbar{k}": ("city", {"kbar": k}) for k in (2, 3, 4)},  # intruder-aware Case 0
    **{f"city-intruder-kbar{k}": ("city-intruder", {"kbar": k}) for k in (2, 3, 4)},  # BEACLS Section VII
    "bay-area": ("bay-area", {}),
}
"""The plans ``stp_env/data/plans/<file>.npz`` may hold: file name -> (registered scenario, overrides), the plan
being for ``make(scenario, **overrides)``. A listed file that is not there is simply not shipped
(``stp-env data plans`` makes them; ``fig6-kbar3`` comes from ``examples/fig6_reproduction.py``)."""


def _shipped_plan(scenario):
    """The shipped plan made for exactly ``scenario`` (equal to ``make(name, **overrides)`` of an entry of
    :data:`SHIPPED_PLANS` whose file exists), else ``None``."""
    from stp_env.planning.stp import shipped_plan
    from stp_env.scenarios import make, names

    if scenario.name not in names():
        return None
    for file, (name, overrides) in SHIPPED_PLANS.items():
        if name != scenario.name:
            continue
        if make(name, **overrides) != scenario:
            continue
        try:
            return shipped_plan(file)
        except ValueError:
            continue  # listed, not shipped
    return None


def params_for(scenario, config: EnvConfig | None = None, *, store=None, progress: bool | None = None) -> EnvParams:
    """Everything from a scenario (a :class:`Scenario` or a registry name): artifacts, plan, params."""
    progress = progress_enabled(progress)
    from stp_env.scenarios import Scenario, make

    if isinstance(scenario, str):
        scenario = make(scenario)
    if not isinstance(scenario, Scenario):
        raise ValueError(f"scenario must be a registry name or a Scenario; got {type(scenario).__name__}.")
    avoid, tracking = load_artifacts(scenario, store=store, progress=progress)
    plan = load_plan(scenario, tracking_bound=tracking.bound, store=store, progress=progress)
    return make_params(scenario, plan, avoid, tracking, config)


def with_buffer(params: EnvParams, buffer) -> EnvParams:
    """``params`` with the relative buffer region ``V^B(0, t_BRD)`` (a :class:`stp_env.reach.buffer.RelativeBuffer`
    computed for the same avoid region), which the buffer-game policies read (the ``worst`` vehicles and the
    ``optimal-max-k`` intruder of :mod:`stp_env.policies`)."""
    grid = buffer.config.grid
    if tuple(np.shape(buffer.values)) != tuple(grid.shape):
        raise ValueError(f"the buffer values have shape {np.shape(buffer.values)}, its grid {grid.shape}.")
    acfg = buffer.config.avoid
    if acfg.grid != params.tables.avoid_grid or not math.isclose(acfg.t_iat, float(params.intruder.t_iat),
                                                                 rel_tol=1e-6):
        raise ValueError("the relative buffer was computed for another avoid region than these params use.")
    return params.replace(tables=dict(buffer_values=jnp.asarray(buffer.values, jnp.float32), buffer_grid=grid))


def load_buffer(scenario, kbar: int | None = None, *, store=None, progress: bool | None = None):
    """The relative buffer region ``V^B(0, t_IAT / k̄)`` of ``scenario``'s vehicle (``kbar``: the scenario's when
    ``None``), from the artifact cache (computed on first use: about a CPU-minute)."""
    progress = progress_enabled(progress)
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.avoid import compute_avoid_region
    from stp_env.reach.buffer import BufferConfig, compute_relative_buffer
    from stp_env.reach.defaults import default_avoid_config

    kbar = scenario.kbar if kbar is None else kbar
    if kbar is None:
        raise ValueError(f"scenario {scenario.name!r} has no k̄: the buffer region needs one.")
    store = ArtifactStore() if store is None else store
    acfg = default_avoid_config(scenario.vehicle, scenario.collision_radius, scenario.t_iat)
    avoid = compute_avoid_region(acfg, store=store, progress=progress)
    return compute_relative_buffer(BufferConfig(avoid=acfg, kbar=int(kbar)), avoid, store=store, progress=progress)
