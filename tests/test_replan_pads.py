"""Replanning keeps the windows in which the original plan held each vehicle's disks: the flight widened by the
pads of the folded lag disks (``stp_env.planning.disks.fold_contained_disks``), recorded in the plan or derived
again for plan files that predate the record."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from stp_env.planning import replan as replan_mod
from stp_env.planning.plan import Plan, SinglePlan, VehiclePlan, obstacle_window, plan_from_arrays, plan_to_arrays
from stp_env.planning.stp import fold_contained_disks, obstacle_disks, shipped_plan, shipped_plan_for
from stp_env.scenarios import make


def _single(t0: float, arrival: float) -> SinglePlan:
    times = t0 + np.arange(6, dtype=float)
    states = np.column_stack([10.0 * np.arange(6), np.zeros(6), np.zeros(6)])
    return SinglePlan(t_ldt=t0, sta=t0 + 5.0, times=times, states=states, controls=np.ones((6, 2)),
                      arrival_time=arrival, n_steps=3)


def _plan(pads, lags=(0.0,), radii=(100.0,), kbar=None) -> Plan:
    vehicles = tuple(VehiclePlan(index=i, priority=i, plan=_single(10.0 * i, 10.0 * i + 3.0),
                                 obstacle_lags=np.asarray(lags), obstacle_radii=np.asarray(radii)) for i in range(2))
    return Plan(vehicles=vehicles, tracking_bound=5.0, collision_radius=90.0, kbar=kbar, obstacle_pads=pads)


def test_obstacle_disks_fold_the_lag_profiles_into_the_lag0_disk():
    prof = type("Profile", (), {"lags": np.array([-4.0, 2.0, 30.0]), "radii": np.array([50.0, 60.0, 10.0])})
    lags, radii, before, after = obstacle_disks(90.0, 5.0, 13.0, 400.0, {"a": prof})
    ref = fold_contained_disks(np.array([0.0, -4.0, 2.0, 30.0]), np.array([400.0, 55.0, 65.0, 15.0]), 13.0)
    np.testing.assert_array_equal(lags, ref[0])
    np.testing.assert_array_equal(radii, ref[1])
    assert (before, after) == (ref[2], ref[3]) == (2.0, 4.0)
    # the lag-30 disk reaches outside the 400 m disk (15 + 13 x 30 > 400) and stays; the other two fold
    np.testing.assert_array_equal(lags, [0.0, 30.0])
    assert obstacle_disks(90.0, 5.0, 13.0)[2:] == (0.0, 0.0)    # without k̄: the lag-0 disk only
    with pytest.raises(ValueError, match="go together"):
        obstacle_disks(90.0, 5.0, 13.0, 400.0, None)


def test_plan_files_keep_the_pads_and_refuse_bad_ones():
    plan = _plan((10.0, 2.5), kbar=2)
    arrays = plan_to_arrays(plan)
    assert plan_from_arrays(arrays).obstacle_pads == (10.0, 2.5)
    unrecorded = {k: v for k, v in arrays.items() if k != "obstacle_pads"}
    assert plan_from_arrays(unrecorded).obstacle_pads is None
    assert "obstacle_pads" not in plan_to_arrays(dataclasses.replace(plan, obstacle_pads=None))
    for bad in ([1.0], [np.nan, 0.0], [-1.0, 0.0]):
        with pytest.raises(ValueError, match="obstacle_pads"):
            plan_from_arrays({**arrays, "obstacle_pads": np.asarray(bad)})


def test_the_shipped_planner_records_its_pads():
    assert shipped_plan("tiny").obstacle_pads == (0.0, 0.0)


def test_a_window_holds_the_disks_for_the_pads_around_the_flight():
    single = _single(0.0, 3.0)
    times, states, start, end = obstacle_window(single, (10.0, 2.5))
    assert (start, end) == (-10.0, 5.5) and times[-1] == 3.0 and len(states) == 4
    never = dataclasses.replace(single, arrival_time=np.inf)
    assert obstacle_window(never, (0.0, 1.0))[3] == 6.0       # the last sample, widened


def test_unrecorded_pads_are_derived_from_the_scenario_or_bounded():
    town = make("town", kbar=2)
    plan = shipped_plan_for("town", 2)
    assert plan.obstacle_pads is None                                    # a file from before the record
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pads = replan_mod.obstacle_pads(plan, town)
    # measured: every lag disk of the town's k̄ = 2 profiles folds into the buffer disk, the longest lag 10 s
    assert pads == (10.0, 10.0)
    assert replan_mod.obstacle_pads(dataclasses.replace(plan, obstacle_pads=(1.0, 2.0)), town) == (1.0, 2.0)
    # disks that are not the scenario's: the bound rho_0 / v on every folded lag, with a warning
    other = dataclasses.replace(plan, vehicles=tuple(
        dataclasses.replace(v, obstacle_radii=v.obstacle_radii + 1.0) for v in plan.vehicles))
    with pytest.warns(UserWarning, match="does not record"):
        bound = replan_mod.obstacle_pads(other, town)
    rho0 = float(other.vehicles[0].obstacle_radii[0])
    assert bound == (rho0 / town.planning_v[1],) * 2 and bound[0] > 10.0
    # without k̄ and one disk nothing was folded
    assert replan_mod.obstacle_pads(_plan(None), make("tiny")) == (0.0, 0.0)


def test_replanning_passes_the_padded_windows_to_the_obstacles(monkeypatch):
    """The windows ``replan`` gives the moving obstacles are the original plan's: flights widened by the pads (a
    replan that used the bare flights would miss the folded disks before departures and after arrivals)."""
    scenario = make("tiny")
    plan = dataclasses.replace(shipped_plan("tiny"), obstacle_pads=(7.0, 3.0))
    seen = {}

    class Stop(Exception):
        """Ends the replan once the obstacles are built (the solve is not what this test checks)."""

    def capture(grid, trajectories, *args, **kwargs):
        seen["windows"] = [(start, end) for *_, start, end in trajectories]
        raise Stop

    monkeypatch.setattr(replan_mod, "planning_obstacles", capture)
    kept = plan.vehicles[0].plan
    with pytest.raises(Stop):
        replan_mod.replan(plan, scenario, {1: (0.0, 0.0, 0.0)}, -60.0)
    end = kept.arrival_time if np.isfinite(kept.arrival_time) else kept.times[-1]
    assert seen["windows"] == [(kept.t_ldt - 7.0, end + 3.0)]


def test_straight_plans_record_the_pads_of_their_disks():
    from stp_env.planning.verify import ObstacleDisks, straight_plan

    scenario = make("pinwheel", kbar=3, radius=389.0, sta_spacing=400.0, n_waves=2)
    assert straight_plan(scenario, 5.0, check=False).obstacle_pads is None      # no disks given: not known
    disks = ObstacleDisks(np.zeros(1), np.array([10.0]), pad_before=4.0, pad_after=1.5)
    assert straight_plan(scenario, 5.0, disks=disks, check=False).obstacle_pads == (4.0, 1.5)
