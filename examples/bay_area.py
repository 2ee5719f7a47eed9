"""The BEACLS paper's multi-city study (Section VI): 200 vehicles between four Bay Area cities.

    python examples/bay_area.py [--vehicles 200] [--sta-spacing 5] [--out bay_area.png]

Plans ``make("bay-area", sta_spacing=...)`` (wind 11 m/s, ``STA_i = 5 (i - 1)`` s by default; ``--sta-spacing 0``
is the paper's Fig. 11 variant) with robust trajectory tracking, the ``--vehicles`` highest-priority vehicles
only if asked (a prefix of the full run: lower priorities never influence higher ones), writes the plan figure and
prints one JSON line (seconds, seconds per vehicle, t_LDT range, latest arrival relative to the STA). With
``--estimate`` it extrapolates the time of all 200 from the mean time per vehicle of the ``--vehicles`` planned
(compilation and re-extractions of late trajectories included, so it errs on the long side). Measured: see
BENCHMARKS.md ("Bay area").
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from stp_env.planning.plots import plot_plan
from stp_env.planning.stp import plan_scenario
from stp_env.scenarios import make


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--vehicles", type=int, default=200)
    parser.add_argument("--sta-spacing", type=float, default=5.0)
    parser.add_argument("--estimate", action="store_true")
    parser.add_argument("--out", default="bay_area.png")
    args = parser.parse_args()
    full = make("bay-area", sta_spacing=args.sta_spacing)
    dist = np.hypot(*(full.targets() - full.starts()[:, :2]).T)
    horizon = 2.0 * float(dist.max()) / full.planning_v[1] + 1.0  # plan_scenario's default for all 200
    scenario = full.with_overrides(vehicles=tuple(v for v in full.vehicles if v.priority < args.vehicles))

    import stp_env.planning.stp as stp

    per_vehicle = []
    original = stp.plan_single

    def timed(*a, **kw):
        t0 = time.perf_counter()
        out = original(*a, **kw)
        per_vehicle.append(time.perf_counter() - t0)
        return out

    stp.plan_single = timed
    t0 = time.perf_counter()
    plan = plan_scenario(scenario, horizon=horizon, progress=True)
    seconds = time.perf_counter() - t0
    plot_plan(plan, scenario, args.out)
    late = max(v.plan.arrival_time - s.sta for v, s in zip(plan.vehicles, scenario.vehicles))
    out = {"case": "bay-area", "vehicles": len(plan.vehicles), "sta_spacing": args.sta_spacing,
           "grid": list(scenario.grid_points), "seconds": round(seconds, 1),
           "seconds_per_plan_call": [round(s, 1) for s in per_vehicle],
           "t_ldt_range": [round(float(plan.t_ldt().min()), 1), round(float(plan.t_ldt().max()), 1)],
           "max_arrival_minus_sta_s": round(float(late), 2)}
    if args.estimate:  # every vehicle so far, compilation and re-extractions included: errs on the long side
        out["estimated_seconds_all_200"] = round(200 * seconds / len(plan.vehicles))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
