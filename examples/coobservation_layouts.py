"""Section III-F (surveillance flows) on the paper's own inputs and over a family of generated layouts.

    python examples/coobservation_layouts.py [--layouts 12] [--out docs]

1. Section II's map and zones with the routes Section II plans without the reachability constraints (its Fig. 2a:
   the ADMM plan of ``stp_env.coobservation.paper.plan(MapExplorationTask(), secured=False)``, about two minutes),
   secured by surveillance robots as in Section III-F (zone 1 an obstacle, zones 2 and 3 forbidden).
2. ``--layouts`` generated layouts (``stp_env.coobservation.layouts.random_survey``, seeds 0, 1, ...).

Each with the ellipses of Def. 3 and with the exact regions of the Section III robots read as Dubins vehicles in
wind (the level-set field of ``examples/coobservation_exact.py``, from the artifact cache). Reports per layout the
Algorithm-1 checkpoints, the cross-route edges, the longest single path's gain (the paper's condition on rho:
at most 1) and K*, the robots after which more stay idle (none when the condition fails: the sweep never stops;
then also K* with rho lowered until the condition holds, in brackets in the figure);
writes ``coobservation_layouts.json`` and ``coobservation_layouts.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from stp_env.coobservation import checkpoints, exact, layouts, paper
from stp_env.files import save_figure, write_text

KEYS = ("checkpoints_algorithm1", "cross_edges", "max_single_flow_gain", "robots_needed")


def dubins_field():
    task = paper.SurveyTask()
    return exact.compute(exact.ExactRegionConfig(v_min=0.25, v_max=0.45, omega_max=0.5, wind=0.05,
                                                 radius=task.radius, horizon=20.0, spacing=0.08, n_headings=24),
                         progress=True)


def both(task, field) -> dict:
    ell = checkpoints.ellipse_test(task.forbidden, task.v_max, task.radius)
    out = {}
    for name, test in (("ellipse", ell), ("exact", field.secure_fn(task.forbidden, fallback=ell))):
        try:
            r = paper.survey_flows(task, test)["result"]
        except checkpoints.UnsecurableRouteError as err:
            out[name] = {"error": str(err)}
            continue
        out[name] = {k: r[k] for k in KEYS}
        out[name]["costs"] = [row["cost"] for row in r["sweep"]]
        gain = r["max_single_flow_gain"]
        if gain > 1.0:
            # the paper's condition on rho fails (a single path is worth more than a robot: the sweep never
            # stops); with rho lowered until it holds, K* exists again
            lowered = dataclasses.replace(task, rho=task.rho / gain * 0.99)
            r2 = paper.survey_flows(lowered, test)["result"]
            out[name]["rho_lowered"] = {"rho": round(lowered.rho, 6), "robots_needed": r2["robots_needed"],
                                        "max_single_flow_gain": r2["max_single_flow_gain"]}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=12)
    ap.add_argument("--out", default="docs")
    args = ap.parse_args(argv)
    out = Path(args.out)
    field = dubins_field()
    start = time.time()
    print("Section II plan without the reachability constraints (ADMM)...", flush=True)
    free = paper.plan(paper.MapExplorationTask(), secured=False, progress=True)
    section2 = layouts.section2_survey(free.q)
    result = {"section2": {"routes": np.asarray(section2.routes()).round(4).tolist(), **both(section2, field)}}
    family = []
    for seed in range(args.layouts):
        task, rejected = layouts.random_survey(seed)
        row = {"seed": seed, "rejected_draws": rejected, "passes": task.passes, "x_range": task.x_range,
               "alternate": task.alternate, "speed": round(task.speed, 4),
               "walls": [list(map(list, w)) for w in task.forbidden], **both(task, field)}
        family.append(row)
        print(json.dumps({k: row[k] for k in ("seed", "rejected_draws")} | {
            n: row[n].get("robots_needed", row[n].get("error")) for n in ("ellipse", "exact")}), flush=True)
    result["family"] = family
    for name in ("ellipse", "exact"):
        ks = [r[name].get("robots_needed") for r in family if "error" not in r[name]]
        lowered = [r[name]["rho_lowered"]["robots_needed"] if "rho_lowered" in r[name] else r[name]["robots_needed"]
                   for r in family if "error" not in r[name]]
        result[f"k_star_{name}"] = {"values": ks, "undefined": sum(k is None for k in ks),
                                    "histogram": {str(k): ks.count(k) for k in sorted({k for k in ks if k})},
                                    "with_rho_lowered": lowered,
                                    "histogram_rho_lowered": {str(k): lowered.count(k)
                                                              for k in sorted({k for k in lowered if k})}}
    result["seconds"] = round(time.time() - start, 1)
    write_text(json.dumps(result, indent=1) + "\n", out / "coobservation_layouts.json")
    figure(section2, family, out / "coobservation_layouts.png")
    print(json.dumps({k: result[k] for k in ("k_star_ellipse", "k_star_exact", "seconds")}))


def figure(section2, family, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stp_env.coobservation import plots

    n = 1 + len(family)
    cols = min(n, 5)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.7 * rows), squeeze=False)
    tasks = [(section2, "Section II routes")] + [(layouts.random_survey(r["seed"])[0], f"layout {r['seed']}")
                                                  for r in family]
    results = [None, *family]
    for ax, (task, title), row in zip(axes.flat, tasks, results):
        plots.draw_zones(ax, task.obstacles, task.forbidden, labels=False)
        for route in task.routes():
            ax.plot(route[:, 0], route[:, 1], lw=0.8)
        if row is not None:
            k = [row[m].get("robots_needed") or (f"({row[m]['rho_lowered']['robots_needed']})"
                                                  if "rho_lowered" in row[m] else "-") for m in ("ellipse", "exact")]
            title += f"\nK* {k[0]} (ellipse), {k[1]} (exact)"
        ax.set_title(title, fontsize=7)
        ax.set_xlim(0, 10)
        ax.set_ylim(0, 10)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle("Section III-F: surveillance robots K* on Section II's routes and on generated layouts", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
