"""The dense scenarios (``corridor``, ``crossing``, ``pinwheel``) and the plan checker they are built on: the checker
measures clearances a closed form gives, the straight plans hold the planner's constraint at the catalog's spacing
and break it one second tighter (so the spacing is the tightest, and the check can fail)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stp_env.assembly import load_artifacts
from stp_env.planning.plan import InfeasiblePlanError, Plan, SinglePlan, VehiclePlan
from stp_env.planning.stp import plan_scenario
from stp_env.planning.verify import ObstacleDisks, obstacle_margin, planner_disks, straight_plan
from stp_env.scenarios import make
from stp_env.scenarios.catalog.corridor import CORRIDOR_SPACING
from stp_env.scenarios.catalog.crossing import CROSSING_SPACING
from stp_env.scenarios.catalog.pinwheel import PINWHEEL_RADIUS, PINWHEEL_SPACING


def _line(index, priority, t0, start, velocity, n=200, dt=0.5):
    times = t0 + dt * np.arange(n)
    pos = np.asarray(start)[None, :] + (times - t0)[:, None] * np.asarray(velocity)[None, :]
    states = np.concatenate([pos, np.full((n, 1), math.atan2(velocity[1], velocity[0]))], axis=1)
    single = SinglePlan(t_ldt=t0, sta=float(times[-1]), times=times, states=states,
                        controls=np.tile([np.hypot(*velocity), 0.0], (n, 1)), arrival_time=float(times[-1]), n_steps=0)
    return VehiclePlan(index=index, priority=priority, plan=single, obstacle_lags=np.zeros(1),
                       obstacle_radii=np.zeros(1))


def test_obstacle_margin_matches_the_closed_form_of_two_crossing_flights():
    # Two flights at 10 m/s crossing at right angles, the second 20 s behind: closest approach 200 / sqrt(2) m.
    a = _line(0, 0, 0.0, (-500.0, 0.0), (10.0, 0.0))
    b = _line(1, 1, 20.0, (0.0, -500.0), (0.0, 10.0))
    plan = Plan(vehicles=(a, b), tracking_bound=1.0, collision_radius=10.0, kbar=None)
    margin, (low, high, _) = obstacle_margin(plan, ObstacleDisks(np.zeros(1), np.asarray([100.0])))
    assert (low, high) == (1, 0)
    assert margin == pytest.approx(200 / math.sqrt(2) - 100.0, abs=0.5)  # sampled every 0.5 s
    # A lag moves the disk along the leader's path: 20 s back puts it on the follower (they cross together).
    lagged, _ = obstacle_margin(plan, ObstacleDisks(np.asarray([-20.0]), np.asarray([100.0])))
    assert lagged == pytest.approx(-100.0, abs=0.5)
    # The pads keep a leader's disk after it arrives; without them the follower flies clear after the end.
    early = Plan(vehicles=(_line(0, 0, 0.0, (0.0, 0.0), (10.0, 0.0), n=3), _line(1, 1, 10.0, (10.0, 20.0),
                                                                                 (0.0, 10.0), n=3)),
                 tracking_bound=1.0, collision_radius=10.0, kbar=None)
    assert obstacle_margin(early, ObstacleDisks(np.zeros(1), np.asarray([30.0])))[0] == math.inf
    assert obstacle_margin(early, ObstacleDisks(np.zeros(1), np.asarray([30.0]), 0.0, 20.0))[0] < 0


@pytest.mark.slow  # the scenarios' reachability artifacts (shared with town)
@pytest.mark.parametrize("name,spacings", [("corridor", CORRIDOR_SPACING), ("crossing", CROSSING_SPACING)])
def test_dense_scenarios_sit_at_the_tightest_spacing_the_planner_constraint_allows(name, spacings):
    for kbar in (1, 2, 3, 4):
        scenario = make(name, kbar=kbar)
        assert len(scenario.vehicles) >= 20 and scenario.method == "straight"
        _, tracking = load_artifacts(scenario, progress=False)
        disks = planner_disks(scenario, tracking.bound)
        plan = plan_scenario(scenario, tracking_bound=tracking.bound, progress=False)
        margin, _ = obstacle_margin(plan, disks)
        assert 0.0 <= margin < 13.0 * 1.0 + 1.0, (kbar, margin)  # within one second of flight of the boundary
        assert all(v.plan.arrival_time < v.plan.sta for v in plan.vehicles)
        # buffer radius drawn from the artifacts: the trail is at least that far apart at every sample
        assert disks.radii[0] > 600.0
        with pytest.raises(InfeasiblePlanError, match="inside the obstacle"):
            straight_plan(make(name, kbar=kbar, sta_spacing=spacings[kbar] - 1.0), tracking.bound, disks=disks)


def test_a_pinwheel_wave_is_an_equilateral_triangle_at_its_closest():
    # Closed form (no artifacts): the three vehicles of a wave pass their tangent points together, sqrt(3) rho apart
    # pairwise, and are never closer; the routes stay in the domain with their target disks.
    rho = 389.0
    scenario = make("pinwheel", kbar=3, radius=rho, sta_spacing=400.0, n_waves=2)
    plan = straight_plan(scenario, 5.0, check=False)
    wave = plan.vehicles[:3]
    times = wave[0].plan.times
    assert all(np.array_equal(v.plan.times, times) for v in wave)
    pos = np.stack([v.plan.states[:, :2] for v in wave])  # (3, T, 2)
    pair = [np.hypot(*(pos[a] - pos[b]).T) for a, b in ((0, 1), (1, 2), (0, 2))]
    closest = [float(d.min()) for d in pair]
    assert closest == pytest.approx([math.sqrt(3) * rho] * 3, abs=0.05)
    at_tangent = np.hypot(*(pos[:, :, :] - np.asarray([2000.0, 2000.0])).transpose(2, 0, 1)).min(axis=1)
    assert at_tangent == pytest.approx([rho] * 3, abs=0.05)  # each route touches the circle
    lo, hi = np.asarray(scenario.domain_lo), np.asarray(scenario.domain_hi)
    for spec in scenario.vehicles:
        for point in (np.asarray(spec.start[:2]), np.asarray(spec.target)):
            assert np.all(point - spec.target_radius >= lo) and np.all(point + spec.target_radius <= hi)


@pytest.mark.slow  # the reachability artifacts (shared with town)
def test_pinwheel_sits_at_the_tightest_radius_and_spacing():
    kbar = 3  # the k̄ it is for; the other radii and spacings come from the same script
    scenario = make("pinwheel", kbar=kbar)
    assert len(scenario.vehicles) >= 20 and scenario.method == "straight"
    _, tracking = load_artifacts(scenario, progress=False)
    disks = planner_disks(scenario, tracking.bound)
    margin, _ = obstacle_margin(plan_scenario(scenario, tracking_bound=tracking.bound, progress=False), disks)
    assert 0.0 <= margin < 2.0, margin  # within one metre of radius (sqrt(3) m of side) of the boundary
    # the triangle's side is the buffer radius, to the metre of radius
    assert 0.0 <= math.sqrt(3) * PINWHEEL_RADIUS[kbar] - disks.radii[0] < math.sqrt(3)
    with pytest.raises(InfeasiblePlanError, match="inside the obstacle"):
        straight_plan(make("pinwheel", kbar=kbar, radius=PINWHEEL_RADIUS[kbar] - 1.0), tracking.bound, disks=disks)
    with pytest.raises(InfeasiblePlanError, match="inside the obstacle"):
        straight_plan(make("pinwheel", kbar=kbar, sta_spacing=PINWHEEL_SPACING[kbar] - 1.0), tracking.bound,
                      disks=disks)


def test_dense_scenario_arguments_are_checked():
    with pytest.raises(ValueError, match="kbar"):
        make("corridor", kbar=5)
    with pytest.raises(ValueError, match="kbar"):
        make("crossing", kbar=0)
    with pytest.raises(ValueError, match="n_vehicles"):
        make("corridor", n_vehicles=0)
    with pytest.raises(ValueError, match="kbar"):
        make("pinwheel", kbar=5)
    with pytest.raises(ValueError, match="n_waves"):
        make("pinwheel", n_waves=0)
    with pytest.raises(ValueError, match="radius"):
        make("pinwheel", radius=1500.0)
    with pytest.raises(ValueError, match="does not point"):
        straight_plan(make("town").with_overrides(method="straight"), 5.0,
                      disks=ObstacleDisks(np.zeros(1), np.ones(1)))
