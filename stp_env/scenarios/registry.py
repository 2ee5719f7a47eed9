"""The scenario registry (``make(name, **overrides)``) and the named scenarios of the papers.

| name | source | vehicles | domain | method | notes |
| --- | --- | --- | --- | --- | --- |
| ``four-vehicle`` | SPP paper Section V, eqs. (28)-(30) | 4 | ``[-1, 1]^2`` | centralized | unit-free toy scale |
| ``city`` | BEACLS Section V, intruder paper Section V-A | 50 | 5 km x 5 km | rtt | synthetic downtown |
| ``bay-area`` | BEACLS Section VI | 200 | 20 km x 15 km | rtt | four cities, no buildings |
| ``tiny`` | ours | 2 | 2 km x 2 km | rtt | two vehicles crossing, 41 x 41 x 40 grid |
| ``tiny-intruder`` | ours | 2 | 2 km x 2 km | rtt | ``tiny`` with ``kbar=2`` |

``make(name, **overrides)``: overrides whose names are keyword parameters of the scenario's factory (for example
``wind``, ``sta_spacing``, ``n_vehicles``, ``seed``, ``kbar`` for ``city``) are passed to the factory, which rebuilds
what depends on them; the others must be :class:`~stp_env.scenarios.config.Scenario` fields and replace them
afterwards (:meth:`~stp_env.scenarios.config.Scenario.with_overrides`); anything else is an error that lists both.

Scheduled times of arrival. For the city and bay-area studies ``STA_i = sta_spacing * priority`` [s]: the
highest-priority vehicle is due at 0 and each next rank ``sta_spacing`` seconds later, BEACLS's ``t_i^STA = 5 (i -
1)`` with ``i = priority + 1``. (BEACLS Section V-A words the medium- and low-density cases with "the latest
``t_i^STA`` being 0"; that is the same schedule shifted by a constant, which changes nothing for time-invariant
dynamics.)
"""

from __future__ import annotations

import inspect
import itertools
import math
from collections.abc import Callable

import numpy as np

from stp_env.dynamics import DubinsWind
from stp_env.scenarios.config import Building, Scenario, VehicleSpec
from stp_env.scenarios.geometry import rotate

ScenarioFactory = Callable[..., Scenario]

_REGISTRY: dict[str, ScenarioFactory] = {}


def register(name: str) -> Callable[[ScenarioFactory], ScenarioFactory]:
    """Decorator: registers a factory (keyword-only parameters, each with a default) under ``name``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"scenario names must be non-empty strings; got {name!r}.")

    def decorator(factory: ScenarioFactory) -> ScenarioFactory:
        if name in _REGISTRY:
            raise ValueError(f"a scenario named {name!r} is already registered.")
        for p in inspect.signature(factory).parameters.values():
            if p.kind is not inspect.Parameter.KEYWORD_ONLY or p.default is inspect.Parameter.empty:
                raise ValueError(f"scenario factory {factory.__name__!r}: parameter {p.name!r} must be keyword-only "
                                 "with a default, so that make(name) works without arguments.")
        _REGISTRY[name] = factory
        return factory

    return decorator


def names() -> tuple[str, ...]:
    """The registered scenario names, sorted."""
    return tuple(sorted(_REGISTRY))


def factory_parameters(name: str) -> tuple[str, ...]:
    """The keyword parameters of scenario ``name``'s factory."""
    return tuple(inspect.signature(_factory(name)).parameters)


def _factory(name: str) -> ScenarioFactory:
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; registered scenarios: {', '.join(names())}.") from None


def make(name: str, **overrides) -> Scenario:
    """Builds the registered scenario ``name``.

    Overrides matching the factory's parameters go to the factory; the rest must be ``Scenario`` fields and replace
    them afterwards. Raises ``ValueError`` for an unknown name or an override that matches neither.
    """
    factory = _factory(name)
    params = set(inspect.signature(factory).parameters)
    fields = set(Scenario.field_names())
    unknown = sorted(set(overrides) - params - fields)
    if unknown:
        raise ValueError(f"unknown override(s) {unknown} for scenario {name!r}; allowed: factory parameters "
                         f"[{', '.join(sorted(params)) or 'none'}] and "
                         f"Scenario fields [{', '.join(Scenario.field_names())}].")
    scenario = factory(**{k: v for k, v in overrides.items() if k in params})
    rest = {k: v for k, v in overrides.items() if k not in params}
    return scenario.with_overrides(**rest) if rest else scenario


# ---------------------------------------------------------------------------------------------------- helpers
def _check_factory_args(*, n_vehicles: int | None = None, sta_spacing: float | None = None,
                        seed: int | None = None) -> None:
    if n_vehicles is not None and (isinstance(n_vehicles, bool) or not isinstance(n_vehicles, (int, np.integer))
                                   or n_vehicles < 1):
        raise ValueError(f"n_vehicles must be an integer >= 1; got {n_vehicles!r}.")
    if sta_spacing is not None and not (isinstance(sta_spacing, (int, float)) and math.isfinite(sta_spacing)
                                        and sta_spacing >= 0):
        raise ValueError(f"sta_spacing must be a finite number of seconds >= 0 (the papers use 0, 5 or 10); "
                         f"got {sta_spacing!r}.")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed must be an integer >= 0; got {seed!r}.")


def _heading(frm, to) -> float:
    return math.atan2(to[1] - frm[1], to[0] - frm[0])


def _paper_vehicle(wind: float) -> DubinsWind:
    """Vehicle bounds of the intruder and BEACLS papers (eq. 43 / 23): ``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``."""
    return DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=float(wind))


def _paper_fields(wind: float) -> dict:
    """Fields shared by the papers' UAV scenarios: vehicle bounds (intruder paper eq. 43 bounds), the BEACLS
    planning set ``U^p`` and ``R_c = 100 m``."""
    return {"vehicle": _paper_vehicle(wind), "planning_v": BEACLS_PLANNING_V,
            "planning_omega_max": BEACLS_PLANNING_OMEGA_MAX, "collision_radius": 100.0}


BEACLS_PLANNING_V = (11.0, 13.0)
BEACLS_PLANNING_OMEGA_MAX = 1.2

CITY_CASES: dict[int, dict[str, float]] = {
    0: {"wind": 6.0, "sta_spacing": 0.0},
    1: {"wind": 11.0, "sta_spacing": 0.0},
    2: {"wind": 6.0, "sta_spacing": 5.0},
    3: {"wind": 11.0, "sta_spacing": 5.0},
    4: {"wind": 11.0, "sta_spacing": 10.0},
}
"""BEACLS Section V-C, Cases 0-4 (wind ``d_r`` [m/s], STA spacing [s]): ``make("city", **CITY_CASES[3])``."""


# ---------------------------------------------------------------------------------------------------- four-vehicle
@register("four-vehicle")
def four_vehicle() -> Scenario:
    """The SPP paper's four-vehicle example (Section V).

    * Dynamics eq. (28): ``v in [0.5, 1]``, ``|omega| <= 1``, wind ``d_r = 0.1``, heading disturbance ``0.2``.
    * Initial states eq. (29): ``(-0.5, 0, 0)``, ``(0.5, 0, pi)``, ``(-0.6, 0.6, 7 pi/4)``, ``(0.6, 0.6, 5 pi/4)``
      (headings stored wrapped to ``[-pi, pi)``: ``-pi``, ``-pi/4``, ``-3 pi/4`` for vehicles 1-3).
    * Targets eq. (30): centres ``(0.7, 0.2)``, ``(-0.7, 0.2)``, ``(0.7, -0.7)``, ``(-0.7, -0.7)``, ``r = 0.1``.
    * ``t_i^STA = 0`` for all (as in the paper); priorities ``Q_1 > Q_2 > Q_3 > Q_4`` (0..3 in that order).
    * Our choices (the paper does not state them): ``R_c = 0.1``; domain ``[-1, 1]^2``; planning set for robust
      trajectory tracking ``U^p = [0.6, 0.7] x |omega| <= 0.2``: the tracking-error bound must stay well below the
      target radius 0.1, and the heading disturbance of 0.2 rad/s makes it grow fast with the reference's turn
      rate (measured on 41^3 error grids of half-width 0.15-0.2 with the converged stopping rule: 0.031 for
      ``omega <= 0.1``, 0.051 for 0.2, 0.074 for 0.3, 0.117 for 0.4, above 0.17 for ``[0.7, 0.8] x 0.5``; a
      reference slower than ``v_min`` plus the wind is overtaken in a tail wind and has no small bound); grid
      81 x 81 x 40 (spacing 0.025: five cells across the target, see ``docs/numerics.md``); trajectory samples
      every 0.01 (paper time units).
    * Default method ``"centralized"`` (Section V-A); ``method="least_restrictive"`` or ``"rtt"`` give V-B and V-C.
    * No intruder (``kbar=None``); ``t_iat`` is left at its default and unused.
    """
    starts = ((-0.5, 0.0, 0.0), (0.5, 0.0, math.pi), (-0.6, 0.6, 7 * math.pi / 4), (0.6, 0.6, 5 * math.pi / 4))
    targets = ((0.7, 0.2), (-0.7, 0.2), (0.7, -0.7), (-0.7, -0.7))
    vehicles = tuple(VehicleSpec(start=s, target=c, target_radius=0.1, sta=0.0, priority=k)
                     for k, (s, c) in enumerate(zip(starts, targets)))
    return Scenario(
        name="four-vehicle",
        domain_lo=(-1.0, -1.0),
        domain_hi=(1.0, 1.0),
        vehicle=DubinsWind(v_min=0.5, v_max=1.0, omega_max=1.0, wind=0.1, heading_disturbance=0.2),
        planning_v=(0.6, 0.7),
        planning_omega_max=0.2,
        collision_radius=0.1,
        vehicles=vehicles,
        method="centralized",
        grid_points=(81, 81, 40),
        time_step=0.01,
        seed=0,
        description="SPP paper Section V four-vehicle example, eqs. (28)-(30); R_c = 0.1 and U^p = [0.6, 0.7] x 0.2 "
                    "are our choices.",
    )


# ---------------------------------------------------------------------------------------------------- city
CITY_DOMAIN = ((0.0, 0.0), (5000.0, 5000.0))
CITY_ORIGIN = (300.0, 2500.0)
CITY_DESTINATIONS = ((4600.0, 2500.0), (4300.0, 4300.0), (4200.0, 800.0), (2600.0, 4500.0))
CITY_TARGET_RADIUS = 100.0
CITY_DOWNTOWN_CENTER = (2600.0, 2500.0)
CITY_CORRIDOR_Y = (2300.0, 2700.0)
"""The clear east-west street through downtown, ``y`` range [m]: no building reaches into it."""
_CITY_LOT_COLUMNS = tuple(1700.0 + 360.0 * k for k in range(6))  # 5 columns of lots, x in [1700, 3500]
_CITY_LOT_ROWS = ((1250.0, 1600.0), (1600.0, 1950.0), (1950.0, 2300.0),
                  (2700.0, 3050.0), (3050.0, 3400.0), (3400.0, 3750.0))
_CITY_STREET_MARGIN = 40.0  # half a street [m] kept free inside each lot's border


def _fit_into(shape: np.ndarray, lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Scales ``shape`` (vertices around 0) down if needed to fit the box ``[lo, hi]`` and places it at random."""
    extent = shape.max(axis=0) - shape.min(axis=0)
    shape = shape * min(1.0, float(np.min((hi - lo) / extent)))
    extent = shape.max(axis=0) - shape.min(axis=0)
    corner = lo + rng.uniform(0.0, 1.0, 2) * (hi - lo - extent)
    return shape - shape.min(axis=0) + corner


def _random_building(lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> Building:
    """One building inside the lot interior ``[lo, hi]``: a rotated rectangle, an L-shaped block or a convex
    polygon (5-7 vertices), vertices rounded to 0.1 m."""
    w, h = hi - lo
    kind = rng.integers(3)
    if kind == 0:
        bw, bh = rng.uniform(0.55, 1.0) * w, rng.uniform(0.55, 1.0) * h
        local = np.array([(-bw, -bh), (bw, -bh), (bw, bh), (-bw, bh)]) / 2
        local = rotate(local, rng.uniform(-0.35, 0.35))
    elif kind == 1:
        a, b = rng.uniform(0.35, 0.65, 2)
        local = np.array([(0, 0), (1, 0), (1, b), (a, b), (a, 1), (0, 1)]) * np.array([w, h]) - np.array([w, h]) / 2
        local = rotate(local, rng.integers(4) * math.pi / 2 + rng.uniform(-0.2, 0.2))
    else:
        k = int(rng.integers(5, 8))
        angles = 2 * math.pi * (np.arange(k) + rng.uniform(-0.3, 0.3, k)) / k + rng.uniform(0, 2 * math.pi)
        radii = 0.5 * np.array([w, h]) * rng.uniform(0.75, 1.0, 2)
        local = np.stack([radii[0] * np.cos(angles), radii[1] * np.sin(angles)], axis=-1)
    world = np.round(_fit_into(local, lo, hi, rng), 1)
    return Building(vertices=tuple((float(x), float(y)) for x, y in world))


def city_buildings(seed: int) -> tuple[Building, ...]:
    """The synthetic downtown of :func:`city` (buildings only; the same for every ``n_vehicles``)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0])
    lots = [(np.array([x0, y0]), np.array([x1, y1]))
            for x0, x1 in itertools.pairwise(_CITY_LOT_COLUMNS) for (y0, y1) in _CITY_LOT_ROWS]
    n_buildings = int(rng.integers(18, 27))
    chosen = np.sort(rng.choice(len(lots), size=n_buildings, replace=False))
    return tuple(_random_building(lots[k][0] + _CITY_STREET_MARGIN, lots[k][1] - _CITY_STREET_MARGIN, rng)
                 for k in chosen)


@register("city")
def city(*, n_vehicles: int = 50, wind: float = 6.0, sta_spacing: float = 0.0, kbar: int | None = None,
         seed: int = 0) -> Scenario:
    """The 50-UAV city study (BEACLS Section V; intruder paper Section V-A), on a synthetic San Francisco.

    * Domain 5 km x 5 km, ``[0, 5000]^2`` m (the papers' 25 km^2 of SF).
    * One origin, ``(300, 2500)`` near the west edge (the papers' air-highway exit, the blue star); every vehicle
      starts there heading east, toward downtown.
    * Four destination disks of radius 100 m at ``(4600, 2500)``, ``(4300, 4300)``, ``(4200, 800)``,
      ``(2600, 4500)``; each vehicle's destination is drawn uniformly (seeded).
    * Buildings: a **synthetic** downtown (not SF's real footprints), 18-26 polygons (rotated rectangles, L-shaped
      blocks, convex polygons) drawn from the seed, one per chosen lot of a 5 x 6 lattice of 360 m x 350 m lots in
      ``[1700, 3500] x [1250, 3750]`` m, with 40 m of street inside each lot border. The east-west street
      ``y in [2300, 2700]`` (:data:`CITY_CORRIDOR_Y`) in line with the origin stays clear, as do the origin and
      all targets (they lie outside the downtown block).
    * ``n_vehicles`` vehicles (50 in the papers) with a random priority order (seeded).
    * Vehicle bounds ``v in [0, 25] m/s``, ``|omega| <= 2 rad/s`` (eq. 23/43), wind ``d_r = wind`` (6 or 11 m/s);
      robust-trajectory-tracking planning set ``U^p = [11, 13] m/s x |omega| <= 1.2 rad/s`` (BEACLS).
    * ``STA_i = sta_spacing * priority`` [s] (0, 5 or 10 s in BEACLS Cases 0-4, :data:`CITY_CASES`).
    * ``R_c = 100 m``, ``t_IAT = 10 s``; ``kbar=None`` plans without regard to an intruder (BEACLS Section V);
      ``kbar=3`` is the intruder paper's setting.
    * Grid 151 x 151 x 24: 33.3 m in position (6 cells across a target, docs/numerics.md asks for >= 5), 15 degrees in
      heading. The solver's time step is set by the heading axis (CFL rate ``omega / dtheta`` = 4.6 /s against
      ``v / dx`` = 0.39 /s at ``U^p``) and the planning turn radius (13 / 1.2 = 11 m) is a third of a cell: with
      the earlier 251 x 251 x 36 (20 m, 10 degrees) a vehicle took ~290 s to plan, with this grid 6.2x fewer
      nodes and 1.6x fewer steps (BENCHMARKS.md, "City planning"). Streets between lots are 80 m, 2.4 cells.
      Trajectory samples every 0.5 s (at most 19 m of travel, under a cell).

    Randomness: ``seed`` is split into two streams, one for the buildings and one for the vehicles (destinations
    and priorities), so ``n_vehicles`` does not change the downtown.
    """
    _check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    buildings = city_buildings(seed)
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])
    destinations = rng.integers(0, len(CITY_DESTINATIONS), n_vehicles)
    priorities = rng.permutation(n_vehicles)
    start = (*CITY_ORIGIN, _heading(CITY_ORIGIN, CITY_DOWNTOWN_CENTER))
    vehicles = tuple(
        VehicleSpec(start=start, target=CITY_DESTINATIONS[int(d)], target_radius=CITY_TARGET_RADIUS,
                    sta=float(sta_spacing) * int(p), priority=int(p))
        for d, p in zip(destinations, priorities))
    return Scenario(
        name="city",
        domain_lo=CITY_DOMAIN[0],
        domain_hi=CITY_DOMAIN[1],
        **_paper_fields(wind),
        vehicles=vehicles,
        buildings=buildings,
        method="rtt",
        kbar=kbar,
        t_iat=10.0,
        grid_points=(151, 151, 24),
        time_step=0.1,
        seed=seed,
        description=f"City study (BEACLS Section V, intruder paper Section V-A) on a synthetic downtown: "
                    f"{n_vehicles} vehicles from one origin to four destinations, wind {wind} m/s, "
                    f"STA spacing {sta_spacing} s, kbar {kbar}, seed {seed}.",
    )


# ---------------------------------------------------------------------------------------------------- bay area
BAY_AREA_DOMAIN = ((0.0, 0.0), (20000.0, 15000.0))
BAY_AREA_CITIES: dict[str, tuple[float, float]] = {
    "Richmond": (5000.0, 12500.0),
    "Berkeley": (15500.0, 10000.0),
    "Oakland": (15000.0, 3500.0),
    "San Francisco": (3500.0, 3000.0),
}
BAY_AREA_CITY_RADIUS = 500.0


@register("bay-area")
def bay_area(*, n_vehicles: int = 200, wind: float = 11.0, sta_spacing: float = 5.0, kbar: int | None = None,
             seed: int = 0) -> Scenario:
    """The 200-UAV multi-city study (BEACLS Section VI).

    * Domain 20 km x 15 km (300 km^2, the paper's area), no static obstacles.
    * Four cities, stylised after the paper's Fig. 9 (not geo-referenced): Richmond ``(5000, 12500)``, Berkeley
      ``(15500, 10000)``, Oakland ``(15000, 3500)``, San Francisco ``(3500, 3000)`` m, so that the Richmond-Oakland
      and Berkeley-San Francisco routes cross in the centre as in the paper. Each city is a disk of radius 500 m
      (our choice: the paper draws city-sized disks; 500 m keeps >= 5 cells across a target on this grid).
    * Each vehicle flies from a random city (it starts at the city centre, heading straight at its destination) to
      a different random city (seeded); random priority order (seeded).
    * Vehicle bounds ``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``, wind ``d_r = 11 m/s``; ``U^p = [11, 13] x 1.2``.
    * ``STA_i = 5 (i - 1)`` s, i.e. ``sta_spacing * priority`` with ``sta_spacing = 5`` (``sta_spacing=0`` gives the
      paper's Fig. 11 variant). ``R_c = 100 m``, method ``"rtt"``.
    * Grid 251 x 189 x 24, i.e. 80 m in position and 15 degrees in heading. Trade-off: the paper needed "a much
      finer grid" over this area (4 GPU-minutes per vehicle); at 80 m a plan costs 1.1 M nodes per time step
      instead of ~27 M at 20 m, but the danger zone (``R_c = 100 m``) and the tracking bubble are only a few cells
      wide, so obstacle edges are resolved to about one cell and plans are conservative only through the planner's
      own margins. The heading axis sets the solver's time step (CFL rate ``omega / dtheta``), and the planning
      turn radius (11 m) is a seventh of a cell, so 24 headings (as for ``city``) rather than 36 make a plan about
      2.2x cheaper (1.5x fewer nodes, 1.5x fewer steps). Refine with ``grid_points=`` for final results.
      Trajectory samples every 1 s (at most 36 m of travel, under a cell).
    """
    _check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    rng = np.random.default_rng(seed)
    centres = list(BAY_AREA_CITIES.values())
    origins = rng.integers(0, len(centres), n_vehicles)
    destinations = (origins + rng.integers(1, len(centres), n_vehicles)) % len(centres)
    priorities = rng.permutation(n_vehicles)
    vehicles = tuple(
        VehicleSpec(start=(*centres[int(o)], _heading(centres[int(o)], centres[int(d)])),
                    target=centres[int(d)], target_radius=BAY_AREA_CITY_RADIUS,
                    sta=float(sta_spacing) * int(p), priority=int(p))
        for o, d, p in zip(origins, destinations, priorities))
    return Scenario(
        name="bay-area",
        domain_lo=BAY_AREA_DOMAIN[0],
        domain_hi=BAY_AREA_DOMAIN[1],
        **_paper_fields(wind),
        vehicles=vehicles,
        method="rtt",
        kbar=kbar,
        t_iat=10.0,
        grid_points=(251, 189, 24),
        time_step=0.2,
        seed=seed,
        description=f"Multi-city study (BEACLS Section VI): {n_vehicles} vehicles between four cities "
                    f"(Richmond, Berkeley, Oakland, San Francisco), wind {wind} m/s, STA spacing {sta_spacing} s, "
                    f"kbar {kbar}, seed {seed}.",
    )


# ---------------------------------------------------------------------------------------------------- tiny
@register("tiny")
def tiny(*, wind: float = 6.0, sta_spacing: float = 0.0, kbar: int | None = None) -> Scenario:
    """Two vehicles crossing at right angles: a smoke test that plans in seconds.

    * Domain ``[0, 2000]^2`` m, grid 41 x 41 x 40 (50 m, 9 degrees), targets of radius 150 m (6 cells across).
    * Vehicle 0 (priority 0): ``(200, 1000)`` heading east to ``(1800, 1000)``; vehicle 1 (priority 1):
      ``(1000, 200)`` heading north to ``(1000, 1800)``. Their straight paths cross at the centre.
    * The city's vehicle (``v in [0, 25]``, ``|omega| <= 2``, wind 6 m/s), ``U^p = [11, 13] x 1.2``, ``R_c = 100 m``,
      ``t_IAT = 10 s``, method ``"rtt"``: the reachability artifacts of the city study apply unchanged.
    * ``STA_i = sta_spacing * priority`` (default 0 for both: the crossing is a real conflict).
    """
    _check_factory_args(sta_spacing=sta_spacing)
    specs = (((200.0, 1000.0, 0.0), (1800.0, 1000.0)), ((1000.0, 200.0, math.pi / 2), (1000.0, 1800.0)))
    vehicles = tuple(VehicleSpec(start=s, target=c, target_radius=150.0, sta=float(sta_spacing) * k, priority=k)
                     for k, (s, c) in enumerate(specs))
    return Scenario(
        name="tiny",
        domain_lo=(0.0, 0.0),
        domain_hi=(2000.0, 2000.0),
        **_paper_fields(wind),
        vehicles=vehicles,
        method="rtt",
        kbar=kbar,
        t_iat=10.0,
        grid_points=(41, 41, 40),
        time_step=0.1,
        seed=0,
        description=f"Two vehicles crossing in a 2 km square (smoke test), wind {wind} m/s, kbar {kbar}.",
    )


@register("tiny-intruder")
def tiny_intruder(*, wind: float = 6.0, sta_spacing: float = 0.0, kbar: int = 2) -> Scenario:
    """:func:`tiny` with intruder-aware planning, ``kbar = 2`` (``t_BRD = 5 s``; at wind 6 m/s the buffer radius is
    about 760 m, so the two vehicles must be separated in time as well as space)."""
    return tiny(wind=wind, sta_spacing=sta_spacing, kbar=kbar).with_overrides(
        name="tiny-intruder",
        description=f"Two vehicles crossing in a 2 km square with an intruder (kbar {kbar}), wind {wind} m/s.")


# ---------------------------------------------------------------------------------------------------- town
TOWN_DOMAIN = ((0.0, 0.0), (4000.0, 4000.0))
TOWN_ORIGIN = (400.0, 2000.0)
TOWN_DESTINATIONS = ((3500.0, 3300.0), (3600.0, 2000.0), (3500.0, 700.0))
TOWN_TARGET_RADIUS = 150.0
TOWN_BUILDINGS = (((2000.0, 3600.0), 260.0, 160.0), ((2000.0, 400.0), 260.0, 160.0))
"""``(centre, width, height)`` [m] of the two synthetic buildings of :func:`town`."""
TOWN_KBARS = (1, 2, 3, 4)


@register("town")
def town(*, kbar: int = 2, n_vehicles: int = 7, wind: float = 6.0, sta_spacing: float | None = None,
         seed: int = 0) -> Scenario:
    """A small intruder-aware default scenario: one launch point, three destinations, seven vehicles sharing the
    airspace, planned for all of them in about a minute on 2 cores (the environment's default scenario).

    What and why:

    * Domain 4 km x 4 km, ``[0, 4000]^2`` m; grid 81 x 81 x 24 (50 m, 15 degrees), so that a plan is cheap; a
      target of radius 150 m spans 6 cells (docs/numerics.md asks for >= 5). The time step is set by the heading axis
      (CFL rate ``omega / dtheta = 4.6 /s`` against ``v / dx = 0.26 /s``); the planning turn radius (13 / 1.2 =
      11 m) is under a quarter cell, so 15 degrees in heading costs little accuracy and 1.5x fewer headings than
      the city's 10 degrees save 2.2x in time.
    * One origin (launch point) ``(400, 2000)``, every vehicle starting there heading east; three destination
      disks of radius 150 m at ``(3500, 3300)``, ``(3600, 2000)``, ``(3500, 700)`` (straight-line distances
      3.36, 3.20, 3.36 km: flights of about 235-250 s at the top planning speed of 13 m/s).
    * ``n_vehicles`` (default 7) vehicles; destinations drawn uniformly and priorities as a random permutation, both
      from ``seed``.
    * ``STA_i = sta_spacing * priority`` [s], default 90 s (100 s for ``k̄ = 1``): vehicles leave the common
      origin one after the other, so a lower-priority vehicle cannot depart before the higher-priority one is a
      buffer radius away. The buffer radii (intruder paper eqs. 21, 48, as disks,
      :func:`stp_env.reach.buffer.buffer_radii`) at wind 6 m/s are about 986, 757, 670 and 629 m for ``k̄`` = 1,
      2, 3, 4, i.e. 76, 58, 52 and 48 s of flight at 13 m/s. With 90 s the ``k̄ = 1`` plan was infeasible (the
      last vehicle trails one bound for another destination by only ~1000 m at departure, under a cell more than
      the buffer), hence 100 s there. Vehicles are then 1.2-1.3 km apart in trail, 1.2-1.9 buffer radii, with
      three of them in the air at once (close enough that an intruder could press more than one if the plan did
      not keep the buffer: the ``k̄`` bound is what the plan enforces).
    * Intruder-aware planning with ``kbar`` (default 2, allowed 1..4: the relative-buffer artifacts exist for
      those; ``t_BRD = t_IAT / k̄``), ``t_IAT = 10 s``, ``R_c = 100 m``.
    * The city's vehicle: ``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``, wind ``d_r = wind`` (default 6 m/s); robust
      trajectory tracking with ``U^p = [11, 13] m/s x |omega| <= 1.2 rad/s`` (BEACLS), method ``"rtt"``: the
      reachability artifacts of the city study apply unchanged.
    * Two **synthetic** buildings, 260 m x 160 m, centred at ``(2000, 3600)`` and ``(2000, 400)``: more than
      1.4 km from every target and about 800 m from the straight routes, i.e. clear of the static-obstacle
      augmentation ``V^S`` (about 410 m at 6 m/s wind, eqs. 32-33) plus the tracking bubble, so that they stay in
      the airspace (for the simulator's collision checks) without bending the routes.
    * Trajectory samples every 0.5 s (at most 19 m of travel, under a cell).

    Shipped plans for ``k̄ = 1, 2, 3`` (default seed and vehicles) are in ``stp_env/data/plans/town-kbar{k}.npz``
    (:func:`stp_env.planning.stp.shipped_plan_for`).
    """
    if isinstance(kbar, bool) or not isinstance(kbar, (int, np.integer)) or int(kbar) not in TOWN_KBARS:
        raise ValueError(f"town: kbar must be one of {TOWN_KBARS} (the intruder may force at most k̄ vehicles to "
                         f"avoid); got {kbar!r}.")
    if sta_spacing is None:
        sta_spacing = 100.0 if kbar == 1 else 90.0
    _check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    rng = np.random.default_rng(seed)
    destinations = rng.integers(0, len(TOWN_DESTINATIONS), n_vehicles)
    priorities = rng.permutation(n_vehicles)
    east = (*TOWN_ORIGIN, 0.0)
    vehicles = tuple(
        VehicleSpec(start=east, target=TOWN_DESTINATIONS[int(d)], target_radius=TOWN_TARGET_RADIUS,
                    sta=float(sta_spacing) * int(p), priority=int(p))
        for d, p in zip(destinations, priorities))
    buildings = tuple(Building.rectangle(c, w, h) for c, w, h in TOWN_BUILDINGS)
    return Scenario(
        name="town",
        domain_lo=TOWN_DOMAIN[0],
        domain_hi=TOWN_DOMAIN[1],
        **_paper_fields(wind),
        vehicles=vehicles,
        buildings=buildings,
        method="rtt",
        kbar=int(kbar),
        t_iat=10.0,
        grid_points=(81, 81, 24),
        time_step=0.1,
        seed=seed,
        description=f"Town (default intruder-aware scenario): {n_vehicles} vehicles from one launch point to three "
                    f"destinations in a 4 km square with two synthetic buildings, kbar {kbar}, wind {wind} m/s, "
                    f"STA spacing {sta_spacing} s, seed {seed}.",
    )
from stp_env.scenarios import fig6 as _fig6  # noqa: E402,F401  (registers "fig6": the intruder paper Fig. 6 worst case)
