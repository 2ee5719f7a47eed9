"""``stp-env data reconcile-controls``: makes every stored control of a plan file carry its sample to the next one
(the states are kept), in place.

    stp-env data reconcile-controls city-case1 city-case3                 # shipped plans, by name (a checkout)
    stp-env data reconcile-controls bay-area.npz --scenario bay-area      # a plan file
    stp-env data reconcile-controls city --check

A plan made before the planner reconciled its controls (:func:`stp_env.planning.verify.reconcile_controls`) can hold
a sample whose stored control is not the one that moved the state, which makes the simulator's reference jump at
the next sample. This rewrites such a file with the controls recovered from its states and nothing else changed
(the other arrays, the packing, every other sample's bits), atomically; a file that needs nothing is left untouched.
Prints one JSON line per plan; with ``--check`` it only reports and exits with status 1 if a plan needs it. A plan
named by its shipped name is the package's own file, rewritten only in a source checkout
(:func:`stp_env.data_tools.shipping.checkout_data`); every argument is resolved before any file is touched.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description, shipping

TRAJECTORIES = ("times", "states", "controls", "packed_trajectories")


def reconcile_file(path: Path, scenario, *, write: bool) -> dict:
    """Reconciles the plan file ``path`` of ``scenario``; returns what was (or, without ``write``, would be) fixed."""
    import numpy as np

    from stp_env.files import atomic_open
    from stp_env.loaders import read_npz
    from stp_env.planning.plan import pack_trajectories, plan_from_arrays, plan_to_arrays
    from stp_env.planning.verify import reconcile_controls

    arrays = read_npz(path, "plan-checkpoint")  # the loader contract: a regular, size-capped .npz, nothing unpickled
    try:
        plan = plan_from_arrays(arrays)
    except (KeyError, ValueError, IndexError, TypeError) as err:  # missing arrays, or of other shapes and dtypes
        raise ValueError(f"{path}: not a plan file ({type(err).__name__}: {err}).") from err
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


def add_parser(sub) -> None:
    """Add ``reconcile-controls`` to the ``stp-env data`` subcommands (building it imports no JAX)."""
    p = sub.add_parser("reconcile-controls", help="repair the stored controls of plan files, in place (--check: "
                                                  "exit 1 if one needs it)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("plans", nargs="+", help="shipped plans' names or plan files (.npz)")
    p.add_argument("--scenario", help="the registered scenario of the plan files (default: from their names)")
    p.add_argument("--check", action="store_true", help="report only; exit 1 if a plan needs reconciling")
    p.set_defaults(run=run, command="data reconcile-controls")


def run(args) -> int:
    """Run ``stp-env data reconcile-controls``: one JSON line per plan; 1 with ``--check`` if one needs it."""
    from stp_env.assembly import SHIPPED_PLANS
    from stp_env.scenarios import make

    jobs = []
    for source in args.plans:  # every argument is resolved before any file is touched
        path = Path(source)
        if not path.is_file():
            if source not in SHIPPED_PLANS or not (shipping.PLANS / f"{source}.npz").is_file():
                raise ValueError(f"{source!r} is neither a shipped plan nor a file.")
            path = shipping.PLANS / f"{source}.npz"
            if not args.check:
                shipping.checkout_data(shipping.PLANS, f"reconciling the shipped plan {source!r}",
                                       "--check only reports")
        stem = path.name.removesuffix(".npz")
        if args.scenario is not None:
            scenario = make(args.scenario)
        elif stem in SHIPPED_PLANS:
            name, overrides = SHIPPED_PLANS[stem]
            scenario = make(name, **overrides)
        else:
            raise ValueError(f"{path.name}: name the scenario it was planned for (--scenario).")
        jobs.append((path, scenario))
    needed = False
    for path, scenario in jobs:
        result = reconcile_file(path, scenario, write=not args.check)
        needed |= result["samples_fixed"] > 0
        print(json.dumps(result), flush=True)
    return 1 if args.check and needed else 0
