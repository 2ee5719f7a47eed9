"""``stp-env data check-plan``: checks a plan against the constraints the sequential planner imposes, from its
nominal trajectories alone: a shipped plan, a plan file, or the planned prefix of a planning checkpoint (a long run
in progress).

    stp-env data check-plan city                                 # a shipped plan (a name of SHIPPED_PLANS)
    stp-env data check-plan my-plan.npz --scenario bay-area      # a plan file of a registered scenario
    stp-env data check-plan DIR/bay-area.ckpt.npz --scenario bay-area --tracking-bound 35.391876220703125
    stp-env data check-plan bay-area.npz --scenario bay-area --figure bay_area.png

For every vehicle, that its samples are a flight of the planning dynamics from its start with its recorded arrival
(:func:`stp_env.planning.verify.trajectory_faults`: without it the checks below would read non-finite or truncated
flights and pass vacuously); its clearance from the disks of every higher-priority vehicle (exact, at its samples:
:func:`stp_env.planning.verify.vehicle_clearances`); the plan's fit to its scenario (vehicles, STAs, bound); each
vehicle's arrival against its STA; the tracking bubble's distance from the domain's edge. Prints one JSON line and
exits with status 1 if a vehicle's trajectory is faulty, comes deeper than half a planning cell into a disk (the
tolerance the shipped plans are tested to), arrives late or never, or its bubble leaves the domain. What it cannot
read or check (a missing path, a directory, an empty, truncated or foreign file, an archive without a plan's arrays,
an unknown scenario) is one line on standard error naming it, and exit status 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description

SHOW = 10  # the deepest vehicles listed


class Refused(ValueError):
    """A plan that cannot be read or checked: one line naming the plan (``stp-env`` exits with status 2; 1 is a plan
    that was checked and fails)."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


def read(source: str, scenario_name: str | None, tracking_bound: float | None):
    """``(plan, scenario, kind, bytes)`` for a shipped name, a plan file or a checkpoint file."""
    import numpy as np

    from stp_env.assembly import SHIPPED_PLANS
    from stp_env.loaders import LoadError, read_npz
    from stp_env.planning.plan import Plan, VehiclePlan, plan_from_arrays
    from stp_env.scenarios import make

    if source in SHIPPED_PLANS and not Path(source).exists():
        from stp_env.planning.stp import shipped_plan

        name, overrides = SHIPPED_PLANS[source]
        if scenario_name is not None and scenario_name != name:
            raise Refused(f"{source!r} is shipped for scenario {name!r}, not {scenario_name!r}.")
        return shipped_plan(source), make(name, **overrides), "shipped", None
    path = Path(source)
    if not path.is_file():
        raise Refused(f"{source!r} is neither a shipped plan ({', '.join(SHIPPED_PLANS)}) nor a file.")
    if scenario_name is None:
        stem = path.name.removesuffix(".npz").removesuffix(".ckpt")
        if stem not in SHIPPED_PLANS:
            raise Refused(f"{path.name}: name the scenario it was planned for (--scenario).")
        scenario_name, overrides = SHIPPED_PLANS[stem]
    else:
        overrides = {}
    scenario = make(scenario_name, **overrides)
    try:  # the loader contract: a regular file within its size cap, an .npz archive, nothing unpickled
        arrays = read_npz(path, "plan-checkpoint")
    except LoadError as err:
        problem = err.problem.removeprefix("not a planning checkpoint: ").rstrip(".")
        raise Refused(f"{path}: not a readable plan file or planning checkpoint ({problem}).") from err
    if "key" in arrays:  # a planning checkpoint: the vehicles planned so far, in priority order
        from stp_env.planning.checkpoint import load

        if tracking_bound is None:
            raise Refused(f"{path} is a planning checkpoint, which does not record the tracking bound: give "
                          "--tracking-bound (the one the run plans with).")
        planned = load(path, str(arrays["key"]))
        vehicles = tuple(VehiclePlan(index=i, priority=rank, plan=single, obstacle_lags=np.zeros(1),
                                     obstacle_radii=np.zeros(1)) for rank, (i, single) in enumerate(planned))
        plan = Plan(vehicles=vehicles, tracking_bound=float(tracking_bound),
                    collision_radius=float(scenario.collision_radius), kbar=scenario.kbar)
        return plan, scenario, "checkpoint", path.stat().st_size
    try:
        plan = plan_from_arrays(arrays)
    except (KeyError, ValueError, IndexError, TypeError) as err:  # missing arrays, or of other shapes and dtypes
        raise Refused(f"{path}: not a plan file ({type(err).__name__}: {err}).") from err
    return plan, scenario, "file", path.stat().st_size


def check(plan, scenario, kind: str) -> dict:
    """The checks of the module docstring, as a dict (``ok``: all of them pass)."""
    import numpy as np

    from stp_env.assembly import plan_mismatch
    from stp_env.planning.verify import domain_margin, planner_disks, trajectory_faults, vehicle_clearances

    half_cell = 0.5 * float(max(scenario.grid().spacing[:2]))
    faults = trajectory_faults(plan, scenario)
    disks = planner_disks(scenario, plan.tracking_bound, progress=False)
    clearances = vehicle_clearances(plan, disks)
    priority = {v.index: v.priority for v in plan.vehicles}
    deep = sorted((c for c in clearances if c[1] < -half_cell), key=lambda c: c[1])
    finite = [c for c in clearances if math.isfinite(c[1])]
    worst = min(finite, key=lambda c: c[1]) if finite else None
    lateness = np.asarray([v.plan.arrival_time - v.plan.sta for v in plan.vehicles])
    margin, where = domain_margin(plan, scenario.domain_lo, scenario.domain_hi)
    mismatch = plan_mismatch(plan, scenario, plan.tracking_bound) if kind != "checkpoint" else None
    late = int(np.sum(~(lateness <= 0.0)))  # a vehicle that never arrives is late (inf)
    return {
        "vehicles": len(plan.vehicles), "of": scenario.n_vehicles, "tracking_bound": plan.tracking_bound,
        "mismatch": mismatch, "trajectory_faults": len(faults),
        "faulty": [{"vehicle": i, "why": why} for i, why in sorted(faults.items())[:SHOW]],
        "half_cell": round(half_cell, 3),
        "worst_clearance": None if worst is None else round(worst[1], 2),
        "worst_at": None if worst is None else {"vehicle": worst[0], "priority": priority[worst[0]],
                                                "disk_of": worst[2], "time": round(worst[3], 2)},
        "deeper_than_half_cell": len(deep),
        "deepest": [{"vehicle": c[0], "priority": priority[c[0]], "clearance": round(c[1], 2), "disk_of": c[2],
                     "time": round(c[3], 2)} for c in deep[:SHOW]],
        "late": late, "earliest_by": round(float(-lateness.max()), 2) if lateness.size else None,
        "domain_margin": round(margin, 2), "domain_vehicle": where[0],
        "ok": not faults and not deep and late == 0 and margin >= plan.tracking_bound and mismatch is None,
    }


def add_parser(sub) -> None:
    """Add ``check-plan`` to the ``stp-env data`` subcommands (building it imports no JAX)."""
    p = sub.add_parser("check-plan", help="check a shipped plan, a plan file or a planning checkpoint (exit 1: it "
                                          "fails; 2: it cannot be read)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("plan", help="a shipped plan's name, a plan file (.npz) or a planning checkpoint")
    p.add_argument("--scenario", help="the registered scenario it was planned for (default: from its name)")
    p.add_argument("--tracking-bound", type=kit.positive, help="r_e [m] of a checkpoint's run (> 0)")
    p.add_argument("--figure", type=Path, help="draw the plan here (PNG)")
    p.set_defaults(run=run, command="data check-plan")


def run(args) -> int:
    """Run ``stp-env data check-plan``: one JSON line; 0 if the plan passes, 1 if it fails (a :class:`Refused`, a
    ``ValueError``, is status 2)."""
    try:
        plan, scenario, kind, size = read(args.plan, args.scenario, args.tracking_bound)
        result = {"plan": args.plan, "kind": kind, "scenario": scenario.name, "bytes": size,
                  **check(plan, scenario, kind)}
        if args.figure is not None:
            from stp_env.planning.plots import plot_plan

            result["figure"] = plot_plan(plan, scenario, str(args.figure))
    except Refused:
        raise
    except (ValueError, OSError) as err:  # an unknown scenario, a foreign checkpoint, an unwritable figure
        raise Refused(f"{args.plan}: {err}" if args.plan not in str(err) else str(err)) from err
    print(json.dumps(result))
    return 0 if result["ok"] else 1
