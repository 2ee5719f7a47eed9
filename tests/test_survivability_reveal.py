"""When an unknown intruder becomes known (``PlannerConfig(reveal=...)``; the survivability paper, Section III-B:
"the ownship is unaware of the intruder's existence until the ownship encounters a conflict with the intruder"):
``segment`` (the default: a conflict anywhere on the next segment, seen at the decision point), ``step`` (a conflict
in the next time step) and ``radius`` (as ``step``, and any intruder within ``sense_km``), on hand-made situations
of a 12 x 12 km mission."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stp_env.survivability import dp
from stp_env.survivability.config import POLICIES, REVEAL_MODELS, SFO, MissionConfig, PlannerConfig, TrafficConfig
from stp_env.survivability.graph import build_graph
from stp_env.survivability.mission import Instance, Knowledge, choose, make_instance, run_mission
from stp_env.survivability.network import build_network
from stp_env.survivability.traffic import Traffic, occupancy

ONE_CELL = 1000.0 / 300.0       # m/s: one 1 km cell per 5-minute window
PLANNER = dict(n_mc=64, n_survival=64)


def small() -> MissionConfig:
    """The 12 x 12 km mission of ``tests/test_survivability.py`` (8 headings, speeds 0..2 cells per window)."""
    return MissionConfig(area_km=12, dh_max=45, n_increments=3, dv_max=ONE_CELL, v_max=2 * ONE_CELL,
                         rta_min=(25, 35), endurance_min=50, departure_heading=0, goal_headings=(0, 45),
                         alternate_headings=(0, 90, 180, 270), alternates=(SFO,),
                         positions_km=((1.5, 1.5), (6.5, 4.5), (7.5, 6.5)))


@pytest.fixture(scope="module")
def graph():
    return build_graph(build_network(small()))


def planner(reveal="segment", sense_km=None) -> PlannerConfig:
    return PlannerConfig(**PLANNER, reveal=reveal, sense_km=sense_km)


def occupancy_instance(g, occ) -> Instance:
    """Intruders known only through their cells ``occ`` ``(n_cells, N)`` (unknown, never sensed: they fly before
    departure in ``traffic``): every segment's robustness is 1 and no realisation blocks anything."""
    n = occ.shape[1]
    far = Traffic(np.zeros((n, 4, 2)), np.zeros((n, 4, 2)), np.full(n, -10.0), np.ones(n), 0)
    return Instance(far, np.ones(g.n_segments, np.float32), occ, blocked_bits=np.zeros((g.n_segments, 2), np.uint32))


def hovering_instance(g, points) -> Instance:
    """Unknown hovering intruders, one per ``(x_km, y_km, t_in, duration)``; their cells from their paths."""
    ctrl = np.repeat(np.array([[p[0], p[1]] for p in points], float)[:, None, :], 4, axis=1)
    traffic = Traffic(ctrl, ctrl.copy(), np.array([p[2] for p in points], float),
                      np.array([p[3] for p in points], float), 0)
    occ = occupancy(traffic, g.net.mission, 6, g.cell_id, g.n_cells)
    return Instance(traffic, np.ones(g.n_segments, np.float32), occ,
                    blocked_bits=np.zeros((g.n_segments, 2), np.uint32))


def free_mission(g):
    """The mission of pi_S with no traffic (the same under every reveal model: nothing to reveal)."""
    res = run_mission(g, occupancy_instance(g, np.zeros((g.n_cells, 0), bool)), "S", planner())
    assert res.outcome == "G" and res.revealed == () and res.reveal_minutes == () and res.conflict_minute is None
    return res


def flown(g, path, i):
    """``(state, primitive, segment, minute)`` of the ``i``-th segment of ``path`` (``minute``: its decision's time
    step since departure)."""
    a = int(np.flatnonzero(g.succ[path[i]] == path[i + 1])[0])
    return path[i], a, int(g.seg[path[i], a]), g.net.window_start_minute(g.window_of(path[i]))


def segment_cells_at(g, seg, minute):
    cells = g.seg_cells[seg][g.seg_cells[seg] >= 0]
    return cells[g.cells[cells, 2] == minute]


def test_reveal_options_are_validated():
    assert PlannerConfig().reveal == "segment" and PlannerConfig().sense_km is None
    assert REVEAL_MODELS == ("segment", "step", "radius")
    with pytest.raises(ValueError, match="reveal must be one of segment, step, radius"):
        PlannerConfig(reveal="conflict")
    with pytest.raises(ValueError, match="needs a sensing radius sense_km"):
        PlannerConfig(reveal="radius")
    for model in ("segment", "step"):
        with pytest.raises(ValueError, match="sense_km applies to reveal='radius' only"):
            PlannerConfig(reveal=model, sense_km=2.0)
    with pytest.raises(ValueError, match="sense_km must be > 0"):
        PlannerConfig(reveal="radius", sense_km=0.0)
    with pytest.raises(ValueError, match="sense_km must be a number"):
        PlannerConfig(reveal="radius", sense_km="2")
    with pytest.raises(ValueError, match="sense_km must be finite"):
        PlannerConfig(reveal="radius", sense_km=float("inf"))
    assert PlannerConfig(reveal="radius", sense_km=3).sense_km == 3.0


def _old_mission(g, inst, policy, plan, seed):
    """The mission loop as it was before the reveal option, with full compiled sweeps: the whole chosen segment is
    checked at the decision point, and a conflict reveals the intruder and asks the decision again."""
    rng = np.random.default_rng(seed)
    know = Knowledge(g, inst)
    omega, switch, n_dp, node, path = "goal", None, 0, g.origin, [g.origin]

    def compute():
        nonlocal n_dp
        n_dp += 1
        t = dp.tables(g, know.feasible, inst.robustness, policy, omega, 0, inst.blocked_bits, plan.nf_count)
        return dp.Tables(*(np.asarray(x) for x in t))

    tables = compute()
    while True:
        if g.term_goal[node] or (omega == "all" and g.term_alt[node]):
            outcome = "G" if g.term_goal[node] else "A"
            break
        if omega == "goal" and tables.n_goal[node] == 0:
            omega, switch = "all", g.window_of(node)
            tables = compute()
        a = choose(g, node, policy, plan.beta, tables, know.feasible, inst.robustness, omega, rng)
        if a is None:
            outcome = "L"
            break
        hit = know.conflicts(g.seg[node, a])
        if hit.size:
            know.reveal(hit)
            tables = compute()
            continue
        node = int(g.succ[node, a])
        path.append(node)
    return outcome, tuple(path), tuple(know.revealed), switch, n_dp


@pytest.mark.slow
def test_default_is_the_segment_model_bit_for_bit(graph):
    """(a) The default flies the same missions as ``reveal="segment"`` named explicitly, and both the same as the
    loop before the option existed; ``step`` changes some; the study fingerprint leaves the default out (a study
    written before the option resumes)."""
    from stp_env.survivability.config import StudyConfig

    g = graph
    traffic = TrafficConfig(n_partial=8, n_unknown=8, reach_km=4)
    default, explicit, step = PlannerConfig(**PLANNER), planner("segment"), planner("step")
    reveals, differ = 0, 0
    for seed in range(5):
        inst = make_instance(g, traffic, default, seed)
        inst2 = make_instance(g, traffic, explicit, seed)
        assert np.array_equal(inst.robustness, inst2.robustness) and np.array_equal(inst.occupancy, inst2.occupancy)
        for policy in POLICIES:
            a = run_mission(g, inst, policy, default, seed=seed)
            b = run_mission(g, inst2, policy, explicit, seed=seed)
            assert a == b
            assert (a.outcome, a.path, a.revealed, a.omega_switch, a.n_dp) == _old_mission(g, inst, policy, default,
                                                                                            seed)
            assert a.conflict_minute is None and len(a.reveal_minutes) == len(a.revealed)
            reveals += len(a.revealed)
            differ += run_mission(g, inst, policy, step, seed=seed) != a
    assert reveals > 0 and differ > 0
    base = StudyConfig(n_partial=(6,), n_unknown=(8,), n_instances=1, mission=small(), planner=default)
    fp = base.fingerprint()
    assert "reveal" not in fp["planner"] and "sense_km" not in fp["planner"]
    assert fp == dataclasses.replace(base, planner=explicit).fingerprint()
    assert dataclasses.replace(base, planner=step).fingerprint()["planner"]["reveal"] == "step"
    radius = dataclasses.replace(base, planner=planner("radius", 2.0)).fingerprint()["planner"]
    assert (radius["reveal"], radius["sense_km"]) == ("radius", 2.0)


def test_step_reveals_a_conflict_one_step_ahead_and_segment_at_the_decision(graph):
    """(b) An intruder blocking one cell of the second segment flown, in its fourth time step only: ``segment``
    reveals it at the segment's decision point and flies another primitive; ``step`` does not see it there and
    reveals it one step before contact, mid-segment, where it cannot be avoided (an emergency landing)."""
    g = graph
    free = free_mission(g)
    _, _, seg, t0 = flown(g, free.path, 1)
    cell = segment_cells_at(g, seg, t0 + 3)[0]
    occ = np.zeros((g.n_cells, 1), bool)
    occ[cell, 0] = True
    inst = occupancy_instance(g, occ)
    seg_res = run_mission(g, inst, "S", planner("segment"))
    assert seg_res.revealed == (0,) and seg_res.reveal_minutes == (t0,) and seg_res.conflict_minute is None
    assert seg_res.path[:2] == free.path[:2] and seg_res.path[2] != free.path[2] and seg_res.outcome in ("G", "A")
    step_res = run_mission(g, inst, "S", planner("step"))
    assert step_res.revealed == (0,) and step_res.reveal_minutes == (t0 + 3,)
    assert step_res.outcome == "L" and step_res.conflict_minute == t0 + 3 and step_res.path == free.path[:2]
    # A cell of the segment's first time step (here the decision point's own cell, so every primitive from it is
    # blocked): both models see it at the decision point, before flying, and fly the same mission.
    first = segment_cells_at(g, seg, t0)[0]
    occ = np.zeros((g.n_cells, 1), bool)
    occ[first, 0] = True
    inst = occupancy_instance(g, occ)
    a, b = run_mission(g, inst, "S", planner("segment")), run_mission(g, inst, "S", planner("step"))
    assert a == b and a.reveal_minutes == (t0,) and a.conflict_minute is None and a.path == free.path[:2]


def test_step_model_never_flies_into_traffic_unseen(graph):
    """With ``step``, every conflict of the flown path is revealed one step ahead: a flown segment crosses no
    actual path, and a mission cut short by an unavoidable conflict stops before the blocked time cell."""
    g = graph
    plan = planner("step")
    conflicts = 0
    for seed in range(6):
        inst = make_instance(g, TrafficConfig(n_partial=8, n_unknown=8, reach_km=4), plan, seed)
        res = run_mission(g, inst, "S", plan, seed=seed)
        for i in range(len(res.path) - 1):
            _, _, seg, _ = flown(g, res.path, i)
            cells = g.seg_cells[seg][g.seg_cells[seg] >= 0]
            assert not inst.occupancy[cells].any()
        if res.conflict_minute is not None:
            conflicts += 1
            assert res.outcome == "L" and res.reveal_minutes[-1] == res.conflict_minute
            assert res.conflict_minute > g.net.window_start_minute(g.window_of(res.path[-1]))
    assert conflicts > 0


@pytest.mark.parametrize("inside", [True, False])
def test_radius_reveals_exactly_within_sense_km(graph, inside):
    """(c) A hovering intruder, present only around one whole time step, at ``sense_km`` -/+ 1 m from the ownship:
    revealed at that step when just inside, never when just outside; mid-segment (the next decision uses it: one
    more sweep) and at a decision point."""
    g = graph
    free = free_mission(g)
    sense = 2.5
    d = sense - 1e-3 if inside else sense + 1e-3
    km = g.net.mission.cell_km
    for i, j in ((1, 2), (2, 0)):      # mid-segment (2 steps into the second segment); the third decision point
        node, _, _, t0 = flown(g, free.path, i)
        start = (g.states[node, :2] + 0.5) * km
        end = (g.states[free.path[i + 1], :2] + 0.5) * km
        pos = start + (end - start) * j / g.net.minutes_per_window
        t = t0 + j
        toward_centre = (6.0 - pos) / np.linalg.norm(6.0 - pos)     # inside the area, off the flown cells
        x, y = pos + d * toward_centre
        inst = hovering_instance(g, [(x, y, t - 0.25, 0.5)])
        res = run_mission(g, inst, "S", planner("radius", sense))
        if inside:
            assert res.revealed == (0,) and res.reveal_minutes == (t,)
            assert res.path == free.path and res.n_dp == free.n_dp + 1 and res.conflict_minute is None
        else:
            assert res == free
        # The intruder is on no flown cell: the conflict rules alone never reveal it.
        assert run_mission(g, inst, "S", planner("step")) == free


def test_gym_env_follows_the_reveal_model(graph):
    """The Gym environment runs the same reveal models: following the free mission's primitives into the intruder
    of test (b) asks the decision again with ``segment`` and ends the episode as an emergency landing with
    ``step``."""
    from stp_env.survivability.gym_env import SurvivabilityEnv

    g = graph
    free = free_mission(g)
    _, _, seg, t0 = flown(g, free.path, 1)
    occ = np.zeros((g.n_cells, 1), bool)
    occ[segment_cells_at(g, seg, t0 + 3)[0], 0] = True
    inst = occupancy_instance(g, occ)
    for model in ("segment", "step"):
        env = SurvivabilityEnv(((0, 1),), mission=small(), planner=planner(model), graph=g)
        env.reset(seed=0, options={"instance": inst})
        _, _, term, _, info = env.step(flown(g, free.path, 0)[1])
        assert not term and info["window"] == 1
        _, reward, term, _, info = env.step(flown(g, free.path, 1)[1])
        assert info["revealed"] == 1
        if model == "segment":
            assert not term and info["window"] == 1 and info["outcome"] is None and env.know.minutes == [t0]
        else:
            assert term and info["outcome"] == "L" and env.know.minutes == [t0 + 3] and reward == env.rewards[2]


def test_cli_reveal_options(tmp_path):
    """(d) ``--reveal`` and ``--sense-km`` parse into the planner; bad values exit with code 2."""
    import argparse

    from _cli import run_cli

    from stp_env.survivability.cli import add_parser, config_from_args

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    out = ["survivability", "--out", str(tmp_path)]
    default = config_from_args(parser.parse_args(out)).planner
    assert (default.reveal, default.sense_km) == ("segment", None) and default == PlannerConfig()
    step = config_from_args(parser.parse_args([*out, "--reveal", "step"])).planner
    assert (step.reveal, step.sense_km) == ("step", None)
    radius = config_from_args(parser.parse_args([*out, "--reveal", "radius", "--sense-km", "2.5"])).planner
    assert (radius.reveal, radius.sense_km) == ("radius", 2.5)
    for argv, message in (([*out, "--reveal", "radius"], "needs a sensing radius"),
                          ([*out, "--sense-km", "2"], "sense_km applies to reveal='radius' only"),
                          ([*out, "--reveal", "step", "--sense-km", "2"], "sense_km applies"),
                          ([*out, "--reveal", "nearest"], "invalid choice"),
                          ([*out, "--reveal", "radius", "--sense-km", "0"], "--sense-km"),
                          ([*out, "--reveal", "radius", "--sense-km", "nan"], "--sense-km")):
        code, _, err = run_cli(argv)
        assert code == 2 and message in err, (argv, err)
    assert not (tmp_path / "study.json").exists()
