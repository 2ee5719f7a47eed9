"""The BEACLS paper's city Cases 0-4 (Section V-C): plans and PNGs that show the lanes.

    python examples/city_cases.py [--cases 0 1 2 3 4] [--vehicles 50] [--out city_cases]
    python examples/city_cases.py --shipped [--cases 0 1 2 3 4] [--out city_cases]

Case ``c`` is ``make("city", **CITY_CASES[c])`` (wind 6 or 11 m/s, STA spacing 0, 5 or 10 s), planned with robust
trajectory tracking (no intruder). ``--vehicles n`` plans only the ``n`` highest-priority vehicles of the
50-vehicle study (the same vehicles, targets and schedule; the lower-priority ones never influence them), so a
short run is a prefix of the full one. Writes, in ``--out``:

* ``case{c}.png``: the plan (:func:`stp_env.planning.plots.plot_plan`), and ``case{c}_plan.npz`` its arrays
  (:func:`stp_env.planning.stp.plan_to_arrays`);
* ``lanes.png``: all cases side by side, each trajectory coloured by its destination, with the lane measures below;

With ``--shipped`` nothing is planned: the shipped 50-vehicle plans (``stp_env/data/plans/city.npz`` and
``city-case{c}.npz``, made by ``stp-env data plans``) are measured and drawn instead.

It prints one JSON line per case: seconds (when planned), t_LDT range and two lane measures per destination:
``spread_m``, the mean over pairs of vehicles with the same destination of the mean distance from one path to the
other (how far apart their *paths* are: large when vehicles are separated in space, "state-separated" lanes), and
``gap_s``, the mean gap between consecutive departures of that destination's vehicles (how far apart they are in
*time*: time-separated, one lane flown in trail). BEACLS Figs. 5-8: with no STA spacing, the vehicles fan out into
separate lanes; with 5-10 s spacing they share one lane; stronger wind makes the lanes straighter and fewer.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from stp_env.assembly import plan_mismatch
from stp_env.planning.plots import plot_plan
from stp_env.planning.stp import plan_scenario, plan_to_arrays, shipped_plan
from stp_env.scenarios import CITY_CASES, make
from stp_env.scenarios.catalog.city import CITY_DESTINATIONS


def city_case(case: int, n_vehicles: int):
    """The ``n_vehicles`` highest-priority vehicles of Case ``case`` and the full study's planning horizon."""
    full = make("city", **CITY_CASES[case])
    dist = np.hypot(*(full.targets() - full.starts()[:, :2]).T)
    horizon = 2.0 * float(dist.max()) / full.planning_v[1] + 1.0  # plan_scenario's default for all 50
    keep = tuple(v for v in full.vehicles if v.priority < n_vehicles)
    return full.with_overrides(vehicles=keep), horizon


def path_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over the points of path ``a`` of the distance to the nearest point of path ``b`` [m]."""
    d = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=-1)
    return float(d.min(axis=1).mean())


def lane_measures(plan, scenario) -> dict:
    out = {}
    for k, dest in enumerate(CITY_DESTINATIONS):
        idx = [i for i, v in enumerate(scenario.vehicles) if v.target == dest]
        if len(idx) < 2:
            continue
        paths = [plan.vehicles[i].plan.flight()[1][::4] for i in idx]
        spread = np.mean([0.5 * (path_distance(a, b) + path_distance(b, a))
                          for a, b in itertools.combinations(paths, 2)])
        departures = np.sort([plan.vehicles[i].plan.t_ldt for i in idx])
        out[str(k)] = {"vehicles": len(idx), "spread_m": round(float(spread), 1),
                       "gap_s": round(float(np.mean(np.diff(departures))), 1)}
    return out


def plot_lanes(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(results)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.9), constrained_layout=True, squeeze=False)
    colors = plt.cm.Set1(np.arange(len(CITY_DESTINATIONS)))
    for ax, (case, scenario, plan, lanes) in zip(axes[0], results):
        for b in scenario.buildings:
            xy = np.asarray(b.vertices)
            ax.fill(xy[:, 0], xy[:, 1], color="0.55", lw=0)
        for k, dest in enumerate(CITY_DESTINATIONS):
            ax.add_patch(plt.Circle(dest, scenario.vehicles[0].target_radius, color=colors[k], alpha=0.3))
        for v, spec in zip(plan.vehicles, scenario.vehicles):
            k = CITY_DESTINATIONS.index(spec.target)
            st = v.plan.flight()[1]
            ax.plot(st[:, 0], st[:, 1], color=colors[k], lw=1.0, alpha=0.8)
        ax.plot(*scenario.vehicles[0].start[:2], "*", color="k", ms=10)
        wind, spacing = CITY_CASES[case]["wind"], CITY_CASES[case]["sta_spacing"]
        text = "\n".join(f"dest {int(k) + 1}: {m['vehicles']} veh, spread {m['spread_m']:.0f} m, "
                         f"gap {m['gap_s']:.0f} s" for k, m in lanes.items())
        ax.set_title(f"Case {case}: wind {wind:g} m/s, STA spacing {spacing:g} s\n{len(plan.vehicles)} vehicles",
                     fontsize=10)
        ax.text(0.02, 0.02, text, transform=ax.transAxes, fontsize=7, va="bottom",
                bbox={"facecolor": "white", "alpha": 0.85, "lw": 0})
        ax.set_xlim(0, 5000)
        ax.set_ylim(0, 5000)
        ax.set_aspect("equal")
        ax.set_xticks([0, 2500, 5000])
        ax.set_yticks([0, 2500, 5000])
        ax.tick_params(labelsize=8)
    fig.suptitle("City cases (BEACLS Section V-C): nominal paths coloured by destination. spread = mean distance "
                 "between paths to the same destination (state separation); gap = mean time between their "
                 "departures (time separation)", fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", type=int, nargs="+", default=sorted(CITY_CASES), choices=sorted(CITY_CASES))
    parser.add_argument("--vehicles", type=int, default=50)
    parser.add_argument("--out", type=Path, default=Path("city_cases"))
    parser.add_argument("--shipped", action="store_true",
                        help="measure and draw the shipped 50-vehicle plans instead of planning (--vehicles unused)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for case in args.cases:
        if args.shipped:
            scenario, timing = make("city", **CITY_CASES[case]), {"source": "shipped"}
            plan = shipped_plan("city" if case == 0 else f"city-case{case}")
            problem = plan_mismatch(plan, scenario, plan.tracking_bound)
            if problem is not None:
                raise SystemExit(f"the shipped plan of Case {case} is not for make('city', **CITY_CASES[{case}]): "
                                 f"{problem}")
        else:
            scenario, horizon = city_case(case, args.vehicles)
            t0 = time.perf_counter()
            plan = plan_scenario(scenario, horizon=horizon, progress=True)
            seconds = time.perf_counter() - t0
            timing = {"seconds": round(seconds, 1), "seconds_per_vehicle": round(seconds / len(plan.vehicles), 1)}
            np.savez_compressed(args.out / f"case{case}_plan.npz", **plan_to_arrays(plan))
        plot_plan(plan, scenario, str(args.out / f"case{case}.png"))
        lanes = lane_measures(plan, scenario)
        results.append((case, scenario, plan, lanes))
        late = max(v.plan.arrival_time - s.sta for v, s in zip(plan.vehicles, scenario.vehicles))
        print(json.dumps({"case": case, **CITY_CASES[case], "vehicles": len(plan.vehicles), **timing,
                          "t_ldt_range": [round(float(plan.t_ldt().min()), 1), round(float(plan.t_ldt().max()), 1)],
                          "max_arrival_minus_sta_s": round(float(late), 2), "tracking_bound_m": plan.tracking_bound,
                          "lanes": lanes}), flush=True)
        plot_lanes(results, args.out / "lanes.png")


if __name__ == "__main__":
    main()
