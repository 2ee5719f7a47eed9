"""Makes every stored control of a plan file carry its sample to the next one (the states are kept), in place.

A plan made before the planner reconciled its controls (``stp_env.planning.verify.reconcile_controls``) can hold a
sample whose stored control is not the one that moved the state, which makes the simulator's reference jump at the
next sample. This rewrites such a file with the controls recovered from its states and nothing else changed (the
other arrays, the packing, every other sample's bits), atomically; a file that needs nothing is left untouched.
Prints one JSON line per plan; with ``--check`` it only reports and exits with status 1 if a plan needs it.

    python scripts/reconcile_controls.py city-case1 city-case3                # shipped plans, by name
    python scripts/reconcile_controls.py bay-area.npz --scenario bay-area     # a plan file
    python scripts/reconcile_controls.py city --check
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from stp_env.assembly import SHIPPED_PLANS
from stp_env.files import atomic_open
from stp_env.planning.plan import pack_trajectories, plan_from_arrays, plan_to_arrays
from stp_env.planning.verify import reconcile_controls
from stp_env.scenarios import make

DATA = Path(__file__).resolve().parents[1] / "stp_env" / "data" / "plans"
TRAJECTORIES = ("times", "states", "controls", "packed_trajectories")


def reconcile_file(path: Path, scenario, *, write: bool) -> dict:
    """Reconciles the plan file ``path`` of ``scenario``; returns what was (or, without ``write``, would be) fixed."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    plan = plan_from_arrays(arrays)
    vehicles, fixed = [], {}
    for veh in plan.vehicles:
        single, samples = reconcile_controls(veh.plan, scenario.time_step, scenario.planning_v,
                                             scenario.planning_omega_max)
        if samples:
            fixed[veh.index] = samples
        vehicles.append(dataclasses.replace(veh, plan=single))
    if fixed and write:
        new = plan_to_arrays(dataclasses.replace(plan, vehicles=tuple(vehicles)))
        trajectories = {k: new[k] for k in ("times", "states", "controls")}
        if "packed_trajectories" in arrays:
            trajectories = {"packed_trajectories": pack_trajectories(new)["packed_trajectories"]}
        out = {**{k: v for k, v in arrays.items() if k not in TRAJECTORIES}, **trajectories}
        with atomic_open(path, "wb") as fh:
            np.savez_compressed(fh, **out)
    return {"file": str(path), "vehicles": len(plan.vehicles), "samples_fixed": sum(map(len, fixed.values())),
            "fixed": {str(i): s for i, s in sorted(fixed.items())}, "written": bool(fixed and write)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("plans", nargs="+", help="shipped plans' names or plan files (.npz)")
    parser.add_argument("--scenario", help="the registered scenario of the plan files (default: from their names)")
    parser.add_argument("--check", action="store_true", help="report only; exit 1 if a plan needs reconciling")
    args = parser.parse_args(argv)
    jobs = []
    for source in args.plans:  # every argument is resolved before any file is touched
        path = Path(source)
        if not path.is_file():
            if source not in SHIPPED_PLANS or not (DATA / f"{source}.npz").is_file():
                raise SystemExit(f"{source!r} is neither a shipped plan nor a file.")
            path = DATA / f"{source}.npz"
        stem = path.name.removesuffix(".npz")
        if args.scenario is not None:
            scenario = make(args.scenario)
        elif stem in SHIPPED_PLANS:
            name, overrides = SHIPPED_PLANS[stem]
            scenario = make(name, **overrides)
        else:
            raise SystemExit(f"{path.name}: name the scenario it was planned for (--scenario).")
        jobs.append((path, scenario))
    needed = False
    for path, scenario in jobs:
        result = reconcile_file(path, scenario, write=not args.check)
        needed |= result["samples_fixed"] > 0
        print(json.dumps(result), flush=True)
    return 1 if args.check and needed else 0


if __name__ == "__main__":
    sys.exit(main())
