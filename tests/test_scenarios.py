"""Contracts of the scenario layer: every registered scenario builds and validates, the paper's data are exact,
overrides and errors are clear, the polygon signed distance is exact, and generation is deterministic."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import scenarios
from stp_env.dynamics import DubinsWind
from stp_env.hj import Grid
from stp_env.scenarios import Building, Scenario, VehicleSpec, polygon_signed_distance
from stp_env.scenarios.catalog.city import CITY_CORRIDOR_Y, CITY_ORIGIN

UNIT_SQUARE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))


@pytest.fixture(scope="module")
def city() -> Scenario:
    return scenarios.make("city")


def _small(**overrides) -> Scenario:
    """A valid two-vehicle scenario with one building, for the error tests."""
    kwargs = dict(
        name="small", domain_lo=(0.0, 0.0), domain_hi=(2000.0, 2000.0),
        vehicle=DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=6.0),
        planning_v=(11.0, 13.0), planning_omega_max=1.2, collision_radius=100.0,
        vehicles=(VehicleSpec(start=(100.0, 100.0, 0.0), target=(1800.0, 1800.0), target_radius=150.0, sta=0.0,
                              priority=0),
                  VehicleSpec(start=(100.0, 1800.0, 0.0), target=(1800.0, 200.0), target_radius=150.0, sta=0.0,
                              priority=1)),
        buildings=(Building.rectangle((1000.0, 1000.0), 200.0, 200.0),),
        method="rtt", grid_points=(41, 41, 20), time_step=0.5, seed=0, description="test")
    kwargs.update(overrides)
    return Scenario(**kwargs)


def _vehicle(i: int, s: Scenario, **changes) -> tuple[VehicleSpec, ...]:
    vehicles = list(s.vehicles)
    vehicles[i] = dataclasses.replace(vehicles[i], **changes)
    return tuple(vehicles)


# ------------------------------------------------------------------------------------------ registry
@pytest.mark.parametrize("name", scenarios.names())
def test_every_registered_scenario_builds_and_validates(name):
    s = scenarios.make(name)
    assert isinstance(s, Scenario) and s.name == name and s.description
    grid = s.grid()
    assert grid.shape == s.grid_points and grid.periodic == (2,)
    assert grid.lo[2] == pytest.approx(-math.pi) and grid.hi[2] == pytest.approx(math.pi)
    assert sorted(s.in_priority_order()) == list(range(s.n_vehicles))
    assert [s.vehicles[i].priority for i in s.in_priority_order()] == list(range(s.n_vehicles))
    assert np.all((s.starts()[:, 2] >= -math.pi) & (s.starts()[:, 2] < math.pi))
    assert s.with_overrides() == s  # re-validation of a valid scenario passes
    hash(s)


def test_registered_names():
    assert {"four-vehicle", "city", "bay-area", "tiny", "tiny-intruder", "town"} <= set(scenarios.names())
    assert scenarios.make("tiny").kbar is None and scenarios.make("tiny-intruder").kbar == 2


def test_four_vehicle_matches_spp_eqs_28_to_30():
    s = scenarios.make("four-vehicle")
    v = s.vehicle
    assert (v.v_min, v.v_max, v.omega_max, v.wind, v.heading_disturbance) == (0.5, 1.0, 1.0, 0.1, 0.2)
    starts = [(-0.5, 0.0, 0.0), (0.5, 0.0, math.pi), (-0.6, 0.6, 7 * math.pi / 4), (0.6, 0.6, 5 * math.pi / 4)]
    targets = [(0.7, 0.2), (-0.7, 0.2), (0.7, -0.7), (-0.7, -0.7)]
    for k, (spec, x0, c) in enumerate(zip(s.vehicles, starts, targets)):
        assert spec.start[:2] == x0[:2]
        # headings are stored wrapped to [-pi, pi): equal modulo 2 pi
        assert math.isclose(math.cos(spec.start[2]), math.cos(x0[2]), abs_tol=1e-12)
        assert math.isclose(math.sin(spec.start[2]), math.sin(x0[2]), abs_tol=1e-12)
        assert spec.target == c and spec.target_radius == 0.1 and spec.sta == 0.0 and spec.priority == k
    assert s.collision_radius == 0.1 and s.method == "centralized"
    assert s.planning_v == (0.6, 0.7) and s.planning_omega_max == 0.2
    assert max(s.grid_spacing[:2]) <= 0.03


def test_city_overrides_go_to_factory_and_fields():
    s = scenarios.make("city", wind=11, sta_spacing=5, kbar=3, n_vehicles=10)
    assert s.vehicle.wind == 11.0 and s.kbar == 3 and s.n_vehicles == 10
    np.testing.assert_array_equal(s.stas(), 5.0 * s.priorities())
    assert s.planning_v == (11.0, 13.0) and s.planning_omega_max == 1.2 and s.collision_radius == 100.0
    # factory parameters and Scenario fields together; fields are applied after the factory
    s2 = scenarios.make("city", n_vehicles=3, method="centralized", t_iat=8.0)
    assert s2.method == "centralized" and s2.t_iat == 8.0 and s2.n_vehicles == 3
    for case in scenarios.CITY_CASES.values():
        assert scenarios.make("city", n_vehicles=2, **case).vehicle.wind == case["wind"]


def test_city_intruder_is_the_city_with_departure_slots():
    from stp_env.scenarios.catalog.city_intruder import CITY_INTRUDER_SLOT

    base = scenarios.make("city", kbar=3, n_vehicles=12)
    s = scenarios.make("city-intruder", kbar=3, n_vehicles=12)
    assert s.name == "city-intruder" and s.kbar == 3 and s.buildings == base.buildings
    assert [(v.start, v.target, v.priority) for v in s.vehicles] == [(v.start, v.target, v.priority)
                                                                     for v in base.vehicles]
    # STA = slot x priority + the straight flight to the target's edge at 13 m/s, rounded up to whole seconds;
    # e.g. the origin (300, 2500) to (2600, 4500): (3048.0 - 100) / 13 = 226.8 -> 227 s
    for v in s.vehicles:
        flight = math.ceil((math.dist(v.start[:2], v.target) - v.target_radius) / 13.0)
        assert v.sta == CITY_INTRUDER_SLOT * v.priority + flight
    near = [v for v in s.vehicles if v.target == (2600.0, 4500.0)]
    assert near and all(v.sta == CITY_INTRUDER_SLOT * v.priority + 227.0 for v in near)
    # consecutive priorities are due at least one slot apart less the flights' spread, never together
    stas = s.stas()[np.argsort(s.priorities())]
    assert np.all(np.diff(stas) >= CITY_INTRUDER_SLOT - 110.0)
    assert scenarios.make("city-intruder", kbar=2, slot=200.0).vehicles[0].sta != s.vehicles[0].sta
    for bad in ({"kbar": 1}, {"kbar": 5}, {"kbar": True}, {"slot": 0.0}, {"slot": float("nan")}, {"slot": "90"}):
        with pytest.raises(ValueError, match="city-intruder"):
            scenarios.make("city-intruder", **bad)


def test_bay_area_setup():
    s = scenarios.make("bay-area")
    (x0, y0), (x1, y1) = s.domain_lo, s.domain_hi
    assert 250e6 <= (x1 - x0) * (y1 - y0) <= 350e6
    assert s.n_vehicles == 200 and s.vehicle.wind == 11.0 and not s.buildings and s.method == "rtt"
    np.testing.assert_array_equal(s.stas(), 5.0 * s.priorities())
    assert 70.0 <= max(s.grid_spacing[:2]) <= 100.0
    assert len({v.target for v in s.vehicles}) == 4
    assert all(np.hypot(*np.subtract(v.start[:2], v.target)) > v.target_radius for v in s.vehicles)


def test_unknown_scenario_and_override_errors():
    with pytest.raises(ValueError, match=r"unknown scenario 'nope'.*city.*four-vehicle"):
        scenarios.make("nope")
    with pytest.raises(ValueError, match=r"unknown override.*'windd'.*factory parameters.*wind.*Scenario fields"):
        scenarios.make("city", windd=3)
    with pytest.raises(ValueError, match=r"unknown Scenario field.*'colision_radius'.*allowed.*collision_radius"):
        scenarios.make("tiny").with_overrides(colision_radius=3.0)
    with pytest.raises(ValueError, match="sta_spacing"):
        scenarios.make("city", sta_spacing=-5)
    with pytest.raises(ValueError, match=r"method 'mpc'.*rtt"):
        scenarios.make("tiny", method="mpc")
    with pytest.raises(ValueError, match="already registered"):
        scenarios.register("tiny")(lambda: None)


# ------------------------------------------------------------------------------------------ validation
def test_small_scenario_is_valid():
    assert _small().n_vehicles == 2


@pytest.mark.parametrize(
    ("make_bad", "pattern"),
    [
        (lambda s: dict(vehicles=_vehicle(1, s, target=(1000.0, 1000.0))),
         r"vehicle 1: target \(1000\.0, 1000\.0\) lies inside building 0"),
        (lambda s: dict(vehicles=_vehicle(0, s, start=(1050.0, 950.0, 0.0))),
         r"vehicle 0: start \(1050\.0, 950\.0\) lies inside building 0"),
        (lambda s: dict(vehicles=_vehicle(1, s, start=(-10.0, 500.0, 0.0))),
         r"vehicle 1: start \(-10\.0, 500\.0\) lies outside the domain"),
        (lambda s: dict(vehicles=_vehicle(0, s, target=(1950.0, 1800.0))),
         r"vehicle 0: target disk .* does not lie inside the domain"),
        (lambda s: dict(kbar=0), r"kbar must be None .* integer >= 1"),
        (lambda s: dict(vehicles=_vehicle(1, s, priority=0)), r"vehicle 1: priority 0 duplicates vehicle 0"),
        (lambda s: dict(vehicles=_vehicle(1, s, priority=5)), r"vehicle 1: priority 5 is out of range 0\.\.1"),
        (lambda s: dict(grid_points=(11, 11, 20)),
         r"vehicle 0: target radius 150\.0 spans only 1\.50 grid cells .* spacing <= 60"),
        (lambda s: dict(domain_hi=(0.0, 2000.0)), r"domain is empty"),
        (lambda s: dict(planning_v=(11.0, 30.0)), r"planning_v .* inside the vehicle's speed range \[0\.0, 25\.0\]"),
        (lambda s: dict(planning_omega_max=2.5), r"planning_omega_max 2\.5 must lie in \[0, 2\.0\]"),
    ],
)
def test_bad_scenarios_name_vehicle_and_reason(make_bad, pattern):
    good = _small()
    with pytest.raises(ValueError, match=pattern):
        good.with_overrides(**make_bad(good))


def test_too_coarse_grid_names_every_vehicle_and_the_needed_grid():
    with pytest.raises(ValueError) as info:
        scenarios.make("city", n_vehicles=3, grid_points=(41, 41, 36))
    msg = str(info.value)
    assert all(f"vehicle {i}:" in msg for i in range(3)) and "spacing <= 40" in msg and "(126, 126, ...)" in msg


def test_bad_vehicle_and_building_specs():
    with pytest.raises(ValueError, match="target_radius"):
        VehicleSpec(start=(0, 0, 0), target=(1, 1), target_radius=0.0, sta=0.0, priority=0)
    with pytest.raises(ValueError, match="priority"):
        VehicleSpec(start=(0, 0, 0), target=(1, 1), target_radius=1.0, sta=0.0, priority=-1)
    with pytest.raises(ValueError, match="at least 3 vertices"):
        Building(vertices=((0, 0), (1, 0)))
    with pytest.raises(ValueError, match="zero area"):
        Building(vertices=((0, 0), (1, 0), (2, 0)))
    with pytest.raises(ValueError, match="not a simple polygon"):
        Building(vertices=((0, 0), (1, 1), (1, 0), (0, 1)))  # bow tie
    with pytest.raises(ValueError, match="coincide"):
        Building(vertices=((0, 0), (1, 0), (1, 1), (0, 0)))
    with pytest.raises(TypeError):
        VehicleSpec(start=(0, 0, 0), target=(1, 1), target_radius=1.0, sta=0.0, priority=0, colour="red")
    spec = VehicleSpec(start=[0, 0, 3 * math.pi], target=[1, 1], target_radius=1, sta=2, priority=0)
    assert spec.start == (0.0, 0.0, -math.pi) and spec.target == (1.0, 1.0)


# ------------------------------------------------------------------------------------------ geometry
@pytest.mark.slow
def test_polygon_signed_distance_unit_square_closed_forms():
    pts = np.array([
        (0.5, 0.5),    # centre: -0.5
        (0.2, 0.3),    # inside, nearest edge x = 0: -0.2
        (0.5, 1.25),   # outside near the top edge: 0.25
        (1.3, 0.6),    # outside near the right edge: 0.3
        (1.3, 1.4),    # outside near the corner (1, 1): hypot(0.3, 0.4) = 0.5
        (-0.6, -0.8),  # outside near the corner (0, 0): 1.0
        (1.0, 0.5),    # on an edge: 0
    ])
    expected = np.array([-0.5, -0.2, 0.25, 0.3, 0.5, 1.0, 0.0])
    np.testing.assert_allclose(polygon_signed_distance(UNIT_SQUARE, pts), expected, atol=1e-12)
    np.testing.assert_allclose(polygon_signed_distance(UNIT_SQUARE[::-1], pts), expected, atol=1e-12)
    np.testing.assert_allclose(np.asarray(polygon_signed_distance(UNIT_SQUARE, jnp.asarray(pts), xp=jnp)),
                               expected, atol=1e-6)
    grid_pts = pts.reshape(7, 1, 2) + np.zeros((1, 3, 2))
    assert polygon_signed_distance(UNIT_SQUARE, grid_pts).shape == (7, 3)


def test_polygon_signed_distance_nonconvex_and_sampled():
    # L-shape: the notch corner (1, 1) is reflex; (1.5, 1.5) is outside, at distance 0.5 from the notch edges.
    ell = ((0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2))
    np.testing.assert_allclose(polygon_signed_distance(ell, np.array([(1.5, 1.5), (0.5, 1.5), (1.5, 0.5)])),
                               [0.5, -0.5, -0.5], atol=1e-12)
    # distance magnitude against a dense sampling of the boundary
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.0, 3.0, (200, 2))
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    boundary = np.concatenate([np.asarray(a) + t * (np.asarray(b) - np.asarray(a))
                               for a, b in zip(ell, ell[1:] + ell[:1])])
    brute = np.min(np.linalg.norm(pts[:, None] - boundary[None], axis=-1), axis=1)
    np.testing.assert_allclose(np.abs(polygon_signed_distance(ell, pts)), brute, atol=1e-3)


def test_buildings_sdf_on_grid():
    grid = Grid.from_bounds((-1.0, -1.0, -math.pi), (2.0, 2.0, math.pi), (31, 31, 8), periodic=2)
    sdf = np.asarray(scenarios.buildings_sdf([Building(vertices=UNIT_SQUARE)], grid))
    assert sdf.shape == grid.shape
    np.testing.assert_array_equal(sdf, np.broadcast_to(sdf[:, :, :1], grid.shape))
    assert sdf[15, 15, 0] == pytest.approx(-0.5)  # (0.5, 0.5)
    assert sdf[0, 0, 3] == pytest.approx(math.sqrt(2.0))  # (-1, -1)
    empty = np.asarray(scenarios.buildings_sdf((), grid))
    assert np.all(empty == scenarios.NO_OBSTACLE_DISTANCE)


def test_city_buildings_clear_origin_targets_and_corridor(city):
    assert 15 <= len(city.buildings) <= 30
    points = np.array([CITY_ORIGIN, *sorted({v.target for v in city.vehicles})])
    radius = city.vehicles[0].target_radius
    for building in city.buildings:
        sd = building.signed_distance(points)
        assert sd[0] > 200.0 and np.all(sd[1:] > radius + 100.0)
        ys = np.array(building.vertices)[:, 1]
        assert np.all((ys < CITY_CORRIDOR_Y[0]) | (ys > CITY_CORRIDOR_Y[1]))
    assert all(v.start == city.vehicles[0].start for v in city.vehicles)  # one origin
    assert len({v.target for v in city.vehicles}) == 4
    g = np.asarray(city.static_obstacle()[:, :, 0])
    assert g.min() < 0 and (g < 0).mean() < 0.1


# ------------------------------------------------------------------------------------------ determinism
def test_same_seed_same_scenario_other_seed_differs(city):
    assert scenarios.make("city") == city
    other = scenarios.make("city", seed=1)
    assert other.buildings != city.buildings and other.vehicles != city.vehicles
    # the downtown does not depend on the number of vehicles
    assert scenarios.make("city", n_vehicles=5).buildings == city.buildings
    bay = scenarios.make("bay-area", n_vehicles=20)
    assert scenarios.make("bay-area", n_vehicles=20) == bay
    assert scenarios.make("bay-area", n_vehicles=20, seed=7).vehicles != bay.vehicles


# ------------------------------------------------------------------------------------------ town
def test_town_setup():
    from stp_env.scenarios.catalog.town import TOWN_DESTINATIONS, TOWN_ORIGIN

    s = scenarios.make("town")
    assert s.kbar == 2 and s.n_vehicles == 7 and s.vehicle.wind == 6.0 and s.method == "rtt"
    assert (s.planning_v, s.planning_omega_max, s.collision_radius, s.t_iat) == ((11.0, 13.0), 1.2, 100.0, 10.0)
    assert s.domain_lo == (0.0, 0.0) and s.domain_hi == (4000.0, 4000.0)
    assert s.grid_spacing[0] == 50.0 and s.grid_spacing[1] == 50.0
    assert np.all(s.starts() == (*TOWN_ORIGIN, 0.0))
    assert {tuple(c) for c in s.targets()} <= set(TOWN_DESTINATIONS) and len({tuple(c) for c in s.targets()}) >= 2
    assert np.all(s.target_radii() == 150.0) and 2 * 150.0 / s.grid_spacing[0] >= 5  # docs/numerics.md
    np.testing.assert_array_equal(s.stas(), 90.0 * s.priorities())
    np.testing.assert_array_equal(scenarios.make("town", kbar=1).stas(), 100.0 * s.priorities())
    # The buildings are far from the targets and from the straight routes: beyond V^S (~410 m at 6 m/s,
    # intruder paper eqs. 32-33) plus the tracking bubble, so they do not bend the routes.
    assert len(s.buildings) == 2
    for b in s.buildings:
        assert np.all(b.signed_distance(np.asarray(TOWN_DESTINATIONS)) > 1000.0)
        for c in TOWN_DESTINATIONS:
            route = np.linspace(TOWN_ORIGIN, c, 400)
            assert b.signed_distance(route).min() > 500.0


@pytest.mark.parametrize("kbar", [1, 2, 3, 4])
def test_town_kbar_range(kbar):
    assert scenarios.make("town", kbar=kbar).kbar == kbar


@pytest.mark.parametrize("bad", [0, 5, None, True, 2.0])
def test_town_rejects_other_kbar(bad):
    with pytest.raises(ValueError, match="kbar must be one of"):
        scenarios.make("town", kbar=bad)


def test_town_seed_sets_destinations_and_priorities():
    a, b = scenarios.make("town"), scenarios.make("town", seed=1)
    assert a == scenarios.make("town", seed=0)
    assert not (np.array_equal(a.priorities(), b.priorities()) and np.array_equal(a.targets(), b.targets()))
    assert a.buildings == b.buildings and a.stas().max() == 90.0 * 6
    assert scenarios.make("town", n_vehicles=8).n_vehicles == 8
