"""Named, typed scenarios of the papers: vehicles, targets, schedules, buildings and the planning problem.

Usage::

    from stp_env import scenarios

    scenario = scenarios.make("city", wind=11, sta_spacing=5, kbar=3)   # BEACLS Case 3, intruder-aware
    grid = scenario.grid()                                               # planning grid (x, y, heading)
    for i in scenario.in_priority_order():                               # STP planning order
        spec = scenario.vehicles[i]                                      # start, target, radius, sta, priority
    g_static = scenario.static_obstacle()                                # buildings' signed distance on the grid

Modules: :mod:`~stp_env.scenarios.config` (``Scenario``, ``VehicleSpec``, ``Building``),
:mod:`~stp_env.scenarios.geometry` (polygon signed distance, building tables),
:mod:`~stp_env.scenarios.registry` (``register``, ``make``, ``names``: the mechanism),
:mod:`~stp_env.scenarios.catalog` (the named scenarios, one module each, found automatically),
:mod:`~stp_env.scenarios.paper` (what the papers' scenarios share).
"""

from stp_env.scenarios import geometry
from stp_env.scenarios.catalog.city import CITY_CASES
from stp_env.scenarios.config import METHODS, Building, Scenario, VehicleSpec, wrap_angle
from stp_env.scenarios.geometry import NO_OBSTACLE_DISTANCE, buildings_sdf, polygon_signed_distance
from stp_env.scenarios.registry import factory_parameters, load_catalog, make, names, register

__all__ = [
    "CITY_CASES",
    "METHODS",
    "NO_OBSTACLE_DISTANCE",
    "Building",
    "Scenario",
    "VehicleSpec",
    "buildings_sdf",
    "factory_parameters",
    "geometry",
    "load_catalog",
    "make",
    "names",
    "polygon_signed_distance",
    "register",
    "wrap_angle",
]
