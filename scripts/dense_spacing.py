"""The tightest STA spacing of the dense scenarios (``corridor``, ``crossing``) for each ``k̄``: the smallest whole
second at which the straight plan keeps every vehicle outside the higher-priority vehicles' planner disks
(:func:`stp_env.planning.verify.straight_plan`), and the clearance there and one second tighter.

    python scripts/dense_spacing.py [--scenarios corridor crossing] [--kbars 1 2 3 4]

Prints one JSON line per (scenario, k̄); the catalog modules' ``CORRIDOR_SPACING`` / ``CROSSING_SPACING`` hold the
results.
"""

from __future__ import annotations

import argparse
import json

from stp_env.planning.verify import obstacle_margin, planner_disks, straight_plan
from stp_env.scenarios import make
from stp_env.sim.build import load_artifacts


def margin_at(name: str, kbar: int, spacing: float, disks, bound: float) -> float:
    scenario = make(name, kbar=kbar, sta_spacing=spacing)
    return obstacle_margin(straight_plan(scenario, bound, disks=disks, check=False), disks)[0]


def tightest(name: str, kbar: int, lo: int = 1, hi: int = 400) -> dict:
    scenario = make(name, kbar=kbar)
    _, tracking = load_artifacts(scenario, progress=False)
    disks = planner_disks(scenario, tracking.bound)
    if margin_at(name, kbar, hi, disks, tracking.bound) < 0:
        raise SystemExit(f"{name} k̄={kbar}: even {hi} s is too tight.")
    while hi - lo > 1:  # the clearance grows with the spacing on these straight, staggered routes
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if margin_at(name, kbar, mid, disks, tracking.bound) >= 0 else (mid, hi)
    return {"scenario": name, "kbar": kbar, "spacing_s": hi, "buffer_radius_m": round(float(disks.radii[0]), 2),
            "clearance_m": round(margin_at(name, kbar, hi, disks, tracking.bound), 2),
            "clearance_1s_tighter_m": round(margin_at(name, kbar, hi - 1, disks, tracking.bound), 2)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenarios", nargs="+", default=["corridor", "crossing"])
    parser.add_argument("--kbars", nargs="+", type=int, default=[1, 2, 3, 4])
    args = parser.parse_args()
    for name in args.scenarios:
        for kbar in args.kbars:
            print(json.dumps(tightest(name, kbar)), flush=True)


if __name__ == "__main__":
    main()
