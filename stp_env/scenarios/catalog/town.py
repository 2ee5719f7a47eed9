"""The environment's default scenario: seven vehicles from one launch point to three destinations."""

from __future__ import annotations

import numpy as np

from stp_env.scenarios.config import Building, Scenario, VehicleSpec
from stp_env.scenarios.paper import check_factory_args, check_kbar, paper_fields
from stp_env.scenarios.registry import register

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
    check_kbar("town", kbar, TOWN_KBARS, " (the intruder may force at most k̄ vehicles to avoid)")
    if sta_spacing is None:
        sta_spacing = 100.0 if kbar == 1 else 90.0
    check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
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
        **paper_fields(wind),
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
