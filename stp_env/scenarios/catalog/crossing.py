"""``crossing``: a dense scenario where the buffer binds: two streams of vehicles crossing at right angles,
interleaved as tightly as the intruder-aware planner allows for the chosen ``k̄``."""

from __future__ import annotations

import math

from stp_env.scenarios.config import Scenario, VehicleSpec
from stp_env.scenarios.paper import check_factory_args, check_kbar, dense_scenario
from stp_env.scenarios.registry import register

CROSSING_DOMAIN = ((0.0, 0.0), (4000.0, 4000.0))
CROSSING_STREAMS = (((300.0, 2000.0, 0.0), (3700.0, 2000.0)),
                    ((2000.0, 300.0, math.pi / 2), (2000.0, 3700.0)))
"""``(start, target)`` of the west-to-east stream and of the south-to-north stream; they cross at ``(2000, 2000)``."""
CROSSING_TARGET_RADIUS = 150.0
CROSSING_KBARS = (1, 2, 3, 4)
CROSSING_SPACING = {1: 108.0, 2: 83.0, 3: 74.0, 4: 74.0}
"""STA spacing [s] between consecutive vehicles (alternating streams) per ``k̄``: the smallest whole second at
which the straight plan keeps every vehicle outside the planner's disks around the higher-priority ones
(``examples/dense_spacing.py``; one second less breaks the constraint). Two vehicles of different streams that pass
the crossing ``s`` seconds apart at speed ``v`` come as close as ``v s / sqrt(2)``, so the spacing is about
``sqrt(2)`` times the buffer radius's flight time (``k̄ = 1``: 108 s, ``sqrt(2) x 989 / 13 = 107.6 s``)."""


@register("crossing")
def crossing(*, kbar: int = 2, n_vehicles: int = 20, wind: float = 6.0, sta_spacing: float | None = None,
             seed: int = 0) -> Scenario:
    """Two streams crossing at right angles at the centre of a 4 km square, ``n_vehicles`` in all (default 20,
    alternating: even indices fly west to east, odd ones south to north), planned intruder-aware for ``kbar``.

    * Domain ``[0, 4000]^2`` m, grid 81 x 81 x 24 (as ``town``).
    * West-east: ``(300, 2000)`` heading east to the disk of radius 150 m at ``(3700, 2000)``; south-north:
      ``(2000, 300)`` heading north to ``(2000, 3700)`` (3.4 km, about 260 s at 13 m/s).
    * Priorities in index order; ``STA_i = 300 + sta_spacing * i`` [s], ``sta_spacing`` by default
      :data:`CROSSING_SPACING` for ``kbar`` (the tightest the planner's constraints accept).
    * Method ``"straight"``: straight flights at 13 m/s checked against the intruder-aware planner's disks
      (:func:`stp_env.planning.verify.straight_plan`): the schedule, not a detour, resolves the crossing.
    * The town's vehicle, planning set, ``R_c = 100 m``, ``t_IAT = 10 s`` and wind (default 6 m/s).

    ``seed`` is recorded (the crossing has no random part).
    """
    check_kbar("crossing", kbar, CROSSING_KBARS)
    if sta_spacing is None:
        sta_spacing = CROSSING_SPACING[int(kbar)]
    check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    vehicles = tuple(VehicleSpec(start=CROSSING_STREAMS[i % 2][0], target=CROSSING_STREAMS[i % 2][1],
                                 target_radius=CROSSING_TARGET_RADIUS, sta=300.0 + float(sta_spacing) * i,
                                 priority=i) for i in range(n_vehicles))
    description = (f"Crossing (dense, the buffer binds): {n_vehicles} vehicles in two streams crossing at right "
                   f"angles in a 4 km square, kbar {kbar}, STA spacing {sta_spacing} s, wind {wind} m/s.")
    return dense_scenario("crossing", domain=CROSSING_DOMAIN, vehicles=vehicles, kbar=kbar, wind=wind,
                          grid_points=(81, 81, 24), seed=seed, description=description)
