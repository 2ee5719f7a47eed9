"""Typed configuration of the mission-survivability study: frozen dataclasses with checked fields.

Units: kilometres and minutes for the space-time network (cells ``cell_km x cell_km x cell_min``), m/s for speeds,
degrees for headings (0 = east, counter-clockwise, so 90 = north), minutes for times. Every class validates itself
on construction; ``with_overrides`` names the allowed fields when given an unknown one.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from stp_env.seeds import check_seed
from stp_env.sim.config import _finite as _number
from stp_env.survivability.names import LEVELS, NF_COUNTS, POLICIES, REVEAL_MODELS, TRAFFIC_MODELS

EARTH_RADIUS_KM = 6371.0


PAPER_HOVER_SHARE = 0.1
"""Share of hovering (degree-1) intruders in the ``paper`` traffic model when ``hover_share`` is not given. The
paper models hovering intruders but states no share: 0.1 is this project's choice."""


def _integer(name: str, value, *, minimum: int = 0) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}.")
    return int(value)


def _pair(name: str, value, *, ordered: bool = True) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two numbers (lo, hi); got {value!r}.") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or (ordered and hi < lo):
        raise ValueError(f"{name} must be finite with lo <= hi; got {value!r}.")
    return lo, hi


def _headings(name: str, value) -> tuple[float, ...]:
    try:
        out = tuple(float(v) % 360.0 for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of headings in degrees; got {value!r}.") from None
    if not out:
        raise ValueError(f"{name} must not be empty.")
    return out


class _Overrides:
    def with_overrides(self, **overrides):
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(f"unknown {type(self).__name__} field(s) {unknown}; allowed: {sorted(names)}.")
        return dataclasses.replace(self, **overrides)


@dataclasses.dataclass(frozen=True)
class Site:
    """A landing site: a name and its WGS-84 latitude/longitude [deg] (rounded to about 100 m)."""

    name: str
    lat: float
    lon: float

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"site name must be a non-empty string; got {self.name!r}.")
        lat = _number(f"{self.name} latitude", self.lat)
        lon = _number(f"{self.name} longitude", self.lon)
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise ValueError(f"{self.name}: latitude/longitude out of range; got ({lat}, {lon}).")


# The paper's Bay-Area mission (Section V-a). The paper gives names only; these positions are ours (public maps,
# rounded to 0.005 deg): the Santa Clara Towers office towers on Freedom Circle, the rooftop pad of UCSF's Mission
# Bay hospital, the centre of San Francisco International Airport and Stanford Hospital.
SANTA_CLARA = Site("Santa Clara Towers Heliport", 37.390, -121.975)
UCSF = Site("UCSF Helipad", 37.768, -122.390)
SFO = Site("San Francisco International Airport", 37.619, -122.375)
STANFORD = Site("Stanford Hospital Heliport", 37.434, -122.175)


@dataclasses.dataclass(frozen=True, kw_only=True)
class MissionConfig(_Overrides):
    """The mission and the discrete space-time network (survivability paper, Sections II and V-a).

    Attributes:
        origin, goal, alternates: landing sites (:class:`Site`); the network is a square of ``area_km`` centred
            on the bounding box of all sites, projected equirectangularly about its centre.
        area_km: side of the square operating area [km] (paper: 85).
        cell_km, cell_min: cell size [km] and time step [min] of the network (paper: 1 km, 1 min).
        window_min: minutes between decision points (paper: 5).
        takeoff_min, landing_min: vertical take-off and landing phases (paper: 5 min each); cruise starts at
            ``takeoff_min`` and an arrival at minute ``t`` of cruise lands at ``t + landing_min``.
        rta_min: required time of arrival window at the goal [min after departure], landing included (paper:
            [40, 55]).
        endurance_min: the latest landing anywhere (paper: 60).
        v_max: cruise speed range is ``[0, v_max]`` m/s (paper: 40).
        dh_max, dv_max: a primitive changes heading by ``[-dh_max, dh_max]`` deg and speed by ``[-dv_max, dv_max]``
            m/s, each in ``n_increments`` equal steps (paper: 30, 10, 5: 25 primitives).
        departure_heading: heading [deg] at the start of cruise (speed 0).
        goal_headings, alternate_headings: admissible headings [deg] on arrival (speed 0) at the goal and at an
            alternative site (paper: {90, 135, 180} and {90, 180, 270}).
        separation_km: a segment is blocked by an intruder in any cell closer than this to the segment (the
            separation radius of Assumption II.2's remark).
        positions_km: optional ``(x, y)`` [km] of the origin, the goal and each alternative site in the network
            frame, replacing the projection of their latitude/longitude (for custom and test networks).
    """

    origin: Site = SANTA_CLARA
    goal: Site = UCSF
    alternates: tuple[Site, ...] = (SFO, STANFORD)
    area_km: float = 85.0
    cell_km: float = 1.0
    cell_min: float = 1.0
    window_min: float = 5.0
    takeoff_min: float = 5.0
    landing_min: float = 5.0
    rta_min: tuple[float, float] = (40.0, 55.0)
    endurance_min: float = 60.0
    v_max: float = 40.0
    dh_max: float = 30.0
    dv_max: float = 10.0
    n_increments: int = 5
    departure_heading: float = 135.0
    goal_headings: tuple[float, ...] = (90.0, 135.0, 180.0)
    alternate_headings: tuple[float, ...] = (90.0, 180.0, 270.0)
    separation_km: float = 0.0
    positions_km: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self) -> None:
        for site in (self.origin, self.goal, *self.alternates):
            if not isinstance(site, Site):
                raise ValueError(f"sites must be Site objects; got {site!r}.")
        object.__setattr__(self, "alternates", tuple(self.alternates))
        for name in ("area_km", "cell_km", "cell_min", "window_min", "endurance_min", "v_max", "dh_max",
                     "dv_max"):
            _number(name, getattr(self, name), positive=True)
        for name in ("takeoff_min", "landing_min", "separation_km"):
            _number(name, getattr(self, name), nonneg=True)
        _integer("n_increments", self.n_increments, minimum=3)
        if self.n_increments % 2 == 0:
            raise ValueError(f"n_increments must be odd (the primitives include 'no change'); got {self.n_increments}.")
        if self.positions_km is not None:
            pos = tuple(_pair("positions_km", p, ordered=False) for p in self.positions_km)
            if len(pos) != 2 + len(self.alternates):
                raise ValueError(f"positions_km needs {2 + len(self.alternates)} (x, y) pairs (origin, goal, "
                                 f"alternates); got {len(pos)}.")
            object.__setattr__(self, "positions_km", pos)
        object.__setattr__(self, "rta_min", _pair("rta_min", self.rta_min))
        object.__setattr__(self, "goal_headings", _headings("goal_headings", self.goal_headings))
        object.__setattr__(self, "alternate_headings", _headings("alternate_headings", self.alternate_headings))
        _number("departure_heading", self.departure_heading)
        ratio = self.window_min / self.cell_min
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"window_min must be a whole number of cell_min; got {self.window_min}, "
                             f"{self.cell_min}.")
        n_side = self.area_km / self.cell_km
        if abs(n_side - round(n_side)) > 1e-9:
            raise ValueError(f"area_km must be a whole number of cells; got {self.area_km} / {self.cell_km}.")
        dh = self.heading_step
        if abs(360.0 / dh - round(360.0 / dh)) > 1e-9:
            raise ValueError(f"2 dh_max / (n_increments - 1) = {dh} deg must divide 360.")
        dv = self.speed_step
        if abs(self.v_max / dv - round(self.v_max / dv)) > 1e-9:
            raise ValueError(f"2 dv_max / (n_increments - 1) = {dv} m/s must divide v_max = {self.v_max}.")
        for name in ("departure_heading", "goal_headings", "alternate_headings"):
            values = getattr(self, name)
            for h in (values if isinstance(values, tuple) else (values,)):
                if abs(h / dh - round(h / dh)) > 1e-9:
                    raise ValueError(f"{name} must be multiples of the heading step {dh} deg; got {h}.")
        _lo, hi = self.rta_min
        if hi > self.endurance_min:
            raise ValueError(f"rta_min upper end {hi} exceeds endurance_min {self.endurance_min}.")
        if self.first_goal_window > self.last_goal_window:
            raise ValueError(f"no decision window ends inside rta_min = {self.rta_min} (cruise windows of "
                             f"{self.window_min} min from minute {self.takeoff_min}).")

    # Derived quantities -----------------------------------------------------------------------------------------
    @property
    def heading_step(self) -> float:
        return 2.0 * self.dh_max / (self.n_increments - 1)

    @property
    def speed_step(self) -> float:
        return 2.0 * self.dv_max / (self.n_increments - 1)

    @property
    def n_headings(self) -> int:
        return round(360.0 / self.heading_step)

    @property
    def n_speeds(self) -> int:
        return round(self.v_max / self.speed_step) + 1

    @property
    def n_cells(self) -> int:
        return round(self.area_km / self.cell_km)

    @property
    def minutes_per_window(self) -> int:
        return round(self.window_min / self.cell_min)

    @property
    def max_windows(self) -> int:
        """Cruise windows that fit in the endurance (paper: 12 windows of flight, 10 of them cruise)."""
        return math.floor((self.endurance_min - self.takeoff_min - self.landing_min) / self.window_min + 1e-9)

    @property
    def first_goal_window(self) -> int:
        return math.ceil((self.rta_min[0] - self.landing_min - self.takeoff_min) / self.window_min - 1e-9)

    @property
    def last_goal_window(self) -> int:
        return min(self.max_windows,
                   math.floor((self.rta_min[1] - self.landing_min - self.takeoff_min) / self.window_min + 1e-9))

    @property
    def n_minutes(self) -> int:
        """Network time cells from departure to the endurance."""
        return round(self.endurance_min / self.cell_min)

    def site_positions_km(self) -> dict[str, tuple[float, float]]:
        """Each site's position [km] in the network frame (x east, y north, the area's south-west corner at 0)."""
        sites = (self.origin, self.goal, *self.alternates)
        if len({s.name for s in sites}) != len(sites):
            raise ValueError("site names must be distinct.")
        if self.positions_km is not None:
            out = {}
            for s, (x, y) in zip(sites, self.positions_km):
                if not (0.0 <= x < self.area_km and 0.0 <= y < self.area_km):
                    raise ValueError(f"site {s.name} lies outside the {self.area_km} km area.")
                out[s.name] = (x, y)
            return out
        lat0 = 0.5 * (min(s.lat for s in sites) + max(s.lat for s in sites))
        lon0 = 0.5 * (min(s.lon for s in sites) + max(s.lon for s in sites))
        k = math.pi / 180.0 * EARTH_RADIUS_KM
        half = 0.5 * self.area_km
        out = {}
        for s in sites:
            x = (s.lon - lon0) * k * math.cos(math.radians(lat0)) + half
            y = (s.lat - lat0) * k + half
            if not (0.0 <= x < self.area_km and 0.0 <= y < self.area_km):
                raise ValueError(f"site {s.name} lies outside the {self.area_km} km area.")
            out[s.name] = (x, y)
        return out


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrafficConfig(_Overrides):
    """Intruder traffic of one scenario (survivability paper, Sections III-B and V-b).

    Attributes:
        n_partial: partially known intruders ``N_p`` (nominal Bezier path and uncertainty radius known).
        n_unknown: unknown intruders ``N_u`` (revealed to the ownship only by a conflict).
        degree: Bezier degree ``k`` of every intruder path in (x, y, t) (``k + 1`` control points).
        uncertainty_km: radius ``r`` of a partially known intruder's uncertainty tube (paper: 5 km).
        reach_km: an intruder's control points after the first are uniform within this distance of the first.
        speed_range: [m/s] an intruder's mean ground speed is uniform in this range (its flight time is its path
            length over that speed).
        samples_per_min: points per minute at which a path is rasterised into cells.
        model: ``paper`` (default) or ``local`` (:data:`TRAFFIC_MODELS`). ``reach_km`` and ``speed_range`` apply
            to ``local`` only: the paper's control points lie anywhere in the area and its times in ``(t_0, t_fu)``.
        hover_share: with ``model="paper"``, the probability that an intruder hovers (drawn independently for
            each intruder, so a larger scenario keeps a smaller one's intruders): a degree-1 curve at a fixed
            location (``None``: :data:`PAPER_HOVER_SHARE`, the project's choice; the
            paper gives none). Must be ``None`` with ``model="local"``, which has no hovering intruders.
        max_speed: [m/s] with ``model="paper"``, the fastest mean ground speed of an intruder's nominal path
            (``None``, the default: unbounded, as the text says nothing of intruder speeds). Given, the paper's
            draw (control points anywhere, entry and exit times in ``(t_0, t_fu)``) is conditioned on the
            curve being flown no faster than this (:func:`stp_env.survivability.traffic.sample_traffic`); the
            cruise speeds of the paper's network end at ``MissionConfig.v_max`` = 40 m/s. Must be ``None`` with
            ``model="local"``, whose speeds are ``speed_range``.
    """

    n_partial: int = 100
    n_unknown: int = 100
    degree: int = 3
    uncertainty_km: float = 5.0
    reach_km: float = 10.0
    speed_range: tuple[float, float] = (20.0, 40.0)
    samples_per_min: int = 6
    model: str = "paper"
    hover_share: float | None = None
    max_speed: float | None = None

    def __post_init__(self) -> None:
        if self.model not in TRAFFIC_MODELS:
            raise ValueError(f"traffic model must be one of {', '.join(TRAFFIC_MODELS)}; got {self.model!r}.")
        if self.max_speed is not None:
            if self.model != "paper":
                raise ValueError(f"max_speed applies to the 'paper' traffic model only (model={self.model!r} draws "
                                 f"its speeds from speed_range); got max_speed={self.max_speed!r}.")
            object.__setattr__(self, "max_speed", float(_number("max_speed", self.max_speed, positive=True)))
        if self.hover_share is not None:
            if self.model != "paper":
                raise ValueError(f"hover_share applies to the 'paper' traffic model only (model={self.model!r} has "
                                 f"no hovering intruders); got hover_share={self.hover_share!r}.")
            share = _number("hover_share", self.hover_share, nonneg=True)
            if share > 1.0:
                raise ValueError(f"hover_share must be in [0, 1]; got {share}.")
            object.__setattr__(self, "hover_share", float(share))
        _integer("n_partial", self.n_partial)
        _integer("n_unknown", self.n_unknown)
        _integer("degree", self.degree, minimum=1)
        _number("uncertainty_km", self.uncertainty_km, nonneg=True)
        _number("reach_km", self.reach_km, positive=True)
        lo, hi = _pair("speed_range", self.speed_range)
        if lo <= 0:
            raise ValueError(f"speed_range must be > 0; got {self.speed_range!r}.")
        object.__setattr__(self, "speed_range", (lo, hi))
        _integer("samples_per_min", self.samples_per_min, minimum=1)

    @property
    def hover_fraction(self) -> float:
        """The share of hovering intruders actually drawn: 0 for ``local``, ``hover_share`` (or
        :data:`PAPER_HOVER_SHARE`) for ``paper``."""
        if self.model != "paper":
            return 0.0
        return PAPER_HOVER_SHARE if self.hover_share is None else self.hover_share


@dataclasses.dataclass(frozen=True, kw_only=True)
class PlannerConfig(_Overrides):
    """How the ownship plans (survivability paper, Section IV).

    Attributes:
        beta: discount of the future term of the receding-horizon objective (eq. 5), in ``[0, 1]``.
        n_mc: Monte Carlo traffic realisations for a candidate segment's robustness (Section III-B; paper: 2,500).
        n_survival: how many of the ``n_mc`` realisations give ``pi_S``'s survivability ``R`` (the fraction of
            them in which some trajectory stays feasible, :mod:`stp_env.survivability.dp`); a multiple of 64, at
            most ``n_mc``; 0: the tree recursion ``R = 1 - prod (1 - p R')`` instead.
        nf_count: what ``pi_Nf``'s ``N_f`` counts (:data:`NF_COUNTS`): ``goal`` (default), the paper's ``c.N_f``
            (Section III-A, Algorithm 1), the trajectories to the current terminal set ``Omega`` summed over the
            successor's cell; ``landing``, the trajectories from the successor state to any landing site.
        reveal: when an intruder's actual path becomes known (:data:`REVEAL_MODELS`, Section III-B's "until the
            ownship encounters a conflict"): ``segment`` (default), a conflict anywhere on the segment chosen at a
            decision point; ``step``, a conflict in the next time step (one cell time, ``cell_min``), so that a
            conflict found after the decision point cannot be avoided (the primitive holds until the next decision
            point, Section II) and ends the mission as an emergency landing; ``radius``, as ``step`` and also an
            intruder within ``sense_km`` of the ownship at a whole time step.
        sense_km: the sensing radius [km] of ``reveal="radius"`` (required there; must be ``None`` otherwise).
    """

    beta: float = 0.5
    n_mc: int = 2500
    n_survival: int = 256
    nf_count: str = "goal"
    reveal: str = "segment"
    sense_km: float | None = None

    def __post_init__(self) -> None:
        beta = _number("beta", self.beta)
        if not 0.0 <= beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1]; got {beta}.")
        _integer("n_mc", self.n_mc, minimum=1)
        _integer("n_survival", self.n_survival)
        if self.nf_count not in NF_COUNTS:
            raise ValueError(f"nf_count must be one of {', '.join(NF_COUNTS)}; got {self.nf_count!r}.")
        if self.reveal not in REVEAL_MODELS:
            raise ValueError(f"reveal must be one of {', '.join(REVEAL_MODELS)}; got {self.reveal!r}.")
        if self.reveal == "radius":
            if self.sense_km is None:
                raise ValueError("reveal='radius' needs a sensing radius sense_km [km] > 0.")
            object.__setattr__(self, "sense_km", float(_number("sense_km", self.sense_km, positive=True)))
        elif self.sense_km is not None:
            raise ValueError(f"sense_km applies to reveal='radius' only (reveal={self.reveal!r} senses nothing); got "
                             f"sense_km={self.sense_km!r}.")
        if self.n_survival % 64 or self.n_survival > self.n_mc:
            raise ValueError(f"n_survival must be a multiple of 64 and at most n_mc = {self.n_mc}; got "
                             f"{self.n_survival}.")


_ADDED_OPTIONS = (("traffic", "model", "local"), ("traffic", "hover_share", None), ("traffic", "max_speed", None),
                  ("planner", "nf_count", "landing"), ("planner", "reveal", "segment"), ("planner", "sense_km", None))


@dataclasses.dataclass(frozen=True, kw_only=True)
class StudyConfig(_Overrides):
    """The scenario sweep.

    Attributes:
        n_partial, n_unknown: the scenario grid (paper: {50, ..., 300} each, 36 scenarios).
        n_instances: traffic instances per scenario (paper: 2,500; 2,401 bound every 95 % half-width by 2 %).
        seed: base seed of the traffic, the Monte Carlo realisations and the tie-breaking.
        policies: which of ``R``, ``Nf``, ``S``, ``AvgR`` fly.
        mission, traffic, planner: the configurations (``traffic.n_partial``/``n_unknown`` are set per scenario).
    """

    n_partial: tuple[int, ...] = LEVELS
    n_unknown: tuple[int, ...] = LEVELS
    n_instances: int = 2401
    seed: int = 0
    policies: tuple[str, ...] = POLICIES
    mission: MissionConfig = dataclasses.field(default_factory=MissionConfig)
    traffic: TrafficConfig = dataclasses.field(default_factory=TrafficConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)

    def __post_init__(self) -> None:
        for name in ("n_partial", "n_unknown"):
            values = tuple(_integer(name, v) for v in getattr(self, name))
            if not values or len(set(values)) != len(values):
                raise ValueError(f"{name} must be a non-empty list of distinct integers; got {values!r}.")
            object.__setattr__(self, name, values)
        _integer("n_instances", self.n_instances, minimum=1)
        object.__setattr__(self, "seed", check_seed(self.seed))  # the one seed function: [0, 2**63 - 1]
        pols = tuple(self.policies)
        if not pols or any(p not in POLICIES for p in pols) or len(set(pols)) != len(pols):
            raise ValueError(f"policies must be distinct names among {', '.join(POLICIES)}; got {pols!r}.")
        object.__setattr__(self, "policies", pols)

    @property
    def scenarios(self) -> list[tuple[int, int]]:
        return [(p, u) for p in self.n_partial for u in self.n_unknown]

    def fingerprint(self) -> dict:
        """What must match for a study directory to be resumed (everything but ``n_instances``)."""
        d = dataclasses.asdict(self)
        d.pop("n_instances")
        # Options added after studies were written are left out at their earlier behaviour, so that those studies
        # resume with the default configuration (and a study with another option never resumes one without).
        for group, name, earlier in _ADDED_OPTIONS:
            if d[group].get(name) == earlier:
                d[group].pop(name)
        return json.loads(json.dumps(d))
