"""Figures of the survivability model (not of the study; those come from ``stp-env survivability``).

    python examples/survivability_figures.py [--out docs] [--scenario 150 150] [--instance 3]

* ``survivability_network.png``: the Bay-Area mission with no traffic: the number of feasible trajectories per
  cell (summed over headings and speeds, best window) to the goal and to any landing site, from the compact graph
  (states reachable from the origin), and the zero-traffic check (how many trajectories reach the goal in which
  window).
* ``survivability_mission.png``: one traffic instance flown by each policy: the partially known intruders'
  nominal paths, the unknown ones, the intruders revealed by conflicts and the ownship's path per policy.
Prints the zero-traffic numbers as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from stp_env.survivability import dp
from stp_env.survivability.config import POLICIES, PlannerConfig, TrafficConfig
from stp_env.survivability.graph import build_graph
from stp_env.survivability.mission import initial_tables, make_instance, run_mission
from stp_env.survivability.report import COLOR, LABEL
from stp_env.survivability.traffic import curve_points, present_samples

ROOT = Path(__file__).resolve().parents[1]


def _sites(ax, net):
    names = {net.mission.origin.name: "Santa Clara (origin)", net.mission.goal.name: "UCSF (goal)"}
    for name, (x, y) in net.site_km.items():
        ax.plot(x, y, "k*" if name == net.mission.goal.name else "ko", ms=9)
        short = "SFO" if name.startswith("San Francisco") else name.split()[0]
        ax.annotate(names.get(name, short + " (alternative)"), (x, y), textcoords="offset points",
                    xytext=(5, 5), fontsize=8)
    ax.set_xlim(0, net.n)
    ax.set_ylim(0, net.n)
    ax.set_aspect("equal")
    ax.set_xlabel("x [km] (east)")
    ax.set_ylabel("y [km] (north)")


def network_figure(out: Path) -> dict:
    g = build_graph()
    net = g.net
    free = np.ones(g.n_segments, bool)
    n_goal = np.asarray(dp.counts(g, free, "goal"))
    n_all = np.asarray(dp.counts(g, free, "all"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.2))
    for ax, counts, title in ((axes[0], n_goal, "to the goal"), (axes[1], n_all, "to any landing site")):
        grid = np.zeros((net.n_windows + 1, net.n, net.n))
        k = np.repeat(np.arange(net.n_windows + 1), np.diff(g.window_start))
        np.add.at(grid, (k, g.states[:, 0], g.states[:, 1]), counts)
        best = grid.max(axis=0)
        im = ax.imshow(np.log10(np.where(best > 0, best, np.nan)).T, origin="lower", cmap="viridis",
                       extent=[0, net.n, 0, net.n])
        fig.colorbar(im, ax=ax, shrink=0.8, label="log10 trajectories per cell (best window)")
        _sites(ax, net)
        ax.set_title(f"Feasible trajectories {title}, no traffic")
    fig.tight_layout()
    fig.savefig(out / "survivability_network.png", dpi=110)
    plt.close(fig)
    # Forward counts: trajectories from the origin to each state (stopping at goal terminal states).
    fwd = np.zeros(g.n_states)
    fwd[g.origin] = 1.0
    for gi in range(g.window_start[net.n_windows]):
        if fwd[gi] == 0 or g.term_goal[gi]:
            continue
        nxt = g.succ[gi][g.succ[gi] >= 0]
        np.add.at(fwd, nxt, fwd[gi])
    k_of = np.repeat(np.arange(net.n_windows + 1), np.diff(g.window_start))
    arrivals = {int(k): float(fwd[g.term_goal & (k_of == k)].sum()) for k in range(net.goal_windows[0],
                                                                                  net.goal_windows[1] + 1)}
    # Every policy with no traffic at all.
    planner = PlannerConfig(nf_count="landing")  # the earlier model, as docs/survivability.md's figures
    empty = make_instance(g, TrafficConfig(n_partial=0, n_unknown=0, model="local"), planner, 0)
    flown = {q: run_mission(g, empty, q, planner) for q in POLICIES}
    origin = {"trajectories to the goal": float(n_goal[g.origin]), "to any site": float(n_all[g.origin]),
              "goal arrivals by cruise window": arrivals, "graph states": g.n_states, "segments": g.n_segments,
              "tracked cells": g.n_cells,
              "no-traffic missions": {q: f"{r.outcome} after {len(r.path) - 1} windows" for q, r in flown.items()}}
    return origin


def mission_figure(out: Path, scenario, instance: int) -> dict:
    g = build_graph()
    net = g.net
    planner = PlannerConfig(nf_count="landing")  # the earlier model, as docs/survivability.md's figures
    traffic = TrafficConfig(n_partial=scenario[0], n_unknown=scenario[1], model="local")
    inst = make_instance(g, traffic, planner, (0, instance))
    first = initial_tables(g, inst, POLICIES)
    results = {q: run_mission(g, inst, q, planner, seed=(0, instance), initial_tables=first[q]) for q in POLICIES}
    tr = inst.traffic
    who, _, s = present_samples(tr.t_in, tr.duration, net.mission, 6)
    nominal, _ = curve_points(tr.nominal, who, s)
    actual, _ = curve_points(tr.actual, who, s)
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    revealed = set().union(*(r.revealed for r in results.values()))
    for i in range(tr.n):
        m = who == i
        if not m.any():
            continue
        if i < tr.n_partial:
            ax.plot(*nominal[m].T, color="0.55", lw=0.7)
        else:
            ax.plot(*actual[m].T, color="0.75", lw=0.7, ls="--")
        if i in revealed:
            ax.plot(*actual[m].T, color="red", lw=1.4)
    for q, r in results.items():
        xy = g.states[list(r.path), :2] + 0.5
        ax.plot(*xy.T, "o-", color=COLOR[q], ms=3, lw=1.8,
                label=f"{LABEL[q]}: {r.outcome} ({len(r.revealed)} revealed)")
    ax.plot([], [], color="0.55", lw=0.7, label="partially known (nominal)")
    ax.plot([], [], color="0.75", lw=0.7, ls="--", label="unknown")
    ax.plot([], [], color="red", lw=1.4, label="revealed by a conflict (actual)")
    _sites(ax, net)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(f"One instance of (N_p, N_u) = {tuple(scenario)}: G goal, A alternative site, L emergency")
    fig.tight_layout()
    fig.savefig(out / "survivability_mission.png", dpi=110)
    plt.close(fig)
    return {q: {"outcome": r.outcome, "revealed": len(r.revealed), "windows": len(r.path) - 1}
            for q, r in results.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs"))
    ap.add_argument("--scenario", type=int, nargs=2, default=[150, 150])
    ap.add_argument("--instance", type=int, default=3)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(json.dumps({"zero_traffic": network_figure(out),
                      "mission": mission_figure(out, args.scenario, args.instance)}, indent=1))


if __name__ == "__main__":
    main()
