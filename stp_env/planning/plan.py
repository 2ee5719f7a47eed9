"""The plan types of sequential trajectory planning and their packing into plain arrays.

:class:`SinglePlan` is one vehicle's nominal trajectory and latest departure (:mod:`stp_env.planning.single`),
:class:`VehiclePlan` its entry in a scenario's :class:`Plan` (:mod:`stp_env.planning.stp` for robust trajectory
tracking, :mod:`stp_env.planning.methods` for the centralized and least-restrictive methods, both of which import
these types from here). :func:`plan_to_arrays` / :func:`plan_from_arrays` turn a plan into ``.npz``-ready arrays
and back (shipped plans, the artifact cache, planning checkpoints); :func:`pack_trajectories` stores the
trajectories of a large shipped plan losslessly in a form that compresses about three times better.
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


def obstacle_window(single: SinglePlan, pads: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(times, states, start, end)`` of one vehicle's disks for the lower-priority vehicles (the form
    :func:`stp_env.planning.obstacles.planning_obstacles` takes): the flight, with the disks present from ``pads[0]``
    s before its departure to ``pads[1]`` s after its arrival (its last sample when it never arrives)."""
    end = single.arrival_time if math.isfinite(single.arrival_time) else single.times[-1]
    return (*single.flight(), single.t_ldt - pads[0], end + pads[1])


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
        obstacle_pads: ``(before, after)`` [s]: every vehicle's disks were present from ``before`` s before its
            departure to ``after`` s after its arrival for the lower-priority vehicles
            (:func:`stp_env.planning.disks.fold_contained_disks`, plus any ``hold_slices``); replanning keeps them.
            ``None`` when not recorded (plan files written before the field existed).
    """

    vehicles: tuple[VehiclePlan, ...]
    tracking_bound: float
    collision_radius: float
    kbar: int | None
    obstacle_pads: tuple[float, float] | None = None

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
        **({} if plan.obstacle_pads is None else {"obstacle_pads": np.asarray(plan.obstacle_pads, np.float64)}),
    }


TRAJECTORY_FIELDS = (("times", 1), ("states", 3), ("controls", 2))
"""The padded trajectory arrays of :func:`plan_to_arrays` and their columns per sample."""


def pack_trajectories(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``arrays`` of :func:`plan_to_arrays` with the padded float64 trajectories replaced by one lossless, compact
    ``uint8`` array ``packed_trajectories`` (for shipped plan files; :func:`plan_from_arrays` reads both forms).

    The valid samples of every vehicle are laid end to end (``lengths`` says where each starts), the six columns'
    float64 bit patterns are differenced sample to sample (modulo 2**64, so the inverse is a cumulative sum), and
    each column's bytes are stored byte plane by byte plane. Consecutive samples of a trajectory share their sign,
    exponent and leading mantissa bits, so the high byte planes are almost all zero and ``np.savez_compressed``
    shrinks them to nearly nothing: a city plan of 49 vehicles that zlib keeps at 6.4 MB in the padded form takes
    about a third of that. Nothing is rounded: unpacking gives the same bits."""
    lengths = np.asarray(arrays["lengths"], np.int64)
    columns = np.concatenate([np.concatenate([np.asarray(arrays[key][i, :m], np.float64).reshape(m, width)
                                              for i, m in enumerate(lengths)] or [np.zeros((0, width))])
                              for key, width in TRAJECTORY_FIELDS], axis=1)           # (samples, 6)
    bits = columns.view(np.uint64)
    delta = np.concatenate([bits[:1], bits[1:] - bits[:-1]])                            # modulo 2**64
    planes = np.ascontiguousarray(delta.T, dtype="<u8").view(np.uint8)
    planes = planes.reshape(delta.shape[1], delta.shape[0], 8).transpose(0, 2, 1)
    out = {k: v for k, v in arrays.items() if k not in dict(TRAJECTORY_FIELDS)}
    out["packed_trajectories"] = np.ascontiguousarray(planes)                           # (6, 8, samples)
    return out


def unpack_trajectories(arrays) -> dict[str, np.ndarray]:
    """The padded ``times``, ``states``, ``controls`` of a plan stored by :func:`pack_trajectories`."""
    lengths = np.asarray(arrays["lengths"], np.int64)
    planes = np.asarray(arrays["packed_trajectories"])
    n_cols = sum(width for _, width in TRAJECTORY_FIELDS)
    if (planes.dtype != np.uint8 or planes.ndim != 3 or planes.shape[:2] != (n_cols, 8)
            or np.any(lengths < 0) or planes.shape[2] != int(lengths.sum())):
        raise ValueError(f"packed_trajectories must be uint8 of shape ({n_cols}, 8, {int(lengths.sum())}) (the "
                         f"sum of lengths); got {planes.dtype} {planes.shape}.")
    delta = np.ascontiguousarray(planes.transpose(0, 2, 1)).view("<u8")[..., 0].T.astype(np.uint64)
    columns = np.cumsum(delta, axis=0, dtype=np.uint64).view(np.float64)               # modulo 2**64
    n, k = len(lengths), int(lengths.max(initial=0))
    starts = np.concatenate([[0], np.cumsum(lengths)])
    out, col = {}, 0
    for key, width in TRAJECTORY_FIELDS:
        padded = np.full((n, k, width), np.nan)
        for i, m in enumerate(lengths):
            padded[i, :m] = columns[starts[i]:starts[i] + m, col:col + width]
        out[key] = padded[..., 0] if width == 1 else padded
        col += width
    return out


def trim_after_arrival(arrays: dict[str, np.ndarray], keep: float) -> dict[str, np.ndarray]:
    """``arrays`` (:func:`plan_to_arrays`) with every trajectory cut ``keep`` seconds after
    its vehicle's arrival (vehicles that never arrive keep all their samples). A vehicle leaves the airspace at
    its arrival, so nothing of the model reads the later samples but a vehicle running late (an avoidance
    manoeuvre), which tracks the reference ``keep`` seconds on and then its last sample; the planner integrates
    every trajectory to its horizon, which in a long plan is most of the samples."""
    if not (math.isfinite(keep) and keep >= 0):
        raise ValueError(f"keep must be a non-negative number of seconds; got {keep}.")
    lengths = np.asarray(arrays["lengths"]).copy()
    for i, m in enumerate(lengths):
        arrival = float(arrays["arrival_time"][i])
        if math.isfinite(arrival):
            lengths[i] = min(m, int(np.searchsorted(arrays["times"][i, :m], arrival + keep, side="right")))
    width = int(lengths.max())
    out = dict(arrays, lengths=lengths)
    for key in ("times", "states", "controls"):
        cut = np.array(arrays[key][:, :width], copy=True)
        for i, m in enumerate(lengths):
            cut[i, m:] = np.nan
        out[key] = cut
    return out


def plan_from_arrays(arrays) -> Plan:
    """Inverse of :func:`plan_to_arrays` (and of :func:`pack_trajectories`)."""
    if "packed_trajectories" in arrays:
        arrays = {**{k: arrays[k] for k in arrays if k != "packed_trajectories"}, **unpack_trajectories(arrays)}
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
    pads = None
    if "obstacle_pads" in arrays:
        pads = np.asarray(arrays["obstacle_pads"], np.float64)
        if pads.shape != (2,) or not (np.all(np.isfinite(pads)) and np.all(pads >= 0)):
            raise ValueError(f"obstacle_pads must be 2 finite seconds >= 0; got {pads!r}.")
        pads = (float(pads[0]), float(pads[1]))
    return Plan(vehicles=tuple(vehicles), tracking_bound=float(arrays["tracking_bound"]),
                collision_radius=float(arrays["collision_radius"]), kbar=None if kbar < 0 else kbar,
                obstacle_pads=pads)
