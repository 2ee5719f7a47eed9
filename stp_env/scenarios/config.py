"""Typed, frozen scenario configuration: vehicles, buildings and the planning problem of one STP study.

Conventions (for the planner and the simulator):

* SI units and the world frame: positions [m], headings [rad] wrapped to ``[-pi, pi)`` (a :class:`VehicleSpec`
  wraps the heading it is given), times [s], speeds [m/s].
* Vehicle ``i`` starts at ``start = (p_x, p_y, theta)`` and must reach the target disk
  ``L_i = {x : ||p - target|| <= target_radius}`` (intruder paper eq. 22 / SPP eq. 30) by its scheduled time of
  arrival ``sta`` (``t_i^STA``, absolute time on one clock shared by all vehicles; the planner computes the latest
  departure time ``t_i^LDT <= sta``).
* ``priority`` 0 is the highest; vehicles plan in increasing ``priority`` (:meth:`Scenario.in_priority_order`).
  Vehicle *indices* are only labels.
* Buildings are simple polygons in the position plane; the static obstacle is their union, as a signed-distance
  table (:func:`stp_env.scenarios.geometry.buildings_sdf`, negative inside).
* ``planning_v`` and ``planning_omega_max`` (the reduced planning set ``U^p``) are used by robust trajectory
  tracking (``method="rtt"``) only; the centralized and least-restrictive methods plan with the full set of
  ``vehicle``.

Every class validates itself on construction and on :meth:`Scenario.with_overrides`, with errors that say what was
wrong and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from stp_env.angles import wrap_angle
from stp_env.arguments import MAX_KBAR, show
from stp_env.dynamics import DubinsWind
from stp_env.hj import Grid
from stp_env.scenarios import geometry

METHODS = ("rtt", "centralized", "least_restrictive", "straight")
"""Induced-obstacle methods of the SPP paper: robust trajectory tracking (Section IV-C), centralized control
(IV-A), least-restrictive control (IV-B); and ``"straight"``: robust trajectory tracking's constraints met by
straight flights at the top planning speed, checked rather than searched
(:func:`stp_env.planning.verify.straight_plan`), for scenarios whose routes are conflict-free by schedule."""

MIN_CELLS_ACROSS_TARGET = 5
"""A target must span at least this many grid cells (diameter / spacing), docs/numerics.md: small targets smear away."""

_MAX_REPORTED_ERRORS = 10


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _finite_tuple(name: str, value, length: int) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of {length} numbers; got {value!r}.") from None
    if len(out) != length or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be {length} finite numbers; got {value!r}.")
    return out


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number; got {value!r}.") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0; got {value!r}.")
    return v


def _raise_all(header: str, errors: list[str]) -> None:
    if not errors:
        return
    shown = errors[:_MAX_REPORTED_ERRORS]
    more = len(errors) - len(shown)
    tail = f"\n  ... and {more} more." if more > 0 else ""
    raise ValueError(header + "\n  " + "\n  ".join(shown) + tail)


@dataclasses.dataclass(frozen=True, kw_only=True)
class VehicleSpec:
    """One STP vehicle.

    Attributes:
        start: initial state ``(p_x [m], p_y [m], theta [rad])``; theta is wrapped to ``[-pi, pi)``.
        target: centre ``c_i`` of the target disk [m].
        target_radius: radius ``r`` of the target disk [m].
        sta: scheduled time of arrival ``t_i^STA`` [s].
        priority: planning rank, 0 = highest priority.
    """

    start: tuple[float, float, float]
    target: tuple[float, float]
    target_radius: float
    sta: float
    priority: int

    def __post_init__(self) -> None:
        start = _finite_tuple("start", self.start, 3)
        object.__setattr__(self, "start", (start[0], start[1], wrap_angle(start[2])))
        object.__setattr__(self, "target", _finite_tuple("target", self.target, 2))
        object.__setattr__(self, "target_radius", _positive("target_radius", self.target_radius))
        try:
            sta = float(self.sta)
        except (TypeError, ValueError):
            raise ValueError(f"sta must be a finite number of seconds; got {self.sta!r}.") from None
        if not math.isfinite(sta):
            raise ValueError(f"sta must be a finite number of seconds; got {self.sta!r}.")
        object.__setattr__(self, "sta", sta)
        if not _is_int(self.priority) or self.priority < 0:
            raise ValueError(f"priority must be an integer >= 0 (0 = highest); got {self.priority!r}.")
        object.__setattr__(self, "priority", int(self.priority))


@dataclasses.dataclass(frozen=True, kw_only=True)
class Building:
    """A static obstacle: a simple polygon in the position plane.

    Attributes:
        vertices: ``((x0, y0), (x1, y1), ...)`` [m], at least 3, either orientation, the first vertex not repeated at
            the end; the polygon must be simple (no two edges cross or touch except neighbours at their shared
            vertex) and have non-zero area.
    """

    vertices: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        try:
            verts = tuple(_finite_tuple(f"vertex {k}", v, 2) for k, v in enumerate(self.vertices))
        except TypeError:
            raise ValueError(f"vertices must be a sequence of (x, y) pairs; got {self.vertices!r}.") from None
        if len(verts) < 3:
            raise ValueError(f"a building needs at least 3 vertices; got {len(verts)}.")
        for k in range(len(verts)):
            if verts[k] == verts[(k + 1) % len(verts)]:
                raise ValueError(f"building vertices {k} and {(k + 1) % len(verts)} coincide at {verts[k]}; "
                                 "consecutive vertices must differ (do not repeat the first vertex at the end).")
        crossings = geometry.self_intersections(verts)
        if crossings:
            k, l = crossings[0]
            raise ValueError(f"building {verts} is not a simple polygon: edges {k} and {l} cross or touch; "
                             "only simple polygons are allowed.")
        xs, ys = [v[0] for v in verts], [v[1] for v in verts]
        scale = max(max(xs) - min(xs), max(ys) - min(ys))
        if abs(geometry.polygon_area(verts)) <= 1e-12 * max(scale, 1e-300) ** 2:
            raise ValueError(f"building {verts} has zero area; a building must be a polygon with non-zero area.")
        object.__setattr__(self, "vertices", verts)

    @classmethod
    def rectangle(cls, center: Sequence[float], width: float, height: float, angle: float = 0.0) -> Building:
        """A ``width x height`` [m] rectangle centred at ``center``, rotated counter-clockwise by ``angle`` [rad]."""
        hw, hh = 0.5 * width, 0.5 * height
        local = np.array([(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh)])
        world = geometry.rotate(local, angle) + np.asarray(center, dtype=np.float64)
        return cls(vertices=tuple((float(x), float(y)) for x, y in world))

    @property
    def area(self) -> float:
        """Area [m^2]."""
        return abs(geometry.polygon_area(self.vertices))

    def signed_distance(self, points):
        """Exact signed distance [m] from ``points`` (shape ``(..., 2)``) to this building, negative inside."""
        return geometry.polygon_signed_distance(self.vertices, points)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Scenario:
    """One sequential-trajectory-planning study.

    Attributes:
        name: registry name (or any label).
        domain_lo, domain_hi: position domain ``[lo_x, hi_x] x [lo_y, hi_y]`` [m].
        vehicle: dynamics and bounds shared by every vehicle and the intruder (control set ``U``, wind ``d_r``,
            heading disturbance).
        planning_v: speed interval of the reduced planning set ``U^p`` [m/s] (``method="rtt"`` only).
        planning_omega_max: turn-rate bound of ``U^p`` [rad/s] (``method="rtt"`` only).
        collision_radius: ``R_c``, the danger-zone radius between two vehicles and with the intruder [m].
        vehicles: the STP vehicles, in index order.
        buildings: static obstacles.
        method: induced-obstacle method, one of :data:`METHODS`.
        kbar: ``k̄``, the most vehicles the intruder may force to avoid (intruder-aware planning); ``None``: plan
            without regard to an intruder.
        t_iat: ``t_IAT``, the longest time the intruder stays [s].
        grid_points: planning-grid points in ``(p_x, p_y, theta)``.
        time_step: sample period of nominal trajectories [s].
        seed: the seed the scenario was generated from.
        description: what the scenario is and where it comes from.
    """

    name: str
    domain_lo: tuple[float, float]
    domain_hi: tuple[float, float]
    vehicle: DubinsWind
    planning_v: tuple[float, float]
    planning_omega_max: float
    collision_radius: float
    vehicles: tuple[VehicleSpec, ...]
    buildings: tuple[Building, ...] = ()
    method: str
    kbar: int | None = None
    t_iat: float = 10.0
    grid_points: tuple[int, int, int]
    time_step: float
    seed: int
    description: str

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string; got {self.name!r}.")
        if not isinstance(self.description, str):
            raise ValueError(f"description must be a string; got {type(self.description).__name__}.")
        lo = _finite_tuple("domain_lo", self.domain_lo, 2)
        hi = _finite_tuple("domain_hi", self.domain_hi, 2)
        if not (hi[0] > lo[0] and hi[1] > lo[1]):
            raise ValueError(f"the domain is empty: domain_hi {hi} must exceed domain_lo {lo} in both x and y.")
        object.__setattr__(self, "domain_lo", lo)
        object.__setattr__(self, "domain_hi", hi)
        if not isinstance(self.vehicle, DubinsWind):
            raise ValueError(f"vehicle must be a stp_env.dynamics.DubinsWind; got {type(self.vehicle).__name__}.")
        self._check_planning_set()
        object.__setattr__(self, "collision_radius", _positive("collision_radius", self.collision_radius))
        object.__setattr__(self, "t_iat", _positive("t_iat", self.t_iat))
        object.__setattr__(self, "time_step", _positive("time_step", self.time_step))
        if self.method not in METHODS:
            raise ValueError(f"method {self.method!r} is not known; allowed: {', '.join(METHODS)}.")
        if self.kbar is not None and (not _is_int(self.kbar) or not 1 <= self.kbar <= MAX_KBAR):
            raise ValueError(f"kbar must be None (intruder-unaware planning) or an integer >= 1 (at most "
                             f"{MAX_KBAR}); got {show(self.kbar)}.")
        if not _is_int(self.seed):
            raise ValueError(f"seed must be an integer; got {self.seed!r}.")
        grid_points = tuple(self.grid_points)
        if len(grid_points) != 3 or not all(_is_int(n) and n >= 5 for n in grid_points):
            raise ValueError(f"grid_points must be 3 integers >= 5 (points in x, y, heading); "
                             f"got {self.grid_points!r}.")
        object.__setattr__(self, "grid_points", tuple(int(n) for n in grid_points))

        vehicles = tuple(self.vehicles)
        if not vehicles:
            raise ValueError("a scenario needs at least one vehicle; got none.")
        for i, v in enumerate(vehicles):
            if not isinstance(v, VehicleSpec):
                raise ValueError(f"vehicle {i}: must be a VehicleSpec; got {type(v).__name__}.")
        object.__setattr__(self, "vehicles", vehicles)
        buildings = tuple(self.buildings)
        for b, building in enumerate(buildings):
            if not isinstance(building, Building):
                raise ValueError(f"building {b}: must be a Building; got {type(building).__name__}.")
        object.__setattr__(self, "buildings", buildings)

        priorities = sorted(v.priority for v in vehicles)
        if priorities != list(range(len(vehicles))):
            seen: dict[int, int] = {}
            errors = []
            for i, v in enumerate(vehicles):
                if v.priority in seen:
                    errors.append(f"vehicle {i}: priority {v.priority} duplicates vehicle {seen[v.priority]}'s.")
                elif v.priority >= len(vehicles):
                    errors.append(f"vehicle {i}: priority {v.priority} is out of range 0..{len(vehicles) - 1}.")
                seen.setdefault(v.priority, i)
            _raise_all(f"priorities must be a permutation of 0..{len(vehicles) - 1} (0 = highest):", errors)
        _raise_all(f"scenario {self.name!r} has invalid vehicles:", self._vehicle_errors())

    # ------------------------------------------------------------------ validation helpers
    def _check_planning_set(self) -> None:
        pv = _finite_tuple("planning_v", self.planning_v, 2)
        v = self.vehicle
        if not (v.v_min <= pv[0] <= pv[1] <= v.v_max):
            raise ValueError(f"planning_v {pv} must be an interval inside the vehicle's speed range "
                             f"[{v.v_min}, {v.v_max}] m/s (lower <= upper).")
        try:
            om = float(self.planning_omega_max)
        except (TypeError, ValueError):
            raise ValueError(f"planning_omega_max must be a number; got {self.planning_omega_max!r}.") from None
        if not 0 <= om <= v.omega_max:
            raise ValueError(f"planning_omega_max {om} must lie in [0, {v.omega_max}] rad/s (the vehicle's "
                             "turn-rate bound): U^p must lie inside U.")
        object.__setattr__(self, "planning_v", pv)
        object.__setattr__(self, "planning_omega_max", om)

    def _vehicle_errors(self) -> list[str]:
        (xlo, ylo), (xhi, yhi) = self.domain_lo, self.domain_hi
        domain = f"[{xlo}, {xhi}] x [{ylo}, {yhi}]"
        spacing = max(self.grid_spacing[:2])
        errors = []
        starts = np.array([v.start[:2] for v in self.vehicles])
        targets = np.array([v.target for v in self.vehicles])
        start_sd = np.full(len(self.vehicles), np.inf)
        target_sd = np.full(len(self.vehicles), np.inf)
        start_in = np.full(len(self.vehicles), -1)
        target_in = np.full(len(self.vehicles), -1)
        for b, building in enumerate(self.buildings):
            sd_s, sd_t = building.signed_distance(starts), building.signed_distance(targets)
            start_in = np.where((sd_s <= 0) & (start_in < 0), b, start_in)
            target_in = np.where((sd_t <= 0) & (target_in < 0), b, target_in)
            start_sd, target_sd = np.minimum(start_sd, sd_s), np.minimum(target_sd, sd_t)
        for i, v in enumerate(self.vehicles):
            px, py, _ = v.start
            cx, cy = v.target
            r = v.target_radius
            if not (xlo <= px <= xhi and ylo <= py <= yhi):
                errors.append(f"vehicle {i}: start ({px}, {py}) lies outside the domain {domain}.")
            if not (xlo <= cx - r and cx + r <= xhi and ylo <= cy - r and cy + r <= yhi):
                errors.append(f"vehicle {i}: target disk at ({cx}, {cy}) with radius {r} does not lie inside the "
                              f"domain {domain}.")
            if start_in[i] >= 0:
                errors.append(f"vehicle {i}: start ({px}, {py}) lies inside building {start_in[i]}.")
            if target_in[i] >= 0:
                errors.append(f"vehicle {i}: target ({cx}, {cy}) lies inside building {target_in[i]}.")
            cells = 2.0 * r / spacing
            if cells < MIN_CELLS_ACROSS_TARGET:
                need = 2.0 * r / MIN_CELLS_ACROSS_TARGET
                nx = math.ceil((xhi - xlo) / need) + 1
                ny = math.ceil((yhi - ylo) / need) + 1
                errors.append(f"vehicle {i}: target radius {r} spans only {cells:.2f} grid cells at spacing "
                              f"{spacing:.4g}; at least {MIN_CELLS_ACROSS_TARGET} cells are needed (docs/numerics.md): "
                              f"use a spacing <= {need:.4g}, i.e. grid_points >= ({nx}, {ny}, ...).")
        return errors

    # ------------------------------------------------------------------ helpers
    @property
    def n_vehicles(self) -> int:
        return len(self.vehicles)

    @property
    def grid_spacing(self) -> tuple[float, float, float]:
        """Planning-grid spacing ``(dx [m], dy [m], dtheta [rad])``."""
        (xlo, ylo), (xhi, yhi) = self.domain_lo, self.domain_hi
        nx, ny, nt = self.grid_points
        return ((xhi - xlo) / (nx - 1), (yhi - ylo) / (ny - 1), 2.0 * math.pi / nt)

    def grid(self) -> Grid:
        """The planning grid: the position domain by ``[-pi, pi)`` in heading (periodic)."""
        return Grid.from_bounds((*self.domain_lo, -math.pi), (*self.domain_hi, math.pi), self.grid_points,
                                periodic=2)

    def in_priority_order(self) -> tuple[int, ...]:
        """Vehicle indices from the highest priority (0) to the lowest: the planning order of STP."""
        return tuple(sorted(range(self.n_vehicles), key=lambda i: self.vehicles[i].priority))

    def starts(self) -> np.ndarray:
        """Initial states, shape ``(N, 3)`` [m, m, rad], in vehicle index order."""
        return np.array([v.start for v in self.vehicles], dtype=np.float64)

    def targets(self) -> np.ndarray:
        """Target-disk centres, shape ``(N, 2)`` [m]."""
        return np.array([v.target for v in self.vehicles], dtype=np.float64)

    def target_radii(self) -> np.ndarray:
        """Target-disk radii, shape ``(N,)`` [m]."""
        return np.array([v.target_radius for v in self.vehicles], dtype=np.float64)

    def stas(self) -> np.ndarray:
        """Scheduled times of arrival, shape ``(N,)`` [s]."""
        return np.array([v.sta for v in self.vehicles], dtype=np.float64)

    def priorities(self) -> np.ndarray:
        """Priorities, shape ``(N,)`` (0 = highest)."""
        return np.array([v.priority for v in self.vehicles], dtype=np.int64)

    def static_obstacle(self, dtype=None):
        """Signed distance to the buildings on :meth:`grid` (negative inside), shape ``grid_points``."""
        kwargs = {} if dtype is None else {"dtype": dtype}
        return geometry.buildings_sdf(self.buildings, self.grid(), **kwargs)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    def with_overrides(self, **overrides) -> Scenario:
        """A copy with some fields replaced (and validated again); unknown field names are an error."""
        allowed = self.field_names()
        unknown = sorted(set(overrides) - set(allowed))
        if unknown:
            raise ValueError(f"unknown Scenario field(s) {unknown}; allowed fields: {', '.join(allowed)}.")
        return dataclasses.replace(self, **overrides)
