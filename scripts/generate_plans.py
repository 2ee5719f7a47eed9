"""Regenerate the plans shipped as package data (``stp_env/data/plans/*.npz``).

    python scripts/generate_plans.py [--names tiny tiny-intruder town-kbar1 town-kbar2 town-kbar3]

Each file holds the arrays of :func:`stp_env.planning.stp.plan_to_arrays` for a registered scenario planned with
robust trajectory tracking and the default tracking bound; ``tests/test_planning.py`` regenerates the small one
and compares it bit for bit. ``town-kbar{k}`` is ``make("town", kbar=k)`` (load it with
:func:`stp_env.planning.stp.shipped_plan_for`); the three take about 2 minutes each on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from stp_env.planning.stp import plan_scenario, plan_to_arrays
from stp_env.scenarios import make

DATA = Path(__file__).resolve().parents[1] / "stp_env" / "data" / "plans"
# The default robust-tracking bound for the papers' vehicle in 6 m/s wind (stp-env precompute; 61^3 error grid).
TRACKING_BOUND = 4.127
SHIPPED: dict[str, tuple[str, dict]] = {
    "tiny": ("tiny", {}),
    "tiny-intruder": ("tiny-intruder", {"sta_spacing": 90}),
    **{f"town-kbar{k}": ("town", {"kbar": k}) for k in (1, 2, 3)},
}
"""File name -> (registered scenario, overrides)."""


def generate(name: str) -> dict[str, np.ndarray]:
    scenario_name, overrides = SHIPPED[name]
    scenario = make(scenario_name, **overrides)
    return plan_to_arrays(plan_scenario(scenario, tracking_bound=TRACKING_BOUND, progress=False))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--names", nargs="+", default=list(SHIPPED), choices=list(SHIPPED))
    args = parser.parse_args()
    DATA.mkdir(parents=True, exist_ok=True)
    for name in args.names:
        t0 = time.perf_counter()
        arrays = generate(name)
        seconds = time.perf_counter() - t0
        path = DATA / f"{name}.npz"
        np.savez_compressed(path, **arrays)
        print(json.dumps({"scenario": name, "file": str(path), "bytes": path.stat().st_size,
                          "seconds": round(seconds, 1), "t_ldt": arrays["t_ldt"].round(3).tolist()}), flush=True)


if __name__ == "__main__":
    main()
