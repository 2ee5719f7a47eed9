"""Build (or load from the cache) every reachability artifact of the default scenario, print a JSON summary
and write the figures.

    python scripts/build_reach_artifacts.py --wind 6 --out-dir figures
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

from stp_env.artifacts import ArtifactStore
from stp_env.reach.defaults import build_reach_artifacts
from stp_env.reach.plots import footprint_area_ratio, plot_buffer_regions, plot_sets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--wind", type=float, default=6.0, help="wind bound of vehicles and intruder [m/s]")
    parser.add_argument("--kbar", type=int, nargs="+", default=[1, 2, 3, 4], help="values of k̄")
    parser.add_argument("--out-dir", default="figures", help="where to write the PNGs")
    parser.add_argument("--cache-dir", default=None, help="artifact cache (default: platformdirs / $STP_ENV_CACHE_DIR)")
    args = parser.parse_args()
    start = time.perf_counter()
    arts = build_reach_artifacts(args.wind, tuple(args.kbar), store=ArtifactStore(args.cache_dir))
    seconds = time.perf_counter() - start
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    k_show = 3 if 3 in arts.buffers else max(arts.buffers)
    plot_sets(arts.avoid, arts.tracking.bound, arts.buffers[k_show], str(out / f"sets_wind{args.wind:g}.png"))
    shown = {k: v for k, v in arts.buffers.items() if k >= 2} or arts.buffers
    plot_buffer_regions(arts.avoid, arts.tracking.bound, shown, arts.radii,
                        str(out / f"buffer_regions_wind{args.wind:g}.png"))
    summary = arts.summary()
    for k, entry in summary["buffers"].items():
        k = int(k)
        entry["buffer_disk_over_grid_set_area"] = round(
            footprint_area_ratio(arts.avoid, arts.tracking.bound, arts.buffers[k], arts.radii[k].buffer), 3)
    summary["build_seconds"] = round(seconds, 1)
    summary["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
