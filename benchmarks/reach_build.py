"""Time and peak memory to build every reachability artifact of the default scenario from an empty cache.

    python benchmarks/reach_build.py [--wind 6]

Prints one JSON line. The peer in the same run is the avoid region alone (the single largest solve), so the
ratio shows how the whole build scales against one set; absolute numbers are recorded in BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time

from stp_env.artifacts import ArtifactStore
from stp_env.dynamics import DubinsWind
from stp_env.reach.avoid import compute_avoid_region
from stp_env.reach.defaults import build_reach_artifacts, default_avoid_config


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--wind", type=float, default=6.0)
    args = parser.parse_args()
    vehicle = DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=args.wind)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        compute_avoid_region(default_avoid_config(vehicle), progress=False)
        avoid_s = time.perf_counter() - start
        start = time.perf_counter()
        arts = build_reach_artifacts(args.wind, (1, 2, 3, 4), store=ArtifactStore(tmp), progress=False)
        total_s = time.perf_counter() - start
    summary = arts.summary()
    print(json.dumps({
        "case": "reach_build", "wind_m_s": args.wind, "total_s": round(total_s, 1),
        "avoid_region_alone_s": round(avoid_s, 1), "ratio_total_over_avoid": round(total_s / avoid_s, 2),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "tracking_bound_m": summary["tracking_bound_m"], "detection_range_m": summary["detection_range_m"],
        "buffer_radius_m": {k: v["buffer_radius_m"] for k, v in summary["buffers"].items()},
    }))


if __name__ == "__main__":
    main()
