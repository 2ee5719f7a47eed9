"""``city-intruder``: the city study with an intruder (BEACLS Section VII, intruder paper Section V-A), planned
intruder-aware for ``k̄`` with one departure slot per vehicle."""

from __future__ import annotations

import dataclasses
import math

from stp_env.scenarios.catalog.city import city
from stp_env.scenarios.config import Scenario
from stp_env.scenarios.paper import check_kbar
from stp_env.scenarios.registry import register

CITY_INTRUDER_KBARS = (2, 3, 4)
CITY_INTRUDER_SLOT = 150.0
"""Departure slot [s] between consecutive priorities (why 150 s: :func:`city_intruder`)."""


def direct_flight_time(start, target, target_radius: float, speed: float) -> float:
    """Whole seconds to fly straight from ``start`` to the edge of the target disk at ``speed`` [m/s]."""
    return float(math.ceil((math.dist(start[:2], target) - target_radius) / speed))


@register("city-intruder")
def city_intruder(*, kbar: int = 3, n_vehicles: int = 50, wind: float = 6.0, slot: float = CITY_INTRUDER_SLOT,
                  seed: int = 0) -> Scenario:
    """The ``city`` (origin, four destinations, synthetic downtown, vehicles, random priorities of ``seed``) planned
    intruder-aware for ``kbar``, with ``STA_i = slot * priority + T_i``, ``T_i`` the straight flight from the origin
    to the edge of vehicle ``i``'s target at the top planning speed (13 m/s, :func:`direct_flight_time`).

    Why not the city's equal STAs (BEACLS Case 0 with ``kbar``, ``make("city", kbar=k)``): with one origin and the
    buffer between vehicles, the vehicles leave one per 61-68 s, so with all STAs equal the 50th leaves about an hour
    before its STA and waits near its target for most of it, where the 760 m buffer disks of the vehicles planned
    before it sweep past for minutes at a time. The planner's trajectories of such waits leave their tubes on this
    grid (docs/city_intruder.md), and no such plan ships. Spaced STAs (``make("city", kbar=2,
    sta_spacing=70)``) do not fix it: the flights to the four destinations differ by up to about 130 s, so the
    vehicles' natural departures collide at the origin, each collision pushes a departure one buffer spacing
    earlier, and at 70 s the 11th vehicle had no departure within the 676 s horizon. Scheduling the departures
    instead (the slot) and deriving the STA from the flight is what an operator of one origin does; the density is
    then set by the slot: a vehicle every 150 s, two or three in the air at once (flights of 236-455 s).

    Why 150 s (:data:`CITY_INTRUDER_SLOT`): the intruder-aware planner keeps a departing vehicle outside the buffer
    disk of each vehicle that left before it, and from the one origin that holds departures 67.5 s apart at
    ``k̄ = 2`` and 61 s at ``k̄ = 3`` (``make("city", kbar=k)``). The planned flights are up to about
    40 s longer than the straight line (the detours around the downtown) and the flights to ``(4600, 2500)`` are
    held back further, so a vehicle's natural departure can fall within one buffer spacing of an earlier one; it then
    leaves earlier, in the first gap of two buffer spacings. With 90 s slots such gaps were rare, the held-back
    departures cascaded, and the 10th vehicle had no departure within the 676 s planning horizon. With 150 s the
    deepest holds in the shipped plans are 249 s before the slot at ``k̄ = 3`` and 382 s at ``k̄ = 2``, which
    needs a 1200 s planning horizon (``stp-env data plans``: at 676 s its 46th vehicle had no departure).

    The BEACLS paper's Section VII plans its intruder-aware city for ``k̄ = 3`` (its Fig. 13) and reports two
    vehicles forced by its intruder.
    """
    check_kbar("city-intruder", kbar, CITY_INTRUDER_KBARS)
    if isinstance(slot, bool) or not isinstance(slot, (int, float)) or not (math.isfinite(slot) and slot > 0):
        raise ValueError(f"city-intruder: slot must be a positive number of seconds; got {slot!r}.")
    base = city(n_vehicles=n_vehicles, wind=wind, kbar=int(kbar), seed=seed)
    top_speed = float(base.planning_v[1])
    vehicles = tuple(
        dataclasses.replace(v, sta=float(slot) * v.priority
                            + direct_flight_time(v.start, v.target, v.target_radius, top_speed))
        for v in base.vehicles)
    return base.with_overrides(
        name="city-intruder", vehicles=vehicles,
        description=f"City with an intruder (BEACLS Section VII) on a synthetic downtown: {n_vehicles} vehicles "
                    f"from one origin to four destinations, planned for kbar {kbar}, one departure every {slot} s, "
                    f"wind {wind} m/s, seed {seed}.")
