"""The closed-loop certificates of the guarantees the simulator runs, one JSON line each.

    python examples/certification_report.py                 # the winds of the shipped plans (6 and 11 m/s)
    python examples/certification_report.py --wind 6 --wind 11 --wind 8

For each wind: the tracking-error bound (where the stopping rule fired, each certification check after it: the horizon,
``V(0)``, the largest excess of the game's worst strategies over the value of their start and their largest error from
zero error, and the bound it stopped at), and the avoid region's certificate (the largest loss of the game flown from
the table's zero level, where it starts, the table error the margin adds) with the avoid margin and the band in which
the check can fire at each certified inner period. Everything is read from the artifact cache (or the shipped copies),
computed there on first use; ``docs/numerics.md`` explains the certification.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from stp_env.artifacts import ArtifactStore
from stp_env.dynamics import DubinsWind
from stp_env.reach.avoid import compute_avoid_region
from stp_env.reach.closed_loop import CERTIFIED_CONTROL_DT
from stp_env.reach.defaults import default_avoid_config
from stp_env.reach.tracking import default_tracking_bound, default_tracking_config
from stp_env.sim.margins import default_avoid_margin


def report(wind: float, store: ArtifactStore, progress: bool) -> dict:
    vehicle = DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=wind)
    tracking = default_tracking_bound(vehicle, store=store, progress=progress)
    art = store.load("tracking_bound", tracking.config)
    checks = np.asarray(art.arrays["checks"]) if art is not None and "checks" in art.arrays else np.zeros((0, 4))
    avoid = compute_avoid_region(default_avoid_config(vehicle), store=store, progress=progress)
    margins = {str(h): {"margin_m": round(default_avoid_margin(h, avoid.fall_rate, avoid.table_error), 4),
                        "band_m": [round(avoid.table_error + 0.01, 4),
                                   round(default_avoid_margin(h, avoid.fall_rate, avoid.table_error), 4)]}
               for h in CERTIFIED_CONTROL_DT}
    return {
        "wind_m_s": wind,
        "tracking": {"bound_m": round(tracking.bound, 4), "certified": tracking.certified,
                     "horizon_s": tracking.horizon, "closed_loop_worst_m": round(tracking.closed_loop_worst, 4),
                     "closed_loop_excess_m": round(tracking.closed_loop_excess, 4),
                     "allowance_m": round(tracking.config.certify_allowance, 4),
                     "box_half_width_m": round(tracking.config.half_width, 3),
                     "default_box_m": round(default_tracking_config(vehicle).half_width, 3),
                     "checks_horizon_V0_excess_worst": [[round(float(v), 3) for v in row] for row in checks]},
        "avoid": {"fall_rate_m_s": round(avoid.fall_rate, 3), "table_error_m": round(avoid.table_error, 4),
                  "certificate": {k: round(v, 4) for k, v in avoid.certificate.items()}, "by_control_dt": margins},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wind", type=float, action="append", help="wind bound [m/s] (repeatable; default 6 and 11)")
    ap.add_argument("--no-progress", action="store_true", help="hide the progress bars of a first computation")
    args = ap.parse_args(argv)
    store = ArtifactStore()
    for wind in args.wind or [6.0, 11.0]:
        print(json.dumps(report(float(wind), store, not args.no_progress)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
