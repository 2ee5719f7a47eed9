"""Seconds and peak memory per vehicle when planning the ``city`` scenario, with a same-run peer.

    python benchmarks/plan_city.py [--vehicles 3] [--peer-seconds 10]

Prints one JSON line. ``new``: the ``n`` highest-priority vehicles of ``make("city")`` (Case 0: wind 6 m/s, STA
spacing 0), planned in one process with the current planner (:func:`stp_env.planning.stp.plan_rtt` defaults:
ENO2 + RK2, early stop at ``t_LDT``, the scenario's grid), horizon as for all 50 vehicles; compile included in the
first vehicle, so the per-vehicle mean is reported with and without it. ``peer``: the settings before this
benchmark (WENO5 + RK2 "high", 251 x 251 x 36 grid, the whole 2x-longest-flight horizon, no early stop),
measured in its own process on the first vehicle's BRS for ``--peer-seconds`` of solver time, and extrapolated
per vehicle as ms/step times the steps of the whole horizon (a full run takes ~5 minutes per vehicle). Both
processes report their peak RSS (``ru_maxrss``), and ``loadavg`` shows how busy the shared machine was.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time

import numpy as np


def _city_subset(n: int):
    from stp_env.scenarios import make

    full = make("city")
    dist = np.hypot(*(full.targets() - full.starts()[:, :2]).T)
    horizon = 2.0 * float(dist.max()) / full.planning_v[1] + 1.0
    keep = tuple(v for v in full.vehicles if v.priority < n)
    return full.with_overrides(vehicles=keep), horizon


def run_new(n: int) -> dict:
    from stp_env.planning.stp import plan_scenario

    scenario, horizon = _city_subset(n)
    times = []
    import stp_env.planning.stp as stp

    original = stp.plan_single

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        out = original(*args, **kwargs)
        times.append(time.perf_counter() - t0)
        return out

    stp.plan_single = timed
    plan = plan_scenario(scenario, tracking_bound=4.127, horizon=horizon, progress=False)
    late = [v.plan.arrival_time - spec.sta for v, spec in zip(plan.vehicles, scenario.vehicles)]
    return {"grid": list(scenario.grid_points), "seconds": [round(t, 2) for t in times],
            "steps": [v.plan.n_steps for v in plan.vehicles],
            "flight_s": [round(v.plan.arrival_time - v.plan.t_ldt, 1) for v in plan.vehicles],
            "arrival_minus_sta_s": [round(x, 2) for x in late], "horizon_s": round(horizon, 1),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def run_peer(peer_seconds: float) -> dict:
    import jax.numpy as jnp

    from stp_env import hj
    from stp_env.dynamics import DubinsWind
    from stp_env.planning.obstacles import static_plane
    from stp_env.planning.single import full_grid_obstacle

    scenario, horizon = _city_subset(1)
    scenario = scenario.with_overrides(grid_points=(251, 251, 36))
    grid, spec = scenario.grid(), scenario.vehicles[0]
    planner = DubinsWind(v_min=11.0, v_max=13.0, omega_max=1.2, wind=0.0)
    target = hj.shapes.cylinder(grid, (0, 1), spec.target, spec.target_radius - 4.127)
    static = {"static": jnp.asarray(np.asarray(scenario.static_obstacle())[:, :, 0] - 4.127, jnp.float32)}
    kw = {"tube": True, "obstacle": static, "obstacle_fn": full_grid_obstacle(static_plane, 36),
          "time_to_reach": True, "progress": False}
    settings = hj.SolverSettings.with_accuracy("high")
    hj.solve(settings, planner, grid, [0.0, -1.0], target, **kw).values.block_until_ready()  # compile
    t0 = time.perf_counter()
    res = hj.solve(settings, planner, grid, [0.0, -peer_seconds], target, **kw)
    res.values.block_until_ready()
    per_step = (time.perf_counter() - t0) / res.n_steps
    full_steps = math.ceil(horizon / res.dt)
    n_slices = max(2, math.ceil(horizon / max(scenario.time_step, horizon / 200)) + 1)
    return {"grid": [251, 251, 36], "ms_per_step": round(1000 * per_step, 2), "dt": round(res.dt, 4),
            "steps_whole_horizon": full_steps, "seconds_per_vehicle_est": round(per_step * full_steps, 1),
            "slice_stack_mb": round(n_slices * int(np.prod(grid.shape)) * 4 / 2**20),
            "peak_rss_mb_short_run": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--vehicles", type=int, default=3)
    parser.add_argument("--peer-seconds", type=float, default=10.0)
    parser.add_argument("--child", choices=["new", "peer"])
    args = parser.parse_args()
    if args.child == "new":
        print(json.dumps(run_new(args.vehicles)))
        return
    if args.child == "peer":
        print(json.dumps(run_peer(args.peer_seconds)))
        return
    out = {"case": "plan_city", "vehicles": args.vehicles, "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    for child in ("new", "peer"):
        cmd = [sys.executable, __file__, "--child", child, "--vehicles", str(args.vehicles),
               "--peer-seconds", str(args.peer_seconds)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode:
            sys.exit(f"{child} failed:\n{proc.stderr[-3000:]}")
        out[child] = json.loads(proc.stdout)
        print(json.dumps({child: out[child]}), file=sys.stderr, flush=True)
    new = out["new"]["seconds"]
    out["new_mean_s_per_vehicle"] = round(float(np.mean(new)), 1)
    out["new_mean_s_per_vehicle_after_first"] = round(float(np.mean(new[1:])), 1) if len(new) > 1 else None
    out["speedup_vs_peer"] = round(out["peer"]["seconds_per_vehicle_est"] / out["new_mean_s_per_vehicle"], 1)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
