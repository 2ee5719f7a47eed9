"""Sequential trajectory planning (STP) with robust trajectory tracking, optionally intruder-aware.

SPP paper Section IV-C (robust trajectory tracking, eq. 27) and intruder paper Algorithm 3 / eq. (34):

* Vehicles are planned in priority order. Each plans with the reduced control set ``U^p`` and no disturbance
  (intruder paper Remark 1) toward its target shrunk by the tracking-error bound ``r_e`` (SPP Section IV-C).
* A higher-priority vehicle ``j`` induces, around its nominal position ``p_j(t)``, the disk of radius
  ``R_c + 2 r_e`` (eq. 27: both vehicles' error bubbles and the danger zone).
* Intruder-aware mode (``kbar`` given): also the buffer disk (eqs. 21, 48; radius from
  :func:`stp_env.reach.buffer.buffer_radii`, which includes both bubbles) and the obstacle lag profiles of eqs.
  (26)-(31), (49)-(57) (:func:`stp_env.reach.obstacles.intruder_obstacle_profiles`), grown by the planning
  vehicle's own bubble ``r_e`` (Remark 1).

Static obstacles (buildings) are avoided by the vehicle's own bubble ``r_e`` and, intruder-aware, by the
conservative ``V^S`` of eqs. (32)-(33) (:func:`stp_env.reach.obstacles.static_inflation_radius`).

The centralized and least-restrictive induced-obstacle methods (SPP Sections IV-A, IV-B: forward reachable sets
under the enforced feedback, or of all controls intersected with the BRS) are in :mod:`stp_env.planning.methods`;
:func:`plan_scenario` dispatches on ``Scenario.method``. What :func:`plan_rtt` plans is a
:class:`stp_env.planning.problem.PlanningProblem` (:func:`problem_for_scenario` builds one for a scenario), with any
planning model of :mod:`stp_env.planning.model`. Replanning is in :mod:`stp_env.planning.replan`; plan
caching in :func:`cached_plan`.

Each vehicle's BRS is solved by the heading-split scheme of :mod:`stp_env.planning.brs` (:data:`PLANNING_SOLVER`);
a run can be checkpointed after every vehicle and resumed (:mod:`stp_env.planning.checkpoint`). The plan types
and their array packing live in :mod:`stp_env.planning.plan` and are importable from here too.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from tqdm.auto import tqdm

from stp_env import hj
from stp_env.planning import checkpoint as checkpoint_io
from stp_env.planning.disks import (  # noqa: F401  (fold_contained_disks: re-exported, its old place)
    aware_obstacles,
    fold_contained_disks,
    obstacle_disks,
)
from stp_env.planning.obstacles import planning_obstacles
from stp_env.planning.plan import (
    InfeasiblePlanError,
    Plan,
    SinglePlan,
    VehiclePlan,
    obstacle_window,
    plan_from_arrays,
    plan_to_arrays,
)
from stp_env.planning.problem import PlanningProblem
from stp_env.planning.single import TubeExcursionWarning, plan_single
from stp_env.planning.verify import flight_clearance

PLANNING_SOLVER = "split"
"""Default BRS solver of :func:`plan_rtt`: the heading-split scheme of :mod:`stp_env.planning.brs` (one compiled
loop per scenario, a step set by the position axes). ``"hj"`` is :func:`stp_env.hj.solve` (BENCHMARKS.md, "City
planning", compares the two)."""

LATE_RETRIES = 2
"""How many times :func:`plan_rtt` re-extracts a nominal trajectory that arrives after its STA, departing earlier."""

DISK_RETRIES = 2
"""How many times :func:`plan_rtt` plans a vehicle again, with the disks grown, when its nominal trajectory enters a
higher-priority vehicle's disk deeper than the tolerance (:func:`plan_clear_of_disks`)."""

DISK_TOLERANCE_CELLS = 0.5
"""The depth, in cells of the coarser position axis, that a nominal trajectory may reach into a higher-priority
vehicle's disk before :func:`plan_rtt` plans it again with the disks grown (the grid resolves the disk's edge to
about half a cell; ``tests/test_plan_domain.py`` asserts the same of the shipped plans)."""

PLANNING_SETTINGS = hj.SolverSettings.with_accuracy("medium")
"""Default solver settings of :func:`plan_rtt`: ENO2 + TVD-RK2 (the ``medium`` preset). The planning BRS has no
relative-frame terms (the reason docs/numerics.md asks for WENO5 in the intruder problems): measured on ``town``, its
nominal trajectories still arrive within 3 s of the planned arrival (one cell at the slowest planning speed before
the STA), at about half the cost per step of WENO5 + RK2; first-order upwinding + Euler costs little less but
departs ~15 s earlier than needed (more dissipation, a smaller tube)."""


def plan_rtt(problem: PlanningProblem, *, progress: bool = True, checkpoint=None, on_vehicle=None) -> Plan:
    """Plans every vehicle of ``problem`` with robust trajectory tracking (optionally intruder-aware).

    ``problem`` (:class:`stp_env.planning.problem.PlanningProblem`) holds what is planned: the vehicles, the planning
    model and ``U^p``, ``r_e`` and ``R_c``, the intruder-aware disks, the static obstacles, the horizon and the solver
    settings. In particular:

    * ``arrival_margin`` (default one cell at the slowest planning speed): the numerical tube is optimistic by about
      a cell, so the nominal trajectory can reach the target up to ``dx / v`` late; the margin absorbs that.
    * ``solver``: the BRS solver of :func:`stp_env.planning.single.plan_single_with_slices` (default
      :data:`PLANNING_SOLVER`; ``"hj"`` is the unsplit solver, kept for comparisons).
    * ``max_slice_dt``: the BRS is stored every ``horizon / 200`` s (at least ``time_step``) and trajectories are
      extracted from those slices interpolated in time; this caps the spacing [s] (more slices, 2.2 MB each on the
      city's grid). With 6 s slices (a 1200 s horizon) a city trajectory came 42 m inside another vehicle's disk at
      the instant that vehicle arrived: the slice after a disk vanishes has none.
    * ``hold_slices``: keep every higher-priority vehicle's disks this many slices (``hold_slices x`` the slice
      spacing) longer before its departure and after its arrival, so that the slices on both sides of an
      appearance or a disappearance hold the disk. One slice made city Case 1 hold the separation (its worst pair
      went from 42 m to 9 m inside), but it costs a shared origin a slice per departure: city Case 0 then has no
      departure for its 48th vehicle within the default horizon. Default 0.
    * ``disk_tolerance``: how deep [m] a nominal trajectory may come into a higher-priority vehicle's disk (checked
      exactly, at its samples) before the vehicle is planned again with the disks grown
      (:func:`plan_clear_of_disks`); default :data:`DISK_TOLERANCE_CELLS` of the coarser position cell.
    * intruder-aware (``kbar``): lag disks inside the buffer disk are folded into it (:func:`fold_contained_disks`).

    Args:
        problem: the planning problem.
        progress: show a progress bar over the vehicles.
        checkpoint: path of a ``.npz`` checkpoint (:mod:`stp_env.planning.checkpoint`): the vehicles it holds are
            not planned again, and it is rewritten atomically after every vehicle, so an interrupted run resumes
            where it stopped, to the same plan bit for bit. A checkpoint of another problem is refused
            (:class:`stp_env.planning.checkpoint.CheckpointMismatchError`), and so is one whose plans fail the
            checks of a finished plan (:func:`stp_env.planning.checkpoint.check_plans`).
        on_vehicle: called as ``on_vehicle(rank, index, plan)`` after each vehicle is planned (and checkpointed).

    The Dubins planner's argument list of release 0.1 (``plan_rtt(grid, vehicle, planning_v, ...)``) is
    :meth:`PlanningProblem.dubins` of the same arguments.
    """
    if not isinstance(problem, PlanningProblem):
        hint = (" (the argument list of release 0.1: pass PlanningProblem.dubins(grid, vehicle, ...))"
                if isinstance(problem, hj.Grid) else "")
        raise TypeError(f"plan_rtt plans a stp_env.planning.problem.PlanningProblem; got "
                        f"{type(problem).__name__}{hint}.")
    return _plan_problem(problem, progress=progress, checkpoint=checkpoint, on_vehicle=on_vehicle)


def _plan_problem(problem: PlanningProblem, *, progress: bool, checkpoint, on_vehicle) -> Plan:
    """:func:`plan_rtt` of a checked problem."""
    grid, planner = problem.grid, problem.model
    starts, targets, radii, stas = problem.starts, problem.targets, problem.target_radii, problem.stas
    priorities = list(problem.priorities)
    tracking_bound, collision_radius = problem.tracking_bound, problem.collision_radius
    horizon, time_step, kbar = problem.horizon, problem.time_step, problem.kbar
    planning_v, static_obstacle = problem.planning_v, problem.static_obstacle
    max_slice_dt, hold_slices = problem.max_slice_dt, problem.hold_slices
    tolerance = (DISK_TOLERANCE_CELLS * float(max(grid.spacing[:2])) if problem.disk_tolerance is None
                 else problem.disk_tolerance)
    n = problem.n_vehicles
    solver = problem.solver or PLANNING_SOLVER
    aware = problem.intruder_aware
    shrunk = radii - tracking_bound
    settings = problem.settings or PLANNING_SETTINGS
    arrival_margin = problem.arrival_margin
    if arrival_margin is None:
        arrival_margin = max(grid.spacing[:2]) / max(planning_v[0], 1e-3 * planning_v[1])
    slice_dt = max(time_step, horizon / 200 if max_slice_dt is None else min(horizon / 200, float(max_slice_dt)))
    lags_arr, rads_arr, pad_before, pad_after = obstacle_disks(collision_radius, tracking_bound, planning_v[1],
                                                               problem.buffer_radius if aware else None,
                                                               problem.obstacle_profiles if aware else None)
    pad_before, pad_after = pad_before + hold_slices * slice_dt, pad_after + hold_slices * slice_dt

    order = problem.order
    # The solves ask for the obstacles between the earliest STA's horizon and the latest STA (one span for all
    # vehicles: the obstacle arrays keep one shape).
    span = (float(np.min(stas)) - arrival_margin - horizon, float(np.max(stas)) + 1.0)
    done: dict[int, VehiclePlan] = {}
    trajectories = []
    key = None
    planned: list[tuple[int, SinglePlan]] = []
    if checkpoint is not None:
        key = checkpoint_io.problem_key(
            "rtt", grid.lo, grid.hi, grid.shape, grid.is_periodic, problem.vehicle, planner, planning_v,
            problem.planning_omega_max, float(tracking_bound), float(collision_radius), starts, targets, radii,
            stas, priorities, float(horizon), kbar, problem.buffer_radius, lags_arr, rads_arr, pad_before,
            pad_after, None if static_obstacle is None else np.asarray(static_obstacle), settings,
            float(time_step), float(arrival_margin), solver, slice_dt, float(tolerance))
        planned = checkpoint_io.load(checkpoint, key)
        if [i for i, _ in planned] != order[:len(planned)]:
            raise checkpoint_io.CheckpointMismatchError(f"planning checkpoint {checkpoint}: its vehicles are not a "
                                                        "prefix of the priority order.")
        # The key says which problem the file claims to be of; its contents are checked as a finished plan's are
        # before anything is planned against them (an edited or corrupted file: a one-line ValueError).
        checkpoint_io.check_plans(checkpoint, planned, starts=starts, targets=targets, target_radii=radii, stas=stas,
                                  priorities=priorities, tracking_bound=tracking_bound, time_step=time_step,
                                  planning_v=planning_v, planning_omega_max=problem.planning_omega_max,
                                  model=planner)
    bar = tqdm(total=n, desc="STP planning", unit="vehicle", disable=not progress, initial=len(planned))
    for rank, i in enumerate(order):
        if rank < len(planned):  # resumed from the checkpoint
            single = planned[rank][1]
            trajectories.append(obstacle_window(single, (pad_before, pad_after)))
            done[i] = VehiclePlan(index=i, priority=rank, plan=single, obstacle_lags=lags_arr,
                                  obstacle_radii=rads_arr)
            continue
        def plan_with(grow, i=i, rank=rank):  # this vehicle, with every disk grown by ``grow`` metres
            obstacles = planning_obstacles(grid, trajectories, lags_arr, rads_arr + grow, static_obstacle,
                                           n_slots=n - 1, n_samples=math.ceil(1.1 * horizon / time_step) + 1,
                                           span=span)
            return _plan_one(grid, planner, starts[i], targets[i], float(shrunk[i]), float(stas[i]),
                             float(stas[i]) - arrival_margin, horizon, settings=settings, time_step=time_step,
                             slice_dt=slice_dt, solver=solver, arrival_margin=arrival_margin, who=(i, rank),
                             **obstacles)

        single = plan_clear_of_disks(plan_with, trajectories, lags_arr, rads_arr, tolerance,
                                      f"vehicle {i} (priority {rank})")
        single = dataclasses.replace(single, sta=float(stas[i]))
        trajectories.append(obstacle_window(single, (pad_before, pad_after)))
        done[i] = VehiclePlan(index=i, priority=rank, plan=single, obstacle_lags=lags_arr, obstacle_radii=rads_arr)
        planned.append((i, single))
        if checkpoint is not None:
            checkpoint_io.save(checkpoint, key, planned)
        bar.update(1)
        if on_vehicle is not None:
            on_vehicle(rank, i, single)
    bar.close()
    return Plan(vehicles=tuple(done[i] for i in range(n)), tracking_bound=float(tracking_bound),
                collision_radius=float(collision_radius), kbar=kbar, obstacle_pads=(pad_before, pad_after))


def _plan_one(grid, planner, start, target, radius, sta, aim, horizon, *, settings, time_step, slice_dt, solver,
              arrival_margin, who, **obstacles) -> SinglePlan:
    """One vehicle of :func:`plan_rtt` against the given obstacles: the BRS and the nominal trajectory, with the
    unsplit solver when the split one's trajectory fails, and up to :data:`LATE_RETRIES` earlier departures when it
    arrives after the STA. ``who``: the vehicle's ``(index, priority)``, for the messages."""
    index, priority = who
    name = f"vehicle {index} (priority {priority})"
    depart_at, vehicle_solver, retries = None, solver, 0
    while True:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                single = plan_single(grid, planner, start, target, radius, aim, horizon, settings=settings,
                                     time_step=time_step, slice_dt=slice_dt, progress=False, depart_at=depart_at,
                                     solver=vehicle_solver, **obstacles)
        except InfeasiblePlanError as err:
            raise InfeasiblePlanError(f"{name}: no feasible departure for its STA {sta} s: {err}",
                                      err.latest_departure) from err
        for w in caught:  # name the vehicle (plan_single does not know it)
            warnings.warn(f"vehicle {index} (priority {priority}, {vehicle_solver!r} BRS): {w.message}", w.category,
                          stacklevel=3)
        late = single.arrival_time - sta
        left = any(issubclass(w.category, TubeExcursionWarning) for w in caught)
        if (math.isinf(late) or left) and vehicle_solver != "hj":
            # The split tube's trajectory never arrived or left the tube (measured on the city: one vehicle of
            # 50 each; the unsplit solver's tube, a little larger, brought the first in, late, so that it could
            # be re-extracted below, and the intruder-aware city's vehicle 4 inside its tube).
            failure = "never reaches the target" if math.isinf(late) else "leaves the reach-avoid tube"
            warnings.warn(f"{name}: its nominal trajectory from the {vehicle_solver!r} BRS {failure}; planning it "
                          "with the unsplit solver 'hj'.", stacklevel=3)
            depart_at, vehicle_solver = None, "hj"
            continue
        if not late > 0:
            return single
        # The tube promised an arrival by ``aim``; the extracted trajectory (a sampled controller following the
        # BRS gradient) came later, e.g. threading a narrow channel. Depart earlier by the delay (the trajectory
        # starts inside the tube, with more time to spare) and extract again.
        earlier = single.t_ldt - late - arrival_margin
        if retries == LATE_RETRIES or earlier < aim - horizon:
            warnings.warn(f"{name}: its nominal trajectory arrives {late:.1f} s after its STA {sta} s (departing at "
                          f"{single.t_ldt:.1f} s); a finer grid or a longer horizon may fix it.", stacklevel=3)
            return single
        depart_at, retries = earlier, retries + 1


def plan_clear_of_disks(plan_with, windows, lags, radii, tolerance: float, name: str) -> SinglePlan:
    """``plan_with(grow)`` (a vehicle planned with the disks' radii grown by ``grow`` metres), checked against the
    exact disks: its sampled flight must keep out of every higher-priority disk (``windows``, ``lags``, ``radii``;
    :func:`stp_env.planning.verify.flight_clearance`) to within ``tolerance`` metres.

    The solver imposes the disks exactly at every step, but the nominal trajectory follows a numerical tube that is
    optimistic by up to about a cell, and where a disk binds (a vehicle departing at its latest time, close behind a
    higher-priority one) it falls behind the tube's zero level into the disk (measured on city Case 0: 22.8 m into a
    110.7 m disk with 33.3 m cells, the tube value along the trajectory rising to +21 m while it flew the tube's own
    control). A vehicle that enters a disk deeper than ``tolerance`` is planned again, up to :data:`DISK_RETRIES`
    times, with every disk grown by the depths measured so far; the vehicles that keep within it are planned exactly
    as before. The shallowest of the attempts is kept (with a warning if it is still too deep)."""
    grow, best, attempts, tried = 0.0, None, 0, 0.0
    for _ in range(DISK_RETRIES + 1):
        try:
            single = plan_with(grow)
            tried = grow
        except InfeasiblePlanError:
            if best is None:
                raise
            break  # the grown disks leave no departure: keep the best attempt so far
        attempts += 1
        depth = -flight_clearance(*single.flight(), windows, lags, radii)[0]
        if best is None or depth < best[0]:
            best = (depth, single)
        if depth <= tolerance:
            break
        grow += depth
    depth, single = best
    if depth > tolerance:
        warnings.warn(f"{name}: its nominal trajectory comes {depth:.1f} m inside another vehicle's disk "
                      f"(tolerance {tolerance:.1f} m; the shallowest of {attempts} plans, the disks grown by up to "
                      f"{tried:.1f} m); a finer grid may fix it.", stacklevel=3)
    return single


def plan_scenario(scenario, *, tracking_bound: float | None = None, store=None, horizon: float | None = None,
                  settings: hj.SolverSettings | None = None, progress: bool = True, solver: str | None = None,
                  checkpoint=None, on_vehicle=None, max_slice_dt: float | None = None, hold_slices: int = 0,
                  disk_tolerance: float | None = None) -> Plan:
    """Plans a registered :class:`stp_env.scenarios.Scenario` with its ``method``: robust trajectory tracking
    (``"rtt"``, below), straight flights checked against its constraints (``"straight"``,
    :func:`stp_env.planning.verify.straight_plan`), or the centralized / least-restrictive methods
    (:func:`stp_env.planning.methods.plan_methods`, full control set, horizon by default twice the longest straight
    flight at ``v_max`` plus 1 s; intruder-aware buffers are not available for them, and ``tracking_bound`` is not
    used).

    ``tracking_bound`` defaults to :func:`stp_env.reach.tracking.compute_tracking_bound` for the scenario's
    vehicle and ``U^p`` (cached in ``store``); intruder-aware scenarios (``kbar`` set) take their buffer radius
    from the avoid and relative-buffer artifacts of the same vehicle (also cached). ``horizon`` defaults to twice
    the longest straight-line flight at the planning speed. ``solver``, ``max_slice_dt``, ``hold_slices`` and
    ``disk_tolerance`` are fields of the :class:`PlanningProblem` (:func:`problem_for_scenario` builds it),
    ``checkpoint`` and ``on_vehicle`` options of :func:`plan_rtt` (robust trajectory tracking only).
    """
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.tracking import default_tracking_bound

    rtt_options = {"solver": solver, "checkpoint": checkpoint, "on_vehicle": on_vehicle, "max_slice_dt": max_slice_dt,
                   "hold_slices": hold_slices or None, "disk_tolerance": disk_tolerance}
    given = [name for name, value in rtt_options.items() if value is not None]
    if given and scenario.method != "rtt":
        raise ValueError(f"scenario {scenario.name!r} plans with method {scenario.method!r}; {', '.join(given)} "
                         "apply to method 'rtt' only.")
    if scenario.method == "straight":
        from stp_env.planning.verify import planner_disks, straight_plan

        store = ArtifactStore() if store is None else store
        if tracking_bound is None:
            tracking_bound = default_tracking_bound(scenario.vehicle, tuple(scenario.planning_v),
                                                    scenario.planning_omega_max, store=store,
                                                    progress=progress).bound
        return straight_plan(scenario, tracking_bound,
                             disks=planner_disks(scenario, tracking_bound, store=store, progress=progress))
    if scenario.method != "rtt":
        from stp_env.planning.methods import plan_methods

        if scenario.kbar is not None:
            raise NotImplementedError(
                f"scenario {scenario.name!r}: intruder-aware planning (kbar={scenario.kbar}) is implemented for "
                f"method 'rtt' only, not {scenario.method!r}.")
        if horizon is None:
            dist = np.hypot(*(scenario.targets() - scenario.starts()[:, :2]).T)
            horizon = 2.0 * float(dist.max()) / scenario.vehicle.v_max + 1.0
        static = np.asarray(scenario.static_obstacle())[:, :, 0] if scenario.buildings else None
        return plan_methods(scenario.grid(), scenario.vehicle, scenario.method, scenario.collision_radius,
                            scenario.starts(), scenario.targets(), scenario.target_radii(), scenario.stas(),
                            scenario.priorities(), horizon=horizon, static_obstacle=static, settings=settings,
                            time_step=scenario.time_step, progress=progress).plan
    problem = problem_for_scenario(scenario, tracking_bound=tracking_bound, store=store, horizon=horizon,
                                   settings=settings, progress=progress, solver=solver, max_slice_dt=max_slice_dt,
                                   hold_slices=hold_slices, disk_tolerance=disk_tolerance)
    return plan_rtt(problem, progress=progress, checkpoint=checkpoint, on_vehicle=on_vehicle)


def problem_for_scenario(scenario, *, tracking_bound: float | None = None, store=None, horizon: float | None = None,
                         settings: hj.SolverSettings | None = None, progress: bool = True, solver: str | None = None,
                         max_slice_dt: float | None = None, hold_slices: int = 0,
                         disk_tolerance: float | None = None) -> PlanningProblem:
    """The :class:`PlanningProblem` that :func:`plan_scenario` plans for a registered scenario of method ``"rtt"``:
    its vehicles, its vehicle planned with ``U^p`` (:meth:`PlanningProblem.dubins`), the tracking bound (default
    :func:`stp_env.reach.tracking.default_tracking_bound`, cached in ``store``), the intruder-aware disks when its
    ``kbar`` is set (:func:`stp_env.planning.disks.aware_obstacles`), the static obstacles as the planner sees them
    (:func:`planning_static_obstacle`) and the horizon (default twice the longest straight-line flight at the top
    planning speed, plus 1 s). ``progress`` shows the progress of the artifacts computed on the way."""
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.tracking import default_tracking_bound

    if scenario.method != "rtt":
        raise ValueError(f"scenario {scenario.name!r} plans with method {scenario.method!r}; a PlanningProblem is "
                         "for method 'rtt'.")
    store = ArtifactStore() if store is None else store
    vehicle = scenario.vehicle
    if tracking_bound is None:
        tracking_bound = default_tracking_bound(vehicle, tuple(scenario.planning_v), scenario.planning_omega_max,
                                                store=store, progress=progress).bound
    grid = scenario.grid()
    starts, targets = scenario.starts(), scenario.targets()
    if horizon is None:
        dist = np.hypot(*(targets - starts[:, :2]).T)
        horizon = 2.0 * float(dist.max()) / scenario.planning_v[1] + 1.0
    aware = aware_obstacles(scenario, tracking_bound, store=store, progress=progress)
    static = planning_static_obstacle(scenario, tracking_bound)
    return PlanningProblem.dubins(grid, vehicle, tuple(scenario.planning_v), scenario.planning_omega_max,
                                  tracking_bound, scenario.collision_radius, starts, targets, scenario.target_radii(),
                                  scenario.stas(), scenario.priorities(), horizon=horizon, static_obstacle=static,
                                  settings=settings, time_step=scenario.time_step, solver=solver,
                                  max_slice_dt=max_slice_dt, hold_slices=hold_slices, disk_tolerance=disk_tolerance,
                                  **aware)


def planning_static_obstacle(scenario, tracking_bound: float):
    """The static obstacles as the planner sees them, on the position plane (shape ``scenario.grid().shape[:2]``,
    ``{<= 0}`` forbidden): the minimum of

    * the buildings' signed distance minus the tracking bound ``r_e`` and, for intruder-aware scenarios, the
      static-obstacle augmentation ``V^S`` (eqs. 32-33, :func:`stp_env.reach.obstacles.static_inflation_radius`);
    * the distance inside the scenario's domain minus ``r_e``: a tracking vehicle stays within ``r_e`` of its
      nominal trajectory, and the simulator ends a vehicle that leaves the domain (out of bounds). Without this
      term nothing kept the nominal trajectory in the domain: the planning grid is the domain, and a trajectory
      that had to lose time (city Case 0, the 49th of 50 vehicles: its start is blocked by later departures, so it
      leaves 280 s early) flew out of the grid, where the clamped value table has no gradient, 1.1 km past the
      edge, and came back 70 s late. The domain term covers the nominal flight, not an avoidance manoeuvre, which
      may still end out of bounds (the papers have no domain edge).
    """
    from stp_env.reach.obstacles import static_inflation_radius

    grid = scenario.grid()
    xs, ys = (np.asarray(c, np.float64) for c in grid.coordinate_vectors()[:2])
    lo, hi = np.asarray(scenario.domain_lo, float), np.asarray(scenario.domain_hi, float)
    inside = np.minimum(np.minimum(xs - lo[0], hi[0] - xs)[:, None], np.minimum(ys - lo[1], hi[1] - ys)[None, :])
    plane = inside - float(tracking_bound)
    if scenario.buildings:
        margin = float(tracking_bound)
        if scenario.kbar is not None:
            margin += static_inflation_radius(scenario.vehicle, scenario.collision_radius, scenario.t_iat)
        plane = np.minimum(plane, np.asarray(scenario.static_obstacle())[:, :, 0] - margin)
    return plane


def cached_plan(scenario, *, tracking_bound: float | None = None, store=None, progress: bool = True) -> Plan:
    """:func:`plan_scenario` through the artifact store: keyed by the whole scenario and the tracking bound."""
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.tracking import default_tracking_bound

    store = ArtifactStore() if store is None else store
    if tracking_bound is None:
        tracking_bound = default_tracking_bound(scenario.vehicle, tuple(scenario.planning_v),
                                                scenario.planning_omega_max, store=store, progress=progress).bound
    params = {"scenario": scenario, "tracking_bound": float(tracking_bound)}
    art = store.load_or_compute(
        "plan", params, lambda: plan_to_arrays(plan_scenario(scenario, tracking_bound=tracking_bound, store=store,
                                                             progress=progress)))
    return plan_from_arrays(art.arrays)


def shipped_plan_for(scenario: str, kbar: int | None = None) -> Plan:
    """The shipped plan of a registered scenario at its default parameters, for one ``k̄`` (``None``: the
    intruder-unaware plan): ``shipped_plan_for("town", 2)`` loads ``town-kbar2.npz`` (``k̄ = 1, 2, 3`` are
    shipped for ``town``), ``shipped_plan_for("tiny")`` loads ``tiny.npz``. The plan is for
    ``make(scenario, kbar=kbar)``; :data:`stp_env.assembly.SHIPPED_PLANS` lists what is shipped."""
    name = scenario if kbar is None else f"{scenario}-kbar{int(kbar)}"
    return shipped_plan(name)


def shipped_plan(name: str) -> Plan:
    """A plan shipped with the package (``stp_env/data/plans``, made by ``stp-env data plans``)."""
    from importlib import resources

    ref = resources.files("stp_env") / "data" / "plans" / f"{name}.npz"
    if not ref.is_file():
        available = sorted(p.name[:-4] for p in (resources.files("stp_env") / "data" / "plans").iterdir()
                           if p.name.endswith(".npz"))
        raise ValueError(f"No shipped plan {name!r}; available: {available}.")
    with resources.as_file(ref) as path, np.load(path, allow_pickle=False) as data:
        return plan_from_arrays({k: data[k] for k in data.files})
