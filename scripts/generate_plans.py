"""Regenerate the plans shipped as package data (``stp_env/data/plans/*.npz``).

    python scripts/generate_plans.py [--names tiny tiny-intruder]

Each file holds the arrays of :func:`stp_env.planning.stp.plan_to_arrays` for a registered scenario planned with
robust trajectory tracking and the default tracking bound; ``tests/test_planning.py`` regenerates the small one
and compares it bit for bit.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from stp_env.planning.stp import plan_scenario, plan_to_arrays
from stp_env.scenarios import make

DATA = Path(__file__).resolve().parents[1] / "stp_env" / "data" / "plans"
# The default robust-tracking bound for the papers' vehicle in 6 m/s wind (stp-env precompute; 61^3 error grid).
TRACKING_BOUND = 4.127
SHIPPED = {"tiny": {}, "tiny-intruder": {"sta_spacing": 90}}


def generate(name: str) -> dict[str, np.ndarray]:
    scenario = make(name, **SHIPPED[name])
    return plan_to_arrays(plan_scenario(scenario, tracking_bound=TRACKING_BOUND, progress=False))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--names", nargs="+", default=list(SHIPPED))
    args = parser.parse_args()
    DATA.mkdir(parents=True, exist_ok=True)
    for name in args.names:
        arrays = generate(name)
        path = DATA / f"{name}.npz"
        np.savez(path, **arrays)
        print(json.dumps({"scenario": name, "file": str(path), "bytes": path.stat().st_size,
                          "t_ldt": arrays["t_ldt"].round(3).tolist()}))


if __name__ == "__main__":
    main()
