"""The planner's exact check of each nominal trajectory against the higher-priority disks, and the re-plan with the
disks grown when a trajectory comes deeper into one than the tolerance."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from stp_env.planning import stp
from stp_env.planning.plan import InfeasiblePlanError, SinglePlan
from stp_env.planning.verify import flight_clearance, obstacle_margin, planner_disks

R_E = 5.337635040283203


def _flight(ts, xy):
    states = np.column_stack([xy, np.zeros(len(ts))])
    return SinglePlan(t_ldt=float(ts[0]), sta=float(ts[-1]) + 1.0, times=np.asarray(ts, float), states=states,
                      controls=np.zeros((len(ts), 2)), arrival_time=float(ts[-1]), n_steps=0)


def test_flight_clearance_is_the_closed_form_depth_into_a_moving_disk():
    # The higher-priority vehicle flies along the x axis at 1 m/s from the origin (t = 0 .. 10 s); the lower one
    # hovers at (5, 3) over the same times. A disk of radius 4: 1 m deep at t = 5 s.
    ts = np.linspace(0.0, 10.0, 101)
    high = (ts, np.column_stack([ts, np.zeros_like(ts)]), 0.0, 10.0)
    low = np.tile([5.0, 3.0, 0.0], (len(ts), 1))
    gap, j, t = flight_clearance(ts, low, [high], [0.0], [4.0])
    assert (gap, j, t) == (pytest.approx(-1.0), 0, pytest.approx(5.0))
    # Lag 2 s: the disk is at p(t + 2), so the deepest point comes 2 s earlier.
    gap, j, t = flight_clearance(ts, low, [high], [2.0], [4.0])
    assert (gap, j, t) == (pytest.approx(-1.0), 0, pytest.approx(3.0))
    # The disk is present only while t + lag lies in its window: ending at 4 s it is deepest then, at (4, 0).
    gap, _, t = flight_clearance(ts, low, [(*high[:2], 0.0, 4.0)], [0.0], [4.0])
    assert (gap, t) == (pytest.approx(math.hypot(1.0, 3.0) - 4.0), pytest.approx(4.0))
    # No disk present together with the flight: infinitely clear.
    gap, j, t = flight_clearance(ts, low, [(*high[:2], 20.0, 30.0)], [0.0], [4.0])
    assert gap == math.inf and j == -1 and math.isnan(t)


def test_obstacle_margin_of_the_shipped_tiny_plan_is_its_second_vehicles_clearance():
    from stp_env.planning.plan import obstacle_window
    from stp_env.scenarios import make

    plan = stp.shipped_plan("tiny")
    disks = planner_disks(make("tiny"), plan.tracking_bound)
    high, low = sorted(plan.vehicles, key=lambda v: v.priority)
    want = flight_clearance(*low.plan.flight(), [obstacle_window(high.plan, (disks.pad_before, disks.pad_after))],
                            disks.lags, disks.radii)
    assert obstacle_margin(plan, disks) == (want[0], (low.index, high.index, want[2]))


# A higher-priority vehicle parked at the origin for 100 s, a 10 m disk around it, and a planner whose flight passes
# the origin at y = 2 m + the growth of the disks it was given: 8 m deep at first, clear once grown by 8 m.
WINDOWS = [(np.array([0.0, 100.0]), np.zeros((2, 3)), 0.0, 100.0)]
LAGS, RADII = np.array([0.0]), np.array([10.0])


def _passing(grown: list, offset=lambda grow: 2.0 + grow, infeasible_after: int | None = None):
    def plan_with(grow):
        grown.append(grow)
        if infeasible_after is not None and len(grown) > infeasible_after:
            raise InfeasiblePlanError("no departure with the grown disks", -math.inf)
        ts = np.linspace(0.0, 20.0, 201)
        return _flight(ts, np.column_stack([ts - 10.0, np.full_like(ts, offset(grow))]))

    return plan_with


def _clearance(single):
    return flight_clearance(*single.flight(), WINDOWS, LAGS, RADII)[0]


def test_a_trajectory_within_the_tolerance_is_planned_once():
    grown = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        single = stp.plan_clear_of_disks(_passing(grown), WINDOWS, LAGS, RADII, 8.5, "v")
    assert grown == [0.0] and _clearance(single) == pytest.approx(-8.0)


def test_a_trajectory_too_deep_is_planned_again_with_the_disks_grown_by_its_depth():
    grown = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        single = stp.plan_clear_of_disks(_passing(grown), WINDOWS, LAGS, RADII, 1.0, "v")
    assert grown == pytest.approx([0.0, 8.0]) and _clearance(single) == pytest.approx(0.0, abs=1e-9)
    # Growth that only halves the depth each time: grown by the sum of the depths, then the shallowest is kept and
    # the remaining depth reported.
    grown = []
    with pytest.warns(UserWarning, match=r"vehicle 3: .* 2\.0 m inside .*tolerance 0\.5 m; the shallowest of 3"):
        single = stp.plan_clear_of_disks(_passing(grown, lambda g: 2.0 + g / 2), WINDOWS, LAGS, RADII, 0.5,
                                          "vehicle 3")
    assert grown == pytest.approx([0.0, 8.0, 12.0]) and _clearance(single) == pytest.approx(-2.0)


def test_when_the_grown_disks_leave_no_departure_the_first_plan_is_kept_and_reported():
    grown = []
    with pytest.warns(UserWarning, match="8.0 m inside"):
        single = stp.plan_clear_of_disks(_passing(grown, infeasible_after=1), WINDOWS, LAGS, RADII, 1.0, "v")
    assert grown == pytest.approx([0.0, 8.0]) and _clearance(single) == pytest.approx(-8.0)
    with pytest.raises(InfeasiblePlanError):  # infeasible with the true disks: the planner's error, unchanged
        stp.plan_clear_of_disks(_passing([], infeasible_after=0), WINDOWS, LAGS, RADII, 1.0, "v")


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf])
def test_disk_tolerance_must_be_a_finite_depth(bad):
    from stp_env.scenarios import make

    with pytest.raises(ValueError, match="disk_tolerance"):
        stp.plan_scenario(make("tiny"), tracking_bound=R_E, progress=False, disk_tolerance=bad)


@pytest.mark.slow
def test_tiny_planned_with_no_tolerance_replans_its_second_vehicle_clear_of_the_first(monkeypatch):
    """The shipped ``tiny`` plan's second vehicle flies 13.6 m into the first's disk (within the default tolerance,
    half of a 50 m cell). Planned with no tolerance it is planned again with the disk grown, and comes out clear of
    the true disk; the first vehicle is planned exactly as before."""
    from stp_env.scenarios import make

    scenario = make("tiny")
    shipped = stp.shipped_plan("tiny")
    disks = planner_disks(scenario, shipped.tracking_bound)
    before, _ = obstacle_margin(shipped, disks)
    assert before < -10.0
    calls = []
    real = stp._plan_one

    def counted(*args, **kwargs):
        calls.append(kwargs["who"])
        return real(*args, **kwargs)

    monkeypatch.setattr(stp, "_plan_one", counted)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plan = stp.plan_scenario(scenario, tracking_bound=shipped.tracking_bound, progress=False,
                                 disk_tolerance=0.0)
    first = min(plan.vehicles, key=lambda v: v.priority)
    assert calls.count((first.index, 0)) == 1
    assert calls.count((1 - first.index, 1)) >= 2
    np.testing.assert_array_equal(first.plan.states, shipped.vehicles[first.index].plan.states)
    after, _ = obstacle_margin(plan, disks)
    assert after > before + 10.0, (before, after)
    assert all(v.plan.arrival_time <= v.plan.sta for v in plan.vehicles)


def test_replanning_checks_the_new_trajectory_against_the_exact_disks(monkeypatch):
    """Algorithm 4's replan runs the same check: the replanned vehicle against every other vehicle's padded window,
    with the plan's disks, half a cell of tolerance, and the disks grown by what the check asks for."""
    import dataclasses

    import stp_env.planning.replan as replan_mod
    from stp_env.scenarios import make

    scenario = make("tiny")
    plan = dataclasses.replace(stp.shipped_plan("tiny"), obstacle_pads=(7.0, 3.0))
    seen = {}

    class Stop(Exception):
        """Ends the replan at the obstacles (the solve is not what this test checks)."""

    def check(plan_with, windows, lags, radii, tolerance, name):
        seen.update(windows=[(w[2], w[3]) for w in windows], lags=lags, radii=radii, tolerance=tolerance, name=name)
        plan_with(12.5)

    def obstacles(grid, trajectories, lags, radii, *args, **kwargs):
        seen["grown"] = np.asarray(radii)
        raise Stop

    monkeypatch.setattr(replan_mod, "plan_clear_of_disks", check)
    monkeypatch.setattr(replan_mod, "planning_obstacles", obstacles)
    with pytest.raises(Stop):
        replan_mod.replan(plan, scenario, {1: (0.0, 0.0, 0.0)}, -60.0)
    kept = plan.vehicles[0].plan
    assert seen["windows"] == [(kept.t_ldt - 7.0, kept.arrival_time + 3.0)]
    np.testing.assert_array_equal(seen["lags"], plan.vehicles[0].obstacle_lags)
    np.testing.assert_array_equal(seen["radii"], plan.vehicles[0].obstacle_radii)
    np.testing.assert_array_equal(seen["grown"], plan.vehicles[0].obstacle_radii + 12.5)
    assert seen["tolerance"] == 0.5 * max(scenario.grid().spacing[:2]) and seen["name"] == "vehicle 1"
