"""``pinwheel``: a dense scenario where the buffer binds for ``k̄ = 3``: three streams circulating around a centre,
their vehicles passing in waves of three, each wave an equilateral triangle one buffer radius on a side.

Why a third dense layout. In a trail (``corridor``) every hop after the first starts on the near side of the vehicle
just forced and must cross the whole gap to the next, so no third vehicle is reached at any spacing the buffer
allows; across two streams (``crossing``) only two vehicles are ever close at once. The buffer's argument lets the
intruder's hop start anywhere on a forced vehicle's avoid boundary; to reach ``k̄ = 3`` the layout must put the
third vehicle beside the second hop's start. Three straight routes tangent to a circle of radius ``rho`` at 120
degrees to each other do that: three vehicles that pass their tangent points at the same time are ``sqrt(3) rho``
apart, pairwise, and that is their closest approach (a vehicle at ``R_k (rho, v t)``, rotated by ``120 k`` degrees,
is ``sqrt(3) sqrt(rho^2 + v^2 t^2)`` from the other two). With ``sqrt(3) rho`` equal to the planner's buffer
radius, the triangle is as tight as the disk allows, and an intruder that appears on one vehicle's boundary
facing the centre has the other two at equal distances ahead of it. There the ``worst`` vehicles and the
``optimal-max-k`` intruder force all three under the buffer game's helping winds (``--wind-model converging``), and
two under the papers' random ones (``docs/dense.md``, ``examples/pinwheel_worst_case.py``).
"""

from __future__ import annotations

import math

import numpy as np

from stp_env.scenarios.config import Scenario, VehicleSpec
from stp_env.scenarios.paper import check_factory_args, check_kbar, dense_scenario
from stp_env.scenarios.registry import register

PINWHEEL_DOMAIN = ((0.0, 0.0), (4000.0, 4000.0))
PINWHEEL_CENTRE = (2000.0, 2000.0)
PINWHEEL_BEFORE = 300.0
PINWHEEL_AFTER = 1600.0
"""Each route starts ``PINWHEEL_BEFORE`` [m] before its tangent point and ends ``PINWHEEL_AFTER`` after it (1.9 km,
about 146 s at 13 m/s). The three lines cross pairwise at the corners of the equilateral triangle around the circle,
``sqrt(3) rho`` from the tangent points; starting short of the corner behind, a stream crosses the others only
after its wave's triangle, and the waves can follow each other about 105 s apart (starting 1.6 km before, the
crossings at both corners would hold them 208 s apart at k̄ = 3)."""
PINWHEEL_TARGET_RADIUS = 150.0
PINWHEEL_KBARS = (1, 2, 3, 4)
PINWHEEL_RADIUS = {1: 571.0, 2: 439.0, 3: 389.0, 4: 387.0}
"""Radius ``rho`` [m] of the circle the routes are tangent to, per ``k̄``: the smallest whole metre at which the
straight plan keeps every vehicle of a wave outside the planner's disks around the higher-priority ones
(``python examples/dense_spacing.py --scenarios pinwheel``; one metre less breaks the constraint). The triangle's
side ``sqrt(3) rho`` is then the buffer radius plus under 2 m (989.0, 760.4 and 673.8 m for ``k̄ = 1, 2, 3``); for
``k̄ = 4`` the intruder-aware lag disks reach further than the 631.7 m buffer disk (side 670.3 m)."""
PINWHEEL_SPACING = {1: 134.0, 2: 114.0, 3: 106.0, 4: 107.0}
"""Seconds [s] between waves per ``k̄`` at :data:`PINWHEEL_RADIUS`: the smallest whole second that keeps the vehicles
of consecutive waves outside each other's disks (the same script; every longer spacing up to 400 s passes too). A
wave's stream-0 vehicle meets the next wave's stream-2 vehicle near the latter's start."""


def stream_geometry(rho: float) -> list[tuple[tuple[float, float, float], tuple[float, float]]]:
    """``(start, target)`` of the three streams for the circle radius ``rho``: stream ``k`` touches the circle at
    angle ``-90 + 120 k`` degrees and flies counter-clockwise around it (stream 0 flies east, south of the
    centre)."""
    out = []
    for k in range(3):
        alpha = -math.pi / 2 + 2 * math.pi * k / 3
        heading = alpha + math.pi / 2
        tx, ty = PINWHEEL_CENTRE[0] + rho * math.cos(alpha), PINWHEEL_CENTRE[1] + rho * math.sin(alpha)
        dx, dy = math.cos(heading), math.sin(heading)
        start = (tx - PINWHEEL_BEFORE * dx, ty - PINWHEEL_BEFORE * dy, math.atan2(dy, dx))
        out.append((start, (tx + PINWHEEL_AFTER * dx, ty + PINWHEEL_AFTER * dy)))
    return out


@register("pinwheel")
def pinwheel(*, kbar: int = 3, n_waves: int = 7, wind: float = 6.0, radius: float | None = None,
             sta_spacing: float | None = None, seed: int = 0) -> Scenario:
    """Three streams around the centre of a 4 km square, ``3 n_waves`` vehicles (default 21), planned intruder-aware
    for ``kbar`` (module docstring).

    * Domain ``[0, 4000]^2`` m, grid 81 x 81 x 24 (as ``town``); routes 1.9 km, tangent to the circle of radius
      ``radius`` (default :data:`PINWHEEL_RADIUS` for ``kbar``) around ``(2000, 2000)``.
    * Vehicle ``i`` flies stream ``i % 3`` in wave ``i // 3``; priorities in index order; the three vehicles of a wave
      share ``STA = 300 + sta_spacing * wave`` [s] (default :data:`PINWHEEL_SPACING` for ``kbar``), so they pass
      their tangent points together.
    * Method ``"straight"``: straight flights at 13 m/s checked against the intruder-aware planner's disks
      (:func:`stp_env.planning.verify.straight_plan`).
    * The town's vehicle, planning set, ``R_c = 100 m``, ``t_IAT = 10 s`` and wind (default 6 m/s).

    ``seed`` is recorded (the pinwheel has no random part).
    """
    check_kbar("pinwheel", kbar, PINWHEEL_KBARS)
    if isinstance(n_waves, bool) or not isinstance(n_waves, (int, np.integer)) or n_waves < 1:
        raise ValueError(f"pinwheel: n_waves must be an integer >= 1; got {n_waves!r}.")
    radius = PINWHEEL_RADIUS[int(kbar)] if radius is None else radius
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not 0 < radius < 1000:
        raise ValueError(f"pinwheel: radius must be a number in (0, 1000) m (the routes must stay in the domain); "
                         f"got {radius!r}.")
    if sta_spacing is None:
        sta_spacing = PINWHEEL_SPACING[int(kbar)]
    check_factory_args(n_vehicles=3 * int(n_waves), sta_spacing=sta_spacing, seed=seed)
    streams = stream_geometry(float(radius))
    vehicles = tuple(VehicleSpec(start=streams[i % 3][0], target=streams[i % 3][1],
                                 target_radius=PINWHEEL_TARGET_RADIUS, sta=300.0 + float(sta_spacing) * (i // 3),
                                 priority=i) for i in range(3 * int(n_waves)))
    description = (f"Pinwheel (dense, the buffer binds at k̄ = 3): {3 * int(n_waves)} vehicles in three streams "
                   f"tangent to a circle of radius {radius} m, waves of three {sta_spacing} s apart, kbar {kbar}, "
                   f"wind {wind} m/s.")
    return dense_scenario("pinwheel", domain=PINWHEEL_DOMAIN, vehicles=vehicles, kbar=kbar, wind=wind,
                          grid_points=(81, 81, 24), seed=seed, description=description)
