"""Two vehicles crossing: the smoke-test scenarios ``tiny`` and ``tiny-intruder``."""

from __future__ import annotations

import math

from stp_env.scenarios.config import Scenario, VehicleSpec
from stp_env.scenarios.paper import check_factory_args, paper_fields
from stp_env.scenarios.registry import register


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
    check_factory_args(sta_spacing=sta_spacing)
    specs = (((200.0, 1000.0, 0.0), (1800.0, 1000.0)), ((1000.0, 200.0, math.pi / 2), (1000.0, 1800.0)))
    vehicles = tuple(VehicleSpec(start=s, target=c, target_radius=150.0, sta=float(sta_spacing) * k, priority=k)
                     for k, (s, c) in enumerate(specs))
    return Scenario(
        name="tiny",
        domain_lo=(0.0, 0.0),
        domain_hi=(2000.0, 2000.0),
        **paper_fields(wind),
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
def tiny_intruder(*, wind: float = 6.0, sta_spacing: float = 90.0, kbar: int = 2) -> Scenario:
    """:func:`tiny` with intruder-aware planning, ``kbar = 2`` (``t_BRD = 5 s``; at wind 6 m/s the buffer radius is
    about 760 m, so the two vehicles must be separated in time as well as space: STAs 0 and ``sta_spacing`` = 90 s
    by default, the plan that ships)."""
    return tiny(wind=wind, sta_spacing=sta_spacing, kbar=kbar).with_overrides(
        name="tiny-intruder",
        description=f"Two vehicles crossing in a 2 km square with an intruder (kbar {kbar}), wind {wind} m/s.")
