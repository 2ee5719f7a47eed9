"""The moving disks of the sequential planner: what every lower-priority vehicle keeps clear of around a
higher-priority vehicle's nominal trajectory (SPP eq. 27; intruder-aware, intruder paper eqs. 21, 48 and the lag
profiles of eqs. 26-31, 49-57), shared by the planner (:func:`stp_env.planning.stp.plan_rtt`), the replanner and
the independent checks of a finished plan (:mod:`stp_env.planning.verify`)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class ObstacleDisks:
    """The moving disks every higher-priority vehicle induces: ``lags`` [s] and ``radii`` [m] (one per lag), present
    from ``pad_before`` s before its departure to ``pad_after`` s after its arrival."""

    lags: np.ndarray
    radii: np.ndarray
    pad_before: float = 0.0
    pad_after: float = 0.0


def obstacle_disks(collision_radius: float, tracking_bound: float, planning_speed: float,
                   buffer_radius: float | None = None, obstacle_profiles: dict | None = None):
    """The disks every lower-priority vehicle avoids around a higher-priority nominal trajectory: the lag-0 disk of
    radius ``R_c + 2 r_e`` (at least the buffer radius of eqs. (21), (48) in intruder-aware planning) and the lag
    disks of the obstacle profiles (eqs. (26)-(31), (49)-(57)) grown by ``r_e``, folded by
    :func:`fold_contained_disks` at the top planning speed. Returns ``(lags, radii, pad_before, pad_after)``."""
    lags = [0.0]
    rads = [collision_radius + 2 * tracking_bound]
    if (buffer_radius is None) != (obstacle_profiles is None):
        raise ValueError("buffer_radius and obstacle_profiles go together (intruder-aware planning) or not at all.")
    if buffer_radius is not None:
        rads[0] = max(rads[0], buffer_radius)
        for prof in obstacle_profiles.values():
            lags.extend(prof.lags.tolist())
            rads.extend((prof.radii + tracking_bound).tolist())
    return fold_contained_disks(np.asarray(lags), np.asarray(rads), planning_speed)


def fold_contained_disks(lags: np.ndarray, radii: np.ndarray, speed: float):
    """Drops the lag disks that lie inside the lag-0 disk ``radii[0]`` (cheaper obstacles, same or larger set).

    A nominal trajectory moves at most ``speed`` (the top planning speed: it is planned with ``U^p`` and no wind),
    so the disk of radius ``rho`` around ``p_j(t + lambda)`` lies inside the disk of radius ``rho_0`` around
    ``p_j(t)`` whenever ``rho + speed |lambda| <= rho_0``. In intruder-aware planning that holds for most lag
    profiles of eqs. (26)-(31), (49)-(57) against the buffer disk of eqs. (21), (48) (for ``k̄ <= 3`` at 6 m/s wind
    for all of them). A lag disk is active while ``t + lambda`` lies in the flight window ``[t_LDT_j, arrival_j]``
    (:func:`stp_env.planning.obstacles.moving_disks`); the lag-0 disk only while ``t`` does. To keep the union a
    superset, the flight window of every higher-priority vehicle is widened by the largest dropped positive lag
    before departure and the largest dropped negative lag's size after arrival: there the lag-0 disk sits at the
    clamped end position, within ``speed |lambda|`` of every dropped disk's centre.

    Returns ``(lags, radii, pad_before, pad_after)`` with the kept disks, lag-0 disk first.
    """
    lags, radii = np.asarray(lags, np.float64), np.asarray(radii, np.float64)
    inside = radii + speed * np.abs(lags) <= radii[0]
    inside[0] = False
    dropped = lags[inside]
    pad_before = float(max(dropped.max(initial=0.0), 0.0))
    pad_after = float(max(-dropped.min(initial=0.0), 0.0))
    return lags[~inside], radii[~inside], pad_before, pad_after


def aware_obstacles(scenario, tracking_bound: float, *, store=None, progress: bool = True) -> dict:
    """The intruder-aware fields of :class:`stp_env.planning.problem.PlanningProblem` for ``scenario`` (``{}`` when
    its ``kbar`` is ``None``): ``kbar``, the buffer radius (:func:`stp_env.reach.buffer.buffer_radii`, from the avoid
    and relative-buffer artifacts of the scenario's vehicle, cached in ``store``) and the obstacle lag profiles."""
    from stp_env.artifacts import ArtifactStore
    from stp_env.reach.avoid import compute_avoid_region
    from stp_env.reach.buffer import BufferConfig, buffer_radii, compute_relative_buffer
    from stp_env.reach.defaults import default_avoid_config
    from stp_env.reach.obstacles import intruder_obstacle_profiles

    if scenario.kbar is None:
        return {}
    store = ArtifactStore() if store is None else store
    vehicle = scenario.vehicle
    avoid_cfg = default_avoid_config(vehicle, scenario.collision_radius, scenario.t_iat)
    avoid = compute_avoid_region(avoid_cfg, store=store, progress=progress)
    buffer = compute_relative_buffer(BufferConfig(avoid=avoid_cfg, kbar=scenario.kbar), avoid, store=store,
                                     progress=progress)
    radii = buffer_radii(scenario.kbar, tracking_bound, avoid.detection_range(), buffer.radius, scenario.t_iat)
    return {"kbar": scenario.kbar, "buffer_radius": radii.buffer,
            "obstacle_profiles": intruder_obstacle_profiles(vehicle, tracking_bound, scenario.collision_radius,
                                                            scenario.t_iat, scenario.kbar)}


def planner_disks(scenario, tracking_bound: float, *, store=None, progress: bool = False) -> ObstacleDisks:
    """The disks :func:`stp_env.planning.stp.plan_rtt` plans ``scenario`` with (the same artifacts and folding)."""
    aware = aware_obstacles(scenario, tracking_bound, store=store, progress=progress)
    lags_arr, rads_arr, before, after = obstacle_disks(scenario.collision_radius, tracking_bound,
                                                       scenario.planning_v[1], aware.get("buffer_radius"),
                                                       aware.get("obstacle_profiles"))
    return ObstacleDisks(np.asarray(lags_arr, float), np.asarray(rads_arr, float), float(before), float(after))
