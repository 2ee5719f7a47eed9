"""The tightest STA spacing of the dense scenarios (``corridor``, ``crossing``, ``pinwheel``) for each ``k̄``: the
smallest whole second at which the straight plan keeps every vehicle outside the higher-priority vehicles' planner
disks (:func:`stp_env.planning.verify.straight_plan`), and the clearance there and one second tighter. For the
``pinwheel`` first the smallest whole metre of the circle's radius (the waves 400 s apart), then the spacing of the
waves at that radius.

    python examples/dense_spacing.py [--scenarios corridor crossing pinwheel] [--kbars 1 2 3 4] [--triples]

Prints one JSON line per (scenario, k̄); the catalog modules' ``CORRIDOR_SPACING`` / ``CROSSING_SPACING`` /
``PINWHEEL_RADIUS`` and ``PINWHEEL_SPACING`` hold the results. ``--triples`` prints instead, for the catalog's
plan, how close three vehicles ever come together: over every triple airborne at the same time (the straight plan
sampled every 0.5 s), the smallest value of their largest pairwise distance. A third vehicle can be forced only
where that is near the buffer radius.
"""

from __future__ import annotations

import argparse
import json

from stp_env.assembly import load_artifacts
from stp_env.planning.verify import obstacle_margin, planner_disks, straight_plan
from stp_env.scenarios import make


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
                          100, 700, f"{name} k̄={kbar} radius")
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


def tightest_triple(name: str, kbar: int, step: float = 0.5) -> dict:
    import itertools

    import numpy as np

    scenario = make(name, kbar=kbar)
    _, tracking = load_artifacts(scenario, progress=False)
    plan = straight_plan(scenario, tracking.bound, check=False)
    end = max(float(v.plan.times[-1]) for v in plan.vehicles)
    ts = np.arange(min(float(v.plan.times[0]) for v in plan.vehicles), end + step, step)
    pos = np.stack([np.stack([np.interp(ts, v.plan.times, v.plan.states[:, i], left=np.nan, right=np.nan)
                              for i in range(2)], 1) for v in plan.vehicles])  # (vehicles, times, 2)
    best = np.inf
    for a, b, c in itertools.combinations(range(len(pos)), 3):
        span = np.max([np.hypot(*(pos[p] - pos[q]).T) for p, q in ((a, b), (b, c), (a, c))], axis=0)
        if np.isfinite(span).any():
            best = min(best, float(np.nanmin(span)))
    return {"scenario": name, "kbar": kbar, "tightest_triple_m": round(best, 1)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenarios", nargs="+", default=["corridor", "crossing", "pinwheel"])
    parser.add_argument("--kbars", nargs="+", type=int, default=[1, 2, 3, 4])
    parser.add_argument("--triples", action="store_true", help="how close three vehicles come (see above)")
    args = parser.parse_args()
    for name in args.scenarios:
        for kbar in args.kbars:
            print(json.dumps((tightest_triple if args.triples else tightest)(name, kbar)), flush=True)


if __name__ == "__main__":
    main()
