"""The SPP paper's four-vehicle example (Section V) planned with the three induced-obstacle methods.

Prints one JSON object: per method the latest departure times t_LDT (vehicles Q1..Q4), the seconds of planning
per vehicle, and the paper's numbers (Section V-A/B/C); optionally writes a figure in the paper's style (Figs. 3,
5, 7: trajectories, positions and danger zones at one time; and Figs. 4, 6: the obstacles induced for Q3).

    python examples/four_vehicle_methods.py [--methods centralized least_restrictive rtt] [--figure out.png]

About 100 s per method on 2 CPU cores (the robust-tracking method also computes its tracking bound).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

PAPER_T_LDT = {
    "centralized": [-1.35, -1.37, -1.94, -2.04],
    "least_restrictive": [-1.35, -1.97, -2.66, -3.39],
    "rtt": [-1.61, -3.16, -3.57, -2.47],
}
HORIZON = 4.0


def run(method: str):
    from stp_env.planning.methods import plan_methods
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    sc = make("four-vehicle", method=method)
    t0 = time.perf_counter()
    if method == "rtt":
        from stp_env.reach.tracking import TrackingConfig, compute_tracking_bound

        cfg = TrackingConfig(vehicle=sc.vehicle, planning_v=sc.planning_v, planning_omega_max=sc.planning_omega_max,
                             half_width=0.15, grid_points=(41, 41, 40))  # as tests/test_four_vehicle.py
        bound = compute_tracking_bound(cfg, progress=False).bound
        t1 = time.perf_counter()
        plan = plan_scenario(sc, tracking_bound=bound, horizon=HORIZON, progress=False)
        seconds = [(time.perf_counter() - t1) / len(plan.vehicles)] * len(plan.vehicles)
        return sc, plan, None, seconds, time.perf_counter() - t0
    mp = plan_methods(sc.grid(), sc.vehicle, method, sc.collision_radius, sc.starts(), sc.targets(),
                      sc.target_radii(), sc.stas(), sc.priorities(), horizon=HORIZON, time_step=sc.time_step,
                      progress=False)
    return sc, mp.plan, mp, mp.seconds_per_vehicle().tolist(), time.perf_counter() - t0


def figure(results: dict, path: str, snapshot: float = -1.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = ["tab:red", "tab:blue", "tab:green", "tab:purple"]
    methods = list(results)
    fig, axes = plt.subplots(2, len(methods), figsize=(4.2 * len(methods), 8.4), squeeze=False)
    for col, method in enumerate(methods):
        sc, plan, mp, _, _ = results[method]
        ax = axes[0, col]
        for i, v in enumerate(plan.vehicles):
            ts, xs = v.plan.flight()
            ax.plot(xs[:, 0], xs[:, 1], ":", color=colors[i])
            tgt = sc.targets()[i]
            ax.add_patch(plt.Circle(tgt, sc.vehicles[i].target_radius, fill=False, color=colors[i]))
            t = min(max(snapshot, ts[0]), ts[-1])
            p = [np.interp(t, ts, xs[:, k]) for k in range(3)]
            ax.plot(p[0], p[1], "*", color=colors[i], ms=10)
            ax.arrow(p[0], p[1], 0.1 * np.cos(p[2]), 0.1 * np.sin(p[2]), color=colors[i], head_width=0.03)
            ax.add_patch(plt.Circle(p[:2], sc.collision_radius, fill=False, ls="--", color=colors[i]))
        ax.set_title(f"{method}: t_LDT = {np.round(plan.t_ldt(), 2).tolist()}\npositions at t = {snapshot}",
                     fontsize=9)
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_aspect("equal")
        ax = axes[1, col]
        if mp is None:
            ax.set_axis_off()
            ax.text(0.1, 0.5, "robust tracking: obstacles are disks\nR_c + 2 r_e around nominal trajectories",
                    fontsize=9)
            continue
        grid = sc.grid()
        xs_, ys_ = grid.coordinate_vector(0), grid.coordinate_vector(1)
        for tq, ls in ((-2.0, ":"), (-1.5, "--"), (-1.0, "-")):
            for j in (0, 1):
                r = mp.reach[j]
                if not (r.obstacle_times[0] <= tq <= r.obstacle_times[-1]):
                    continue
                k = int(np.argmin(np.abs(r.obstacle_times - tq)))
                ax.contour(xs_, ys_, r.obstacle[k].T, levels=[0.0], colors="k", linestyles=ls, linewidths=1)
            r3 = mp.reach[2]
            k = int(np.argmin(np.abs(r3.slice_times - tq)))
            ax.contour(xs_, ys_, np.min(np.asarray(r3.brs[k]), axis=-1).T, levels=[0.0], colors="tab:green",
                       linestyles=ls, linewidths=1)
        for i in range(4):
            ax.plot(*sc.starts()[i, :2], "o", color=colors[i])
        ax.set_title("BRS of Q3 (green) and obstacles from Q1, Q2 (black)\nat t = -2 (:), -1.5 (--), -1 (-)",
                     fontsize=9)
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["centralized", "least_restrictive", "rtt"],
                        choices=list(PAPER_T_LDT))
    parser.add_argument("--figure", default=None, help="PNG path for the figure")
    args = parser.parse_args()
    results, out = {}, {}
    for method in args.methods:
        results[method] = run(method)
        _, plan, _, seconds, total = results[method]
        out[method] = {"t_ldt": np.round(plan.t_ldt(), 3).tolist(), "paper_t_ldt": PAPER_T_LDT[method],
                       "seconds_per_vehicle": np.round(seconds, 1).tolist(), "total_seconds": round(total, 1),
                       "arrival_nominal": np.round([v.plan.arrival_time for v in plan.vehicles], 3).tolist()}
    print(json.dumps(out))
    if args.figure:
        figure(results, args.figure)


if __name__ == "__main__":
    main()
