"""Replanning after the intruder leaves (intruder paper Section IV-E, eqs. 39-42, Algorithm 4).

The vehicles forced to avoid (``N^RP``, eq. 39) end up at states ``x~_i^0`` at ``t_bar = t_ + t_IAT``. Each gets
(in priority order):

1. a new STA: the earliest time at which the forward reachable set ``W^RP(t_bar, t)`` of eq. (41)-(42), grown from
   ``x~_i^0`` while avoiding the obstacles of the other vehicles, meets its target;
2. a new plan from ``x~_i^0`` to its target by that STA (Algorithm 3's planning step, here robust tracking).

The obstacles are the nominal trajectories of every vehicle outside ``N^RP`` (as in Algorithm 4) and, so that the
replanned vehicles cannot collide with each other either, those already replanned, with the disks of the original
plan; and the buildings, grown as for the original plan (:func:`stp_env.planning.stp.planning_static_obstacle`).
Plans of the other vehicles are returned unchanged (the same objects).

``replan`` is host-side (level-set solves) and can be called while a simulation runs: ``parallel_env(...,
replan=True)`` calls it when the intruder leaves and swaps the new plans into the running simulation
(:func:`stp_env.sim.with_plan`).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning.obstacles import planning_obstacles
from stp_env.planning.single import InfeasiblePlanError, full_grid_obstacle, initial_ball, plan_single
from stp_env.planning.stp import PLANNING_SETTINGS, Plan, VehiclePlan, planning_static_obstacle


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


def replan(plan: Plan, scenario, affected: dict[int, tuple[float, float, float]], t_bar: float, *,
           horizon: float | None = None, settings: hj.SolverSettings | None = None) -> Plan:
    """New plans for the vehicles in ``affected`` (index -> state ``x~^0`` at ``t_bar``), Algorithm 4.

    Returns a :class:`Plan` in which only the affected vehicles' entries differ; their ``sta`` is the new STA.
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
    trajectories = [(*v.plan.flight(), v.plan.t_ldt, v.plan.arrival_time) for v in others]
    for i in sorted(affected, key=lambda k: plan.vehicles[k].priority):
        spec = scenario.vehicles[i]
        kwargs = planning_obstacles(grid, trajectories, lags, radii, static, n_slots=n - 1,
                                    n_samples=math.ceil(1.1 * horizon / time_step) + 1)
        shrunk = spec.target_radius - r_e
        sta = earliest_arrival(grid, planner, affected[i], t_bar, spec.target, shrunk, horizon,
                               slice_dt=max(time_step, horizon / 100), settings=settings, **kwargs)
        if not math.isfinite(sta):
            raise ValueError(f"vehicle {i}: its target cannot be reached from {tuple(affected[i])} within "
                             f"{horizon} s of t = {t_bar} s; increase the horizon.")
        # The FRS starts from a ball of ~1.5 cells around the state, so its earliest arrival is optimistic by up to
        # that ball's crossing time: move the STA later by the deficit until the plan departs no earlier than
        # t_bar (one correction is usually enough).
        sta_new = sta + margin
        for _ in range(5):
            try:
                single = plan_single(grid, planner, affected[i], spec.target, shrunk, sta_new - margin,
                                     horizon=sta_new - t_bar + margin, settings=settings, time_step=time_step,
                                     slice_dt=max(time_step, horizon / 200), depart_at=t_bar, **kwargs)
                break
            except InfeasiblePlanError as err:
                deficit = err.latest_departure - t_bar if err.latest_departure is not None else None
                if deficit is None or not math.isfinite(deficit):
                    sta_new += 0.1 * horizon
                else:
                    sta_new += -deficit + time_step
        else:
            raise ValueError(f"vehicle {i}: no plan from {tuple(affected[i])} at t = {t_bar} s found after moving "
                             f"its STA to {sta_new:.1f} s.")
        single = dataclasses.replace(single, sta=sta_new)
        vehicles[i] = VehiclePlan(index=i, priority=plan.vehicles[i].priority, plan=single, obstacle_lags=lags,
                                  obstacle_radii=radii)
        trajectories.append((*single.flight(), single.t_ldt, single.arrival_time))
    return dataclasses.replace(plan, vehicles=tuple(vehicles))
