"""The sequential planning problem: everything :func:`stp_env.planning.stp.plan_rtt` plans from, in one checked,
immutable object.

:class:`PlanningProblem` groups the vehicles (starts, targets, target radii, STAs, priorities), the planning model
(:class:`stp_env.planning.model.PlanningModel`: the dynamics with the reduced control set ``U^p``), the bounds of
robust trajectory tracking (``r_e``, ``R_c``), the intruder-aware part (``k̄``, the buffer radius and the obstacle
lag profiles: all three or none), the static obstacles, and the horizon, sample period, arrival margin and solver
settings. It checks them when it is built, so that a malformed problem fails with one message before any BRS is
solved. :meth:`PlanningProblem.dubins` builds one for the papers' Dubins vehicle from the argument list the planner
took before the problem object existed; :func:`stp_env.planning.stp.problem_for_scenario` builds one for a
registered scenario.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning.model import DubinsPlanning, PlanningModel, as_planning_model

SOLVERS = ("hj", "split")
"""The BRS solvers a problem may name (:func:`stp_env.planning.single.plan_single_with_slices`)."""


def _finite(name: str, value, *, minimum: float | None = None, strict: bool = False):
    """``value`` checked to be a finite real number (and ``>= minimum``, or ``> minimum`` with ``strict``); returned
    as given, so that the planner computes with the caller's number exactly as it would have without the check."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number; got {value!r}.")
    number = float(value)
    ok = math.isfinite(number) and (minimum is None or (number > minimum if strict else number >= minimum))
    if not ok:
        bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
        raise ValueError(f"{name} must be a finite number{bound}; got {value!r}.")
    return value


def _rows(name: str, value, width: int) -> np.ndarray:
    """``value`` as a read-only float64 array of shape ``(n, width)``, finite."""
    try:
        arr = np.array(value, np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a sequence of {width}-vectors of numbers: {err}") from None
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{name} must have shape (n, {width}); got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite.")
    arr.setflags(write=False)
    return arr


@dataclasses.dataclass(frozen=True, eq=False)
class PlanningProblem:
    """One sequential planning problem (robust trajectory tracking, SPP paper Section IV-C; intruder-aware with
    ``kbar``: intruder paper Algorithm 3).

    Attributes:
        grid: planning grid ``(p_x, p_y, theta)``, heading periodic.
        model: the planning model (:class:`stp_env.planning.model.PlanningModel`; a ``DubinsWind`` is wrapped in
            :class:`stp_env.planning.model.DubinsPlanning`): the dynamics with ``U^p`` and, for robust trajectory
            tracking, no wind.
        starts: ``(n, 3)`` initial states ``(p_x, p_y, theta)``.
        targets: ``(n, 2)`` target centres [m].
        target_radii: ``(n,)`` target radii [m] (a number: the same for every vehicle); each larger than
            ``tracking_bound`` (the planner aims at the target shrunk by it).
        stas: ``(n,)`` scheduled times of arrival [s].
        tracking_bound: ``r_e`` [m] (:func:`stp_env.reach.tracking.compute_tracking_bound`).
        collision_radius: ``R_c`` [m].
        horizon: how far before each STA to look for a departure [s].
        priorities: ``(n,)`` a permutation of ``0..n-1``, ``0`` the highest (``None``: input order).
        vehicle: the full dynamics the plan is tracked with (``U``, wind); only recorded (checkpoint key).
        kbar, buffer_radius, obstacle_profiles: intruder-aware planning, all three or none: ``k̄``, the buffer radius
            of eqs. (21), (48) [m] and the obstacle lag profiles of eqs. (26)-(31), (49)-(57)
            (:func:`stp_env.reach.obstacles.intruder_obstacle_profiles`).
        static_obstacle: signed distance to the static obstacles on the position plane (``grid.shape[:2]``,
            ``{<= 0}`` forbidden), already grown by the margin the caller needs.
        time_step: trajectory sample period [s].
        arrival_margin: plan to arrive this much before each STA [s] (``None``: one cell at the slowest planning
            speed).
        settings: solver settings (``None``: :data:`stp_env.planning.stp.PLANNING_SETTINGS`).
        solver: ``"split"`` or ``"hj"`` (``None``: :data:`stp_env.planning.stp.PLANNING_SOLVER`).
        max_slice_dt, hold_slices, disk_tolerance: the slice spacing cap [s], the slices every disk is held longer,
            and the depth [m] a trajectory may reach into a disk (see :func:`stp_env.planning.stp.plan_rtt`).
    """

    grid: hj.Grid
    model: PlanningModel
    starts: np.ndarray
    targets: np.ndarray
    target_radii: np.ndarray
    stas: np.ndarray
    tracking_bound: float
    collision_radius: float
    horizon: float
    priorities: tuple[int, ...] | None = None
    vehicle: Any = None
    kbar: int | None = None
    buffer_radius: float | None = None
    obstacle_profiles: Mapping | None = None
    static_obstacle: np.ndarray | None = None
    time_step: float = 0.05
    arrival_margin: float | None = None
    settings: hj.SolverSettings | None = None
    solver: str | None = None
    max_slice_dt: float | None = None
    hold_slices: int = 0
    disk_tolerance: float | None = None

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)

        if not isinstance(self.grid, hj.Grid):
            raise TypeError(f"grid must be a stp_env.hj.Grid; got {type(self.grid).__name__}.")
        if self.grid.ndim != 3 or not self.grid.is_periodic[2]:
            raise ValueError(f"the planning grid must be 3-D (p_x, p_y, theta) with a periodic heading; got "
                             f"{self.grid.ndim} dimensions, periodic {self.grid.is_periodic}.")
        put("model", as_planning_model(self.model))
        starts = _rows("starts", self.starts, 3)
        n = len(starts)
        if n == 0:
            raise ValueError("a planning problem needs at least one vehicle; starts is empty.")
        targets = _rows("targets", self.targets, 2)
        stas = np.array(self.stas, np.float64)
        if stas.shape != (n,) or len(targets) != n:
            raise ValueError(f"starts, targets and stas must have one entry per vehicle; got {n} starts, "
                             f"{len(targets)} targets and stas of shape {stas.shape}.")
        if not np.all(np.isfinite(stas)):
            raise ValueError("stas must be finite.")
        radii = np.array(self.target_radii, np.float64)
        if radii.ndim == 0:
            radii = np.full(n, float(radii))
        if radii.shape != (n,):
            raise ValueError(f"target_radii must be a number or one radius per vehicle ({n}); got shape "
                             f"{radii.shape}.")
        if not (np.all(np.isfinite(radii)) and np.all(radii > 0)):
            raise ValueError(f"target radii must be finite and > 0; got {radii.tolist()}.")
        for arr in (stas, radii):
            arr.setflags(write=False)
        put("starts", starts)
        put("targets", targets)
        put("stas", stas)
        put("target_radii", radii)
        priorities = list(range(n)) if self.priorities is None else list(self.priorities)
        if sorted(priorities) != list(range(n)):
            raise ValueError(f"priorities must be a permutation of 0..{n - 1}; got {priorities}.")
        put("priorities", tuple(int(p) for p in priorities))
        put("tracking_bound", _finite("tracking_bound", self.tracking_bound, minimum=0.0))
        put("collision_radius", _finite("collision_radius", self.collision_radius, minimum=0.0))
        shrunk = radii - self.tracking_bound
        for i in range(n):
            if shrunk[i] <= 0:
                raise ValueError(f"vehicle {i}: the tracking-error bound ({self.tracking_bound:.3f} m) is not smaller "
                                 f"than its target radius ({radii[i]:.3f} m); no target is left to plan for.")
        put("horizon", _finite("horizon", self.horizon, minimum=0.0, strict=True))
        put("time_step", _finite("time_step", self.time_step, minimum=0.0, strict=True))
        if self.arrival_margin is not None:
            put("arrival_margin", _finite("arrival_margin", self.arrival_margin, minimum=0.0))
        self._check_intruder_aware(put)
        if self.static_obstacle is not None:
            static = np.array(self.static_obstacle)
            if static.shape != tuple(self.grid.shape[:2]):
                raise ValueError(f"static_obstacle must lie on the position plane, shape {tuple(self.grid.shape[:2])}; "
                                 f"got {static.shape}.")
            if not np.issubdtype(static.dtype, np.floating) or np.any(np.isnan(static)):
                raise ValueError("static_obstacle must be a real-valued signed distance without NaN.")
            static.setflags(write=False)
            put("static_obstacle", static)
        if self.settings is not None and not isinstance(self.settings, hj.SolverSettings):
            raise TypeError(f"settings must be a stp_env.hj.SolverSettings or None; got "
                            f"{type(self.settings).__name__}.")
        if self.solver is not None and self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS} or None; got {self.solver!r}.")
        if self.max_slice_dt is not None and not (
                isinstance(self.max_slice_dt, (int, float, np.integer, np.floating))
                and not isinstance(self.max_slice_dt, bool)
                and math.isfinite(self.max_slice_dt) and self.max_slice_dt > 0):
            raise ValueError(f"max_slice_dt must be a positive number of seconds; got {self.max_slice_dt}.")
        if (isinstance(self.hold_slices, bool) or not isinstance(self.hold_slices, (int, np.integer))
                or self.hold_slices < 0):
            raise ValueError(f"hold_slices must be a whole number of slices >= 0; got {self.hold_slices!r}.")
        if self.disk_tolerance is not None and not (
                isinstance(self.disk_tolerance, (int, float, np.floating)) and not isinstance(self.disk_tolerance, bool)
                and math.isfinite(self.disk_tolerance) and self.disk_tolerance >= 0):
            raise ValueError(f"disk_tolerance must be a finite number of metres >= 0; got {self.disk_tolerance!r}.")

    def _check_intruder_aware(self, put) -> None:
        given = {name: getattr(self, name) is not None for name in ("kbar", "buffer_radius", "obstacle_profiles")}
        if not any(given.values()):
            return
        if not all(given.values()):
            missing = [name for name, ok in given.items() if not ok]
            present = [name for name, ok in given.items() if ok]
            raise ValueError(f"intruder-aware planning needs kbar, buffer_radius and obstacle_profiles together (or "
                             f"none of them); got {', '.join(present)} without {', '.join(missing)}.")
        if isinstance(self.kbar, bool) or not isinstance(self.kbar, (int, np.integer)) or self.kbar < 0:
            raise ValueError(f"kbar must be a whole number of intruders >= 0; got {self.kbar!r}.")
        put("buffer_radius", _finite("buffer_radius", self.buffer_radius, minimum=0.0, strict=True))
        if not isinstance(self.obstacle_profiles, Mapping):
            raise TypeError(f"obstacle_profiles must be a mapping of lag profiles; got "
                            f"{type(self.obstacle_profiles).__name__}.")
        for key, prof in self.obstacle_profiles.items():
            lags, radii = (np.asarray(getattr(prof, name, None), np.float64) for name in ("lags", "radii"))
            if lags.ndim != 1 or lags.shape != radii.shape or not np.all(np.isfinite(lags) & np.isfinite(radii)):
                raise ValueError(f"obstacle profile {key!r} must have finite 1-D lags and radii of one length.")

    @classmethod
    def dubins(cls, grid: hj.Grid, vehicle: DubinsWind, planning_v: tuple[float, float], planning_omega_max: float,
               tracking_bound: float, collision_radius: float, starts: Sequence, targets: Sequence,
               target_radius: float | Sequence[float], stas: Sequence[float],
               priorities: Sequence[int] | None = None, **fields) -> PlanningProblem:
        """The problem of the papers' Dubins vehicles: ``vehicle`` (``U``, wind) planned with
        ``U^p = planning_v x [-planning_omega_max, planning_omega_max]`` and no wind
        (:class:`stp_env.planning.model.DubinsPlanning`). ``fields``: the other attributes (``horizon`` and the
        optional ones), by name."""
        if len(planning_v) != 2:
            raise ValueError(f"planning_v must be (v_min, v_max); got {planning_v!r}.")
        planner = DubinsWind(v_min=planning_v[0], v_max=planning_v[1], omega_max=planning_omega_max, wind=0.0)
        return cls(grid=grid, model=DubinsPlanning(planner), starts=starts, targets=targets,
                   target_radii=target_radius, stas=stas, tracking_bound=tracking_bound,
                   collision_radius=collision_radius, priorities=priorities, vehicle=vehicle, **fields)

    @property
    def n_vehicles(self) -> int:
        return len(self.starts)

    @property
    def planning_v(self) -> tuple[float, float]:
        """``(v_min, v_max)`` of ``U^p`` (the model's)."""
        return tuple(self.model.speed_bounds)

    @property
    def planning_omega_max(self) -> float:
        """The largest turn rate of ``U^p`` (the model's)."""
        return self.model.omega_max

    @property
    def intruder_aware(self) -> bool:
        return self.kbar is not None

    @property
    def order(self) -> list[int]:
        """The vehicle indices in planning order (highest priority first)."""
        return sorted(range(self.n_vehicles), key=lambda i: self.priorities[i])
