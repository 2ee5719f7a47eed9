"""Mission survivability (stp_env.survivability): counts against closed forms, brute force and the paper's
backtracking; segment robustness against an analytic blocking probability; the policies' choices; missions."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from stp_env.survivability import backtrack, dense, dp
from stp_env.survivability.config import POLICIES, SFO, MissionConfig, PlannerConfig, StudyConfig, TrafficConfig
from stp_env.survivability.graph import build_graph, feasible_from_blocked
from stp_env.survivability.mission import Instance, Knowledge, choose, initial_tables, make_instance, run_mission
from stp_env.survivability.network import build_network, segment_box_distance
from stp_env.survivability.robustness import interior_reach, segment_robustness
from stp_env.survivability.traffic import Traffic, bernstein, sample_traffic

ONE_CELL = 1000.0 / 300.0       # m/s: one 1 km cell per 5-minute window


def corridor(n_windows: int = 6, goal_x: float = 20.5) -> MissionConfig:
    """One heading (east; a heading change of 360 deg is no change), speeds 0..3 cells per window: a 1-D corridor.
    The goal lands exactly ``n_windows`` windows after the start of cruise."""
    t = 10.0 + 5.0 * n_windows
    return MissionConfig(area_km=30, dh_max=360, dv_max=ONE_CELL, v_max=3 * ONE_CELL, n_increments=3,
                         rta_min=(t, t), endurance_min=t, departure_heading=0, goal_headings=(0,),
                         alternate_headings=(0,), alternates=(), positions_km=((0.5, 10.5), (goal_x, 10.5)))


def small(**kw) -> MissionConfig:
    """A 12 x 12 km mission with 8 headings and speeds 0..2 cells per window, one alternative site 2 km from the
    goal, two windows of endurance after the RTA."""
    base = dict(area_km=12, dh_max=45, n_increments=3, dv_max=ONE_CELL, v_max=2 * ONE_CELL, rta_min=(25, 35),
                endurance_min=50, departure_heading=0, goal_headings=(0, 45), alternate_headings=(0, 90, 180, 270),
                alternates=(SFO,), positions_km=((1.5, 1.5), (6.5, 4.5), (7.5, 6.5)))
    return MissionConfig(**{**base, **kw})


MOTZKIN = [1, 1, 2, 4, 9, 21, 51, 127]


def test_config_validation():
    with pytest.raises(ValueError, match="beta"):
        PlannerConfig(beta=1.5)
    with pytest.raises(ValueError, match="n_increments"):
        MissionConfig(n_increments=4)
    with pytest.raises(ValueError, match="unknown MissionConfig"):
        MissionConfig().with_overrides(speed=3)
    with pytest.raises(ValueError, match="positions_km"):
        MissionConfig(positions_km=((1, 1),))
    with pytest.raises(ValueError, match="outside"):
        MissionConfig(area_km=10).site_positions_km()


def test_paper_network_and_zero_traffic_feasibility():
    net = build_network()
    assert (net.n, net.n_headings, net.n_speeds, net.n_actions, net.n_windows) == (85, 24, 9, 25, 10)
    assert net.goal_windows == (6, 9)
    # 40 m/s for a 5-minute window is 12 km.
    assert sorted(np.abs(net.moves).max(axis=1))[-1] == 12
    # UCSF is 55.7 km from Santa Clara; with speed 0 at both ends of cruise, 9 windows reach at most 60 km.
    (ox, oy), (gx, gy) = net.site_km[net.mission.origin.name], net.site_km[net.mission.goal.name]
    assert 55 < math.hypot(gx - ox, gy - oy) < 60


@pytest.mark.slow
def test_corridor_counts_motzkin_and_by_area():
    """In the 1-D corridor a trajectory of n windows is a speed path 0 -> 0 with steps in {-1, 0, 1} (speeds 0..3
    cells per window). From a start L cells before the goal, the trajectories are the paths of area L (enumerated
    here); summed over all starts, their number is the Motzkin number M_n."""
    n = 6
    net = build_network(corridor(n))
    assert net.n_headings == 1 and net.n_actions == 3
    counts = np.asarray(dense.counts(net, dense.free_feasibility(net), "goal"))
    (gx, y) = net.goal
    assert counts[0, :, y, 0, 0].sum() == MOTZKIN[n]
    by_area = {}
    for steps in itertools.product((-1, 0, 1), repeat=n):
        v = np.cumsum(steps)
        if v[-1] == 0 and v.min() >= 0 and v.max() <= 3:
            by_area[int(v.sum())] = by_area.get(int(v.sum()), 0) + 1
    assert sum(by_area.values()) == MOTZKIN[n]
    for area in range(gx + 1):
        assert counts[0, gx - area, y, 0, 0] == by_area.get(area, 0)
    # The compact graph from the origin (20 cells before the goal: too far for 6 windows).
    g = build_graph(build_network(corridor(n, goal_x=6.5)))
    assert float(dp.counts(g, np.ones(g.n_segments, bool), "goal")[g.origin]) == by_area[6]


def test_dp_matches_literal_backtracking_with_blocked_cells():
    net = build_network(small())
    rng = np.random.default_rng(3)
    blocked = rng.random((net.mission.n_minutes, net.n, net.n)) < 0.05
    blocked_set = {(int(x), int(y), int(t)) for t, x, y in zip(*np.nonzero(blocked))}
    states, cells = backtrack.backtrack_counts(net, blocked_set, kind="all")
    full = np.asarray(dense.counts(net, dense.feasibility_from_blocked(net, blocked), "all"))
    assert states and all(full[k, x, y, h, v] == c for (k, x, y, h, v), c in states.items())
    # Every state with trajectories that inequality 4 keeps was generated by the backtracking.
    reach = net.mission.v_max * 0.3
    kept = [(k, x, y, h, v) for k, x, y, h, v in zip(*np.nonzero(full))
            if math.hypot(x - net.origin[0], y - net.origin[1]) <= reach * k + 1e-9]
    assert all((k, x, y, h, v) in states for k, x, y, h, v in kept)
    assert sum(cells.values()) == sum(states.values())
    # The compact graph, from the origin.
    g = build_graph(net)
    compact = np.asarray(dp.counts(g, feasible_from_blocked(g, blocked), "all"))
    for gi in range(0, g.n_states, 7):
        k = g.window_of(gi)
        assert compact[gi] == full[(k, *g.states[gi])]
    assert compact[g.origin] == states[(0, *net.origin_state())] > 0


def test_segment_cells_and_separation():
    net = build_network()
    # A hover occupies its own cell for the 5 minutes of the window, nothing else without separation.
    hover = int(np.flatnonzero((net.moves == 0).all(axis=1))[0])
    cells = net.segment_cells(10, 20, 0, hover)
    assert sorted(map(tuple, cells)) == [(10, 20, 5 + j) for j in range(5)]
    assert segment_box_distance([0.5, 0.5], [3.5, 0.5], np.array([[1.0, 1.0], [5.0, 0.0]])).tolist() == [0.5, 1.5]
    # With separation: the 4 side neighbours are 0.5 km from the centre, the diagonal ones 0.71 km.
    assert len(build_network(MissionConfig(separation_km=0.6)).segment_cells(10, 20, 0, hover)) == 5 * 5
    assert len(build_network(MissionConfig(separation_km=0.75)).segment_cells(10, 20, 0, hover)) == 5 * 9


def _hit_probability_radial(c, square_lo, r, n=400_001):
    """P that the segment from c to c + d/2, d uniform in the disk of radius r, meets the unit square at
    square_lo: the ray of angle theta enters the square at distance e(theta); it gets there when |d| / 2 >= e."""
    theta = np.linspace(0.0, 2 * np.pi, n)[:-1]
    d = np.stack([np.cos(theta), np.sin(theta)], 1)
    lo, hi = np.asarray(square_lo, float) - c, np.asarray(square_lo, float) + 1.0 - c
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = lo / d, hi / d
    t_enter = np.nanmax(np.minimum(t1, t2), axis=1)
    t_exit = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (t_exit >= np.maximum(t_enter, 0.0))
    e = np.maximum(t_enter, 0.0)
    return float(np.mean(np.where(hit, np.clip(1.0 - (2.0 * e / r) ** 2, 0.0, 1.0), 0.0)))


@pytest.mark.slow
def test_segment_robustness_against_analytic_blocking_probability():
    """A partially known intruder hovering at c (degree-2 curve, all control points at c) actually flies out and
    back along c + 2 s (1 - s) d, d uniform in the disk of radius r: it blocks a hovering ownship's cell with a
    probability given by one integral over the direction of d."""
    net = build_network(small())
    g = build_graph(net)
    hover = int(np.flatnonzero((net.moves == 0).all(axis=1))[0])
    k, x, y, _ = g.segments[np.flatnonzero(g.segments[:, 3] == hover)[-1]]
    t0 = net.window_start_minute(int(k))
    c = np.array([x + 0.5 + 1.3, y + 0.5 + 0.4])
    r = 4.0
    one = Traffic(nominal=np.repeat(c[None, None], 3, 1), actual=np.repeat(c[None, None], 3, 1),
                  t_in=np.array([t0 + 0.2]), duration=np.array([4.5]), n_partial=1)
    seg_id = int(np.flatnonzero((g.segments == [k, x, y, hover]).all(axis=1))[0])
    n_mc = 2500
    p = segment_robustness(np.random.default_rng(0), g, one, uncertainty_km=r, n_mc=n_mc, samples_per_min=60)
    p_true = 1.0 - _hit_probability_radial(c, (x, y), r)
    assert 0.85 < p_true < 0.97                        # a non-trivial probability
    se = math.sqrt(p_true * (1 - p_true) / n_mc)
    assert abs(p[seg_id] - p_true) < 4 * se + 0.005
    # Two independent copies of the intruder: robustness multiplies.
    two = Traffic(*(np.concatenate([a, a]) for a in one[:4]), n_partial=2)
    p2 = segment_robustness(np.random.default_rng(1), g, two, uncertainty_km=r, n_mc=n_mc, samples_per_min=60)
    assert abs(p2[seg_id] - p_true**2) < 4 * math.sqrt(p_true**2 * (1 - p_true**2) / n_mc) + 0.005
    # Segments of other windows never meet the intruder (it flies within window k only).
    assert p[g.segments[:, 0] != k].min() == 1.0 and p[g.segments[:, 0] == k].min() < 1.0


def test_bezier_tube_and_traffic_prefixes():
    assert interior_reach(1) == 0 and abs(interior_reach(2) - 0.5) < 1e-6 and abs(interior_reach(3) - 0.75) < 1e-6
    assert np.allclose(bernstein(3, np.linspace(0, 1, 7)).sum(-1), 1.0)
    mission = MissionConfig()
    big = sample_traffic(5, mission, TrafficConfig(n_partial=30, n_unknown=20, model="local"))
    few = sample_traffic(5, mission, TrafficConfig(n_partial=10, n_unknown=5, model="local"))
    assert np.array_equal(big.nominal[:10], few.nominal[:10])
    assert np.array_equal(big.nominal[30:35], few.nominal[10:15])
    assert np.array_equal(big.t_in[:10], few.t_in[:10])
    # Actual paths stay in the tube and keep their end points; unknown intruders fly their nominal path.
    dev = np.linalg.norm(big.actual - big.nominal, axis=-1)
    assert dev[:30, 1:-1].max() <= 5.0 and dev[:30, [0, -1]].max() == 0 and dev[30:].max() == 0


def _tables(policy="S", **kw):
    n = 3
    base = dict(n_goal=np.ones(n), n_all=np.array([100.0, 10.0, 1.0]), value=np.zeros(n), future=np.zeros(n))
    base.update(kw)
    return dp.Tables(**{k: np.asarray(v, float) for k, v in base.items()})


def test_policy_scores_on_a_hand_built_case():
    """Three successors: many trajectories but a risky first segment, fewer and safer, one and safest."""
    succ = np.array([0, 1, 2])
    p1 = np.array([0.2, 0.9, 1.0])
    nf = _tables(value=[100.0, 10.0, 1.0], future=[50.0, 40.0, 0.0])
    assert np.argmax(dp.scores("Nf", 0.5, nf, succ, p1)) == 0           # most trajectories
    r = _tables(future=[3.0, 2.9, 2.0])                                # sum of later robustness
    assert np.argmax(dp.scores("R", 0.5, r, succ, p1)) == 1            # 0.9 + 1.45 > 0.2 + 1.5, 1.0 + 1.0
    s = _tables(value=[0.99, 0.6, 0.3], future=[5.0, 3.0, 1.0])        # survivability R and its future sum
    assert np.argmax(dp.scores("S", 0.5, s, succ, p1)) == 0
    assert np.argmax(dp.scores("S", 0.01, s, succ, p1)) == 2           # small beta: the first segment decides


def _enumerate(g, gi, feasible, terminal, limit=10_000):
    """All trajectories (lists of (state, segment)) from graph state gi to a state of ``terminal`` (brute force)."""
    out = []

    def rec(s, path):
        if terminal[s]:
            out.append(path)
            return
        for a in range(g.succ.shape[1]):
            nxt, seg = g.succ[s, a], g.seg[s, a]
            if nxt >= 0 and feasible[seg]:
                rec(int(nxt), [*path, (int(nxt), int(seg))])
        if len(out) > limit:
            raise RuntimeError("too many trajectories")

    rec(gi, [])
    return out


@pytest.mark.slow
def test_dp_values_and_choice_match_brute_force():
    """At states a few windows from the end: N, W / N and the policies' choices by enumerating every trajectory;
    each policy picks the argmax of eq. 5 evaluated on the enumerated trajectories."""
    net = build_network(small())
    g = build_graph(net)
    rng = np.random.default_rng(7)
    feasible = rng.random(g.n_segments) < 0.9
    p = rng.uniform(0.3, 1.0, g.n_segments).astype(np.float32)
    many = dp.tables_many(g, feasible, p, POLICIES, "all")
    term = g.term_goal | g.term_alt
    n_all = np.asarray(many["S"].n_all)
    starts = [gi for gi in range(g.window_start[3], g.window_start[4]) if n_all[gi] > 1 and not term[gi]][:4]
    assert starts
    beta = 0.5
    for policy, gi in itertools.product(POLICIES, starts):
        t = dp.Tables(*(np.asarray(a, np.float64) for a in many[policy]))
        paths = _enumerate(g, gi, feasible, term)
        assert len(paths) == t.n_all[gi]
        if policy == "AvgR":      # the average robustness of the trajectories (eq. 1)
            w = sum(np.prod([float(p[s]) for _, s in path]) for path in paths)
            assert t.value[gi] == pytest.approx(w / len(paths), rel=1e-4)
        if policy == "Nf":
            assert t.value[gi] == len(paths)

        def later(path, policy=policy, t=t):      # eq. 5's future term along a trajectory, from its second state on
            if policy == "R":
                return sum(float(p[s]) for _, s in path[1:])
            return sum(float(t.value[st]) for st, _ in path[1:])

        first = {}
        for path in paths:
            (s1, seg1) = path[0]
            head = float(p[seg1]) if policy != "Nf" else 0.0
            v1 = float(t.value[s1]) if policy != "R" else 0.0
            score = head + beta * (later(path) + v1) if policy != "Nf" else v1 + beta * later(path)
            first[s1] = max(first.get(s1, -np.inf), score)
        a = choose(g, gi, policy, beta, t, feasible, p, "all", np.random.default_rng(0))
        assert first[int(g.succ[gi, a])] == pytest.approx(max(first.values()), rel=1e-5)


@pytest.mark.slow
def test_cone_tables_equal_the_compiled_sweep_on_the_reachable_states():
    """The numpy recomputation over the states reachable from a root gives the compiled sweep's entries bit for
    bit, for every policy and terminal set, on random feasibility, robustness and realisation bits (with
    ``jnp.sum`` in the compiled sweep, pi_Avg(R)'s values differed in the last bits); the cone is exactly the set
    of states reachable from the root. 25 primitives, as in the paper (with 9, XLA's own order matched)."""
    g = build_graph(build_network(small(n_increments=5)))
    rng = np.random.default_rng(3)
    p = rng.uniform(0.2, 1.0, g.n_segments).astype(np.float32)
    bits = rng.integers(0, 2**32, (g.n_segments, 2), dtype=np.uint32) & rng.integers(0, 2**32, (g.n_segments, 2),
                                                                                       dtype=np.uint32)
    K = g.net.n_windows
    for trial in range(6):
        feasible = rng.random(g.n_segments) < (0.8, 0.95, 1.0)[trial % 3]
        k = int(rng.integers(1, K - 1))
        root = int(rng.integers(g.window_start[k], g.window_start[k + 1]))
        layers = dp.cone(g, root)
        seen, frontier = {root}, {root}                                  # reachability by brute force
        while frontier:
            frontier = {int(s) for x in frontier for s in g.succ[x] if s >= 0} - seen
            seen |= frontier
        idx = np.concatenate(layers)
        assert set(idx.tolist()) == seen and len(idx) == len(seen)
        for policy, omega in itertools.product(POLICIES, dp.OMEGAS):
            fast = dp.cone_tables(g, feasible, p, policy, omega, root, bits)
            full = dp.tables(g, feasible, p, policy, omega, k, bits)
            for name, a, b in zip(dp.Tables._fields, fast, full):
                assert np.array_equal(a[idx], np.asarray(b)[idx]), (policy, omega, name)
            assert np.isfinite(fast.future[root]) == ((fast.n_goal if omega == "goal" else fast.n_all)[root] > 0)
    assert dp.cone_tables(g, feasible, p, "S", "goal", root) is None        # the tree recursion: compiled only


def test_packed_successor_groups_keep_every_state_s_successors_in_order_and_the_sweep_s_bits(monkeypatch):
    """The sweep's packed layout (dp._buckets): each state's valid primitives moved left in their order, states
    grouped by how many they have; the tables equal the layout without groups (one group per window) bit for bit
    for every policy, terminal set and pi_Nf count, pi_S both exact and by the tree recursion."""
    g = build_graph(build_network(small(n_increments=5)))
    monkeypatch.setattr(dp, "BUCKET_MIN_STATES", 0)                     # groups in every window of this network
    dp._consts.cache_clear()
    c = dp._consts(g)[1]
    ws = g.window_start
    widths = set()
    for k in range(g.net.n_windows):
        valid = g.succ[ws[k]:ws[k + 1]] >= 0
        seen = np.zeros(len(valid), int)
        for rows, succ, seg in c["buckets"][k]:
            rows, succ, seg = np.asarray(rows), np.asarray(succ), np.asarray(seg)
            widths.add(succ.shape[1])
            for r, a, b in zip(rows, succ, seg):
                keep = valid[r]
                n_next = ws[k + 2] - ws[k + 1]
                want = np.r_[g.succ[ws[k] + r][keep] - ws[k + 1], np.full(len(a) - keep.sum(), n_next)]
                assert np.array_equal(a, want) and np.array_equal(b[:keep.sum()], g.seg[ws[k] + r][keep])
                assert np.all(b[keep.sum():] == g.n_segments)
                seen[r] += 1
        assert np.all(seen == 1)
        order = np.asarray(c["order"][k])
        assert np.array_equal(np.concatenate([np.asarray(r) for r, _, _ in c["buckets"][k]])[order],
                              np.arange(len(valid)))
    assert len(widths) >= 3                                               # several groups on this network
    rng = np.random.default_rng(11)
    p = rng.uniform(0.2, 1.0, g.n_segments).astype(np.float32)
    bits = rng.integers(0, 2**32, (g.n_segments, 2), dtype=np.uint32)
    feasible = rng.random(g.n_segments) < 0.9
    cases = [(POLICIES, "goal", "goal", bits), (("S", "Nf"), "all", "landing", None)]
    packed = [dp.tables_many(g, feasible, p, q, omega, 1, b, nf) for q, omega, nf, b in cases]
    monkeypatch.setattr(dp, "BUCKET_WIDTHS", ())
    dp._consts.cache_clear()
    try:
        assert len(dp._consts(g)[1]["buckets"][3]) == 1
        for (q, omega, nf, b), want in zip(cases, packed):
            got = dp.tables_many(g, feasible, p, q, omega, 1, b, nf)
            for policy in q:
                for name, x, y in zip(dp.Tables._fields, got[policy], want[policy]):
                    assert np.array_equal(np.asarray(x), np.asarray(y)), (policy, omega, nf, name)
    finally:
        dp._consts.cache_clear()


def test_knowledge_reveal_blocks_exactly_the_segments_through_revealed_cells():
    """Feasibility after successive reveals (updated through the cells' segment lists) equals its definition: no
    cell of the segment is on a revealed intruder's actual path."""
    g = build_graph(build_network(small()))
    rng = np.random.default_rng(5)
    occ = rng.random((g.n_cells, 6)) < 0.01
    know = Knowledge(g, _instance(g, occ))
    for group in ([2], [0, 4], [2, 5]):
        before = know.feasible
        know.reveal(group)
        blocked = np.append(occ[:, know.revealed].any(axis=1), False)
        assert np.array_equal(know.feasible, ~blocked[g.seg_cells].any(axis=1))
        assert not know.feasible.all() and before is not know.feasible


def test_survivability_from_realisations_matches_brute_force():
    """R(s) from the realisations' bit sets (one sweep, 64 realisations at once) equals, state by state, the fraction
    of realisations in which a trajectory from s stays free (reachability computed realisation by realisation);
    the tree recursion of eq. 3 overestimates it on average (shared segments counted as independent)."""
    g = build_graph(build_network(small()))
    rng = np.random.default_rng(0)
    words = 2
    bits = rng.integers(0, 2**32, size=(g.n_segments, words), dtype=np.uint64).astype(np.uint32)
    for _ in range(2):                                       # each realisation blocks a segment w.p. 1/8
        bits &= rng.integers(0, 2**32, size=(g.n_segments, words), dtype=np.uint64).astype(np.uint32)
    feasible = np.ones(g.n_segments, bool)
    p = (1.0 - np.bitwise_count(bits).sum(axis=1) / (32 * words)).astype(np.float32)
    exact = np.asarray(dp.tables(g, feasible, p, "S", "all", blocked_bits=bits).value)
    term = g.term_goal | g.term_alt
    brute = np.zeros(g.n_states)
    for j in range(32 * words):
        free = ((bits[:, j // 32] >> np.uint32(j % 32)) & 1) == 0
        reach = term.copy()
        for gi in range(g.window_start[-2] - 1, -1, -1):
            ok = g.succ[gi] >= 0
            reach[gi] |= bool((free[g.seg[gi][ok]] & reach[g.succ[gi][ok]]).any())
        brute += reach
    inner = slice(0, g.window_start[-2])
    assert np.allclose(exact[inner], brute[inner] / (32 * words))
    # (All four policies in one sweep: the same compiled program as the brute-force test of the policies' values.)
    tree = np.asarray(dp.tables_many(g, feasible, p, POLICIES, "all")["S"].value)
    assert (tree - exact)[inner].mean() > 0.05


def _instance(g, occupancy=None):
    """Intruders known only through ``occupancy`` (unknown, revealed on conflict): every segment's robustness is 1
    and none of 64 realisations blocks anything (the realisations' shape is that of ``PlannerConfig(n_survival=64)``,
    so that these missions share their compiled sweeps with the other tests)."""
    n = 0 if occupancy is None else occupancy.shape[1]
    empty = Traffic(np.zeros((n, 4, 2)), np.zeros((n, 4, 2)), np.zeros(n), np.ones(n), 0)
    return Instance(empty, np.ones(g.n_segments, np.float32),
                    np.zeros((g.n_cells, n), bool) if occupancy is None else occupancy,
                    blocked_bits=np.zeros((g.n_segments, 2), np.uint32))


@pytest.mark.slow
def test_missions_without_traffic_reach_the_goal():
    g = build_graph(build_network(small()))
    inst = _instance(g)
    first = initial_tables(g, inst, POLICIES)
    for policy in POLICIES:
        res = run_mission(g, inst, policy, PlannerConfig(), initial_tables=first[policy])
        assert res.outcome == "G" and res.revealed == () and res.omega_switch is None and res.n_dp == 0
        assert g.term_goal[res.path[-1]]


@pytest.mark.slow
def test_unknown_intruder_on_the_goal_sends_the_mission_to_the_alternative_site():
    g = build_graph(build_network(small()))
    goal = np.flatnonzero((g.cells[:, 0] == g.net.goal[0]) & (g.cells[:, 1] == g.net.goal[1]))
    occ = np.zeros((g.n_cells, 1), bool)
    occ[goal, 0] = True
    res = run_mission(g, _instance(g, occ), "S", PlannerConfig())
    assert res.outcome == "A" and res.revealed == (0,) and res.omega_switch is not None
    assert g.term_alt[res.path[-1]]


def test_mission_with_no_way_out_fails_and_never_flies_into_traffic():
    g = build_graph(build_network(small()))
    occ = np.ones((g.n_cells, 1), bool)                               # every cell of every minute
    res = run_mission(g, _instance(g, occ), "S", PlannerConfig())
    assert res.outcome == "L" and res.path == (g.origin,)
    # Dense random traffic: conflicts reveal intruders, and no flown segment crosses an actual path.
    planner = PlannerConfig(n_mc=64, n_survival=64)
    revealed = 0
    for seed in range(6):
        inst = make_instance(g, TrafficConfig(n_partial=8, n_unknown=8, reach_km=4), planner, seed)
        for policy in ("S",):
            res = run_mission(g, inst, policy, planner, seed=seed)
            revealed += len(res.revealed)
            for a, b in itertools.pairwise(res.path):
                seg = g.seg[a][np.flatnonzero(g.succ[a] == b)[0]]
                cells = g.seg_cells[seg][g.seg_cells[seg] >= 0]
                assert not inst.occupancy[cells].any()
    assert revealed > 0


@pytest.mark.slow
def test_gym_env_passes_check_env_and_reveals_on_conflict():
    from gymnasium.utils.env_checker import check_env

    from stp_env.survivability.gym_env import SurvivabilityEnv, observation_size

    traffic, planner = TrafficConfig(reach_km=4), PlannerConfig(n_mc=64, n_survival=64)
    env = SurvivabilityEnv(((4, 4), (8, 8)), mission=small(), traffic=traffic, planner=planner)
    assert env.observation_space.shape == (observation_size(env.action_space.n),) == (12 + 5 * 9,)
    check_env(env, skip_render_check=True)
    # An invalid primitive ends the mission as an emergency landing; the first valid one keeps it going.
    obs, info = env.reset(seed=0, options={"scenario": (0, 0)})
    bad = int(np.flatnonzero(~info["valid"])[0])
    assert env.step(bad)[1:3] == (0.0, True) and env.outcome == "L"
    # A pool of prepared instances: the valid flags in the observation match the info's mask.
    g = env.graph
    pool = [((8, 8), make_instance(g, traffic.with_overrides(n_partial=8, n_unknown=8), planner, s)) for s in range(3)]
    env = SurvivabilityEnv(((8, 8),), mission=small(), traffic=traffic, planner=planner, graph=g, pool=pool)
    outcomes = set()
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        done = False
        while not done:
            assert np.array_equal(obs[12::5] > 0.5, info["valid"])
            obs, _, term, trunc, info = env.step(int(np.flatnonzero(info["valid"])[-1]))
            done = term or trunc
        outcomes.add(info["outcome"])
    assert outcomes <= {"G", "A", "L"} and outcomes
    # A given instance (evaluation on held-out instances) is flown as given, whatever the pool.
    obs, info = env.reset(seed=0, options={"instance": pool[1][1]})
    assert env.instance is pool[1][1] and info["scenario"] == (8, 8)


@pytest.mark.slow
def test_exported_ppo_policy_matches_sb3(tmp_path):
    """The exported actor (numpy weights, no pickle) picks the same primitive as SB3's deterministic predict."""
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO

    from stp_env.policies.learned import export_mlp
    from stp_env.survivability.gym_env import SurvivabilityEnv
    from stp_env.survivability.learned import load_policy

    env = SurvivabilityEnv(((0, 0),), mission=small(), planner=PlannerConfig(n_mc=64, n_survival=64))
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=64, seed=0, device="cpu",
                policy_kwargs={"net_arch": [16, 16], "activation_fn": torch.nn.Tanh})
    policy = load_policy(str(export_mlp(model, tmp_path / "p.npz")), n_actions=env.action_space.n)
    obs = np.random.default_rng(0).uniform(-1, 1, (50, env.observation_space.shape[0])).astype(np.float32)
    assert [policy(o) for o in obs] == [int(a) for a in model.predict(obs, deterministic=True)[0]]
    with pytest.raises(ValueError, match="unknown policy"):
        load_policy("nonexistent")
    with pytest.raises(ValueError, match="9 outputs; expected 25"):      # exported for another network
        load_policy(str(tmp_path / "p.npz"))


def test_exported_maskable_ppo_policy_matches_sb3_contrib_with_masks(tmp_path):
    """An actor trained with action masking (sb3-contrib's MaskablePPO) is exported like a plain one and, read back
    with numpy, picks the valid primitive MaskablePPO's deterministic predict picks under the observation's valid
    flags; the environment's action_masks are those flags. Without the mask the numpy argmax would differ (the check
    can fail)."""
    pytest.importorskip("sb3_contrib")
    import torch
    from sb3_contrib import MaskablePPO

    from stp_env.policies.learned import export_mlp
    from stp_env.survivability.gym_env import N_ACTION_FEATURES, N_STATE_FEATURES, SurvivabilityEnv
    from stp_env.survivability.learned import load_policy

    env = SurvivabilityEnv(((0, 0),), mission=small(), planner=PlannerConfig(n_mc=64, n_survival=64))
    obs, info = env.reset(seed=0)
    flags = obs[N_STATE_FEATURES::N_ACTION_FEATURES][:env.action_space.n] > 0.5
    assert np.array_equal(env.action_masks(), info["valid"]) and np.array_equal(env.action_masks(), flags)
    assert 0 < flags.sum() < env.action_space.n
    model = MaskablePPO("MlpPolicy", env, n_steps=64, batch_size=64, seed=0, device="cpu",
                        policy_kwargs={"net_arch": [16, 16], "activation_fn": torch.nn.Tanh})
    policy = load_policy(str(export_mlp(model, tmp_path / "m.npz", metadata={"action_masking": True})),
                         n_actions=env.action_space.n)
    plain = load_policy(str(export_mlp(model, tmp_path / "p.npz")), n_actions=env.action_space.n)
    rng = np.random.default_rng(1)
    obs = rng.uniform(-1, 1, (200, env.observation_space.shape[0])).astype(np.float32)
    idx = N_STATE_FEATURES + N_ACTION_FEATURES * np.arange(env.action_space.n)
    obs[:, idx] = (rng.random((200, env.action_space.n)) < 0.2).astype(np.float32)
    obs[np.arange(200), idx[rng.integers(0, env.action_space.n, 200)]] = 1.0      # at least one valid
    masks = obs[:, idx] > 0.5
    want = [int(model.predict(o, deterministic=True, action_masks=m)[0]) for o, m in zip(obs, masks)]
    assert [policy(o) for o in obs] == want
    assert all(m[a] for m, a in zip(masks, want))
    assert [plain(o) for o in obs] != want


def _write_missions(path, config, outcomes, extra=None):
    """The missions file of the study ``config`` (and its ``study.json``) from ``{(n_p, n_u): {policy: [outcome per
    instance]}}``, written as the study writes them (a report uses only rows that prove they are the study's own);
    ``extra(instance, outcome)``: columns that replace the defaults (no reveal, the goal kept, 9 windows)."""
    from stp_env.survivability.records import write_missions, write_study_metadata

    rows = [{"n_partial": p, "n_unknown": u, "instance": i, "policy": policy, "outcome": o, "reveals": 0,
             "omega_switch": -1, "n_dp": 1, "windows": 9, "instance_s": 1.0, "mission_s": 0.25,
             **(extra(i, o) if extra else {})}
            for (p, u), per in outcomes.items() for policy, outs in per.items() for i, o in enumerate(outs)]
    write_study_metadata(config, path.parent)
    write_missions(config, path, rows)


def test_report_thresholds_rates_and_cli_on_a_hand_built_study(tmp_path):
    """Survival of pi_Nf minus pi_S at N_p = 100 is -0.2, -0.1, +0.1 at N_u = 50, 100, 150: phi(100) = 125 (linear
    interpolation); at N_p = 50 pi_S stays ahead (no crossing). The CLI writes the results and figures from the
    missions file alone, and refuses bad options with one line."""
    from _cli import run_cli

    g, a, lost = "G", "A", "L"
    outcomes = {}
    for u, (n_nf, n_s) in zip((50, 100, 150), ((8, 10), (9, 10), (10, 9))):
        outcomes[(100, u)] = {"Nf": [g] * n_nf + [lost] * (10 - n_nf),
                              "S": [a] * 2 + [g] * (n_s - 2) + [lost] * (10 - n_s)}
        outcomes[(50, u)] = {"Nf": [g] * 5 + [lost] * 5, "S": [g] * 10}
    # The study the command line below describes (its defaults but for the scenarios and policies).
    config = StudyConfig(n_partial=(50, 100), n_unknown=(50, 100, 150), policies=("Nf", "S"))
    _write_missions(tmp_path / "missions.csv", config, outcomes)
    argv = ["survivability", "--out", str(tmp_path), "--report-only", "--partial", "50", "100", "--unknown", "50",
            "100", "150", "--policies", "Nf", "S", "--bootstrap", "200"]
    code, _, err = run_cli(argv)
    assert code == 0, err
    report = json.loads((tmp_path / "results.json").read_text())
    phi = report["thresholds"]["phi"]
    assert phi["100"]["value"] == pytest.approx(125.0) and phi["50"]["value"] is None
    assert phi["100"]["differences"] == pytest.approx([-0.2, -0.1, 0.1])
    cell = next(s for s in report["scenarios"] if (s["n_partial"], s["n_unknown"]) == (100, 50))
    assert cell["S"]["survival"]["rate"] == 1.0 and cell["S"]["success"]["rate"] == 0.8
    lo, hi = cell["Nf"]["survival"]["ci95"]
    assert lo < 0.8 < hi and hi < 1.0                             # Clopper-Pearson for 8 of 10
    assert report["comparisons"]["100,50"]["survival-success[S]"]["diff"] == pytest.approx(0.2)
    assert report["timing"]["mean_instance_setup_s"] == 1.0 and report["timing"]["mean_mission_s"] == 0.25
    assert report["goal_loss"]["100,50"]["S"] == {"missions": 10, "lost": 0, "by_window": {}}
    assert (tmp_path / "results.md").exists() and (tmp_path / "fig9_survival_vs_nu.png").exists()
    code, _, err = run_cli(["survivability", "--out", str(tmp_path / "empty"), "--report-only"])
    assert code == 2 and err.count("\n") == 1 and "no completed missions" in err


def test_goal_loss_counts_when_the_goal_was_lost_and_what_followed():
    """Hand-built missions: the losses are counted by window and by what followed (an alternative site, an
    emergency landing in the window of the loss, one later); missions that kept the goal and instances not flown
    by every policy do not count; a mission that lost the goal and landed there is refused."""
    from stp_env.survivability.analysis import goal_loss

    def row(i, policy, outcome, switch, windows):
        return {"n_partial": 100, "n_unknown": 50, "instance": i, "policy": policy, "outcome": outcome,
                "omega_switch": switch, "windows": windows}

    rows = [row(0, "S", "A", 6, 8), row(1, "S", "L", 7, 7), row(2, "S", "L", 7, 9), row(3, "S", "G", -1, 9),
            row(4, "S", "A", 7, 9),
            row(0, "Nf", "G", -1, 9), row(1, "Nf", "L", 8, 8), row(2, "Nf", "G", -1, 9), row(3, "Nf", "A", 5, 9),
            row(4, "Nf", "L", 3, 3),
            row(5, "S", "L", 2, 2)]                       # instance 5: only pi_S flew it, so it does not count
    out = goal_loss(rows, ("S", "Nf"))[(100, 50)]
    assert out["S"] == {"missions": 5, "lost": 4, "by_window": {6: {"A": 1, "L_at_loss": 0, "L_later": 0},
                                                                7: {"A": 1, "L_at_loss": 1, "L_later": 1}}}
    assert out["Nf"]["lost"] == 3 and list(out["Nf"]["by_window"]) == [3, 5, 8]
    assert out["Nf"]["by_window"][3] == {"A": 0, "L_at_loss": 1, "L_later": 0}
    with pytest.raises(ValueError, match="lost the goal and then landed there"):
        goal_loss([*rows, row(5, "Nf", "G", 4, 9)], ("S", "Nf"))


@pytest.mark.slow
def test_goal_corridor_against_enumerated_trajectories():
    """The share of goal trajectories whose state at each window could reach an alternative site instead
    (``analysis.goal_corridor``, forward and backward counts) equals the share found by listing every trajectory
    from the origin to the goal on the small network and checking each of its states by brute force (a depth-first
    search to an alternative site). With the alternative site north of the origin, away from the goal, the
    shares fall from 1 to 0 along the way (the comparison can fail)."""
    from stp_env.survivability.analysis import goal_corridor

    def brute(g):
        memo = {}

        def reaches_alt(s):
            if s not in memo:
                memo[s] = bool(g.term_alt[s]) or any(reaches_alt(int(t)) for t in g.succ[s] if t >= 0)
            return memo[s]

        paths, stack = [], [(g.origin,)]
        while stack:
            path = stack.pop()
            s = path[-1]
            if g.term_goal[s]:
                paths.append(path)
                continue
            stack.extend((*path, int(t)) for t in g.succ[s] if t >= 0)
        shares = {}
        for k in range(max(len(p) for p in paths)):
            through = [p for p in paths if len(p) > k + 1]          # the state at window k is not the goal itself
            if through:
                shares[k] = sum(reaches_alt(p[k]) for p in through) / len(through)
        return len(paths), shares

    for endurance in (45, 50):     # the alternative site to the north of the origin, away from the goal
        g = build_graph(build_network(small(endurance_min=endurance, positions_km=((1.5, 1.5), (6.5, 4.5),
                                                                                   (1.5, 4.5)))))
        n_paths, shares = brute(g)
        assert n_paths >= 8
        rows = goal_corridor(g)
        assert {r["window"]: r["trajectories"] for r in rows} == pytest.approx(shares)
        assert all(0 <= r["states_alt"] <= r["states"] for r in rows)
        assert shares[0] == 1.0 and shares[max(shares)] == 0.0 and any(0 < v < 1 for v in shares.values())


@pytest.mark.slow
def test_shipped_policy_is_masked_and_flies_only_valid_primitives():
    """The shipped learned policy (MaskablePPO, ``docs/survivability.md``) loads with numpy, declares its masking,
    and on the paper's mission picks a valid primitive at every decision of a few missions."""
    from stp_env.survivability.gym_env import SurvivabilityEnv
    from stp_env.survivability.learned import load_policy

    policy = load_policy("ppo")
    assert policy.masked and policy.mlp.metadata["algo"] == "MaskablePPO"
    env = SurvivabilityEnv(((100, 100),), planner=PlannerConfig(n_mc=256))
    outcomes = []
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        done = False
        while not done:
            a = policy(obs)
            assert info["valid"][a], (seed, a)
            obs, _, term, trunc, info = env.step(a)
            done = term or trunc
        outcomes.append(info["outcome"])
    assert set(outcomes) <= {"G", "A", "L"}


@pytest.mark.slow
def test_study_shares_robustness_across_n_u_and_reads_split_missions_files(tmp_path):
    """Instance ``i`` of scenarios with the same N_p computes its robustness once (the key check refuses another
    seed, N_p or Monte Carlo setting); the missions equal those flown without sharing; a study whose missions are
    split over ``missions-IofN.csv`` files (as release 0.1's ``--worker I/N`` wrote them) is read whole, and a
    rerun adds nothing."""
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.records import read_missions, read_study
    from stp_env.survivability.study import run_instance, run_study

    planner = PlannerConfig(n_mc=64, n_survival=64)
    config = StudyConfig(n_partial=(3, 6), n_unknown=(4, 20, 60), n_instances=4, mission=small(),
                         traffic=TrafficConfig(reach_km=4), planner=planner)
    g = build_graph(build_network(config.mission))

    def traffic(p, u):
        return config.traffic.with_overrides(n_partial=p, n_unknown=u)

    base = make_instance(g, traffic(6, 4), planner, (0, 1))
    assert base.robustness.min() < 1.0                               # the partially known traffic matters here
    same = make_instance(g, traffic(6, 20), planner, (0, 1), reuse=base)
    assert same.robustness is base.robustness and same.blocked_bits is base.blocked_bits
    assert same.occupancy.shape[1] == 26
    fresh = make_instance(g, traffic(6, 20), planner, (0, 1))
    assert np.array_equal(fresh.robustness, base.robustness) and np.array_equal(fresh.blocked_bits, base.blocked_bits)
    others = (make_instance(g, traffic(6, 4), planner, (0, 0), reuse=base),                          # another seed
              make_instance(g, traffic(3, 4), planner, (0, 1), reuse=base),                          # another N_p
              make_instance(g, traffic(6, 4), PlannerConfig(n_mc=128, n_survival=64), (0, 1), reuse=base))
    assert all(o.robustness is not base.robustness for o in others)
    assert not np.array_equal(others[0].robustness, base.robustness)          # sharing it would have been wrong

    run_study(config, tmp_path, progress=False)
    whole = tmp_path / "missions.csv"
    header, *lines = whole.read_text(encoding="utf-8").splitlines(keepends=True)
    for w in (0, 1):  # the rows of every other group in each file, as two workers wrote them
        (tmp_path / f"missions-{w}of2.csv").write_text(header + "".join(lines[w::2]), encoding="utf-8")
    whole.unlink()
    rows = read_study(tmp_path)
    assert len(rows) == 2 * 4 * 3 * len(POLICIES)
    assert sum(len(read_missions(tmp_path / f"missions-{w}of2.csv")) for w in (0, 1)) == len(rows)

    keys = ("outcome", "reveals", "omega_switch", "n_dp", "windows")
    plain = {(r["n_partial"], r["n_unknown"], r["instance"], r["policy"]): tuple(r[k] for k in keys)
             for p, u in config.scenarios for i in range(4) for r in run_instance(g, config, p, u, i)}
    shared = {(r["n_partial"], r["n_unknown"], r["instance"], r["policy"]): tuple(r[k] for k in keys) for r in rows}
    assert shared == plain
    assert any(r["reveals"] for r in rows) and {r["outcome"] for r in rows} >= {"G", "L"}      # traffic mattered
    run_study(config, tmp_path, progress=False)
    assert len(read_study(tmp_path)) == len(rows) and not whole.exists()  # nothing left to fly


def test_a_failed_reset_changes_nothing():
    """The reset contract of every environment (``docs/threat-model.md``): the seed and the options are checked, and
    the episode drawn, before anything changes."""
    from stp_env.survivability.gym_env import SurvivabilityEnv

    traffic, planner = TrafficConfig(reach_km=4), PlannerConfig(n_mc=64, n_survival=64)
    env = SurvivabilityEnv(((4, 4),), mission=small(), traffic=traffic, planner=planner)
    env.reset(seed=3)
    state = env.np_random.bit_generator.state
    before = (env.instance, env.scenario, env.g, env.steps, env.outcome)
    for seed, options in [(1.5, None), ("1", None), (True, None), (-1, None), (2**63, None), (None, "options"),
                          (None, {"scenario": (4,)}), (None, {"scenario": (-1, 4)}), (None, {"instance": 5}),
                          (None, {"instance_seed": -3})]:
        with pytest.raises(ValueError):
            env.reset(seed=seed, options=options)
        assert env.np_random.bit_generator.state == state and (env.instance, env.scenario, env.g, env.steps,
                                                               env.outcome) == before, (seed, options)


def test_report_names_the_best_policy_on_the_diagonal_the_relative_gain_and_the_conflicts(tmp_path):
    """Hand-built (50, 50): pi_R lands at the goal most often (30 of 40 against pi_S's 20) but pi_S survives most
    (36 against 30): the diagonal findings name them with resolved paired leads; pi_S's survival over success is 40
    points, 80 % relative; conflicts per mission are the ``reveals`` column's mean; the goal-loss figure is drawn."""
    import matplotlib

    matplotlib.use("Agg")
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.report import build_report, figures

    outcomes = {(50, 50): {"R": ["G"] * 30 + ["L"] * 10, "S": ["G"] * 20 + ["A"] * 16 + ["L"] * 4}}
    config = StudyConfig(n_partial=(50,), n_unknown=(50,), n_instances=40, policies=("R", "S"),
                         mission=small())
    _write_missions(tmp_path / "missions.csv", config, outcomes, lambda i, o: {
        "reveals": i % 3, "omega_switch": -1 if o == "G" else 4, "windows": 4 if o == "L" else 9})
    report = build_report(config, tmp_path, n_boot=50)
    diag = report["findings"]["fig7_diagonal"][100]
    assert diag["success"]["best"] == "R" and diag["success"]["runner_up"] == "S"
    assert diag["success"]["lead"]["diff"] == pytest.approx(0.25) and diag["success"]["resolved"]
    assert diag["survival"]["best"] == "S" and diag["survival"]["lead"]["diff"] == pytest.approx(0.15)
    assert report["findings"]["survival-success[S] at 100 intruders"]["ours"]["diff"] == pytest.approx(0.4)
    assert report["findings"]["survival/success[S] - 1 at 100 intruders"]["ours"] == pytest.approx(0.8)
    assert report["conflicts_per_mission"]["50,50"]["S"] == {"mean": pytest.approx(39 / 40), "max": 2, "n": 40}
    assert 0.0 < report["airborne_fraction"]["50,50"] < 1.0
    md = (tmp_path / "results.md").read_text()
    assert "| 100 | π_R (+25.0 over π_S" in md and "relative 80.00 %" in md
    figures(config, tmp_path, report)
    assert (tmp_path / "fig13_goal_loss_window.png").stat().st_size > 1000
