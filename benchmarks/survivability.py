"""Survivability study throughput, one JSON line per case, each with a peer measured in the same run.

    python benchmarks/survivability.py [--instances 12] [--segments 300]
        [--cases counts robustness instance study sweeps changed]

* ``counts``: trajectory counts to any landing site with no traffic, on the compact mission graph
  (:func:`stp_env.survivability.dp.counts`) against the dense network of every cell, heading and speed
  (:func:`stp_env.survivability.dense.counts`); both give the same count at the origin.
* ``robustness``: the robustness of every segment from 2,500 Monte Carlo realisations in one jitted program
  (bit sets per cell, OR per segment) against the direct evaluation of the same realisations, segment by segment,
  in numpy (timed on ``--segments`` random segments and scaled to all of them); both give the same values.
* ``instance``: one traffic instance flown by the four policies (set-up: traffic, robustness, the first DP sweep
  shared by the policies; then the missions), at (N_p, N_u) = (50, 50), (175, 175) ~ the grid's mean, (300, 300);
  peers: the same instances with every recomputation over all states from the current window (``no_cone``: no
  numpy sweep over the states reachable from the current one) and from the first window (``full``); the
  missions (outcomes, reveals, sweeps, windows) must be the same in all three.
* ``sweeps``: one recomputation of a policy's tables (``R``, ``S``, ``AvgR``) from a state of cruise window 0, 1
  or 2, where the paper's traffic causes most of them: the compiled sweep over every state from the window
  (:func:`stp_env.survivability.dp.tables`) against the numpy sweep over the states reachable from that one
  (:func:`stp_env.survivability.dp.cone_tables`; the same entries, checked), and against the compiled sweep
  with one group of states per window (``peer_one_group``: each state's successors packed left but every state
  padded to the window's largest count, ``dp.BUCKET_WIDTHS = ()``; the same tables, checked); and the search for
  the reachable states with the 4,000-state limit a mission uses against the whole search.
* ``changed``: what an incremental sweep could save: every policy's missions through ``--instances`` instances of
  (100, 100) and (200, 200) are replayed reveal by reveal (the reveals of one decision point as one; a widening of
  ``Omega``, which changes every ``future`` entry, is not counted and is replayed after its window's reveals), and
  each recomputation's tables are
  compared with the previous ones: the share of the states from the current window whose entries changed, per
  window (a sweep that recomputed only those would do at most ``1 / share`` times less work).
* ``study``: a group of scenarios with one N_p and all six N_u (the study's unit of work), instances sharing
  their robustness and first tables (``run_instance(..., shared)``) against the same instances computed alone.

Times exclude compilation (a warm-up pass over the same instances first, for each variant); ``cpu_s`` is this
process's user + system time, ``loadavg`` the machine's 1-minute load average before the case (the machine is
shared).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

import numpy as np


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def timed(fn, repeats=3):
    fn()
    best, c0 = np.inf, cpu()
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best, (cpu() - c0) / repeats


def case_counts(graph) -> dict:
    from stp_env.survivability import dense, dp

    load = os.getloadavg()[0]
    free = np.ones(graph.n_segments, bool)
    full = dense.free_feasibility(graph.net)
    a, t_a, c_a = timed(lambda: np.asarray(dp.counts(graph, free, "all")))
    b, t_b, c_b = timed(lambda: np.asarray(dense.counts(graph.net, full, "all")))
    assert np.isclose(a[graph.origin], b[(0, *graph.net.origin_state())], rtol=1e-6)   # float32 sums
    return {"case": "counts", "graph_s": round(t_a, 4), "dense_s": round(t_b, 4), "ratio": round(t_b / t_a, 1),
            "cpu_s": [round(c_a, 4), round(c_b, 4)], "graph_states": graph.n_states,
            "dense_states": int(np.prod(b.shape)), "origin_count": float(a[graph.origin]), "loadavg": load}


def case_robustness(graph, n_segments: int) -> dict:
    import jax.numpy as jnp

    from stp_env.survivability import robustness as R
    from stp_env.survivability.config import TrafficConfig
    from stp_env.survivability.traffic import sample_traffic

    load = os.getloadavg()[0]
    mission = graph.net.mission
    traffic = sample_traffic(7, mission, TrafficConfig(n_partial=175, n_unknown=175))
    n_mc, spm, radius = 2500, 6, 5.0
    p, t_all, c_all = timed(lambda: R.segment_robustness(np.random.default_rng(0), graph, traffic,
                                                         uncertainty_km=radius, n_mc=n_mc, samples_per_min=spm))
    # Peer: the same realisations (same generator draws), segment by segment in numpy.
    pts, weights, who, minute = R.candidate_points(graph, traffic, radius, spm)
    used, who = np.unique(who, return_inverse=True)
    n_used = -(-len(used) // 16) * 16
    n_chunks = -(-n_mc // R.CHUNK)
    u = np.random.default_rng(0).random((n_chunks, R.CHUNK, n_used, weights.shape[1], 2), dtype=np.float32)
    u = u.reshape(-1, n_used, weights.shape[1], 2)[:n_mc]
    del jnp
    rng = np.random.default_rng(1)
    segs = rng.choice(graph.n_segments, n_segments, replace=False)

    def peer():
        r = radius * np.sqrt(u[..., 0])
        a = 2 * np.pi * u[..., 1]
        off = np.stack([r * np.cos(a), r * np.sin(a)], -1)[:, who]              # (n_mc, P, k - 1, 2)
        xy = np.floor(pts[None] + np.einsum("pi,jpid->jpd", weights, off)).astype(np.int64)
        n = graph.net.n
        inside = (xy[..., 0] >= 0) & (xy[..., 0] < n) & (xy[..., 1] >= 0) & (xy[..., 1] < n)
        ids = np.where(inside, graph.cell_id[np.broadcast_to(minute, inside.shape), np.clip(xy[..., 0], 0, n - 1),
                                             np.clip(xy[..., 1], 0, n - 1)], -1)
        out = []
        for s in segs:
            cells = graph.seg_cells[s][graph.seg_cells[s] >= 0]
            out.append(1.0 - np.isin(ids, cells).any(axis=1).mean())
        return np.array(out)

    q, t_peer, c_peer = timed(peer, repeats=1)
    assert np.allclose(p[segs], q, atol=1e-6), float(np.abs(p[segs] - q).max())
    scaled = t_peer * graph.n_segments / n_segments
    return {"case": "robustness", "n_mc": n_mc, "segments": graph.n_segments, "batched_s": round(t_all, 3),
            "per_segment_numpy_s_scaled": round(scaled, 1), "ratio": round(scaled / t_all, 1),
            "cpu_s": [round(c_all, 3), round(c_peer * graph.n_segments / n_segments, 1)],
            "checked_segments": n_segments, "max_abs_diff": float(np.abs(p[segs] - q).max()),
            "candidate_points": len(pts), "scenario": [175, 175], "loadavg": load}


def case_instance(graph, n_instances: int, scenario) -> dict:
    from stp_env.survivability import mission
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.study import run_instance

    load = os.getloadavg()[0]
    config = StudyConfig()
    out = {}
    defaults = mission.SWEEP_FROM_CURRENT_ABOVE, mission.CONE_STATES_MAX
    keys = ("outcome", "reveals", "omega_switch", "n_dp", "windows")
    for name, (threshold, cone_max) in (("cone", defaults), ("no_cone", (defaults[0], 0)), ("full", (10**12, 0))):
        mission.SWEEP_FROM_CURRENT_ABOVE, mission.CONE_STATES_MAX = threshold, cone_max
        for i in range(n_instances):                                            # warm-up: compile every shape
            run_instance(graph, config, *scenario, 20_000 + i)
        c0, t0 = cpu(), time.perf_counter()
        rows = [r for i in range(n_instances) for r in run_instance(graph, config, *scenario, 20_000 + i)]
        out[name] = (time.perf_counter() - t0, cpu() - c0, [tuple(r[k] for k in keys) for r in rows], rows)
    mission.SWEEP_FROM_CURRENT_ABOVE, mission.CONE_STATES_MAX = defaults
    wall, c, missions, rows = out["cone"]
    setup = float(np.mean([r["instance_s"] for r in rows[::4]]))
    per_mission = float(np.mean([r["mission_s"] for r in rows]))
    return {"case": "instance", "scenario": list(scenario), "instances": n_instances,
            "wall_s_per_instance": round(wall / n_instances, 3), "cpu_s_per_instance": round(c / n_instances, 3),
            "setup_s": round(setup, 3), "mission_s": round(per_mission, 4),
            "dp_sweeps_per_mission": round(float(np.mean([r["n_dp"] for r in rows])) - 0.75, 2),
            "reveals_per_mission": round(float(np.mean([r["reveals"] for r in rows])), 2),
            "peer_no_cone_wall_s_per_instance": round(out["no_cone"][0] / n_instances, 3),
            "peer_no_cone_mission_s": round(float(np.mean([r["mission_s"] for r in out["no_cone"][3]])), 4),
            "peer_full_sweeps_wall_s_per_instance": round(out["full"][0] / n_instances, 3),
            "ratio_vs_no_cone": round(out["no_cone"][0] / wall, 2), "ratio_vs_full": round(out["full"][0] / wall, 2),
            "same_missions": all(out[k][2] == missions for k in out), "loadavg": load}


def case_study(graph, n_instances: int, n_partial: int = 175) -> dict:
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.names import LEVELS
    from stp_env.survivability.study import run_instance

    load = os.getloadavg()[0]
    config = StudyConfig()
    keys = ("outcome", "reveals", "omega_switch", "n_dp", "windows")
    run_instance(graph, config, n_partial, LEVELS[0], 30_000)                   # warm-up
    out = {}
    for name in ("alone", "shared"):
        c0, t0 = cpu(), time.perf_counter()
        rows = []
        for i in range(n_instances):
            shared = {} if name == "shared" else None
            for u in LEVELS:
                rows += run_instance(graph, config, n_partial, u, 31_000 + i, shared)
        out[name] = (time.perf_counter() - t0, cpu() - c0, [tuple(r[k] for k in keys) for r in rows])
    n = n_instances * len(LEVELS)
    return {"case": "study", "n_partial": n_partial, "n_unknown": list(LEVELS), "instances": n,
            "wall_s_per_instance": round(out["shared"][0] / n, 3), "cpu_s_per_instance": round(out["shared"][1] / n, 3),
            "peer_alone_wall_s_per_instance": round(out["alone"][0] / n, 3),
            "ratio": round(out["alone"][0] / out["shared"][0], 2),
            "same_missions": out["alone"][2] == out["shared"][2], "loadavg": load}


def case_sweeps(graph, window: int) -> dict:
    from stp_env.survivability import dp, mission
    from stp_env.survivability.config import StudyConfig

    load = os.getloadavg()[0]
    config = StudyConfig()
    inst = mission.make_instance(graph, config.traffic, config.planner, (config.seed, 40_000))
    feasible = np.ones(graph.n_segments, bool)
    feasible[::50] = False                                               # some known conflicts
    root = graph.origin if window == 0 else int(graph.window_start[window]) + 7
    layers = dp.cone(graph, root)
    out = {"case": "sweeps", "window": window, "reachable_states": int(sum(len(x) for x in layers)),
           "graph_states": graph.n_states}
    for policy in ("R", "S", "AvgR"):
        a, t_a, _ = timed(lambda p=policy: mission._numpy(dp.tables(
            graph, feasible, inst.robustness, p, "goal", window, inst.blocked_bits)), repeats=10)
        b, t_b, _ = timed(lambda p=policy: dp.cone_tables(graph, feasible, inst.robustness, p, "goal", root,
                                                            inst.blocked_bits, layers), repeats=10)
        cone = np.concatenate(layers)
        assert all(np.array_equal(x[cone], y[cone]) for x, y in zip(a, b))     # the same entries, bit for bit
        # Peer 2: the same compiled sweep with one group of states per window (no grouping by successor count).
        widths = dp.BUCKET_WIDTHS
        dp.BUCKET_WIDTHS = ()
        dp._consts.cache_clear()
        try:
            c, t_c, _ = timed(lambda p=policy: mission._numpy(dp.tables(
                graph, feasible, inst.robustness, p, "goal", window, inst.blocked_bits)), repeats=10)
        finally:
            dp.BUCKET_WIDTHS = widths
            dp._consts.cache_clear()
        assert all(np.array_equal(x, y) for x, y in zip(a, c))                 # the same tables, bit for bit
        out[policy] = {"compiled_ms": round(1e3 * t_a, 2), "peer_numpy_cone_ms": round(1e3 * t_b, 2),
                       "ratio": round(t_b / t_a, 2), "peer_one_group_ms": round(1e3 * t_c, 2),
                       "ratio_one_group": round(t_c / t_a, 2)}
    _, t_all, _ = timed(lambda: dp.cone(graph, root), repeats=10)
    _, t_lim, _ = timed(lambda: dp.cone(graph, root, limit=mission.CONE_STATES_MAX), repeats=10)
    out["cone_search_ms"] = {"limited": round(1e3 * t_lim, 3), "peer_whole": round(1e3 * t_all, 3),
                             "ratio": round(t_all / t_lim, 1)}
    out["loadavg"] = load
    return out


def case_changed(graph, n_instances: int) -> dict:
    from stp_env.survivability import dp, mission
    from stp_env.survivability.config import StudyConfig

    config = StudyConfig()
    planner = config.planner
    shares: dict = {}
    n_missions = n_widened = 0

    def tables(policy, know, omega, window, inst):
        return mission._numpy(dp.tables(graph, know.feasible, inst.robustness, policy, omega, window,
                                        inst.blocked_bits, planner.nf_count))

    minutes = [graph.net.window_start_minute(k) for k in range(graph.net.n_windows + 1)]
    for i in range(n_instances):
        for scenario in ((100, 100), (200, 200)):
            traffic = config.traffic.with_overrides(n_partial=scenario[0], n_unknown=scenario[1])
            inst = mission.make_instance(graph, traffic, planner, (config.seed, 50_000 + i))
            for policy in config.policies:
                res = mission.run_mission(graph, inst, policy, planner, seed=(config.seed, 50_000 + i))
                n_missions += 1
                n_widened += res.omega_switch is not None
                know = mission.Knowledge(graph, inst)
                omega, prev = "goal", tables(policy, know, "goal", 0, inst)
                switch = res.omega_switch
                for minute in sorted(set(res.reveal_minutes)):
                    window = minutes.index(minute)
                    if switch is not None and window > switch and omega == "goal":
                        omega, prev = "all", tables(policy, know, "all", window, inst)
                    know.reveal([r for r, m in zip(res.revealed, res.reveal_minutes) if m == minute], minute)
                    new = tables(policy, know, omega, window, inst)
                    lo = graph.window_start[window]
                    changed = np.zeros(graph.n_states - lo, bool)
                    for a, b in zip(prev, new):
                        changed |= a[lo:] != b[lo:]
                    shares.setdefault(window, []).append(float(changed.mean()))
                    prev = new
                    if window == switch and omega == "goal":    # widened after this window's reveals
                        omega, prev = "all", tables(policy, know, "all", window, inst)
    return {"case": "changed", "missions": n_missions, "widened": n_widened,
            "scenarios": [[100, 100], [200, 200]],
            "per_window": {str(k): {"recomputations": len(v), "changed_share_mean": round(float(np.mean(v)), 3),
                                    "changed_share_median": round(float(np.median(v)), 3),
                                    "incremental_ceiling": round(1.0 / max(float(np.mean(v)), 1e-9), 1)}
                           for k, v in sorted(shares.items())}}


CASES = ("counts", "robustness", "instance", "study", "sweeps", "changed")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--instances", type=int, default=12)
    ap.add_argument("--segments", type=int, default=300)
    ap.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    args = ap.parse_args()
    from stp_env.survivability.graph import build_graph

    graph = build_graph()
    if "counts" in args.cases:
        print(json.dumps(case_counts(graph)), flush=True)
    if "robustness" in args.cases:
        print(json.dumps(case_robustness(graph, args.segments)), flush=True)
    if "instance" in args.cases:
        for scenario in ((50, 50), (175, 175), (300, 300)):
            print(json.dumps(case_instance(graph, args.instances, scenario)), flush=True)
    if "study" in args.cases:
        print(json.dumps(case_study(graph, max(1, args.instances // 4))), flush=True)
    if "changed" in args.cases:
        print(json.dumps(case_changed(graph, args.instances)), flush=True)
    if "sweeps" in args.cases:
        for window in (0, 1, 2):
            print(json.dumps(case_sweeps(graph, window)), flush=True)


if __name__ == "__main__":
    main()
