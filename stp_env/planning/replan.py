"""Replanning after the intruder leaves (intruder paper Section IV-E, eqs. 39-42, Algorithm 4).

The vehicles forced to avoid (``N^RP``, eq. 39) end up at states ``x~_i^0`` at ``t_bar = t_ + t_IAT``. Each gets
(in priority order):

1. a new STA: the earliest time at which the forward reachable set ``W^RP(t_bar, t)`` of eq. (41)-(42), grown from
   ``x~_i^0`` while avoiding the obstacles of the other vehicles, meets its target;
2. a new plan from ``x~_i^0`` to its target by that STA (Algorithm 3's planning step, here robust tracking).

The obstacles are the nominal trajectories of every vehicle outside ``N^RP`` (as in Algorithm 4) and, so that the
replanned vehicles cannot collide with each other either, those already replanned, with the disks of the original
plan, present over the same windows (each flight widened by the plan's ``obstacle_pads``: the lag disks folded into
the lag-0 disk are only covered that way, :func:`stp_env.planning.disks.fold_contained_disks`); and the buildings,
grown as for the original plan (:func:`stp_env.planning.stp.planning_static_obstacle`). Plans of the other vehicles
are returned unchanged (the same objects).

``replan`` is host-side (level-set solves) and can be called while a simulation runs: ``parallel_env(...,
replan=True)`` calls it when the intruder leaves and swaps the new plans into the running simulation
(:func:`stp_env.assembly.with_plan`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning.obstacles import planning_obstacles
from stp_env.planning.plan import obstacle_window
from stp_env.planning.single import InfeasiblePlanError, full_grid_obstacle, initial_ball, plan_single
from stp_env.planning.stp import (
    DISK_TOLERANCE_CELLS,
    PLANNING_SETTINGS,
    Plan,
    VehiclePlan,
    aware_obstacles,
    obstacle_disks,
    plan_clear_of_disks,
    planning_static_obstacle,
)


def earliest_arrival(grid: hj.Grid, planner: DubinsWind, state, t_bar: float, target_center, target_radius: float,
                     horizon: float, *, obstacle_fn=None, obstacle_params=None, slice_dt: float = 1.0,
                     settings: hj.SolverSettings | None = None, segment: int = 10) -> float:
    """``arg inf_t {W^RP(t_bar, t) meets L}`` (eqs. 41-42): the FRS from a ball of 1.5 cells around ``state``
    (position and heading, :func:`stp_env.planning.single.initial_ball`), the control covering every input
    (``"max"``), obstacles enforced at every step; ``inf`` if the target is not reached within ``horizon``. The
    solve stops after the first group of ``segment`` slices in which the set meets the target (the time returned is
    that of the first such slice)."""
    settings = settings or hj.SolverSettings.with_accuracy("high")
    init = initial_ball(grid, state)
    n = max(2, math.ceil(horizon / slice_dt) + 1)
    times = t_bar + np.linspace(0.0, horizon, n)
    dyn = planner.with_modes(control_mode="max", disturbance_mode="min")
    full_fn = None if obstacle_fn is None else full_grid_obstacle(obstacle_fn, grid.shape[2])
    in_target = jnp.broadcast_to(hj.shapes.cylinder(grid, (0, 1), target_center, target_radius) <= 0, grid.shape)
    # Forward in segments of ``segment`` slices, stopping at the first segment in which the set meets the target
    # (each continues from the previous one's last values: the same values as one solve of the whole horizon).
    values, lo = init, 0
    while lo < n - 1:
        hi = min(lo + segment, n - 1)
        res = hj.solve(settings, dyn, grid, times[lo:hi + 1], init, obstacle=obstacle_params, obstacle_fn=full_fn,
                       initial_values=values, progress=False)
        hits = np.nonzero(np.asarray(jnp.any((res.values <= 0) & in_target, axis=(1, 2, 3))))[0]
        if hits.size:
            return float(times[lo + hits[0]])
        values, lo = res.values[-1], hi
    return math.inf


def obstacle_pads(plan: Plan, scenario, *, store=None) -> tuple[float, float]:
    """``(before, after)`` [s]: how much longer than its flight each vehicle's disks were present in ``plan``.

    A plan that records them (:attr:`Plan.obstacle_pads`) gives its own. A plan file written before they were
    recorded: a plan without k̄ has only the lag-0 disk, so nothing was folded (``(0, 0)``); an intruder-aware one
    has them derived again from ``scenario`` (its buffer artifacts, cached in ``store``), used when the plan's folded
    disks are the ones derived with them. Otherwise (a warning) both pads are ``rho_0 / v``, the lag-0 radius over
    the top planning speed: every folded disk had ``rho + v |lambda| <= rho_0``, so no folded lag is longer. A
    ``hold_slices`` widening of an unrecorded plan cannot be recovered and is not included."""
    if plan.obstacle_pads is not None:
        return plan.obstacle_pads
    stored = plan.vehicles[0]
    if plan.kbar is None and len(stored.obstacle_lags) <= 1:
        return 0.0, 0.0
    speed = float(scenario.planning_v[1])
    if plan.kbar is not None:
        aware = aware_obstacles(scenario, plan.tracking_bound, store=store, progress=False)
        lags, radii, before, after = obstacle_disks(plan.collision_radius, plan.tracking_bound, speed,
                                                    aware["buffer_radius"], aware["obstacle_profiles"])
        if np.array_equal(lags, stored.obstacle_lags) and np.allclose(radii, stored.obstacle_radii, rtol=0,
                                                                        atol=1e-9):
            return before, after
    pad = float(stored.obstacle_radii[0]) / speed
    warnings.warn(f"the plan does not record how long its disks were held around each flight, and scenario "
                  f"{scenario.name!r} does not give its disks again; replanning holds them {pad:.1f} s on both "
                  "sides (a bound on every folded lag).", stacklevel=2)
    return pad, pad


def replan(plan: Plan, scenario, affected: dict[int, tuple[float, float, float]], t_bar: float, *,
           horizon: float | None = None, settings: hj.SolverSettings | None = None, store=None) -> Plan:
    """New plans for the vehicles in ``affected`` (index -> state ``x~^0`` at ``t_bar``), Algorithm 4.

    Returns a :class:`Plan` in which only the affected vehicles' entries differ; their ``sta`` is the new STA. Each
    new trajectory is checked against the exact disks of every other vehicle and planned again with the disks grown
    when it comes deeper into one than half a cell (:func:`stp_env.planning.stp.plan_clear_of_disks`).
    ``store`` caches the buffer artifacts that :func:`obstacle_pads` reads for plans that do not record their pads.
    """
    if not affected:
        return plan
    n = len(plan.vehicles)
    for i, state in affected.items():
        if not 0 <= i < n:
            raise ValueError(f"affected vehicle index {i} is out of range 0..{n - 1}.")
        if len(state) != 3 or not all(math.isfinite(float(v)) for v in state):
            raise ValueError(f"vehicle {i}: the state after avoidance must be 3 finite numbers; got {state}.")
    grid = scenario.grid()
    planner = DubinsWind(v_min=scenario.planning_v[0], v_max=scenario.planning_v[1],
                         omega_max=scenario.planning_omega_max, wind=0.0)
    r_e = plan.tracking_bound
    lags, radii = plan.vehicles[0].obstacle_lags, plan.vehicles[0].obstacle_radii
    if horizon is None:
        horizon = 2.0 * float(np.max(np.hypot(*(scenario.targets() - scenario.starts()[:, :2]).T))) \
            / scenario.planning_v[1] + 1.0
    time_step = scenario.time_step
    margin = max(grid.spacing[:2]) / scenario.planning_v[0]
    settings = settings or PLANNING_SETTINGS
    static = planning_static_obstacle(scenario, r_e)
    vehicles = list(plan.vehicles)
    others = [v for v in plan.vehicles if v.index not in affected]
    pads = obstacle_pads(plan, scenario, store=store)
    trajectories = [obstacle_window(v.plan, pads) for v in others]
    tolerance = DISK_TOLERANCE_CELLS * float(max(grid.spacing[:2]))
    for i in sorted(affected, key=lambda k: plan.vehicles[k].priority):
        spec = scenario.vehicles[i]
        shrunk = spec.target_radius - r_e

        def plan_with(grow, i=i, spec=spec, shrunk=shrunk):  # vehicle i, with every disk grown by ``grow`` metres
            kwargs = planning_obstacles(grid, trajectories, lags, radii + grow, static, n_slots=n - 1,
                                        n_samples=math.ceil(1.1 * horizon / time_step) + 1)
            sta = earliest_arrival(grid, planner, affected[i], t_bar, spec.target, shrunk, horizon,
                                   slice_dt=max(time_step, horizon / 100), settings=settings, **kwargs)
            if not math.isfinite(sta):
                raise InfeasiblePlanError(f"vehicle {i}: its target cannot be reached from {tuple(affected[i])} "
                                          f"within {horizon} s of t = {t_bar} s; increase the horizon.", math.nan)
            # The FRS starts from a ball of ~1.5 cells around the state, so its earliest arrival is optimistic by up
            # to that ball's crossing time: move the STA later by the deficit until the plan departs no earlier
            # than t_bar (one correction is usually enough).
            sta_new = sta + margin
            for _ in range(5):
                try:
                    single = plan_single(grid, planner, affected[i], spec.target, shrunk, sta_new - margin,
                                         horizon=sta_new - t_bar + margin, settings=settings, time_step=time_step,
                                         slice_dt=max(time_step, horizon / 200), depart_at=t_bar, **kwargs)
                    return dataclasses.replace(single, sta=sta_new)
                except InfeasiblePlanError as err:
                    deficit = err.latest_departure - t_bar if err.latest_departure is not None else None
                    if deficit is None or not math.isfinite(deficit):
                        sta_new += 0.1 * horizon
                    else:
                        sta_new += -deficit + time_step
            raise InfeasiblePlanError(f"vehicle {i}: no plan from {tuple(affected[i])} at t = {t_bar} s found after "
                                      f"moving its STA to {sta_new:.1f} s.", math.nan)

        # Checked against the exact disks, as plan_rtt does: planned again with the disks grown if deeper than half
        # a cell (an InfeasiblePlanError, a ValueError, when even the true disks leave no plan).
        single = plan_clear_of_disks(plan_with, trajectories, lags, radii, tolerance, f"vehicle {i}")
        vehicles[i] = VehiclePlan(index=i, priority=plan.vehicles[i].priority, plan=single, obstacle_lags=lags,
                                  obstacle_radii=radii)
        trajectories.append(obstacle_window(single, pads))
    return dataclasses.replace(plan, vehicles=tuple(vehicles), obstacle_pads=pads)
