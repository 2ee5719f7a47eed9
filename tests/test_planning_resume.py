"""The heading-split planning BRS against the unsplit solver and brute force; resumable sequential planning."""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from _cli import run_cli

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning import checkpoint
from stp_env.planning.brs import heading_min_filter
from stp_env.planning.problem import PlanningProblem
from stp_env.planning.single import plan_single
from stp_env.planning.stp import plan_rtt, plan_to_arrays

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)
PLANNER = DubinsWind(v_min=0.5, v_max=0.6, omega_max=0.5, wind=0.0)
GRID = hj.Grid.from_bounds((-1.5, -1.5, -np.pi), (1.5, 1.5, np.pi), (31, 31, 16), periodic=2)  # coarse: fast
STARTS = [(-1.2, 0.0, 0.0), (0.0, -1.2, np.pi / 2), (-1.2, -1.2, np.pi / 4)]
TARGETS = [(1.2, 0.0), (0.0, 1.2), (1.1, 1.1)]


@pytest.mark.parametrize("width", [0.0, 0.4, 1.0, 1.91, 2.5])
def test_heading_window_is_the_minimum_of_the_interpolant(width):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(3, 2, 12)).astype(np.float32)
    got = np.asarray(heading_min_filter(jnp.asarray(v), width))
    # Brute force: the periodic piecewise-linear interpolant sampled densely over [j - width, j + width].
    n = v.shape[-1]
    offsets = np.linspace(-width, width, 2001)
    want = np.empty_like(v)
    for j in range(n):
        pos = (j + offsets) % n
        lo = np.floor(pos).astype(int)
        w = pos - lo
        samples = (1 - w) * v[..., lo] + w * v[..., (lo + 1) % n]
        want[..., j] = samples.min(axis=-1)
    np.testing.assert_allclose(got, want, atol=2e-3 * max(width, 1e-3) + 1e-6)
    assert np.all(got <= want + 1e-6)  # the exact minimum is never above a sampled one


@pytest.mark.slow
def test_split_solver_matches_the_straight_path_and_the_unsplit_solver():
    start, target, r = (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2
    split = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=4.0, time_step=0.05, solver="split")
    full = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=4.0, time_step=0.05, solver="hj")
    dx = GRID.spacing[0]
    exact = -(2.0 - r) / PLANNER.v_max
    assert split.t_ldt == pytest.approx(exact, abs=dx / PLANNER.v_max)
    assert split.t_ldt == pytest.approx(full.t_ldt, abs=dx / PLANNER.v_max)
    assert split.arrival_time <= 0.05 + (split.t_ldt - exact) + 1e-6
    assert np.all(np.abs(split.flight()[1][:, 1]) < dx)


@pytest.mark.slow
def test_split_step_is_set_by_the_position_axes_on_the_city_grid():
    # City grid and U^p: the unsplit CFL step is limited by the turn rate (w_max / dth = 4.6 /s); the split one by
    # the position (0.55 /s) and the cap of MAX_TURN_PER_STEP rad of turn per step.
    from stp_env.planning.brs import MAX_TURN_PER_STEP, split_time_step
    from stp_env.scenarios import make

    grid = make("city").grid()
    planner = DubinsWind(v_min=11.0, v_max=13.0, omega_max=1.2, wind=0.0)
    settings = hj.SolverSettings.with_accuracy("medium")
    unsplit, _ = hj.cfl_time_step(settings, planner, grid)
    split = split_time_step(settings, planner, grid)
    assert unsplit == pytest.approx(0.75 / (1.2 / grid.spacing[2] + 13.0 * math.sqrt(2) / grid.spacing[0]), rel=1e-3)
    assert split == pytest.approx(MAX_TURN_PER_STEP / 1.2)
    assert split > 2.5 * unsplit


def _problem(starts=STARTS, targets=TARGETS, stas=(0.0, 0.0, 0.0), priorities=None, **fields):
    return PlanningProblem.dubins(GRID, VEHICLE, (0.5, 0.6), 0.5, 0.05, 0.2, starts, targets, 0.25, list(stas),
                                  priorities, horizon=8.0, **fields)


def _plan(tmp_path=None, on_vehicle=None, stas=(0.0, 0.0, 0.0)):
    return plan_rtt(_problem(stas=stas, priorities=[2, 0, 1]), progress=False,
                    checkpoint=None if tmp_path is None else tmp_path / "ck.npz", on_vehicle=on_vehicle)


class _Stop(Exception):
    pass


@pytest.mark.slow
def test_interrupted_planning_resumes_to_the_same_plan_bit_for_bit(tmp_path):
    reference = plan_to_arrays(_plan())
    seen = []

    def stop_after_two(rank, index, plan):
        seen.append((rank, index))
        if rank == 1:
            raise _Stop

    with pytest.raises(_Stop):
        _plan(tmp_path, stop_after_two)
    assert seen == [(0, 1), (1, 2)]  # priorities [2, 0, 1]: vehicle 1 first, then 2
    # The checkpoint holds the two planned vehicles; resuming plans only the third.
    resumed_calls = []
    resumed = plan_to_arrays(_plan(tmp_path, lambda rank, index, plan: resumed_calls.append(rank)))
    assert resumed_calls == [2]
    assert sorted(resumed) == sorted(reference)
    for key in reference:
        assert np.asarray(resumed[key]).tobytes() == np.asarray(reference[key]).tobytes(), key
    # A finished checkpoint replans nothing; one of another problem is refused, and left as it was.
    again = []
    _plan(tmp_path, lambda rank, index, plan: again.append(rank))
    assert again == []
    before = (tmp_path / "ck.npz").read_bytes()
    with pytest.raises(checkpoint.CheckpointMismatchError, match="another planning problem"):
        _plan(tmp_path, stas=(0.0, 1.0, 0.0))
    assert (tmp_path / "ck.npz").read_bytes() == before


@pytest.mark.parametrize("file_format", checkpoint.FORMATS)
def test_checkpoint_round_trip_and_bad_files(tmp_path, file_format):
    from stp_env.planning.plan import SinglePlan

    p = SinglePlan(t_ldt=-3.5, sta=0.0, times=np.array([-3.5, -3.4]), states=np.arange(6.0).reshape(2, 3),
                   controls=np.ones((2, 2)), arrival_time=math.inf, n_steps=7)
    q = SinglePlan(t_ldt=-1.0, sta=2.0, times=np.array([-1.0]), states=np.zeros((1, 3)), controls=np.zeros((1, 2)),
                   arrival_time=0.5, n_steps=3)
    path = tmp_path / "sub" / "ck.npz"
    checkpoint.save(path, "k1", [(4, p), (0, q)], file_format=file_format)
    (i0, a), (i1, b) = checkpoint.load(path, "k1")
    assert (i0, i1) == (4, 0)
    for x, y in ((a, p), (b, q)):
        assert x.t_ldt == y.t_ldt and x.sta == y.sta and x.arrival_time == y.arrival_time and x.n_steps == y.n_steps
        for f in ("times", "states", "controls"):
            assert getattr(x, f).tobytes() == getattr(y, f).tobytes()
    assert list(tmp_path.joinpath("sub").iterdir()) == [path]  # no temporary file left behind
    with pytest.raises(checkpoint.CheckpointMismatchError):
        checkpoint.load(path, "k2")
    assert checkpoint.load(tmp_path / "absent.npz", "k1") == []
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable"):
        checkpoint.load(bad, "k1")
    assert checkpoint.problem_key(np.zeros(2), "a") != checkpoint.problem_key(np.zeros(3), "a")
    np.savez(bad, **{**dict(np.load(path)), "format": np.asarray(3)})
    with pytest.raises(ValueError, match="not a checkpoint of formats"):
        checkpoint.load(bad, "k1")
    with pytest.raises(ValueError, match="file_format"):
        checkpoint.save(bad, "k1", [(4, p)], file_format=3)


def test_a_converted_checkpoint_keeps_its_key_and_bits_and_the_compact_one_is_smaller(tmp_path):
    from stp_env.planning.plan import SinglePlan

    rng = np.random.default_rng(0)
    plans = []
    for i in range(3):  # smooth trajectories, as a planner's are, of different lengths
        m = 400 + 50 * i
        times = -40.0 + 0.1 * np.arange(m)
        heading = np.cumsum(rng.uniform(-0.05, 0.05, m))
        states = np.stack([np.cumsum(1.2 * np.cos(heading)), np.cumsum(1.2 * np.sin(heading)), heading], axis=1)
        plans.append((2 - i, SinglePlan(t_ldt=float(times[0]), sta=0.0, times=times, states=states,
                                        controls=np.tile([12.0, 0.3], (m, 1)), arrival_time=float(times[-5]),
                                        n_steps=11)))
    one, two, back = tmp_path / "one.npz", tmp_path / "two.npz", tmp_path / "back.npz"
    checkpoint.save(one, "the-key", plans, file_format=1)
    assert checkpoint.convert(one, two, 2) == 3 and checkpoint.convert(two, back, 1) == 3
    with np.load(one) as a, np.load(back) as b:
        assert sorted(a.files) == sorted(b.files)
        assert all(a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes() for k in a.files)
    with np.load(two) as c:
        assert int(c["format"]) == 2 and "times" not in c.files
    assert two.stat().st_size < one.stat().st_size / 2
    for (i, x), (j, y) in zip(checkpoint.load(two, "the-key"), plans):
        assert i == j and x.states.tobytes() == y.states.tobytes() and x.times.tobytes() == y.times.tobytes()
    with pytest.raises(checkpoint.CheckpointMismatchError):
        checkpoint.load(two, "another-key")
    code, out, _ = run_cli(["data", "convert-checkpoint", str(two), str(tmp_path / "again.npz"), "--format", "1"])
    assert code == 0 and json.loads(out)["vehicles"] == 3
    assert (tmp_path / "again.npz").read_bytes() != b"" and checkpoint.load(tmp_path / "again.npz", "the-key")
    code, out, err = run_cli(["data", "convert-checkpoint", str(tmp_path / "absent.npz"), str(tmp_path / "x.npz")])
    assert code == 2 and out == "" and "stp-env data convert-checkpoint: error:" in err and "no such file" in err


@pytest.mark.slow
def test_a_split_trajectory_that_never_arrives_is_planned_with_the_unsplit_solver(monkeypatch):
    import dataclasses

    import stp_env.planning.stp as stp

    calls = []
    original = stp.plan_single

    def split_never_arrives(*args, **kwargs):
        calls.append(kwargs["solver"])
        plan = original(*args, **kwargs)
        return dataclasses.replace(plan, arrival_time=math.inf) if kwargs["solver"] == "split" else plan

    monkeypatch.setattr(stp, "plan_single", split_never_arrives)
    with pytest.warns(UserWarning, match="never reaches the target"):
        plan = plan_rtt(_problem(STARTS[:1], TARGETS[:1], [0.0]), progress=False)
    assert calls == ["split", "hj"]
    assert plan.vehicles[0].plan.arrival_time <= 0.0


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_max_slice_dt_must_be_a_positive_number(bad):
    with pytest.raises(ValueError, match="max_slice_dt"):
        _problem(max_slice_dt=bad)


@pytest.mark.slow
def test_the_slice_spacing_is_part_of_the_checkpoint_key(tmp_path):
    def plan(cap, on_vehicle):
        # horizon / 200 = 0.04 s above the 0.02 s time step: a cap of 0.03 s changes the slices, one of 0.05 s does not
        return plan_rtt(_problem(time_step=0.02, max_slice_dt=cap), progress=False, checkpoint=tmp_path / "ck.npz",
                        on_vehicle=on_vehicle)

    def stop(rank, index, single):
        raise _Stop

    with pytest.raises(_Stop):
        plan(None, stop)  # one vehicle planned and checkpointed with 0.04 s slices
    with pytest.raises(checkpoint.CheckpointMismatchError):
        plan(0.03, stop)
    resumed = []

    def record(rank, index, single):
        resumed.append(rank)
        raise _Stop

    with pytest.raises(_Stop):
        plan(0.05, record)  # the same slices: the checkpoint is accepted and the second vehicle is next
    assert resumed == [1]
