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

Not yet here: the centralized and least-restrictive induced-obstacle methods (they need forward reachable sets
under closed-loop feedback), static obstacles (``V^S``), replanning (Algorithm 4) and plan caching.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from tqdm.auto import tqdm

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning.obstacles import disk_params, moving_disks
from stp_env.planning.single import SinglePlan, plan_single


@dataclasses.dataclass(frozen=True)
class VehiclePlan:
    """One vehicle's entry of a :class:`Plan` (see :class:`stp_env.planning.single.SinglePlan`)."""

    index: int
    priority: int
    plan: SinglePlan
    obstacle_lags: np.ndarray
    obstacle_radii: np.ndarray


@dataclasses.dataclass(frozen=True)
class Plan:
    """Plans of all vehicles, in the order of the inputs (not of priority).

    Attributes:
        vehicles: one :class:`VehiclePlan` per vehicle.
        tracking_bound: ``r_e`` [m].
        collision_radius: ``R_c`` [m].
        kbar: ``k̄`` for intruder-aware plans, else ``None``.
    """

    vehicles: tuple[VehiclePlan, ...]
    tracking_bound: float
    collision_radius: float
    kbar: int | None

    def t_ldt(self) -> np.ndarray:
        return np.asarray([v.plan.t_ldt for v in self.vehicles])


def plan_rtt(grid: hj.Grid, vehicle: DubinsWind, planning_v: tuple[float, float], planning_omega_max: float,
             tracking_bound: float, collision_radius: float, starts: Sequence, targets: Sequence,
             target_radius: float | Sequence[float], stas: Sequence[float], priorities: Sequence[int] | None = None,
             *, horizon: float, kbar: int | None = None, buffer_radius: float | None = None,
             obstacle_profiles: dict | None = None, settings: hj.SolverSettings | None = None,
             time_step: float = 0.05, progress: bool = True) -> Plan:
    """Plans every vehicle with robust trajectory tracking (optionally intruder-aware).

    Args:
        grid: planning grid ``(p_x, p_y, theta)``.
        vehicle: the vehicles' full dynamics bounds (``U``, wind); the plan uses ``U^p`` and no wind.
        planning_v, planning_omega_max: the planning set ``U^p``.
        tracking_bound: ``r_e`` from :func:`stp_env.reach.tracking.compute_tracking_bound` [m].
        collision_radius: ``R_c`` [m].
        starts, targets, target_radius, stas: per vehicle ``(p_x, p_y, theta)``, target centre, radius, STA.
        priorities: ``0`` = highest (default: input order).
        horizon: planning horizon before each STA [s].
        kbar, buffer_radius, obstacle_profiles: intruder-aware mode (all three or none).
    """
    n = len(starts)
    radii = np.broadcast_to(np.asarray(target_radius, float), (n,))
    if not (len(targets) == len(stas) == n):
        raise ValueError(f"starts, targets and stas must have the same length; got {n}, {len(targets)}, "
                         f"{len(stas)}.")
    priorities = list(range(n)) if priorities is None else list(priorities)
    if sorted(priorities) != list(range(n)):
        raise ValueError(f"priorities must be a permutation of 0..{n - 1}; got {priorities}.")
    aware = kbar is not None
    if aware and (buffer_radius is None or obstacle_profiles is None):
        raise ValueError("Intruder-aware planning (kbar given) needs buffer_radius and obstacle_profiles.")
    shrunk = radii - tracking_bound
    for i in range(n):
        if shrunk[i] <= 0:
            raise ValueError(f"vehicle {i}: the tracking-error bound ({tracking_bound:.3f} m) is not smaller than "
                             f"its target radius ({radii[i]:.3f} m); no target is left to plan for.")
    planner = DubinsWind(v_min=planning_v[0], v_max=planning_v[1], omega_max=planning_omega_max, wind=0.0)
    # Obstacle radii around each higher-priority nominal trajectory (lag 0 disk first).
    lags = [0.0]
    rads = [collision_radius + 2 * tracking_bound]
    if aware:
        rads[0] = max(rads[0], buffer_radius)
        for prof in obstacle_profiles.values():
            lags.extend(prof.lags.tolist())
            rads.extend((prof.radii + tracking_bound).tolist())
    lags_arr, rads_arr = np.asarray(lags), np.asarray(rads)

    order = sorted(range(n), key=lambda i: priorities[i])
    done: dict[int, VehiclePlan] = {}
    trajectories = []
    for rank, i in enumerate(tqdm(order, desc="STP planning", unit="vehicle", disable=not progress)):
        kwargs = {}
        if trajectories:
            kwargs = {"obstacle_fn": moving_disks,
                      "obstacle_params": disk_params(grid, trajectories, lags_arr, rads_arr)}
        single = plan_single(grid, planner, starts[i], targets[i], float(shrunk[i]), float(stas[i]), horizon,
                             settings=settings, time_step=time_step, progress=False, **kwargs)
        end = single.arrival_time if math.isfinite(single.arrival_time) else single.times[-1]
        trajectories.append((single.times, single.states, single.t_ldt, end))
        done[i] = VehiclePlan(index=i, priority=rank, plan=single, obstacle_lags=lags_arr, obstacle_radii=rads_arr)
    return Plan(vehicles=tuple(done[i] for i in range(n)), tracking_bound=float(tracking_bound),
                collision_radius=float(collision_radius), kbar=kbar)
