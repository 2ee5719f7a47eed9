"""Reproduce the intruder paper's Figs. 6 and 7 on the simulation core (scenario ``fig6``, intruder
``optimal-max-k``): the worst vehicles of the buffer game (Fig. 6) and the vehicles' own ``u*`` (``switching``,
Fig. 7). Writes docs/fig6_reproduction.json, docs/fig6_worst.png, docs/fig7_nominal.png and ships the straight-line
plan as stp_env/data/plans/fig6-kbar3.npz.

    python examples/fig6_reproduction.py [--orders]

``--orders`` also plays every order of ``Q2``-``Q4`` with :func:`stp_env.policies.ordered_max_k` under the worst
vehicles (a brute-force check that the greedy order of ``optimal-max-k`` forces the most; one compilation each).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
COLORS = ("tab:blue", "tab:red", "tab:green", "tab:pink")


def _outline(grid, value_at, heading_rel):
    """A set's position footprint for one relative heading, in the vehicle's body frame (contour data):
    ``value_at(state)`` on a 121 x 121 raster of ``grid``'s positions."""
    import jax
    import jax.numpy as jnp

    xs = np.linspace(grid.lo[0], grid.hi[0], 121)
    pts = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    vals = jax.vmap(lambda p: value_at(jnp.asarray([p[0], p[1], heading_rel])))(jnp.asarray(pts, jnp.float32))
    return xs, np.asarray(vals).reshape(121, 121)


def _avoid_outline(avoid, tau, heading_rel):
    import jax.numpy as jnp

    from stp_env import hj

    taus, values = jnp.asarray(avoid.taus), jnp.asarray(avoid.values)
    return _outline(avoid.grid, lambda x: hj.interpolation.interpolate_slices(avoid.grid, taus, values, tau, x),
                    heading_rel)


def _draw_in_frame(ax, xv, xs, vals, **kw):
    c, s = math.cos(xv[2]), math.sin(xv[2])
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    ax.contour(xv[0] + c * gx - s * gy, xv[1] + s * gx + c * gy, vals, levels=[0.0], **kw)


def plot_run(run, params, avoid, title, path, paper_times):
    traj = run["trajectory"]
    t = traj["t"] - run["t_appear_s"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 5.6), gridspec_kw={"width_ratios": [2.2, 1]})
    present = (traj["intruder_status"] == 1)
    xi = traj["intruder_x"]
    ax.plot(xi[present, 0], xi[present, 1], "k-", lw=2, label="intruder (present)")
    ax.plot(*xi[present][0, :2], "k^", ms=9)
    starts = run["avoid_start_s"]
    for i in range(params.vehicles.n):
        fly = traj["status"][:, i] == 1
        ax.plot(traj["x"][fly, i, 0], traj["x"][fly, i, 1], "-", color=COLORS[i], lw=1.6, label=f"Q{i + 1}")
        k0 = int(np.argmin(np.abs(t)))
        ax.plot(traj["x"][k0, i, 0], traj["x"][k0, i, 1], "o", color=COLORS[i], ms=7)
        if math.isfinite(starts[i]):
            k = int(np.argmin(np.abs(t - starts[i])))
            xv = traj["x"][k, i]
            ax.plot(xv[0], xv[1], "*", color=COLORS[i], ms=15, mec="k")
            ax.plot(xi[k, 0], xi[k, 1], "*", color="k", ms=9)
            # the avoid region V^A(tau) of Q_i at its avoid start (position footprint at the actual relative heading)
            xs, vals = _avoid_outline(avoid, starts[i], float(xi[k, 2] - xv[2]))
            _draw_in_frame(ax, xv, xs, vals, colors=[COLORS[i]], linewidths=1.0, linestyles="--")
            ax.annotate(f"t{i + 1} = {starts[i]:.2f} s", (xv[0], xv[1]), textcoords="offset points",
                        xytext=(6, 10 if i % 2 else -16), color=COLORS[i], fontsize=9)
    # the relative buffer region V^B(0, t_BRD) of Q2 when the intruder appears (at the intruder's relative heading):
    # the intruder's spawn lies on its boundary, so the first hop takes t_BRD
    import jax.numpy as jnp

    from stp_env import hj

    k0 = int(np.argmin(np.abs(t)))
    x2 = traj["x"][k0, 1]
    bvals = jnp.asarray(params.tables.buffer_values)
    xs, vals = _outline(params.tables.buffer_grid, lambda x: hj.interpolation.interpolate(params.tables.buffer_grid,
                                                                                          bvals, x),
                        float(xi[k0, 2] - x2[2]))
    _draw_in_frame(ax, x2, xs, vals, colors=["k"], linewidths=0.8, linestyles=":")
    ax.plot([], [], "k:", lw=0.8, label="V^B(0, t_BRD) of Q2 at t = 0")
    ax.set_aspect("equal")
    ax.set_xlim(-450, 800)
    ax.set_ylim(-330, 330)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("trajectories (o at the intruder's appearance, * avoid start, black: the intruder while present;\n"
                 "dashed: the avoid region V^A(t_i) of Q_i at its avoid start; dotted: Q2's buffer region at t = 0)",
                 fontsize=9)
    ax.grid(alpha=0.3)
    names = [f"Q{i + 1}" for i in range(params.vehicles.n)]
    y = np.arange(len(names))
    sim_t = [s if math.isfinite(s) else np.nan for s in starts]
    pap_t = [s if math.isfinite(s) else np.nan for s in paper_times]
    bx.barh(y + 0.18, sim_t, height=0.34, color=COLORS, label="simulated")
    bx.barh(y - 0.18, pap_t, height=0.34, color="lightgray", edgecolor="k", label="paper")
    for i in range(len(names)):
        for val, dy in ((starts[i], 0.18), (paper_times[i], -0.18)):
            bx.text(min(val, 10.2) if math.isfinite(val) else 0.2, y[i] + dy,
                    f"{val:.2f}" if math.isfinite(val) else "never", va="center", fontsize=8)
    bx.axvline(float(params.intruder.t_iat), color="k", ls=":", label="t_IAT (intruder leaves)")
    for k in (1, 2):
        bx.axvline(k * float(params.intruder.t_iat) / 3, color="gray", ls="--", lw=0.8)
    bx.set_yticks(y, names)
    bx.set_xlim(0, 11.5)
    bx.set_xlabel("avoid start t_i - t_ [s]")
    bx.legend(fontsize=8, loc="lower right")
    bx.set_title(f"|N^RP| = {run['n_forced']} (k̄ = 3)", fontsize=10)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--orders", action="store_true", help="brute force over the intruder's vehicle orders")
    args = ap.parse_args()

    from stp_env import assembly
    from stp_env.evaluation.worst_case import FIG6_PAPER_TIMES, FIG7_PAPER_TIMES, fig6_params, reproduce
    from stp_env.planning.stp import plan_to_arrays
    from stp_env.policies import optimal_max_k, ordered_max_k, switching, worst
    from stp_env.reach.buffer import position_radius
    from stp_env.scenarios import make
    from stp_env.scenarios.catalog.fig6 import fig6_plan

    scenario = make("fig6")
    avoid, tracking = assembly.load_artifacts(scenario, progress=True)
    params = fig6_params(scenario, progress=True)
    out = {"command": "python examples/fig6_reproduction.py" + (" --orders" if args.orders else ""),
           "tracking_bound_m": round(float(tracking.bound), 3),
           "detection_range_m": round(float(params.tables.detection_range), 2),
           "relative_buffer_radius_m": round(position_radius(params.tables.buffer_grid, params.tables.buffer_values),
                                             2),
           "avoid_margin_m": float(params.tables.avoid_margin), "runs": {}}
    plan_path = ROOT / "stp_env" / "data" / "plans" / "fig6-kbar3.npz"
    np.savez_compressed(plan_path, **plan_to_arrays(fig6_plan(scenario, tracking.bound)))
    runs = {"fig6_worst": (worst, optimal_max_k, FIG6_PAPER_TIMES,
                           "Fig. 6: worst vehicles (buffer game) vs the optimal max-k intruder"),
            "fig7_nominal": (switching, optimal_max_k, FIG7_PAPER_TIMES,
                             "Fig. 7: vehicles fly u^PP until forced (u*, 'switching') vs the optimal max-k intruder")}
    for name, (vp, ip, paper, title) in runs.items():
        start = time.perf_counter()
        run = reproduce(params, vp, ip)
        out["runs"][name] = {"avoid_start_s": run["avoid_start_s"], "paper_s": list(paper), "n_forced": run["n_forced"],
                             "min_avoid_value_m": run["min_avoid_value_m"],
                             "min_avoid_value_time_s": run["min_avoid_value_time_s"],
                             "collisions": run["collisions"], "assumption_ok": run["assumption_ok"],
                             "t_appear_s": round(run["t_appear_s"], 3),
                             "seconds": round(time.perf_counter() - start, 1)}
        print(name, json.dumps(out["runs"][name]), flush=True)
        plot_run(run, params, avoid, f"fig6 scenario, calm air — {title}", ROOT / "docs" / f"{name}.png", paper)
    if args.orders:
        out["orders"] = {}
        for order in itertools.permutations((1, 2, 3)):
            run = reproduce(params, worst, ordered_max_k(order))
            out["orders"][",".join(f"Q{i + 1}" for i in order)] = run["n_forced"]
            print(order, run["n_forced"], run["avoid_start_s"], flush=True)
    def finite(x):  # JSON has no infinity: a vehicle never forced is null
        if isinstance(x, dict):
            return {k: finite(v) for k, v in x.items()}
        if isinstance(x, list):
            return [finite(v) for v in x]
        return None if isinstance(x, float) and math.isinf(x) else x

    (ROOT / "docs" / "fig6_reproduction.json").write_text(json.dumps(finite(out), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
