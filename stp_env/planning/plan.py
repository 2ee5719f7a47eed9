"""The plan types of sequential trajectory planning and their packing into plain arrays.

:class:`SinglePlan` is one vehicle's nominal trajectory and latest departure (:mod:`stp_env.planning.single`),
:class:`VehiclePlan` its entry in a scenario's :class:`Plan` (:mod:`stp_env.planning.stp` for robust trajectory
tracking, :mod:`stp_env.planning.methods` for the centralized and least-restrictive methods, both of which import
these types from here). :func:`plan_to_arrays` / :func:`plan_from_arrays` turn a plan into ``.npz``-ready arrays
and back (shipped plans, the artifact cache, planning checkpoints).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


class InfeasiblePlanError(ValueError):
    """No departure time lets the vehicle reach its target by its STA within the planning horizon (or not from
    the imposed departure time; ``latest_departure`` then holds the latest feasible one)."""

    def __init__(self, message: str, latest_departure: float | None = None):
        super().__init__(message)
        self.latest_departure = latest_departure


@dataclasses.dataclass(frozen=True)
class SinglePlan:
    """The plan of one vehicle.

    Attributes:
        t_ldt: latest departure time [s] (the departure time ``depart_at`` when one was imposed).
        sta: scheduled time of arrival [s].
        times: trajectory sample times from ``t_ldt`` [s], shape ``(K,)``; they run a little past the STA.
        states: nominal states ``(p_x, p_y, theta)`` at ``times``, shape ``(K, 3)`` [m, m, rad].
        controls: nominal controls ``(v, omega)`` applied from each sample, shape ``(K, 2)`` [m/s, rad/s].
        arrival_time: first sample time inside the target [s]; the vehicle leaves the airspace then, and
            :meth:`flight` is the part of the trajectory before it.
        n_steps: solver time steps of the BRS.
    """

    t_ldt: float
    sta: float
    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    arrival_time: float
    n_steps: int

    def flight(self) -> tuple[np.ndarray, np.ndarray]:
        """``(times, states)`` from departure to arrival (inclusive)."""
        k = int(np.searchsorted(self.times, self.arrival_time, side="right")) if math.isfinite(
            self.arrival_time) else len(self.times)
        return self.times[:k], self.states[:k]


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


def plan_to_arrays(plan: Plan) -> dict[str, np.ndarray]:
    """Packs a plan into plain arrays (ragged trajectories padded with NaN, lengths kept) for ``.npz`` files."""
    n = len(plan.vehicles)
    k = max(len(v.plan.times) for v in plan.vehicles)
    times = np.full((n, k), np.nan)
    states = np.full((n, k, 3), np.nan)
    controls = np.full((n, k, 2), np.nan)
    for i, v in enumerate(plan.vehicles):
        m = len(v.plan.times)
        times[i, :m], states[i, :m], controls[i, :m] = v.plan.times, v.plan.states, v.plan.controls
    return {
        "times": times, "states": states, "controls": controls,
        "lengths": np.asarray([len(v.plan.times) for v in plan.vehicles]),
        "t_ldt": np.asarray([v.plan.t_ldt for v in plan.vehicles]),
        "sta": np.asarray([v.plan.sta for v in plan.vehicles]),
        "arrival_time": np.asarray([v.plan.arrival_time for v in plan.vehicles]),
        "n_steps": np.asarray([v.plan.n_steps for v in plan.vehicles]),
        "priority": np.asarray([v.priority for v in plan.vehicles]),
        "obstacle_lags": plan.vehicles[0].obstacle_lags, "obstacle_radii": plan.vehicles[0].obstacle_radii,
        "tracking_bound": np.asarray(plan.tracking_bound), "collision_radius": np.asarray(plan.collision_radius),
        "kbar": np.asarray(-1 if plan.kbar is None else plan.kbar),
    }


def plan_from_arrays(arrays) -> Plan:
    """Inverse of :func:`plan_to_arrays`."""
    vehicles = []
    for i, m in enumerate(np.asarray(arrays["lengths"])):
        single = SinglePlan(t_ldt=float(arrays["t_ldt"][i]), sta=float(arrays["sta"][i]),
                            times=np.asarray(arrays["times"][i, :m]), states=np.asarray(arrays["states"][i, :m]),
                            controls=np.asarray(arrays["controls"][i, :m]),
                            arrival_time=float(arrays["arrival_time"][i]), n_steps=int(arrays["n_steps"][i]))
        vehicles.append(VehiclePlan(index=i, priority=int(arrays["priority"][i]), plan=single,
                                    obstacle_lags=np.asarray(arrays["obstacle_lags"]),
                                    obstacle_radii=np.asarray(arrays["obstacle_radii"])))
    kbar = int(arrays["kbar"])
    return Plan(vehicles=tuple(vehicles), tracking_bound=float(arrays["tracking_bound"]),
                collision_radius=float(arrays["collision_radius"]), kbar=None if kbar < 0 else kbar)
