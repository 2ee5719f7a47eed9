"""``scripts/check_plan.py``: the plan checker passes a shipped plan, fails one whose vehicle flies into another's
disk (naming it), reads a planning checkpoint's prefix, and refuses what it cannot check with a clear message."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from stp_env.planning import checkpoint
from stp_env.planning.plan import plan_to_arrays
from stp_env.planning.stp import shipped_plan
from stp_env.planning.verify import obstacle_margin, planner_disks, vehicle_clearances
from stp_env.scenarios import make

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "check_plan.py"


@pytest.fixture(scope="module")
def check_plan():
    spec = importlib.util.spec_from_file_location("check_plan", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(module, argv, capsys):
    status = module.main(argv)
    return status, json.loads(capsys.readouterr().out)


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


def test_a_shipped_plan_passes(check_plan, capsys):
    status, out = _run(check_plan, ["tiny"], capsys)
    assert status == 0 and out["ok"] and out["kind"] == "shipped"
    assert out["vehicles"] == out["of"] == 2 and out["deeper_than_half_cell"] == 0 and out["late"] == 0


def test_a_vehicle_inside_anothers_disk_fails_and_is_named(check_plan, capsys, tmp_path):
    bad, index = _intruding(shipped_plan("tiny"))
    path = tmp_path / "bad.npz"
    np.savez(path, **plan_to_arrays(bad))
    status, out = _run(check_plan, [str(path), "--scenario", "tiny"], capsys)
    assert status == 1 and not out["ok"]
    assert out["deeper_than_half_cell"] == 1 and out["deepest"][0]["vehicle"] == index
    assert out["worst_clearance"] < -out["half_cell"]


def test_a_checkpoint_prefix_is_checked_with_its_runs_bound(check_plan, capsys, tmp_path):
    plan = shipped_plan("tiny")
    ordered = sorted(plan.vehicles, key=lambda v: v.priority)
    path = tmp_path / "tiny.ckpt.npz"
    checkpoint.save(path, "some-run", [(ordered[0].index, ordered[0].plan)])
    with pytest.raises(SystemExit, match="--tracking-bound"):
        check_plan.main([str(path), "--scenario", "tiny"])
    status, out = _run(check_plan, [str(path), "--scenario", "tiny", "--tracking-bound", str(plan.tracking_bound)],
                       capsys)
    assert status == 0 and out["kind"] == "checkpoint" and out["vehicles"] == 1 and out["of"] == 2


def test_what_cannot_be_checked_is_refused(check_plan, tmp_path):
    with pytest.raises(SystemExit, match="neither a shipped plan"):
        check_plan.main(["no-such-plan"])
    path = tmp_path / "mine.npz"
    np.savez(path, x=np.zeros(3))
    with pytest.raises(SystemExit, match="--scenario"):
        check_plan.main([str(path)])
    with pytest.raises(SystemExit, match="not a plan file"):
        check_plan.main([str(path), "--scenario", "tiny"])
    with pytest.raises(SystemExit, match="shipped for scenario 'tiny'"):
        check_plan.main(["tiny", "--scenario", "town"])
