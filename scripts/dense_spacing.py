"""The tightest STA spacing of the dense scenarios (``corridor``, ``crossing``, ``pinwheel``) for each ``k̄``: the
smallest whole second at which the straight plan keeps every vehicle outside the higher-priority vehicles' planner
disks (:func:`stp_env.planning.verify.straight_plan`), and the clearance there and one second tighter. For the
``pinwheel`` first the smallest whole metre of the circle's radius (the waves 400 s apart), then the spacing of the
waves at that radius.

    python scripts/dense_spacing.py [--scenarios corridor crossing pinwheel] [--kbars 1 2 3 4]

Prints one JSON line per (scenario, k̄); the catalog modules' ``CORRIDOR_SPACING`` / ``CROSSING_SPACING`` /
``PINWHEEL_RADIUS`` and ``PINWHEEL_SPACING`` hold the results.
"""

from __future__ import annotations

import argparse
import json

from stp_env.planning.verify import obstacle_margin, planner_disks, straight_plan
from stp_env.scenarios import make
from stp_env.sim.build import load_artifacts


def margin_at(name: str, kbar: int, disks, bound: float, **overrides) -> float:
    scenario = make(name, kbar=kbar, **overrides)
    return obstacle_margin(straight_plan(scenario, bound, disks=disks, check=False), disks)[0]


def smallest(clearance, lo: int, hi: int, what: str) -> int:
    """The smallest whole number in ``(lo, hi]`` with ``clearance(n) >= 0``, by bisection: the clearance grows with
    the spacing (and the pinwheel's radius) on these straight, staggered routes."""
    if clearance(hi) < 0:
        raise SystemExit(f"{what}: even {hi} is too tight.")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if clearance(mid) >= 0 else (mid, hi)
    return hi


def tightest(name: str, kbar: int) -> dict:
    scenario = make(name, kbar=kbar)
    _, tracking = load_artifacts(scenario, progress=False)
    disks = planner_disks(scenario, tracking.bound)
    fixed, out = {}, {"scenario": name, "kbar": kbar}
    if name == "pinwheel":
        radius = smallest(lambda r: margin_at(name, kbar, disks, tracking.bound, radius=float(r), sta_spacing=400.0),
                          100, 999, f"{name} k̄={kbar} radius")
        fixed = {"radius": float(radius)}
        out.update(radius_m=radius, triangle_side_m=round(3 ** 0.5 * radius, 2), clearance_1m_smaller_m=round(
            margin_at(name, kbar, disks, tracking.bound, radius=radius - 1.0, sta_spacing=400.0), 2))
    spacing = smallest(lambda s: margin_at(name, kbar, disks, tracking.bound, sta_spacing=float(s), **fixed),
                       1, 400, f"{name} k̄={kbar} spacing")
    out.update(spacing_s=spacing, buffer_radius_m=round(float(disks.radii[0]), 2),
               clearance_m=round(margin_at(name, kbar, disks, tracking.bound, sta_spacing=spacing, **fixed), 2),
               clearance_1s_tighter_m=round(margin_at(name, kbar, disks, tracking.bound, sta_spacing=spacing - 1,
                                                      **fixed), 2))
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenarios", nargs="+", default=["corridor", "crossing", "pinwheel"])
    parser.add_argument("--kbars", nargs="+", type=int, default=[1, 2, 3, 4])
    args = parser.parse_args()
    for name in args.scenarios:
        for kbar in args.kbars:
            print(json.dumps(tightest(name, kbar)), flush=True)


if __name__ == "__main__":
    main()
