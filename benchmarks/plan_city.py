"""Seconds per vehicle when planning the ``city`` scenario: the heading-split planner against the unsplit one.

    python benchmarks/plan_city.py [--vehicles 3] [--tracking-bound 5.338]

Prints one JSON line. The ``n`` highest-priority vehicles of ``make("city")`` (Case 0: wind 6 m/s, STA spacing 0,
robust trajectory tracking, the synthetic downtown; horizon as for all 50 vehicles) are planned twice, each in its
own process (peak RSS is its own): ``new`` with :func:`stp_env.planning.stp.plan_rtt`'s default solver (the
heading split of :mod:`stp_env.planning.brs`, one compiled loop per scenario) and ``old`` with ``solver="hj"``
(:func:`stp_env.hj.solve` on all three axes, early stop checked in segments), both with ENO2 + RK2. Per vehicle:
wall seconds (the first includes compilation, so the mean is also given without it) and the process's CPU
seconds (user + system: on a shared machine wall time depends on the other jobs, CPU time much less). ``diff``
compares the plans: latest departure and arrival times, the largest distance between the two nominal positions at
the same time over the common flight window, and the Hausdorff distance between the two flown paths, in metres
and in position cells.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np


def _city_subset(n: int):
    from stp_env.scenarios import make

    full = make("city")
    dist = np.hypot(*(full.targets() - full.starts()[:, :2]).T)
    horizon = 2.0 * float(dist.max()) / full.planning_v[1] + 1.0
    keep = tuple(v for v in full.vehicles if v.priority < n)
    return full.with_overrides(vehicles=keep), horizon


def run_child(solver: str, n: int, bound: float, out: str) -> dict:
    import stp_env.planning.stp as stp

    scenario, horizon = _city_subset(n)
    wall, cpu = [], []
    original = stp.plan_single

    def timed(*args, **kwargs):
        t0, c0 = time.perf_counter(), time.process_time()
        result = original(*args, **kwargs)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        return result

    stp.plan_single = timed
    plan = stp.plan_scenario(scenario, tracking_bound=bound, horizon=horizon, settings=None, progress=False,
                             solver=solver)
    np.savez(out, **stp.plan_to_arrays(plan))
    return {"solver": solver, "seconds": [round(t, 2) for t in wall], "cpu_seconds": [round(t, 2) for t in cpu],
            "steps": [v.plan.n_steps for v in plan.vehicles],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def plan_difference(a: dict, b: dict, dx: float) -> dict:
    """How far apart two plans' trajectories are (arrays of :func:`stp_env.planning.stp.plan_to_arrays`)."""
    same_time, hausdorff = [], []
    for i, (la, lb) in enumerate(zip(a["lengths"], b["lengths"])):
        ta, pa = a["times"][i, :la], a["states"][i, :la, :2]
        tb, pb = b["times"][i, :lb], b["states"][i, :lb, :2]
        end = min(a["arrival_time"][i], b["arrival_time"][i])
        grid_t = np.arange(max(ta[0], tb[0]), end, 0.5)
        qa = np.stack([np.interp(grid_t, ta, pa[:, k]) for k in (0, 1)], -1)
        qb = np.stack([np.interp(grid_t, tb, pb[:, k]) for k in (0, 1)], -1)
        same_time.append(float(np.max(np.linalg.norm(qa - qb, axis=-1))) if grid_t.size else 0.0)
        fa, fb = pa[ta <= a["arrival_time"][i]], pb[tb <= b["arrival_time"][i]]
        d = np.linalg.norm(fa[:, None] - fb[None], axis=-1)
        hausdorff.append(float(max(d.min(0).max(), d.min(1).max())))
    return {
        "t_ldt_abs_diff_s": np.abs(a["t_ldt"] - b["t_ldt"]).round(2).tolist(),
        "arrival_abs_diff_s": np.abs(a["arrival_time"] - b["arrival_time"]).round(2).tolist(),
        "max_same_time_dev_m": np.round(same_time, 1).tolist(),
        "path_hausdorff_m": np.round(hausdorff, 1).tolist(),
        "path_hausdorff_cells": np.round(np.asarray(hausdorff) / dx, 2).tolist(),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--vehicles", type=int, default=3)
    parser.add_argument("--tracking-bound", type=float, default=5.338,
                        help="r_e [m] (default: the converged bound at 6 m/s wind)")
    parser.add_argument("--child", choices=["split", "hj"])
    parser.add_argument("--out")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(run_child(args.child, args.vehicles, args.tracking_bound, args.out)))
        return
    out = {"case": "plan_city", "vehicles": args.vehicles, "tracking_bound": args.tracking_bound,
           "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    arrays = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, solver in (("new", "split"), ("old", "hj")):
            path = os.path.join(tmp, f"{solver}.npz")
            cmd = [sys.executable, __file__, "--child", solver, "--vehicles", str(args.vehicles),
                   "--tracking-bound", str(args.tracking_bound), "--out", path]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode:
                sys.exit(f"{name} failed:\n{proc.stderr[-3000:]}")
            out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
            print(json.dumps({name: out[name]}), file=sys.stderr, flush=True)
            with np.load(path, allow_pickle=False) as data:
                arrays[name] = {k: data[k] for k in data.files}
    scenario, _ = _city_subset(1)
    out["diff"] = plan_difference(arrays["new"], arrays["old"], max(scenario.grid().spacing[:2]))
    for name in ("new", "old"):
        wall, cpu = out[name]["seconds"], out[name]["cpu_seconds"]
        out[f"{name}_mean_s_per_vehicle"] = round(float(np.mean(wall)), 1)
        out[f"{name}_mean_s_per_vehicle_after_first"] = round(float(np.mean(wall[1:])), 1) if len(wall) > 1 else None
        out[f"{name}_mean_cpu_s_per_vehicle_after_first"] = round(float(np.mean(cpu[1:])), 1) if len(cpu) > 1 else None
    out["speedup_wall"] = round(out["old_mean_s_per_vehicle"] / out["new_mean_s_per_vehicle"], 2)
    if args.vehicles > 1:
        out["speedup_cpu_after_first"] = round(out["old_mean_cpu_s_per_vehicle_after_first"]
                                               / out["new_mean_cpu_s_per_vehicle_after_first"], 2)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
