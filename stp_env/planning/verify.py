"""Checks of a finished plan against the constraints the sequential planner imposes, computed from the nominal
trajectories alone (not from the BRS that produced them): an independent test of any plan, and the acceptance
test of plans built without the BRS (:func:`straight_plan`).

The constraint (robust trajectory tracking, SPP eq. 27; intruder-aware, intruder paper eqs. 21, 48 and the lag
profiles of eqs. 26-31, 49-57) is that of :func:`stp_env.planning.obstacles.moving_disks`: while a lower-priority
vehicle flies (departure to arrival), its nominal position stays outside every disk of radius ``rho_l`` around a
higher-priority vehicle's nominal position ``p_j(t + lambda_l)``, for each lag ``lambda_l`` at which that vehicle is
present (``t + lambda_l`` in its flight window grown by the pads of
:func:`stp_env.planning.disks.fold_contained_disks`). The disks themselves are :mod:`stp_env.planning.disks`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from stp_env.angles import wrap_angle
from stp_env.planning.disks import ObstacleDisks, planner_disks
from stp_env.planning.model import as_planning_model, dubins_control_between, dubins_step64
from stp_env.planning.plan import InfeasiblePlanError, Plan, SinglePlan, VehiclePlan, obstacle_window


def flight_clearance(times, states, windows, lags, radii) -> tuple[float, int, float]:
    """The smallest signed clearance [m] of one vehicle's sampled flight ``(times, states)`` from the disks of radii
    ``radii`` around the positions ``p_j(t + lags_l)`` of the vehicles of ``windows`` (each ``(times, states, start,
    end)``, :func:`~stp_env.planning.plan.obstacle_window`: a disk of lag ``lambda`` is present while ``t + lambda``
    lies in ``[start, end]``), and where ``(index into windows, time)``; ``(inf, -1, nan)`` when none is ever
    present. Positions between a window's samples are interpolated linearly, as the planner's obstacle function
    (:func:`stp_env.planning.obstacles.moving_disks`) does; the check runs at ``times``."""
    times, states = np.asarray(times, float), np.asarray(states, float)
    best, where = math.inf, (-1, math.nan)
    for j, (h_times, h_states, start, end) in enumerate(windows):
        for lag, rad in zip(lags, radii):
            tq = times + lag
            present = (tq >= start) & (tq <= end)
            if not present.any():
                continue
            cx = np.interp(tq[present], h_times, h_states[:, 0])
            cy = np.interp(tq[present], h_times, h_states[:, 1])
            gap = np.hypot(states[present, 0] - cx, states[present, 1] - cy) - rad
            k = int(np.argmin(gap))
            if gap[k] < best:
                best, where = float(gap[k]), (j, float(times[present][k]))
    return best, *where


def vehicle_clearances(plan: Plan, disks: ObstacleDisks) -> list[tuple[int, float, int, float]]:
    """Each vehicle's smallest signed clearance [m] from the disks of every higher-priority vehicle, in priority
    order: ``(vehicle index, clearance, index of the vehicle whose disk it is, time)``; ``(index, inf, -1, nan)``
    for a vehicle that never flies while a higher-priority disk is present (the first always).

    Positions between samples of the higher-priority vehicle are interpolated linearly, as the planner's obstacle
    function does; the check runs at the lower-priority vehicle's samples (:func:`flight_clearance`)."""
    by_priority = sorted(plan.vehicles, key=lambda v: v.priority)
    pads = (disks.pad_before, disks.pad_after)
    windows = [obstacle_window(v.plan, pads) for v in by_priority]
    out = []
    for rank, low in enumerate(by_priority):
        gap, j, t = flight_clearance(*low.plan.flight(), windows[:rank], disks.lags, disks.radii)
        out.append((low.index, gap, by_priority[j].index if j >= 0 else -1, t))
    return out


def obstacle_margin(plan: Plan, disks: ObstacleDisks) -> tuple[float, tuple[int, int, float]]:
    """The smallest signed clearance [m] of any vehicle's sampled nominal flight from the disks of every
    higher-priority vehicle, and where it occurs ``(lower-priority index, higher-priority index, time)``; ``inf``
    when no pair is ever present together. A negative margin means the plan breaks the planner's constraint
    (:func:`vehicle_clearances` gives every vehicle's)."""
    best, where = math.inf, (-1, -1, math.nan)
    for low, gap, high, t in vehicle_clearances(plan, disks):
        if gap < best:
            best, where = gap, (low, high, t)
    return best, where


def domain_margin(plan: Plan, domain_lo, domain_hi) -> tuple[float, tuple[int, float]]:
    """The smallest distance [m] of any vehicle's sampled nominal flight (departure to arrival) inside the
    rectangle ``domain_lo``-``domain_hi``, and where ``(vehicle index, time)``; negative outside. The planner keeps
    it at least ``r_e`` (:func:`stp_env.planning.stp.planning_static_obstacle`): a tracking vehicle then stays in
    the domain, which the simulator requires (a vehicle that leaves it is out of bounds)."""
    lo, hi = np.asarray(domain_lo, float), np.asarray(domain_hi, float)
    best, where = math.inf, (-1, math.nan)
    for v in plan.vehicles:
        times, states = v.plan.flight()
        inside = np.minimum(states[:, :2] - lo, hi - states[:, :2]).min(axis=1)
        k = int(np.argmin(inside))
        if inside[k] < best:
            best, where = float(inside[k]), (v.index, float(times[k]))
    return best, where


def straight_plan(scenario, tracking_bound: float, *, speed: float | None = None,
                  disks: ObstacleDisks | None = None, check: bool = True) -> Plan:
    """Every vehicle flies straight from its start to its target centre at ``speed`` (default the top planning
    speed, ``omega = 0``: a trajectory of ``U^p``), departing so that it enters its target (shrunk by ``r_e``, as the
    planner aims) one sample period before its STA; sampled every ``scenario.time_step``.

    With ``check`` (default) the plan must keep every vehicle outside the disks of the higher-priority ones
    (:func:`obstacle_margin` with ``disks``, default :func:`planner_disks`): otherwise
    :class:`~stp_env.planning.plan.InfeasiblePlanError` names the pair. A plan that passes satisfies the constraint
    the STP planner imposes, so it is one the planner could return: for routes that are straight and conflict-free by
    schedule (a corridor, streams that cross at staggered times) it is the planner's answer without the BRS, exact
    rather than a grid approximation."""
    if check and disks is None:
        disks = planner_disks(scenario, tracking_bound)
    speed = float(scenario.planning_v[1] if speed is None else speed)
    if not scenario.planning_v[0] <= speed <= scenario.planning_v[1]:
        raise ValueError(f"speed {speed} m/s is outside the planning set {scenario.planning_v}.")
    dt = float(scenario.time_step)
    vehicles = []
    for k, spec in enumerate(scenario.vehicles):
        x0, y0 = spec.start[0], spec.start[1]
        dx, dy = spec.target[0] - x0, spec.target[1] - y0
        length = math.hypot(dx, dy)
        heading = math.atan2(dy, dx)
        if abs(((spec.start[2] - heading + math.pi) % (2 * math.pi)) - math.pi) > 1e-6:
            raise ValueError(f"vehicle {k}: its start heading {spec.start[2]:.4f} rad does not point at its target "
                             f"({heading:.4f} rad); a straight plan needs it to.")
        inner = spec.target_radius - tracking_bound
        if inner <= 0:
            raise ValueError(f"vehicle {k}: the tracking bound {tracking_bound} m is not smaller than its target "
                             f"radius {spec.target_radius} m.")
        n_flight = math.ceil((length - inner) / (speed * dt))  # samples until inside the shrunk target
        t_ldt = float(spec.sta) - dt * (n_flight + 1)
        times = t_ldt + dt * np.arange(n_flight + 2)
        s = np.minimum(speed * (times - t_ldt), length)
        states = np.stack([x0 + s * math.cos(heading), y0 + s * math.sin(heading), np.full_like(s, heading)], 1)
        controls = np.tile([speed, 0.0], (len(times), 1))
        arrival = float(times[n_flight])
        single = SinglePlan(t_ldt=t_ldt, sta=float(spec.sta), times=times, states=states, controls=controls,
                            arrival_time=arrival, n_steps=0)
        vehicles.append(VehiclePlan(index=k, priority=spec.priority, plan=single,
                                    obstacle_lags=np.zeros(0) if disks is None else disks.lags,
                                    obstacle_radii=np.zeros(0) if disks is None else disks.radii))
    plan = Plan(vehicles=tuple(vehicles), tracking_bound=float(tracking_bound),
                collision_radius=float(scenario.collision_radius), kbar=scenario.kbar,
                obstacle_pads=None if disks is None else (disks.pad_before, disks.pad_after))
    if check:
        margin, (low, high, t) = obstacle_margin(plan, disks)
        if margin < 0:
            raise InfeasiblePlanError(f"scenario {scenario.name!r}: the straight plan brings vehicle {low} "
                                      f"{-margin:.1f} m inside the obstacle of higher-priority vehicle {high} at "
                                      f"t = {t:.2f} s; space the STAs further apart.", math.nan)
    return plan


POSITION_TOLERANCE = 0.05
"""[m] How far a stored sample may lie from the exact planning-dynamics step of the sample before it, and from the
vehicle's start. The planner integrates in float32 (:func:`stp_env.sim.physics.dubins_step`); at 20 km from the
origin a float32 position is resolved to 2 mm, and one step's rounding stays a few ulps."""

ANGLE_TOLERANCE = 1e-4
"""[rad] The same for the heading."""

CONTROL_TOLERANCE = 1e-5
"""Relative slack on the planning set ``U^p`` for stored controls (float32 values of float64 bounds)."""


def _model_step64(model):
    """``step64(states, controls, dt)`` of a planning model (:class:`stp_env.planning.model.PlanningModel`); the
    exact Dubins step without wind when ``model`` is ``None``."""
    if model is None:
        return lambda states, controls, dt: dubins_step64(states, controls[:, 0], controls[:, 1], dt)
    return as_planning_model(model).step64


def _angle_gap(a, b):
    return np.abs(wrap_angle(np.asarray(a, np.float64) - np.asarray(b, np.float64)))


def _step_misses(states, controls, dt, model=None):
    """How far [m, rad] the exact step of each sample under its control (the planning ``model``'s
    :meth:`~stp_env.planning.model.PlanningModel.step64`; ``None``: Dubins, no wind) lands from the next sample:
    ``(n - 1,)`` each."""
    pred = _model_step64(model)(states[:-1], controls[:-1], dt)
    return np.hypot(*(pred[:, :2] - states[1:, :2]).T), _angle_gap(pred[:, 2], states[1:, 2])


def flight_faults(times, states, controls, t_ldt: float, *, dt: float, planning_v, planning_omega_max: float,
                  end: int | None = None, model=None) -> list[str]:
    """What makes one stored trajectory something other than a flight of the planning dynamics, from its samples
    alone (the dynamics-only checks of :func:`trajectory_faults`, for a trajectory whose start is not the
    scenario's, e.g. a vehicle replanned in the air): finite samples and departure, samples starting at ``t_ldt``
    and ``dt`` apart, controls in ``U^p = planning_v x [-planning_omega_max, planning_omega_max]`` and each sample
    the exact step (Dubins motion, no wind; or the planning ``model``'s
    :meth:`~stp_env.planning.model.PlanningModel.step64`) of the one before under its control, up to the sample
    ``end`` (the flight's last; ``None``: the last stored). ``[]`` when it is a flight."""
    times, states, controls = (np.asarray(a, np.float64) for a in (times, states, controls))
    if times.ndim != 1 or len(times) == 0 or states.shape != (len(times), 3) or controls.shape != (len(times), 2):
        return [f"trajectory arrays of shapes {times.shape}, {states.shape}, {controls.shape}"]
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(states)) and np.all(np.isfinite(controls))
            and math.isfinite(t_ldt)):
        return ["non-finite samples or departure"]
    why = []
    if abs(times[0] - t_ldt) > 1e-6 * max(1.0, abs(t_ldt)):
        why.append(f"first sample at {times[0]:.6g} s, departure {t_ldt:.6g} s")
    steps = np.diff(times)
    if steps.size and np.max(np.abs(steps - dt)) > 1e-6 * max(1.0, float(np.max(np.abs(times)))):
        why.append(f"samples {float(steps.min()):.6g}-{float(steps.max()):.6g} s apart, not {dt} s")
    end = len(times) - 1 if end is None else int(end)
    v_lo, v_hi = (float(b) for b in planning_v)
    w_hi = float(planning_omega_max)
    v, w = controls[:end, 0], controls[:end, 1]
    slack = CONTROL_TOLERANCE * max(v_hi, 1.0)
    if end and (v.min() < v_lo - slack or v.max() > v_hi + slack or np.abs(w).max() > w_hi * (1 + CONTROL_TOLERANCE)):
        why.append(f"controls outside U^p: speeds {v.min():.4g}-{v.max():.4g} m/s, turn rates up to "
                   f"{np.abs(w).max():.4g} rad/s")
    if end:
        jump, turn = _step_misses(states[:end + 1], controls[:end + 1], dt, model)
        if jump.max() > POSITION_TOLERANCE or turn.max() > ANGLE_TOLERANCE:
            k = int(np.argmax(jump))
            why.append(f"samples off the planning dynamics by up to {jump.max():.3g} m / {turn.max():.3g} rad "
                       f"(first worst at {times[k + 1]:.6g} s)")
    return why


def flight_end(states, target, target_radius: float, tracking_bound: float) -> int | None:
    """Index of a trajectory's first sample inside its target shrunk by ``r_e`` (where the planner aims,
    :func:`stp_env.planning.stp.plan_rtt`), ``None`` if no sample is."""
    states = np.asarray(states, np.float64)
    dist = np.hypot(states[:, 0] - target[0], states[:, 1] - target[1])
    inside = np.nonzero(dist <= target_radius - tracking_bound)[0]
    return int(inside[0]) if inside.size else None


def trajectory_faults(plan: Plan, scenario, *, model=None) -> dict[int, list[str]]:
    """What makes each vehicle's stored trajectory something other than a flight of the planning dynamics from its
    start, checked from the samples alone; ``{vehicle index: [reasons]}`` for the vehicles with any (empty when the
    plan is sound). :func:`vehicle_clearances` and :func:`domain_margin` read a plan's samples up to its recorded
    arrival, so without this check a plan with non-finite samples, an arrival recorded too early, or a trajectory
    that jumps between samples would pass them vacuously. Per vehicle, within its flight (departure to the first
    sample inside its target shrunk by ``r_e``, which is where the planner aims, :func:`stp_env.planning.stp.plan_rtt`):

    - every stored time, state and control is finite;
    - the samples start at ``t_ldt`` and are ``scenario.time_step`` apart;
    - the first sample is the scenario's start (:data:`POSITION_TOLERANCE`, :data:`ANGLE_TOLERANCE`);
    - each control lies in the planning set ``U^p`` (speeds ``planning_v``, turn rates up to
      ``planning_omega_max``; :data:`CONTROL_TOLERANCE`);
    - each sample is the exact step (Dubins motion, no wind: the nominal dynamics of robust trajectory tracking)
      of the one before under its control;
    - the recorded arrival time is the first sample inside the shrunk target (``inf`` if none);
    - the plan's priority order is the scenario's.

    The dynamics-only checks (the first, second, fourth and fifth) are :func:`flight_faults`; ``model`` is the
    planning model whose motion the samples follow (:class:`stp_env.planning.model.PlanningModel`; default Dubins).
    """
    faults: dict[int, list[str]] = {}
    dt = float(scenario.time_step)
    for veh in plan.vehicles:
        why = []
        if not 0 <= veh.index < len(scenario.vehicles):
            faults[veh.index] = [f"index {veh.index} is not a vehicle of the scenario"]
            continue
        spec, p = scenario.vehicles[veh.index], veh.plan
        if veh.priority != spec.priority:
            why.append(f"priority {veh.priority}, the scenario's {spec.priority}")
        states = np.asarray(p.states, np.float64)
        shaped = states.ndim == 2 and states.shape[1:] == (3,) and len(states) > 0 and np.all(np.isfinite(states))
        end = flight_end(states, spec.target, spec.target_radius, plan.tracking_bound) if shaped else None
        dynamics = flight_faults(p.times, p.states, p.controls, p.t_ldt, dt=dt, planning_v=scenario.planning_v,
                                 planning_omega_max=scenario.planning_omega_max, end=end, model=model)
        if not shaped or (dynamics and dynamics[0].startswith(("trajectory arrays", "non-finite"))):
            faults[veh.index] = [*why, *dynamics]
            continue
        off = math.hypot(states[0, 0] - spec.start[0], states[0, 1] - spec.start[1])
        if off > POSITION_TOLERANCE or _angle_gap(states[0, 2], spec.start[2]) > ANGLE_TOLERANCE:
            why.append(f"first sample {off:.3g} m / {float(_angle_gap(states[0, 2], spec.start[2])):.3g} rad "
                       "from the start")
        arrival = math.inf if end is None else float(np.asarray(p.times, np.float64)[end])
        if not (arrival == p.arrival_time or (math.isfinite(arrival) and math.isfinite(p.arrival_time)  # inf: exact
                                              and abs(arrival - p.arrival_time) <= 1e-6 * max(1.0, abs(arrival)))):
            why.append(f"arrival recorded at {p.arrival_time:.6g} s, the first sample in the target at "
                       f"{arrival:.6g} s")
        why.extend(dynamics)
        if why:
            faults[veh.index] = why
    return faults


def reconcile_controls(single: SinglePlan, dt: float, planning_v, planning_omega_max: float, *, model=None):
    """``single`` with each stored control that does not carry its sample to the next one (exact Dubins step, no
    wind, :data:`POSITION_TOLERANCE` / :data:`ANGLE_TOLERANCE`) replaced by one of ``U^p`` that does, and the indices
    of the samples whose control was replaced.

    The planner's rollout chooses, at every sample, between two candidate controls and the states they lead to;
    compiled, the choice of the state and the choice of the stored control are separate selections, and where the
    test between them sits at its threshold they have been seen to disagree (city Cases 1 and 3: one sample each,
    a stored 13 m/s where the state moved at 11 m/s, 0.2 m at 0.1 s samples). The simulator rebuilds the reference
    between samples from the sample and its control (:func:`stp_env.sim.reference.nominal_reference`), so such a
    sample makes the reference jump by that much at the next one, outside the dynamics the tracking bound assumes.
    The states are what the planner checked against its tube, so they are kept and the control is recovered from
    them: the previous or the next sample's control if it carries the sample within tolerance, else the control
    solved from the two states (clipped to ``U^p``). Raises :class:`ValueError` when none carries the sample within
    tolerance: the states themselves are then not a trajectory of the planning dynamics. ``model``: the planning
    model whose motion the samples follow (:class:`stp_env.planning.model.PlanningModel`; default Dubins, no wind),
    its ``step64`` and ``control_between``."""
    states = np.asarray(single.states, np.float64)
    controls = np.array(single.controls, np.float64)
    if len(states) < 2:
        return single, []
    v_lo, v_hi = (float(b) for b in planning_v)
    w_hi = float(planning_omega_max)

    between = dubins_control_between if model is None else as_planning_model(model).control_between

    def fits(k, u):
        jump, turn = _step_misses(states[k:k + 2], np.stack([u, u]), dt, model)
        return jump[0] <= POSITION_TOLERANCE and turn[0] <= ANGLE_TOLERANCE

    jump, turn = _step_misses(states, controls, dt, model)
    fixed = [int(k) for k in np.nonzero(~((jump <= POSITION_TOLERANCE) & (turn <= ANGLE_TOLERANCE)))[0]]
    for k in fixed:
        v, omega = between(states[k], states[k + 1], dt)
        candidates = [controls[j] for j in (k - 1, k + 1) if 0 <= j < len(controls)]
        candidates.append(np.asarray([min(max(v, v_lo), v_hi), min(max(omega, -w_hi), w_hi)]))
        candidates = [u for u in candidates if v_lo <= u[0] <= v_hi and abs(u[1]) <= w_hi * (1 + CONTROL_TOLERANCE)]
        good = [u for u in candidates if fits(k, u)]
        if not good:
            raise ValueError(f"sample {k} (t = {float(single.times[k]):.6g} s) does not reach the next one by any "
                             f"control of U^p: the trajectory is not one of the planning dynamics.")
        controls[k] = good[0]  # a neighbour's control (one the rollout applied) before the solved one
    if not fixed:
        return single, []
    return dataclasses.replace(single, controls=controls), fixed
