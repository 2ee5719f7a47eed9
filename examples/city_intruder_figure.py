"""The shipped intruder-aware city plans (``city-intruder``, BEACLS Section VII): one figure per k̄ in the spirit of
the BEACLS paper's Fig. 13 (nominal trajectories and the induced obstacles when the most vehicles are in the air),
and one JSON line per plan with what the figure shows.

    python examples/city_intruder_figure.py --kbars 2 3 4 --out docs

Writes ``city_intruder_k{k}.png`` to ``--out``. Loads the shipped plans only (never plans): a k̄ whose plan does not
ship is reported and skipped.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from stp_env.assembly import flying_counts, plan_mismatch
from stp_env.planning.plots import plot_plan
from stp_env.planning.stp import shipped_plan
from stp_env.scenarios import make


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kbars", type=int, nargs="+", default=[2, 3, 4])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for kbar in args.kbars:
        scenario = make("city-intruder", kbar=kbar)
        try:
            plan = shipped_plan(f"city-intruder-kbar{kbar}")
        except ValueError:
            print(json.dumps({"kbar": kbar, "shipped": False}), flush=True)
            continue
        mismatch = plan_mismatch(plan, scenario, plan.tracking_bound)
        if mismatch is not None:
            raise SystemExit(f"the shipped city-intruder-kbar{kbar} plan is not for make('city-intruder', "
                             f"kbar={kbar}): {mismatch}")
        start = min(v.plan.t_ldt for v in plan.vehicles)
        end = max(v.plan.arrival_time for v in plan.vehicles)
        times = np.arange(start, end, 1.0)
        counts = flying_counts(plan, times)
        snapshot = float(times[int(np.argmax(counts))])
        path = args.out / f"city_intruder_k{kbar}.png"
        plot_plan(plan, scenario, str(path), snapshot_time=snapshot)
        flights = np.asarray([v.plan.arrival_time - v.plan.t_ldt for v in plan.vehicles])
        early = np.asarray([v.plan.sta - v.plan.arrival_time for v in plan.vehicles])
        print(json.dumps({
            "kbar": kbar, "figure": str(path), "vehicles": len(plan.vehicles),
            "buffer_disk_m": round(float(plan.vehicles[0].obstacle_radii[0]), 1),
            "airborne_max": int(counts.max()), "airborne_mean": round(float(counts.mean()), 2),
            "snapshot_s": round(snapshot, 1), "flight_s": [round(float(flights.min()), 1),
                                                          round(float(flights.max()), 1)],
            "early_s": [round(float(early.min()), 1), round(float(early.max()), 1)],
            "span_s": [round(float(start), 1), round(float(end), 1)]}), flush=True)


if __name__ == "__main__":
    main()
