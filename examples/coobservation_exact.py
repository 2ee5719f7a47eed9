"""Exact reachability regions of the UAV between two observations, against the ellipse (part 5 of the study).

Solves the forward time-to-reach field of the simulator's UAV (``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``,
wind 6 m/s) from the observation disk (radius 200 m + 20 m tracking margin), and the backward one to check the
time-reversal identity ``T_B(x, theta) = T_F(x, theta + pi)``; then

* area ratios exact / ellipse for observers moving apart at the formation's speed, for several intervals;
* the same for a fixed-wing variant (``v in [15, 25] m/s``, ``|omega| <= 0.5 rad/s``: it cannot hover or turn
  on the spot);
* how many co-observation times each test needs to secure the formation's route (greedy, 1 s grid);
* a figure of both regions for one interval next to zone A (``docs/coobservation_exact.png``);
* the paper's Section III-F survey with robots read as Dubins vehicles in wind (``v in [0.25, 0.45]`` m per step,
  ``|omega| <= 0.5`` rad per step, wind 0.05: ``v_max + wind`` is the paper's 0.5): checkpoints and surveillance
  robots needed with the ellipse and with the exact regions.

Writes ``docs/coobservation_exact.json`` and prints it. ``python examples/coobservation_exact.py`` (about 15-30
minutes on 2 cores, most of it the two level-set solves; cached afterwards).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from stp_env.coobservation import checkpoints, exact
from stp_env.coobservation.uav import FormationScenario

ROOT = Path(__file__).resolve().parents[1]


def uav_config(sc: FormationScenario, horizon: float, spacing: float) -> exact.ExactRegionConfig:
    return exact.ExactRegionConfig(v_min=0.0, v_max=sc.v_max, omega_max=sc.omega_max, wind=sc.wind,
                                   radius=sc.ellipse_radius, horizon=horizon, spacing=spacing, n_headings=24)


def ratios(regions, speed, deltas):
    """Area ratios for observers moving apart at ``speed`` over each interval."""
    out = []
    for d in deltas:
        q1 = np.zeros(2)
        q2 = np.array([speed * d, 0.0])
        r = exact.area_ratio(regions, q1, q2, d)
        out.append({"interval_s": d, **{k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()}})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--horizon", type=float, default=90.0, help="longest interval [s]")
    ap.add_argument("--spacing", type=float, default=25.0, help="grid spacing [m]")
    ap.add_argument("--out", default=str(ROOT / "docs"), help="folder for the JSON and the figure")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stp_env.coobservation import plots

    sc = FormationScenario()
    result = {"scenario": {"v_max": sc.v_max, "omega_max": sc.omega_max, "wind": sc.wind,
                           "radius_m": sc.ellipse_radius, "speed": sc.speed}}
    t0 = time.time()
    uav = exact.compute(uav_config(sc, args.horizon, args.spacing), check_reversal=True)
    result["uav_solve_s"] = round(time.time() - t0, 1)
    result["reversal_max_error_s"] = uav.reversal_error
    deltas = [10.0, 20.0, 40.0, 60.0, 90.0]
    result["uav_area_ratio"] = ratios(uav, sc.speed, [d for d in deltas if d <= args.horizon])
    fixed = exact.compute(exact.ExactRegionConfig(v_min=15.0, v_max=sc.v_max, omega_max=0.5, wind=sc.wind,
                                                  radius=sc.ellipse_radius, horizon=args.horizon,
                                                  spacing=args.spacing, n_headings=24))
    result["fixed_wing_area_ratio"] = ratios(fixed, sc.speed, [d for d in deltas if d <= args.horizon])

    ell = checkpoints.ellipse_test(sc.forbidden, sc.attacker_speed, sc.ellipse_radius)
    times_ellipse = sc.secured_times(ell)
    times_exact = sc.secured_times(uav.secure_fn(sc.forbidden, fallback=ell))
    times_fixed = sc.secured_times(fixed.secure_fn(sc.forbidden, fallback=ell))
    result["secured_times"] = {"ellipse": times_ellipse, "exact_uav": times_exact, "exact_fixed_wing": times_fixed}
    result["observation_times_needed"] = {k: len(v) - 2 for k, v in result["secured_times"].items()}

    # the paper's survey with Dubins robots: checkpoints and robots with the ellipse and with the exact regions
    from stp_env.coobservation import paper

    task = paper.SurveyTask()
    dubins = exact.compute(exact.ExactRegionConfig(v_min=0.25, v_max=0.45, omega_max=0.5, wind=0.05,
                                                   radius=task.radius, horizon=20.0, spacing=0.08, n_headings=24))
    ell_paper = checkpoints.ellipse_test(task.forbidden, task.v_max, task.radius)
    survey = {}
    for name, test in (("ellipse", ell_paper), ("exact", dubins.secure_fn(task.forbidden, fallback=ell_paper))):
        r = paper.survey_flows(task, test)["result"]
        survey[name] = {k: r[k] for k in ("checkpoints_algorithm1", "checkpoints_greedy", "cross_edges",
                                          "max_single_flow_gain", "robots_needed")}
        survey[name]["costs"] = [row["cost"] for row in r["sweep"]]
    result["paper_survey_dubins"] = survey
    result["paper_survey_area_ratio"] = ratios(dubins, 0.35, [2.0, 5.0, 10.0, 20.0])

    # figure: the ellipse-secured schedule with one exact region; then two single intervals where turning matters
    k = int(np.argmin([abs(t - 100.0) for t in times_ellipse]))
    t1, t2 = times_ellipse[k], times_ellipse[k + 1]
    lo, hi = np.array(sc.domain_lo), np.array(sc.domain_hi)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.6))
    ax = axes[0]
    plots.draw_zones(ax, (), sc.forbidden, names=["zone A", "zone B"])
    pos = sc.positions(np.linspace(0, sc.duration, 200))
    for i in range(sc.n_vehicles):
        ax.plot(pos[i, :, 0], pos[i, :, 1], color=plots.COLORS[i], lw=1)
    for ta, tb in itertools.pairwise(times_ellipse):
        f1, f2 = sc.segment_foci(sc.segments_between(ta, tb)[0])  # the left vehicle's, observed by the centre one
        plots.draw_ellipse(ax, f1, f2, (sc.attacker_speed * (tb - ta)) / 2 + sc.ellipse_radius, color="k", lw=0.6)
    f1, f2 = sc.segment_foci(sc.segments_between(t1, t2)[0])
    mask, xs, ys = uav.region_mask(f1, f2, t2 - t1, lo, hi, 10.0)
    ax.contour(xs, ys, mask.astype(float), levels=[0.5], colors="tab:red", linewidths=1.5)
    ax.plot([], [], color="tab:red", label=f"exact region {t1:g}-{t2:g} s")
    ax.plot([], [], color="k", lw=0.6, label="ellipses (v_max + wind, +220 m)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"UAV formation, ellipse-secured: {len(times_ellipse) - 2} co-observation times\n"
                 f"(exact regions: {len(times_exact) - 2})", fontsize=10)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    for ax, regions, speed, delta, title in (
            (axes[1], fixed, sc.speed, 10.0, "fixed-wing UAV (v >= 15 m/s, 0.5 rad/s), 10 s"),
            (axes[2], dubins, 0.35, 5.0, "Section III robots as Dubins in wind, 5 steps")):
        cfg = regions.config
        q1, q2 = np.zeros(2), np.array([speed * delta, 0.0])
        a = (cfg.v_max + cfg.wind) * delta / 2 + cfg.radius
        plots.draw_ellipse(ax, q1, q2, a, color="k", lw=1)
        box_lo, box_hi = np.array([-a, -a]) + q1, np.array([a, a]) + q2
        mask, xs, ys = regions.region_mask(q1, q2, delta, box_lo, box_hi, cfg.spacing / 2)
        ax.contourf(xs, ys, mask.astype(float), levels=[0.5, 1.5], colors=["tab:red"], alpha=0.35)
        for q in (q1, q2):
            ax.add_patch(plt.Circle(q, cfg.radius, fill=False, ls=":", color="0.3"))
        r = exact.area_ratio(regions, q1, q2, delta)
        ax.set_title(f"{title}\nexact / ellipse area = {r['ratio']:.2f}", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlim(box_lo[0], box_hi[0])
        ax.set_ylim(box_lo[1], box_hi[1])
    fig.suptitle("Reachable positions between two observations: exact (red, HJ) and the ellipse (black)")
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "coobservation_exact.png", dpi=100)
    result["figure_interval_s"] = [t1, t2]
    text = json.dumps(result, indent=1)
    (out / "coobservation_exact.json").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
