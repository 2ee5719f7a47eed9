"""``corridor``: a dense scenario where the buffer binds: vehicles in trail on one straight route, spaced as
tightly as the intruder-aware planner allows for the chosen ``k̄``."""

from __future__ import annotations

from stp_env.scenarios.config import Scenario, VehicleSpec
from stp_env.scenarios.paper import check_factory_args, check_kbar, dense_scenario
from stp_env.scenarios.registry import register

CORRIDOR_DOMAIN = ((0.0, 0.0), (3600.0, 1600.0))
CORRIDOR_START = (300.0, 800.0, 0.0)
CORRIDOR_TARGET = (3300.0, 800.0)
CORRIDOR_TARGET_RADIUS = 150.0
CORRIDOR_KBARS = (1, 2, 3, 4)
CORRIDOR_SPACING = {1: 87.0, 2: 69.0, 3: 62.0, 4: 63.0}
"""STA spacing [s] per ``k̄``: the smallest whole second at which the straight plan keeps every follower outside
the planner's disks around its leader (``examples/dense_spacing.py``; one second less breaks the constraint). At
13 m/s the trail is ``13 x spacing`` m: 1131, 897, 806 and 819 m against buffer radii
(:func:`stp_env.reach.buffer.buffer_radii`, 6 m/s wind) of 989, 760, 673 and 632 m. The gap over the radius is
the flight time from the start to the target's edge rounding to whole samples plus the pads: a leader's disk is
present 10 s before its departure and after its arrival (:func:`stp_env.planning.disks.fold_contained_disks`), when
it stands still; for ``k̄ = 4`` the intruder-aware lag disks reach further than the buffer disk."""


@register("corridor")
def corridor(*, kbar: int = 2, n_vehicles: int = 20, wind: float = 6.0, sta_spacing: float | None = None,
             seed: int = 0) -> Scenario:
    """``n_vehicles`` (default 20) vehicles in trail on one route, planned intruder-aware for ``kbar``.

    * Domain ``[0, 3600] x [0, 1600]`` m, grid 73 x 33 x 24 (50 m, 15 degrees, as ``town``).
    * Every vehicle starts at ``(300, 800)`` heading east and flies to the disk of radius 150 m at ``(3300, 800)``
      (3 km, about 230 s at 13 m/s); priorities in launch order.
    * ``STA_i = 300 + sta_spacing * i`` [s], ``sta_spacing`` by default :data:`CORRIDOR_SPACING` for ``kbar``: the
      tightest the planner's constraints accept, so the followers trail each other by about one buffer radius, and
      an intruder that forces one vehicle finds the next one as close as the plan allows.
    * Method ``"straight"``: every vehicle flies the route at 13 m/s, checked against the intruder-aware planner's
      disks (:func:`stp_env.planning.verify.straight_plan`); on one straight route that is the planner's answer.
    * The town's vehicle, planning set, ``R_c = 100 m``, ``t_IAT = 10 s`` and wind (default 6 m/s), so the
      reachability artifacts are shared with ``town``.

    ``seed`` is recorded (the corridor has no random part).
    """
    check_kbar("corridor", kbar, CORRIDOR_KBARS)
    if sta_spacing is None:
        sta_spacing = CORRIDOR_SPACING[int(kbar)]
    check_factory_args(n_vehicles=n_vehicles, sta_spacing=sta_spacing, seed=seed)
    vehicles = tuple(VehicleSpec(start=CORRIDOR_START, target=CORRIDOR_TARGET, target_radius=CORRIDOR_TARGET_RADIUS,
                                 sta=300.0 + float(sta_spacing) * i, priority=i) for i in range(n_vehicles))
    description = (f"Corridor (dense, the buffer binds): {n_vehicles} vehicles in trail on one 3 km route, kbar "
                   f"{kbar}, STA spacing {sta_spacing} s, wind {wind} m/s.")
    return dense_scenario("corridor", domain=CORRIDOR_DOMAIN, vehicles=vehicles, kbar=kbar, wind=wind,
                          grid_points=(73, 33, 24), seed=seed, description=description)
