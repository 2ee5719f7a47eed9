"""Regenerate the plans shipped as package data (``stp_env/data/plans/*.npz``).

    python scripts/generate_plans.py [--names tiny tiny-intruder town-kbar1 town-kbar2 town-kbar3]

Each file holds the arrays of :func:`stp_env.planning.stp.plan_to_arrays` for a registered scenario planned with
robust trajectory tracking and the scenario's default tracking bound (:func:`stp_env.sim.build.load_artifacts`,
computed into the artifact cache on first use); ``tests/test_planning.py`` regenerates the small one and compares
it bit for bit. ``town-kbar{k}`` is ``make("town", kbar=k)`` (load it with
:func:`stp_env.planning.stp.shipped_plan_for`); the three take a few minutes each on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from stp_env.planning.stp import plan_scenario, plan_to_arrays
from stp_env.scenarios import make
from stp_env.sim.build import load_artifacts

DATA = Path(__file__).resolve().parents[1] / "stp_env" / "data" / "plans"
SHIPPED: dict[str, tuple[str, dict]] = {
    "tiny": ("tiny", {}),
    "tiny-intruder": ("tiny-intruder", {"sta_spacing": 90}),
    **{f"town-kbar{k}": ("town", {"kbar": k}) for k in (1, 2, 3)},
}
"""File name -> (registered scenario, overrides)."""


def generate(name: str) -> dict[str, np.ndarray]:
    scenario_name, overrides = SHIPPED[name]
    scenario = make(scenario_name, **overrides)
    _, tracking = load_artifacts(scenario, progress=False)
    return plan_to_arrays(plan_scenario(scenario, tracking_bound=tracking.bound, progress=False))


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
