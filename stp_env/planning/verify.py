"""Checks of a finished plan against the constraints the sequential planner imposes, computed from the nominal
trajectories alone (not from the BRS that produced them): an independent test of any plan, and the acceptance
test of plans built without the BRS (:func:`straight_plan`).

The constraint (robust trajectory tracking, SPP eq. 27; intruder-aware, intruder paper eqs. 21, 48 and the lag
profiles of eqs. 26-31, 49-57) is that of :func:`stp_env.planning.obstacles.moving_disks`: while a lower-priority
vehicle flies (departure to arrival), its nominal position stays outside every disk of radius ``rho_l`` around a
higher-priority vehicle's nominal position ``p_j(t + lambda_l)``, for each lag ``lambda_l`` at which that vehicle is
present (``t + lambda_l`` in its flight window grown by the pads of :func:`stp_env.planning.stp.fold_contained_disks`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from stp_env.planning.plan import InfeasiblePlanError, Plan, SinglePlan, VehiclePlan, obstacle_window


@dataclasses.dataclass(frozen=True)
class ObstacleDisks:
    """The moving disks every higher-priority vehicle induces: ``lags`` [s] and ``radii`` [m] (one per lag), present
    from ``pad_before`` s before its departure to ``pad_after`` s after its arrival."""

    lags: np.ndarray
    radii: np.ndarray
    pad_before: float = 0.0
    pad_after: float = 0.0


def planner_disks(scenario, tracking_bound: float, *, store=None, progress: bool = False) -> ObstacleDisks:
    """The disks :func:`stp_env.planning.stp.plan_rtt` plans ``scenario`` with (the same artifacts and folding)."""
    from stp_env.planning.stp import aware_obstacles, obstacle_disks

    aware = aware_obstacles(scenario, tracking_bound, store=store, progress=progress)
    lags_arr, rads_arr, before, after = obstacle_disks(scenario.collision_radius, tracking_bound,
                                                       scenario.planning_v[1], aware.get("buffer_radius"),
                                                       aware.get("obstacle_profiles"))
    return ObstacleDisks(np.asarray(lags_arr, float), np.asarray(rads_arr, float), float(before), float(after))


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
