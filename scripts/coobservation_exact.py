"""Exact reachability regions of the UAV between two observations, against the ellipse (part 5 of the study).

Solves the forward time-to-reach field of the simulator's UAV (``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``,
wind 6 m/s) from the observation disk (radius 200 m + 20 m tracking margin), and the backward one to check the
time-reversal identity ``T_B(x, theta) = T_F(x, theta + pi)``; then

* area ratios exact / ellipse for observers moving apart at the formation's speed, for several intervals;
* the same for a fixed-wing variant (``v in [15, 25] m/s``, ``|omega| <= 0.5 rad/s``: it cannot hover or turn
  on the spot);
* how many co-observation times each test needs to secure the formation's route (greedy, 1 s grid);
* a figure of both regions for one interval next to zone A (``docs/coobservation_exact.png``).

Writes ``docs/coobservation_exact.json`` and prints it. ``python scripts/coobservation_exact.py`` (about 15-30
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

    # figure: the interval of the ellipse-secured schedule next to zone A, both regions
    k = int(np.argmin([abs(t - 100.0) for t in times_ellipse]))
    t1, t2 = times_ellipse[k], times_ellipse[k + 1]
    lo, hi = np.array(sc.domain_lo), np.array(sc.domain_hi)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.2))
    for ax, (name, times) in zip(axes, (("ellipse-secured", times_ellipse), ("exact-secured (UAV)", times_exact))):
        plots.draw_zones(ax, (), sc.forbidden, names=["zone A", "zone B"])
        pos = sc.positions(np.linspace(0, sc.duration, 200))
        for i in range(sc.n_vehicles):
            ax.plot(pos[i, :, 0], pos[i, :, 1], color=plots.COLORS[i], lw=1)
        for ta, tb in itertools.pairwise(times):
            seg = sc.segments_between(ta, tb)[0]  # the left vehicle's (observed by the centre vehicle)
            f1, f2 = sc.segment_foci(seg)
            plots.draw_ellipse(ax, f1, f2, (sc.attacker_speed * (tb - ta)) / 2 + sc.ellipse_radius, color="k",
                               lw=0.6)
        ax.set_title(f"{name}: {len(times) - 2} co-observation times")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
    seg = sc.segments_between(t1, t2)[0]
    f1, f2 = sc.segment_foci(seg)
    mask, xs, ys = uav.region_mask(f1, f2, t2 - t1, lo, hi, 10.0)
    axes[0].contour(xs, ys, mask.astype(float), levels=[0.5], colors="tab:red", linewidths=1.5)
    axes[0].plot([], [], color="tab:red", label=f"exact region, {t1:g}-{t2:g} s")
    axes[0].plot([], [], color="k", lw=0.6, label="ellipses (v_max + wind)")
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle("Reachability regions of the formation's left vehicle between co-observations")
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "coobservation_exact.png", dpi=110)
    result["figure_interval_s"] = [t1, t2]
    text = json.dumps(result, indent=1)
    (out / "coobservation_exact.json").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
