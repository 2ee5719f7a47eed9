"""The 50-UAV city study (BEACLS Section V; intruder paper Section V-A) on a synthetic downtown."""

from __future__ import annotations

import itertools
import math

import numpy as np

from stp_env.scenarios.config import Building, Scenario, VehicleSpec
from stp_env.scenarios.geometry import rotate
from stp_env.scenarios.paper import check_factory_args, heading, paper_fields
from stp_env.scenarios.registry import register

CITY_CASES: dict[int, dict[str, float]] = {
    0: {"wind": 6.0, "sta_spacing": 0.0},
    1: {"wind": 11.0, "sta_spacing": 0.0},
    2: {"wind": 6.0, "sta_spacing": 5.0},
    3: {"wind": 11.0, "sta_spacing": 5.0},
    4: {"wind": 11.0, "sta_spacing": 10.0},
}
"""BEACLS Section V-C, Cases 0-4 (wind ``d_r`` [m/s], STA spacing [s]): ``make("city", **CITY_CASES[3])``."""


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
      ``kbar=3`` is the intruder paper's setting. With ``kbar`` and all STAs equal, the one origin releases a
      vehicle a minute and the last ones wait an hour near their targets; no such plan ships (it is planned on
      first use). The shipped intruder-aware city is ``city-intruder``
      (:mod:`stp_env.scenarios.catalog.city_intruder`): the same city with one departure slot per vehicle.
    * Grid 151 x 151 x 24: 33.3 m in position (6 cells across a target, docs/numerics.md asks for >= 5), 15 degrees in
      heading. The solver's time step is set by the heading axis (CFL rate ``omega / dtheta`` = 4.6 /s against
      ``v / dx`` = 0.39 /s at ``U^p``) and the planning turn radius (13 / 1.2 = 11 m) is a third of a cell: with
      the earlier 251 x 251 x 36 (20 m, 10 degrees) a vehicle took ~290 s to plan, with this grid 6.2x fewer
      nodes and 1.6x fewer steps (BENCHMARKS.md, "City planning"). Streets between lots are 80 m, 2.4 cells.
      Trajectory samples every 0.5 s (at most 19 m of travel, under a cell).

    Randomness: ``seed`` is split into two streams, one for the buildings and one for the vehicles (destinations
    and priorities), so ``n_vehicles`` does not change the downtown.
    """
    check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    buildings = city_buildings(seed)
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])
    destinations = rng.integers(0, len(CITY_DESTINATIONS), n_vehicles)
    priorities = rng.permutation(n_vehicles)
    start = (*CITY_ORIGIN, heading(CITY_ORIGIN, CITY_DOWNTOWN_CENTER))
    vehicles = tuple(
        VehicleSpec(start=start, target=CITY_DESTINATIONS[int(d)], target_radius=CITY_TARGET_RADIUS,
                    sta=float(sta_spacing) * int(p), priority=int(p))
        for d, p in zip(destinations, priorities))
    return Scenario(
        name="city",
        domain_lo=CITY_DOMAIN[0],
        domain_hi=CITY_DOMAIN[1],
        **paper_fields(wind),
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
