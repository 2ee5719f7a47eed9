"""``stp-env data check-plan``: the plan checker passes a shipped plan, fails one whose vehicle flies into another's
disk (naming it), fails plans that the disk check alone would pass vacuously (non-finite samples, an arrival
recorded early, a jump between samples, a control outside ``U^p``, a moved start), reads a planning checkpoint's
prefix, and refuses what it cannot check with a clear message. Also ``reconcile_controls`` and
``stp-env data reconcile-controls``, which repair a stored control that does not carry its sample to the next."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest
from _cli import run_cli

from stp_env.data_tools import check_plan
from stp_env.planning import checkpoint
from stp_env.planning.plan import plan_from_arrays, plan_to_arrays
from stp_env.planning.stp import shipped_plan
from stp_env.planning.verify import (
    obstacle_margin,
    planner_disks,
    reconcile_controls,
    trajectory_faults,
    vehicle_clearances,
)
from stp_env.scenarios import make


def _run(command, argv):
    """``(exit status, the JSON line)`` of ``stp-env data command argv``."""
    status, out, err = run_cli(["data", command, *argv])
    assert out, err
    return status, json.loads(out)


def _refused(command, argv, match):
    """``stp-env data command argv`` exits with status 2 and one line on standard error that matches ``match``."""
    status, out, err = run_cli(["data", command, *argv])
    assert status == 2 and out == "", (status, out, err)
    assert err.startswith(f"stp-env data {command}: error:") and "\n" not in err.strip(), err
    assert re.search(match, err), err


def _intruding(plan):
    """``plan`` with its lower-priority vehicle moved onto the higher-priority one's positions (same times)."""
    high, low = sorted(plan.vehicles, key=lambda v: v.priority)
    states = low.plan.states.copy()
    states[:, 0] = np.interp(low.plan.times, high.plan.times, high.plan.states[:, 0])
    states[:, 1] = np.interp(low.plan.times, high.plan.times, high.plan.states[:, 1])
    moved = dataclasses.replace(low, plan=dataclasses.replace(low.plan, states=states))
    return dataclasses.replace(plan, vehicles=tuple(moved if v is low else v for v in plan.vehicles)), low.index


def test_vehicle_clearances_give_obstacle_margins_minimum():
    scenario, plan = make("tiny"), shipped_plan("tiny")
    disks = planner_disks(scenario, plan.tracking_bound)
    rows = vehicle_clearances(plan, disks)
    assert [r[0] for r in rows] == [v.index for v in sorted(plan.vehicles, key=lambda v: v.priority)]
    assert rows[0][1] == math.inf and rows[0][2] == -1  # the first vehicle has no higher-priority disk
    margin, where = obstacle_margin(plan, disks)
    low = min(rows, key=lambda r: r[1])
    assert margin == low[1] and where == (low[0], low[2], low[3])


def test_a_shipped_plan_passes():
    status, out = _run("check-plan", ["tiny"])
    assert status == 0 and out["ok"] and out["kind"] == "shipped"
    assert out["vehicles"] == out["of"] == 2 and out["deeper_than_half_cell"] == 0 and out["late"] == 0


def test_a_vehicle_inside_anothers_disk_fails_and_is_named(tmp_path):
    bad, index = _intruding(shipped_plan("tiny"))
    path = tmp_path / "bad.npz"
    np.savez(path, **plan_to_arrays(bad))
    status, out = _run("check-plan", [str(path), "--scenario", "tiny"])
    assert status == 1 and not out["ok"]
    assert out["deeper_than_half_cell"] == 1 and out["deepest"][0]["vehicle"] == index
    assert out["worst_clearance"] < -out["half_cell"]


def test_a_checkpoint_prefix_is_checked_with_its_runs_bound(tmp_path):
    plan = shipped_plan("tiny")
    ordered = sorted(plan.vehicles, key=lambda v: v.priority)
    path = tmp_path / "tiny.ckpt.npz"
    checkpoint.save(path, "some-run", [(ordered[0].index, ordered[0].plan)])
    _refused("check-plan", [str(path), "--scenario", "tiny"], "--tracking-bound")
    status, out = _run("check-plan", [str(path), "--scenario", "tiny", "--tracking-bound", str(plan.tracking_bound)])
    assert status == 0 and out["kind"] == "checkpoint" and out["vehicles"] == 1 and out["of"] == 2


def test_what_cannot_be_checked_is_refused(tmp_path):
    _refused("check-plan", ["no-such-plan"], "neither a shipped plan")
    path = tmp_path / "mine.npz"
    np.savez(path, x=np.zeros(3))
    _refused("check-plan", [str(path)], "--scenario")
    _refused("check-plan", [str(path), "--scenario", "tiny"], "not a plan file")
    _refused("check-plan", ["tiny", "--scenario", "town"], "shipped for scenario 'tiny'")


def _with_vehicle(plan, index, **changes):
    """``plan`` with vehicle ``index``'s :class:`SinglePlan` fields replaced."""
    vehicles = tuple(dataclasses.replace(v, plan=dataclasses.replace(v.plan, **changes)) if v.index == index else v
                     for v in plan.vehicles)
    return dataclasses.replace(plan, vehicles=vehicles)


def _mutants(plan):
    """Plans of ``tiny`` broken in ways the disk, arrival and domain checks do not see, by name."""
    low = max(plan.vehicles, key=lambda v: v.priority).plan
    k = len(low.flight()[0]) // 2
    nan_states = low.states.copy()
    nan_states[k:] = np.nan
    jump = low.states.copy()
    jump[k:, 1] += 30.0  # a sideways jump of 30 m half way, then the same flight
    fast = low.controls.copy()
    fast[k, 0] = 20.0
    moved = low.states.copy()
    moved[0, 0] -= 5.0
    index = max(plan.vehicles, key=lambda v: v.priority).index
    return {
        "non-finite samples": _with_vehicle(plan, index, states=nan_states),
        "arrival recorded at the departure": _with_vehicle(plan, index, arrival_time=low.t_ldt),
        "a jump between samples": _with_vehicle(plan, index, states=jump),
        "a control outside U^p": _with_vehicle(plan, index, controls=fast),
        "a moved start": _with_vehicle(plan, index, states=moved),
    }


MUTANTS = ["non-finite samples", "arrival recorded at the departure", "a jump between samples",
           "a control outside U^p", "a moved start"]


@pytest.mark.parametrize("mutant", MUTANTS)
def test_a_plan_the_disk_check_would_pass_vacuously_fails(mutant):
    scenario = make("tiny")
    plan = _mutants(shipped_plan("tiny"))[mutant]
    faults = trajectory_faults(plan, scenario)
    index = max(plan.vehicles, key=lambda v: v.priority).index
    assert list(faults) == [index] and faults[index]
    out = check_plan.check(plan, scenario, "file")
    assert not out["ok"] and out["trajectory_faults"] == 1 and out["faulty"][0]["vehicle"] == index
    # Without the trajectory check every other criterion passes: the mutant would have been accepted.
    assert out["deeper_than_half_cell"] == 0 and out["late"] == 0 and out["mismatch"] is None
    assert out["domain_margin"] >= plan.tracking_bound


def test_every_shipped_plan_is_a_flight_of_the_planning_dynamics():
    from stp_env.assembly import SHIPPED_PLANS

    checked = 0
    for file, (name, overrides) in SHIPPED_PLANS.items():
        try:
            plan = shipped_plan(file)
        except ValueError:
            continue  # listed, not shipped
        assert trajectory_faults(plan, make(name, **overrides)) == {}, file
        checked += 1
    assert checked >= 14


def test_reconcile_controls_recovers_the_applied_control_and_refuses_a_jump():
    scenario, plan = make("tiny"), shipped_plan("tiny")
    single = next(v.plan for v in plan.vehicles if len(np.unique(v.plan.controls[:, 0])) == 2)
    runs = np.nonzero((single.controls[1:-1, 0] == single.controls[:-2, 0])
                      & (single.controls[1:-1, 0] == single.controls[2:, 0]))[0] + 1
    k = int(runs[len(runs) // 2])  # inside a run of one speed: the speed stored there is not the one applied
    wrong = single.controls.copy()
    wrong[k, 0] = sum(scenario.planning_v) - wrong[k, 0]
    broken = dataclasses.replace(single, controls=wrong)
    args = (scenario.time_step, scenario.planning_v, scenario.planning_omega_max)
    fixed, samples = reconcile_controls(broken, *args)
    assert samples == [k]
    assert np.array_equal(fixed.controls, single.controls)  # the neighbour's control, bit for bit
    assert np.array_equal(fixed.states, single.states) and fixed.arrival_time == single.arrival_time
    assert reconcile_controls(single, *args) == (single, [])  # nothing to do: the same object
    jump = single.states.copy()
    jump[k + 1:, 0] += 30.0
    with pytest.raises(ValueError, match=f"sample {k} .*not one of the planning dynamics"):
        reconcile_controls(dataclasses.replace(single, states=jump), *args)


def test_reconcile_command_rewrites_only_the_broken_control(tmp_path):
    scenario, plan = make("tiny"), shipped_plan("tiny")
    index, single = next((v.index, v.plan) for v in plan.vehicles if len(np.unique(v.plan.controls[:, 0])) == 2)
    k = int(np.nonzero(single.controls[1:-1, 0] == single.controls[:-2, 0])[0][0]) + 1
    wrong = single.controls.copy()
    wrong[k, 0] = sum(scenario.planning_v) - wrong[k, 0]
    path = tmp_path / "tiny.npz"
    arrays = plan_to_arrays(_with_vehicle(plan, index, controls=wrong))
    arrays["extra"] = np.arange(3)  # arrays the script does not know are kept
    np.savez(path, **arrays)
    before = path.read_bytes()
    status, out = _run("reconcile-controls", [str(path), "--check"])
    assert status == 1 and out["samples_fixed"] == 1 and not out["written"]
    assert path.read_bytes() == before  # --check writes nothing
    status, out = _run("reconcile-controls", [str(path)])
    assert status == 0 and out["written"] and out["fixed"] == {str(index): [k]}
    with np.load(path, allow_pickle=False) as data:
        after = {key: data[key] for key in data.files}
    assert np.array_equal(after["extra"], np.arange(3))
    expected = plan_to_arrays(plan)
    for key in expected:
        assert np.array_equal(after[key], expected[key], equal_nan=True), key
    assert trajectory_faults(plan_from_arrays(after), scenario) == {}
    assert _run("reconcile-controls", [str(path), "--check"])[0] == 0
    _refused("reconcile-controls", ["no-such-plan"], "neither a shipped plan nor a file")
