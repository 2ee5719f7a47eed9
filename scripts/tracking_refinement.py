"""Grid-refinement study of the robust-tracking error bound (NUMERICS.md: coarse grids overstate it).

    python scripts/tracking_refinement.py --wind 6 --points 41 51 61 81

Prints one JSON line per grid: the bound V(0), the horizon at which the stopping rule fired, and the time.
"""

from __future__ import annotations

import argparse
import json
import time

from stp_env.dynamics import DubinsWind
from stp_env.reach.tracking import TrackingConfig, compute_tracking_bound


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--wind", type=float, default=6.0, help="wind bound [m/s]")
    parser.add_argument("--half-width", type=float, default=None, help="error box half-width [m]")
    parser.add_argument("--points", type=int, nargs="+", default=[41, 51, 61])
    args = parser.parse_args()
    half_width = args.half_width or (10.0 if args.wind <= 6 else 30.0)
    for n in args.points:
        cfg = TrackingConfig(vehicle=DubinsWind(wind=args.wind), half_width=half_width,
                             grid_points=(n, n, n - n % 2))
        start = time.perf_counter()
        res = compute_tracking_bound(cfg, progress=False)
        print(json.dumps({"wind": args.wind, "points": n, "spacing_m": round(cfg.grid.spacing[0], 3),
                          "bound_m": round(res.bound, 3), "converged": res.converged, "horizon_s": res.horizon,
                          "seconds": round(time.perf_counter() - start, 1)}), flush=True)


if __name__ == "__main__":
    main()
