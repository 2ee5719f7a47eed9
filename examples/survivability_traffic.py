"""What each reading of the survivability paper's traffic model (Section III-B) puts in the air over the
Bay-Area mission: path length, flight duration and speed of the intruders, the share in flight at a minute, and
the space-time cells each one blocks (:func:`stp_env.survivability.traffic.traffic_statistics`), on the same
seeds for every reading.

    python examples/survivability_traffic.py [--intruders 300] [--instances 20]

Prints one JSON line per reading: ``local`` (the earlier model), ``paper`` (the default: unbounded speeds) and
``paper`` with ``--max-speed 40`` (the paths conditioned on the top cruise speed of the paper's network).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from stp_env.survivability.config import MissionConfig, TrafficConfig
from stp_env.survivability.traffic import sample_traffic, traffic_statistics

READINGS = {"local": {"model": "local"}, "paper": {}, "paper, max_speed 40 m/s": {"max_speed": 40.0}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--intruders", type=int, default=300, help="intruders per instance (all partially known)")
    ap.add_argument("--instances", type=int, default=20, help="instances per reading (seeds 0, 1, ...)")
    args = ap.parse_args()
    mission = MissionConfig()
    for name, options in READINGS.items():
        config = TrafficConfig(n_partial=args.intruders, n_unknown=0, **options)
        stats = [traffic_statistics(sample_traffic(i, mission, config), mission, config.samples_per_min)
                 for i in range(args.instances)]
        weights = np.array([s["moving"] for s in stats], float)
        line = {"reading": name, "intruders": args.intruders * args.instances}
        for key in ("length_km", "duration_min"):
            line[key] = round(float(np.average([s[key] for s in stats], weights=weights)), 1)
        line["speed_ms_p50_p90_p99"] = np.median([s["speed_ms_p50_p90_p99"] for s in stats], axis=0).round(1).tolist()
        for key in ("airborne_fraction", "cells_per_intruder"):
            line[key] = round(float(np.mean([s[key] for s in stats])), 3)
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
