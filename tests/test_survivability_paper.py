"""The survivability paper's traffic model and pi_Nf count as options (``TrafficConfig(model="paper")``,
``PlannerConfig(nf_count="goal")``): control points and times spread as in Section III-B, hovering degree-1
intruders, realisations over the whole uncertainty tube; per-cell counts to ``Omega`` as in Algorithm 1 against a
hand count; the defaults unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stp_env.survivability import dp
from stp_env.survivability.config import (
    PAPER_HOVER_SHARE,
    POLICIES,
    SFO,
    MissionConfig,
    PlannerConfig,
    TrafficConfig,
)
from stp_env.survivability.graph import build_graph, feasible_from_blocked
from stp_env.survivability.mission import initial_tables, make_instance, run_mission
from stp_env.survivability.network import build_network
from stp_env.survivability.robustness import segment_robustness
from stp_env.survivability.traffic import (
    Traffic,
    airborne_fraction,
    bernstein,
    curve_points,
    occupancy,
    sample_traffic,
    tube_offsets,
)

ONE_CELL = 1000.0 / 300.0       # m/s: one 1 km cell per 5-minute window


def small(**kw) -> MissionConfig:
    """A 12 x 12 km mission (the one of ``tests/test_survivability.py``)."""
    base = dict(area_km=12, dh_max=45, n_increments=3, dv_max=ONE_CELL, v_max=2 * ONE_CELL, rta_min=(25, 35),
                endurance_min=50, departure_heading=0, goal_headings=(0, 45), alternate_headings=(0, 90, 180, 270),
                alternates=(SFO,), positions_km=((1.5, 1.5), (6.5, 4.5), (7.5, 6.5)))
    return MissionConfig(**{**base, **kw})


def ks_statistic(sample, cdf) -> float:
    """Kolmogorov-Smirnov distance between the empirical distribution of ``sample`` and ``cdf``."""
    x = np.sort(np.asarray(sample, float))
    n = len(x)
    f = cdf(x)
    return float(max((np.arange(1, n + 1) / n - f).max(), (f - np.arange(n) / n).max()))


def ks_passes(sample, cdf) -> bool:
    """The KS test at level 0.01 (critical value 1.63 / sqrt(n))."""
    return ks_statistic(sample, cdf) < 1.63 / np.sqrt(len(sample))


def spans_area(traffic: Traffic, mission: MissionConfig) -> dict[str, bool]:
    """The paper's "x_i^B in [X_l, X_u], y_i^B in [Y_l, Y_u]" for every control point, checked four ways on the
    curves that do not hover (their control points are independent and uniform over the area)."""
    area = mission.area_km
    flying = traffic.nominal if traffic.hovering is None else traffic.nominal[~traffic.hovering]
    pts = flying.reshape(-1, 2)
    k = flying.shape[1] - 1

    def uniform(x):
        return np.clip(x / area, 0.0, 1.0)

    # The range of k + 1 independent uniforms has mean k / (k + 2) of the interval.
    own_range = (flying.max(axis=1) - flying.min(axis=1)).mean() / area
    return {
        "inside": bool(((pts >= 0) & (pts <= area)).all()),
        "cover": all(np.ptp(pts[:, d]) > 0.9 * area for d in (0, 1)),
        "uniform": all(ks_passes(pts[:, d], uniform) for d in (0, 1)),
        "own_range": abs(own_range - k / (k + 2)) < 0.05,
    }


def test_paper_traffic_spans_the_area_and_the_mission_window():
    """Section III-B: every control point uniform over the area, control times in (t_0, t_fu). The ``local``
    model's short hops fail the same checks."""
    mission = MissionConfig()
    paper = sample_traffic(0, mission, TrafficConfig(n_partial=300, n_unknown=300, model="paper"))
    local = sample_traffic(0, mission, TrafficConfig(n_partial=300, n_unknown=300, model="local"))
    assert all(spans_area(paper, mission).values()), spans_area(paper, mission)
    checks = spans_area(local, mission)
    assert not checks["inside"] and not checks["own_range"], checks
    # Entry and exit: the smaller and the larger of two uniform times in (t_0, t_fu) = (0, 55).
    t_fu = mission.rta_min[1]
    t_in, t_out = paper.t_in, paper.t_in + paper.duration
    assert t_in.min() > 0 and t_out.max() < t_fu
    assert ks_passes(t_in, lambda t: 1 - (1 - np.clip(t / t_fu, 0, 1)) ** 2)
    assert ks_passes(t_out, lambda t: np.clip(t / t_fu, 0, 1) ** 2)
    assert not ks_passes(local.t_in, lambda t: 1 - (1 - np.clip(t / t_fu, 0, 1)) ** 2)
    # The smaller scenario's intruders are the larger one's first ones (common random numbers).
    few = sample_traffic(0, mission, TrafficConfig(n_partial=30, n_unknown=20, model="paper"))
    for name in ("nominal", "actual", "t_in", "duration", "hovering"):
        big, sm = getattr(paper, name), getattr(few, name)
        assert np.array_equal(big[:30], sm[:30]) and np.array_equal(big[300:320], sm[30:50]), name


def test_airborne_fraction_is_larger_with_the_paper_traffic():
    """About 10 % of the local model's intruders fly at any minute; the paper's fly a third of (0, 55), so
    (55 / 3) / 60 = 0.306 of the 60 minutes on average."""
    mission = MissionConfig()
    paper = airborne_fraction(sample_traffic(1, mission, TrafficConfig(n_partial=500, n_unknown=500,
                                                                        model="paper")), mission)
    local = airborne_fraction(sample_traffic(1, mission, TrafficConfig(n_partial=500, n_unknown=500,
                                                                         model="local")), mission)
    assert abs(paper - mission.rta_min[1] / 3 / mission.endurance_min) < 0.02
    assert 0.05 < local < 0.15 and paper > 2 * local
    # By hand: one intruder flying minutes [10, 40) of a 60-minute mission is airborne half the time.
    one = Traffic(np.zeros((1, 4, 2)), np.zeros((1, 4, 2)), np.array([10.0]), np.array([30.0]), 0)
    assert airborne_fraction(one, mission) == pytest.approx(0.5)


def test_hovering_intruders_are_degree_one_with_the_documented_share():
    mission = MissionConfig()
    assert PAPER_HOVER_SHARE == 0.1
    for share, config in ((PAPER_HOVER_SHARE, TrafficConfig(n_partial=1500, n_unknown=1500, model="paper")),
                          (0.4, TrafficConfig(n_partial=1500, n_unknown=1500, model="paper", hover_share=0.4))):
        t = sample_traffic(2, mission, config)
        n = t.n
        assert abs(t.hovering.mean() - share) < 4 * np.sqrt(share * (1 - share) / n)
        # A hovering curve is the degree-1 line of one location: all control points (degree-elevated) equal,
        # so the curve stays at that location for its whole time interval.
        hov = t.nominal[t.hovering]
        assert np.array_equal(hov, np.repeat(hov[:, :1], hov.shape[1], axis=1))
        s = np.linspace(0, 1, 11)
        pts = np.einsum("sk,nkd->nsd", bernstein(hov.shape[1] - 1, s), hov)
        assert np.allclose(pts, hov[:, :1])
        # The others are genuine degree-3 curves.
        fly = t.nominal[~t.hovering]
        assert (np.linalg.norm(fly[:, 1:] - fly[:, :1], axis=-1) > 0).all()
    assert sample_traffic(2, mission, TrafficConfig(model="paper", hover_share=0.0)).hovering.sum() == 0
    assert sample_traffic(2, mission, TrafficConfig(model="local")).hovering is None


def test_paper_realisations_use_the_whole_tube():
    """"The intruder may fly a trajectory that deviates at most r from the planned trajectory": the paper's
    realisations stay inside the tube, keep the end points, and at mid-flight are uniform over the whole disk of
    radius r (mean distance 2 r / 3); the local model's reach at most 0.75 r there."""
    mission = MissionConfig()
    r = 5.0
    s = np.linspace(0, 1, 101)

    def deviation(t):
        n = t.n_partial
        basis = bernstein(t.nominal.shape[1] - 1, s)
        diff = np.einsum("sk,nkd->nsd", basis, t.actual[:n] - t.nominal[:n])
        return np.linalg.norm(diff, axis=-1)                                       # (n, len(s))

    paper = deviation(sample_traffic(3, mission, TrafficConfig(n_partial=2000, n_unknown=0, model="paper")))
    local = deviation(sample_traffic(3, mission, TrafficConfig(n_partial=2000, n_unknown=0, model="local")))
    assert paper.max() <= r + 1e-9 and paper[:, [0, -1]].max() < 1e-9
    mid = paper[:, 50]
    assert mid.max() > 0.98 * r and abs(mid.mean() - 2 * r / 3) < 0.1
    assert ks_passes(mid, lambda d: np.clip(d / r, 0, 1) ** 2)                   # uniform in the disk
    assert local[:, 50].max() <= 0.75 * r + 1e-9 and not ks_passes(local[:, 50], lambda d: np.clip(d / r, 0, 1) ** 2)
    # Unknown intruders fly their nominal path.
    t = sample_traffic(3, mission, TrafficConfig(n_partial=5, n_unknown=50, model="paper"))
    assert np.array_equal(t.actual[5:], t.nominal[5:])


@pytest.mark.slow
def test_paper_robustness_matches_the_blocking_frequency_of_drawn_realisations():
    """The Monte Carlo robustness with ``model="paper"`` (realisations drawn inside the jitted program) against the
    blocking frequency of realisations drawn by :func:`tube_offsets` and rasterised by :func:`occupancy`: the same
    distribution, so each segment's ``p`` agrees within Monte Carlo error; the local model's narrower
    realisations give a visibly different ``p``."""
    mission = small()
    g = build_graph(build_network(mission))
    n_mc, r = 2048, 3.0
    # One partially known cubic intruder crossing the area during the flight.
    nominal = np.array([[[1.0, 9.0], [4.0, 2.0], [8.0, 10.0], [11.0, 3.0]]])
    one = Traffic(nominal, nominal.copy(), np.array([8.0]), np.array([30.0]), 1)
    p = segment_robustness(np.random.default_rng(0), g, one, uncertainty_km=r, n_mc=n_mc, samples_per_min=6,
                           model="paper")
    p_local = segment_robustness(np.random.default_rng(0), g, one, uncertainty_km=r, n_mc=n_mc, samples_per_min=6)
    many = nominal.repeat(n_mc, axis=0)
    actual = many.copy()
    actual[:, 1:3] += tube_offsets(np.random.default_rng(1), n_mc, 3, r)
    drawn = Traffic(many, actual, np.full(n_mc, 8.0), np.full(n_mc, 30.0), n_mc)
    occ = np.vstack([occupancy(drawn, mission, 6, g.cell_id, g.n_cells), np.zeros((1, n_mc), bool)])
    blocked = occ[g.seg_cells].any(axis=1)                                  # (n_seg, n_mc); -1 pads hit the zero row
    freq = 1.0 - blocked.mean(axis=1)
    touched = freq < 1.0
    assert touched.sum() > 50
    assert np.abs(p - freq).max() < 4.5 * np.sqrt(0.25 / n_mc) * np.sqrt(2)
    assert np.abs(p_local - freq).max() > 0.1
    # The nominal path itself: positions on the curve lie inside the area (the test intruder is a real one).
    pts, _ = curve_points(nominal, np.zeros(5, int), np.linspace(0, 1, 5))
    assert ((pts >= 0) & (pts <= mission.area_km)).all()


def test_traffic_options_are_validated():
    with pytest.raises(ValueError, match="traffic model must be one of paper, local"):
        TrafficConfig(model="uniform")
    with pytest.raises(ValueError, match="hover_share applies to the 'paper' traffic model only"):
        TrafficConfig(model="local", hover_share=0.2)
    with pytest.raises(ValueError, match=r"hover_share must be in \[0, 1\]"):
        TrafficConfig(model="paper", hover_share=1.5)
    with pytest.raises(ValueError, match="hover_share must be >= 0"):
        TrafficConfig(model="paper", hover_share=-0.1)
    with pytest.raises(ValueError, match="hover_share must be a number"):
        TrafficConfig(model="paper", hover_share="0.1")
    with pytest.raises(ValueError, match="nf_count must be one of goal, landing"):
        PlannerConfig(nf_count="cell")
    g = build_graph(build_network(small()))
    with pytest.raises(ValueError, match="nf_count"):
        dp.tables(g, np.ones(g.n_segments, bool), np.ones(g.n_segments, np.float32), "Nf", "goal", nf_count="all")
    assert TrafficConfig(model="paper").hover_fraction == PAPER_HOVER_SHARE
    assert TrafficConfig(model="local").hover_fraction == 0


def corridor_with_alternate(alternate: bool) -> MissionConfig:
    """One heading (east), speeds 0..3 cells per window, 4 cruise windows; origin cell 0, goal cell 2 landing after
    exactly 4 windows, and (``alternate``) an alternative site at cell 1, between them."""
    t = 10.0 + 5.0 * 4
    return MissionConfig(area_km=30, dh_max=360, dv_max=ONE_CELL, v_max=3 * ONE_CELL, n_increments=3,
                         rta_min=(t, t), endurance_min=t, departure_heading=0, goal_headings=(0,),
                         alternate_headings=(0,), alternates=(SFO,) if alternate else (),
                         positions_km=((0.5, 10.5), (2.5, 10.5)) + (((1.5, 10.5),) if alternate else ()))


# By hand, on the corridor: a trajectory from cell x at window k flies speeds v_{k+1}, ..., v_4 (cells per
# window; each within 1 of the previous one, v_4 = 0) with x + v_{k+1} + ... + v_4 = 2. Per state (x, v):
#   window 3: (2, 0) -> 1 [v_4 = 0], (2, 1) -> 1 [v_4 = 0]
#   window 2: (0, 0) -> 0 [needs v_3 = 2 from speed 0], (1, 0) -> 1 [1, 0], (1, 1) -> 1 [1, 0], (2, 1) -> 1 [0, 0]
#   window 1: (0, 0) -> 1 [1, 1, 0], (1, 1) -> 2 [0, 1, 0 and 1, 0, 0]
#   window 0: (0, 0) -> 3 [0, 1, 1, 0; 1, 0, 1, 0; 1, 1, 0, 0]
# Per cell (the paper's c.N_f: the sum over the cell's states), the cells with at least one trajectory:
HAND_CELL_COUNTS = {
    0: {0: 3},
    1: {0: 1, 1: 2},
    2: {1: 2, 2: 1},
    3: {2: 2},
    4: {2: 1},
}


def _cell_values(g, values):
    out = {}
    for gi in range(g.n_states):
        k = g.window_of(gi)
        x = int(g.states[gi, 0])
        prev = out.setdefault(k, {}).setdefault(x, None)
        assert prev is None or prev == values[gi]         # every state of a cell carries the cell's count
        out[k][x] = float(values[gi])
    return {k: {x: v for x, v in cells.items()} for k, cells in out.items()}


@pytest.mark.slow
def test_nf_goal_count_is_the_hand_count_of_trajectories_to_the_goal_per_cell():
    for alternate in (False, True):
        g = build_graph(build_network(corridor_with_alternate(alternate)))
        feasible = np.ones(g.n_segments, bool)
        p = np.ones(g.n_segments, np.float32)
        goal = dp.tables(g, feasible, p, "Nf", "goal", nf_count="goal")
        cells = _cell_values(g, np.asarray(goal.value))
        # Cells with states that reach only the alternative site (alternate=True) count 0 trajectories to the goal.
        assert {k: {x: v for x, v in c.items() if v} for k, c in cells.items()} == HAND_CELL_COUNTS, (alternate, cells)
        # The per-state counts to the goal are the hand's too: (1, 1) at window 1 has 2 trajectories.
        assert float(goal.n_goal[g.index(1, (1, 10, 0, 1))]) == 2.0
        assert float(goal.n_goal[g.origin]) == 3.0
    # With the alternative site, the landing count (per state, to any site) is another number: from the origin it
    # also counts the trajectories that land at cell 1, and a cell's states no longer share one value.
    landing = dp.tables(g, feasible, p, "Nf", "goal")
    assert float(landing.value[g.origin]) > 3.0
    assert float(landing.value[g.origin]) == float(dp.counts(g, feasible, "all")[g.origin])
    assert not np.array_equal(np.asarray(landing.value), np.asarray(goal.value))
    # Once Omega includes the alternative site, the paper's count is to Omega = goal + alternative, per cell.
    both = dp.tables(g, feasible, p, "Nf", "all", nf_count="goal")
    assert np.array_equal(np.asarray(both.value), dp.cell_sums(g, np.asarray(dp.counts(g, feasible, "all"))))


@pytest.mark.slow
def test_nf_goal_count_equals_cell_sums_with_blocked_cells_and_flies_missions():
    """On the 12 x 12 km mission with random blocked cells: the sweep's per-cell count equals the numpy cell sums
    of the per-state counts to Omega, and pi_Nf's future term sums those values; missions fly with it."""
    mission = small()
    g = build_graph(build_network(mission))
    rng = np.random.default_rng(4)
    blocked = rng.random((mission.n_minutes, mission.n_cells, mission.n_cells)) < 0.05
    feasible = feasible_from_blocked(g, blocked)
    p = rng.uniform(0.5, 1.0, g.n_segments).astype(np.float32)
    for omega, kind in (("goal", "goal"), ("all", "all")):
        t = dp.tables(g, feasible, p, "Nf", omega, nf_count="goal")
        want = dp.cell_sums(g, np.asarray(dp.counts(g, feasible, kind), np.float64))
        assert np.allclose(np.asarray(t.value), want, rtol=1e-6)
        assert not np.allclose(np.asarray(t.value), np.asarray(dp.tables(g, feasible, p, "Nf", omega).value))
    assert dp.cone_tables(g, feasible, p, "Nf", "goal", g.origin, nf_count="goal") is None   # cells leave the cone
    # With no traffic, pi_Nf with the paper's count still reaches the goal.
    empty = make_instance(g, TrafficConfig(n_partial=0, n_unknown=0), PlannerConfig(n_mc=64, n_survival=64), 0)
    planner = PlannerConfig(n_mc=64, n_survival=64, nf_count="goal")
    first = initial_tables(g, empty, ("Nf",), "goal")
    assert run_mission(g, empty, "Nf", planner, initial_tables=first["Nf"]).outcome == "G"


def _slice(config):
    from stp_env.survivability.study import run_instance

    g = build_graph(build_network(config.mission))
    keys = ("outcome", "reveals", "omega_switch", "n_dp", "windows")
    rows, shared = {}, {}
    for p, u in config.scenarios:
        for i in range(config.n_instances):
            for r in run_instance(g, config, p, u, i, shared):
                rows[(p, u, i, r["policy"])] = tuple(r[k] for k in keys)
    inst = make_instance(g, config.traffic.with_overrides(n_partial=6, n_unknown=8), config.planner, (0, 1))
    return rows, inst


@pytest.mark.slow
def test_defaults_are_the_papers_and_the_earlier_model_is_a_named_variant():
    """The default configuration flies the same missions, with the same robustness, as ``model="paper"``,
    ``nf_count="goal"`` named explicitly; the earlier model (``local``, ``landing``) changes them. A study of the
    earlier model, named explicitly, has the fingerprint of a study written before the options existed (so such a
    study resumes when its options are given); the default's fingerprint names the paper's options."""
    from stp_env.survivability.config import StudyConfig

    planner = PlannerConfig(n_mc=64, n_survival=64)
    base = StudyConfig(n_partial=(6,), n_unknown=(8, 30), n_instances=3, mission=small(),
                       traffic=TrafficConfig(reach_km=4), planner=planner)
    explicit = dataclasses.replace(base, traffic=TrafficConfig(reach_km=4, model="paper"),
                                   planner=PlannerConfig(n_mc=64, n_survival=64, nf_count="goal"))
    earlier = dataclasses.replace(base, traffic=TrafficConfig(reach_km=4, model="local"),
                                  planner=PlannerConfig(n_mc=64, n_survival=64, nf_count="landing"))
    rows0, inst0 = _slice(base)
    rows1, inst1 = _slice(explicit)
    rows2, inst2 = _slice(earlier)
    assert rows0 == rows1
    for name in ("robustness", "blocked_bits", "occupancy"):
        assert np.array_equal(getattr(inst0, name), getattr(inst1, name)), name
    assert np.array_equal(inst0.traffic.actual, inst1.traffic.actual)
    assert len(rows0) == 2 * 3 * len(POLICIES)
    assert rows2 != rows0 and not np.array_equal(inst2.robustness, inst0.robustness)
    fp = earlier.fingerprint()
    assert "model" not in fp["traffic"] and "hover_share" not in fp["traffic"] and "nf_count" not in fp["planner"]
    assert base.fingerprint() == explicit.fingerprint() != fp
    assert base.fingerprint()["traffic"]["model"] == "paper" and base.fingerprint()["planner"]["nf_count"] == "goal"


def test_cli_traffic_and_nf_count_options(tmp_path):
    import argparse

    from _cli import run_cli

    from stp_env.survivability.cli import add_parser, config_from_args

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    out = ["survivability", "--out", str(tmp_path)]
    default = config_from_args(parser.parse_args(out))
    assert (default.traffic.model, default.traffic.hover_share, default.planner.nf_count) == ("paper", None, "goal")
    assert default.traffic.hover_fraction == PAPER_HOVER_SHARE
    args = parser.parse_args([*out, "--traffic", "paper", "--nf-count", "goal", "--hover-share", "0.25"])
    config = config_from_args(args)
    assert (config.traffic.model, config.traffic.hover_fraction, config.planner.nf_count) == ("paper", 0.25, "goal")
    code, _, err = run_cli([*out, "--traffic", "local", "--hover-share", "0.25"])
    assert code == 2 and err.count("\n") == 1 and "hover_share applies" in err
    code, _, err = run_cli([*out, "--traffic", "bezier"])
    assert code == 2 and "invalid choice" in err


def test_max_speed_is_the_paper_draw_conditioned_on_the_bound():
    """``TrafficConfig(max_speed=v)``: every nominal path is flown at a mean speed of at most ``v`` inside
    ``(t_0, t_fu)``, and the exact conditional construction (acceptance by curve length, the time triangle scaled)
    has the distribution of brute-force rejection of the unbounded draw (means and spread of the length, the
    duration and the entry time within 4.5 standard errors); a smaller scenario's intruders are a larger one's."""
    from stp_env.survivability.traffic import KM_PER_MIN_PER_MS, curve_length

    mission, v, n = MissionConfig(), 40.0, 4000
    t_fu = mission.rta_min[1]
    t = sample_traffic(5, mission, TrafficConfig(n_partial=n, n_unknown=0, hover_share=0.0, max_speed=v))
    length = curve_length(t.nominal)
    assert (length / t.duration <= v * KM_PER_MIN_PER_MS * (1 + 1e-9)).all()
    assert (t.t_in >= 0).all() and (t.t_in + t.duration <= t_fu + 1e-9).all()
    # Brute force: the unbounded model's draw (control points anywhere, sorted times), kept when slow enough.
    rng = np.random.default_rng(6)
    kept = []
    while sum(len(k[0]) for k in kept) < n:
        ctrl = rng.uniform(0.0, mission.area_km, size=(20_000, 4, 2))
        times = np.sort(rng.uniform(0.0, t_fu, size=(20_000, 2)), axis=1)
        ln, dur = curve_length(ctrl), times[:, 1] - times[:, 0]
        ok = ln <= v * KM_PER_MIN_PER_MS * dur
        kept.append((ln[ok], dur[ok], times[ok, 0]))
    ref = [np.concatenate([k[i] for k in kept])[:n] for i in range(3)]
    for got, want in zip((length, t.duration, t.t_in), ref):
        se = np.sqrt(got.var() / n + want.var() / n)
        assert abs(got.mean() - want.mean()) < 4.5 * se
        assert abs(got.std() - want.std()) < 0.05 * want.std()
    # The bound lengthens the flights (the unbounded model's median speed is far above 40 m/s).
    free = sample_traffic(5, mission, TrafficConfig(n_partial=n, n_unknown=0, hover_share=0.0))
    assert np.median(curve_length(free.nominal) / free.duration) > 1.5 * v * KM_PER_MIN_PER_MS
    assert t.duration.mean() > 1.5 * free.duration.mean()
    # Common random numbers: the intruders of (50, 50) are those of (300, 300).
    small_t = sample_traffic(3, mission, TrafficConfig(n_partial=50, n_unknown=50, max_speed=v))
    big_t = sample_traffic(3, mission, TrafficConfig(n_partial=300, n_unknown=300, max_speed=v))
    for a, b in zip(small_t[:4], big_t[:4]):
        assert np.array_equal(a[:50], b[:50]) and np.array_equal(a[50:], b[300:350])
    # Hovering intruders keep the unbounded model's times (they do not move).
    hov = sample_traffic(7, mission, TrafficConfig(n_partial=500, n_unknown=0, max_speed=v))
    free_hov = sample_traffic(7, mission, TrafficConfig(n_partial=500, n_unknown=0))
    assert np.array_equal(hov.hovering, free_hov.hovering) and hov.hovering.any()
    assert np.array_equal(hov.t_in[hov.hovering], free_hov.t_in[hov.hovering])
    assert np.array_equal(hov.nominal[hov.hovering], free_hov.nominal[hov.hovering])


def test_max_speed_option_checks_and_fingerprint(tmp_path):
    import argparse

    from _cli import run_cli

    from stp_env.survivability.cli import add_parser, config_from_args
    from stp_env.survivability.config import StudyConfig

    with pytest.raises(ValueError, match="max_speed applies to the 'paper' traffic model only"):
        TrafficConfig(model="local", max_speed=40.0)
    with pytest.raises(ValueError, match="max_speed must be > 0"):
        TrafficConfig(max_speed=0.0)
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    out = ["survivability", "--out", str(tmp_path)]
    assert config_from_args(parser.parse_args(out)).traffic.max_speed is None
    bounded = config_from_args(parser.parse_args([*out, "--max-speed", "40"]))
    assert bounded.traffic.max_speed == 40.0
    # Studies written before the option resume (it is left out at its default); a bounded study is another one.
    assert "max_speed" not in StudyConfig().fingerprint()["traffic"]
    assert bounded.fingerprint()["traffic"]["max_speed"] == 40.0
    code, _, err = run_cli([*out, "--traffic", "local", "--max-speed", "40"])
    assert code == 2 and err.count("\n") == 1 and "max_speed applies" in err


def test_traffic_statistics_by_hand():
    """One intruder flying 10 km east in 10 minutes (a straight cubic with equally spaced control points): 1 km per
    minute = 16.7 m/s, airborne 10 of the mission's 60 minutes, and 2 cells blocked per minute (the path crosses
    from x in [m + 0.5, m + 1.5) in minute m), 20 in all; a hovering intruder is left out of the path figures."""
    from stp_env.survivability.traffic import traffic_statistics

    mission = MissionConfig()
    line = np.array([[[0.5 + 10.0 * i / 3, 0.5] for i in range(4)]])
    one = Traffic(line, line, np.array([0.0]), np.array([10.0]), 1)
    stats = traffic_statistics(one, mission, 6)
    assert stats["moving"] == 1 and stats["length_km"] == pytest.approx(10.0)
    assert stats["duration_min"] == 10.0 and stats["speed_ms_p50_p90_p99"] == pytest.approx([1000 / 60] * 3)
    assert stats["airborne_fraction"] == pytest.approx(10 / 60) and stats["cells_per_intruder"] == 20
    hover = np.full((1, 4, 2), 40.5)
    two = Traffic(np.concatenate([line, hover]), np.concatenate([line, hover]), np.array([0.0, 0.0]),
                  np.array([10.0, 30.0]), 2, np.array([False, True]))
    stats = traffic_statistics(two, mission, 6)
    assert stats["moving"] == 1 and stats["length_km"] == pytest.approx(10.0)
    assert stats["cells_per_intruder"] == (20 + 30) / 2
