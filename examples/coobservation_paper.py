"""The co-observation paper's two experiments, reproduced with our coordinates (``docs/coobservation.md``).

* ``planning`` (Section II-K, Figs. 2a and 7): the map-exploration task planned by the generalised ADMM without
  and with the reachability constraints; every constraint checked on the result against the sets themselves;
  ``docs/coobservation_planning.png`` and ``planning.json``.
* ``flows`` (Section III-F, Figs. 12-15): three unsecured survey routes, their Algorithm-1 checkpoints, the
  checkpoint graph (Algorithm 2 with RRT*), and the multi-flow LP (60) for K = 1, 2, ... until a flow stays empty
  (``w_c = 10, w_t = 1, rho = 0.01``); ``docs/coobservation_flows.png`` and ``flows.json``.

``python examples/coobservation_paper.py planning flows`` (about 10-20 minutes on 2 busy cores).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from stp_env.coobservation import admm, paper, plots
from stp_env.coobservation.schedule import segments

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = admm.ADMMSettings(max_iters=300, inner_iters=60)


def planning(out: Path) -> dict:
    import matplotlib.pyplot as plt

    task = paper.MapExplorationTask()
    cost = task.cost()
    q0 = task.initial()
    t = time.time()
    free = paper.plan(task, secured=False, q0=q0, settings=SETTINGS)
    t_free = time.time() - t
    t = time.time()
    sec = paper.plan(task, secured=True, q0=free.q, settings=SETTINGS)
    t_sec = time.time() - t
    result = {}
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.4))
    for ax, (name, res, secs) in zip(axes, (("without reachability constraints", free, t_free),
                                            ("with reachability constraints", sec, t_sec))):
        check = paper.verify(task, res.q)
        result[name] = {"iterations": res.iterations, "seconds": round(secs, 1), "max_variance":
                        round(cost.max_variance(res.q), 4), "mean_variance": round(cost.mean_variance(res.q), 4),
                        "admm_violations": res.violations,
                        **{k: v for k, v in check.items()}}
        plots.draw_variance(ax, cost, res.q, task.lo, task.hi, vmax=task.cost().prior)
        plots.draw_zones(ax, task.obstacles, task.forbidden, names=["zone 1", "zone 2", "zone 3"])
        for seg, ell in zip(segments(task.observations(), task.n_agents), check["ellipses"]):
            f = [np.asarray(o[1]) if o[0] == "point" else res.q[o[1], round(o[2])]
                 for o in (seg.observer1, seg.observer2)]
            a = task.v_max * (seg.t2 - seg.t1) / 2 + task.radius
            plots.draw_ellipse(ax, f[0], f[1], a, color="k" if ell["clear"] else "tab:red", lw=0.8,
                               ls="-" if ell["clear"] else "--")
        plots.draw_trajectories(ax, res.q, labels=["robot 1", "robot 2", "robot 3"])
        for a, b, tt in task.coobservations:
            ax.plot(*np.stack([res.q[a, tt], res.q[b, tt]]).T, "m-", lw=2.5, zorder=6)
            ax.annotate(f"t={tt}", res.q[a, tt], fontsize=7, color="m", xytext=(3, 3), textcoords="offset points")
        _agent, point, tt = task.checkpoint
        ax.plot(*point, "kD", ms=6, zorder=6)
        ax.annotate(f"checkpoint t={tt}", point, fontsize=7, xytext=(4, -10), textcoords="offset points")
        clear = sum(e["clear"] for e in check["ellipses"])
        ax.set_title(f"{name}\n{clear}/{len(check['ellipses'])} ellipses clear, final variance mean "
                     f"{result[name]['mean_variance']:.3f}, max {result[name]['max_variance']:.3f}", fontsize=10)
        ax.set_xlim(task.lo[0], task.hi[0])
        ax.set_ylim(task.lo[1], task.hi[1])
        ax.set_aspect("equal")
    axes[0].legend(loc="lower left", fontsize=7)
    fig.suptitle("Section II-K: map exploration with co-observations (magenta) and reachability ellipses")
    fig.tight_layout()
    fig.savefig(out / "coobservation_planning.png", dpi=110)
    plt.close(fig)
    np.savez(out / "coobservation_planning_plans.npz", free=free.q, secured=sec.q)
    return result


def flow_study(out: Path) -> dict:
    import matplotlib.pyplot as plt

    task = paper.SurveyTask()
    t = time.time()
    study = paper.survey_flows(task, progress=True)
    result = {**study["result"], "seconds": round(time.time() - t, 1)}
    routes, graph = study["routes"], study["graph"]
    feasible = [s for s in study["sweep"] if s.status == "optimal"]
    shown = feasible[:2]  # the smallest feasible K and the next (the paper's Figs. 12-15: K = 3 and 4)
    fig, axes = plt.subplots(2, len(shown), figsize=(6 * len(shown), 10.5), squeeze=False)
    for col, sol in enumerate(shown):
        _draw_graph(axes[0, col], graph, sol)
        _draw_workspace(axes[1, col], task, routes, graph, sol)
    fig.suptitle("Section III-F: checkpoint graph and surveillance flows (one colour per flow)")
    fig.tight_layout()
    fig.savefig(out / "coobservation_flows.png", dpi=100)
    plt.close(fig)
    return result


def _draw_graph(ax, graph, sol):
    pos = {k: (v.route, -v.index) for k, v in enumerate(graph.vertices)}
    for i, j, kind in graph.edges:
        (x0, y0), (x1, y1) = pos[i], pos[j]
        ax.plot([x0, x1], [y0, y1], color="0.8" if kind == "route" else "0.6", lw=0.8,
                ls="-" if kind == "route" else ":", zorder=1)
    for f, path in enumerate(sol.paths):
        c = plots.COLORS[f % len(plots.COLORS)]
        for a, b in itertools.pairwise(path):
            (x0, y0), (x1, y1) = pos[a], pos[b]
            off = 0.06 * (f - len(sol.paths) / 2)
            ax.annotate("", (x1 + off, y1), (x0 + off, y0), arrowprops={"arrowstyle": "->", "color": c, "lw": 1.6})
    for k, v in enumerate(graph.vertices):
        ax.plot(*pos[k], "o" if v.checkpoint else "^", color="k" if v.checkpoint else "0.5", ms=5, zorder=3)
        ax.annotate(str(v.index), pos[k], fontsize=6, xytext=(4, -2), textcoords="offset points")
    ax.set_xticks(range(3), ["route 1", "route 2", "route 3"])
    ax.set_yticks([])
    ax.set_xlim(-0.6, 2.8)
    ax.set_title(f"K = {sol.k}: {sol.n_used} flows used, cost (60a) {sol.cost:.3f} (time runs down)", fontsize=10)


def _draw_workspace(ax, task, routes, graph, sol):
    plots.draw_zones(ax, (), task.forbidden, names=["zone A", "zone B"])
    for p, r in enumerate(routes):
        ax.plot(r[:, 0], r[:, 1], color="0.6", lw=1)
        ax.annotate(f"route {p + 1}", r[0], fontsize=8)
    for _k, v in enumerate(graph.vertices):
        if v.checkpoint:
            ax.plot(*routes[v.route, v.index], "k.", ms=4)
    for f, path in enumerate(sol.paths):
        c = plots.COLORS[f % len(plots.COLORS)]
        for a, b in itertools.pairwise(path):
            if (a, b) in graph.paths:
                pts = graph.paths[(a, b)]
                ax.plot(pts[:, 0], pts[:, 1], "-.", color=c, lw=1.8)
                ax.annotate("", pts[-1], pts[-2], arrowprops={"arrowstyle": "->", "color": c})
    ax.set_xlim(task.lo[0], task.hi[0])
    ax.set_ylim(task.lo[1], task.hi[1])
    ax.set_aspect("equal")
    ax.set_title(f"K = {sol.k}: cross-route transfers in the workspace", fontsize=10)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("parts", nargs="+", choices=["planning", "flows"])
    ap.add_argument("--out", default=str(ROOT / "docs"), help="folder for figures and JSON")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for part in args.parts:
        result = planning(out) if part == "planning" else flow_study(out)
        text = json.dumps(result, indent=1, default=float)
        (out / f"coobservation_{part}.json").write_text(text + "\n")
        print(text)


if __name__ == "__main__":
    main()
