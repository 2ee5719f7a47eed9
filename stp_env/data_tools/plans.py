"""``stp-env data plans``: plan registered scenarios as the package ships them, into ``--out`` (or, in a source
checkout, with ``--ship``, into the package's own ``stp_env/data/plans``).

    stp-env data plans --out plans                      # tiny tiny-intruder town-kbar1 town-kbar2 town-kbar3
    stp-env data plans --names city --checkpoint-dir plan-checkpoints --out plans
    stp-env data plans --names town-kbar2 --ship        # a checkout: replace the shipped town-kbar2.npz

Each file ``NAME.npz`` holds the arrays of :func:`stp_env.planning.stp.plan_to_arrays` for the entry ``NAME`` of
:data:`stp_env.assembly.SHIPPED_PLANS` (a registered scenario and its overrides; ``fig6-kbar3`` is not made here:
``examples/fig6_reproduction.py`` makes it), planned with robust trajectory tracking and the scenario's default
tracking bound (:func:`stp_env.assembly.load_artifacts`, computed into the artifact cache on first use), with the
settings of this module (:data:`HORIZONS`, :data:`SLICE_DT`, :data:`HOLD_SLICES`, :data:`KEEP_AFTER_ARRIVAL`).
Prints one JSON line per plan. ``tests/test_planning.py`` makes the small one and compares it with the shipped
file bit for bit. ``town-kbar{k}`` is ``make("town", kbar=k)`` (load it with
:func:`stp_env.planning.stp.shipped_plan_for`); the three take a few minutes each on 2 cores.

``city`` (``make("city")``: BEACLS Case 0, 50 vehicles) is not in the default list: it took 532 s (10.6 s per
vehicle) on 2 otherwise idle cores, with ``--tracking-bound 5.337635040283203`` (the default bound). The other
cases (``city-case1`` .. ``city-case4``, :data:`stp_env.scenarios.CITY_CASES`) plan with a 1200 s horizon
(:data:`HORIZONS`); Case 2 took 580 s. ``bay-area`` (200 vehicles) took 6,537 s.
With ``--checkpoint-dir`` every vehicle's plan is saved as it is made (:mod:`stp_env.planning.checkpoint`, one
file per plan name) and a rerun of the same command resumes after the last saved vehicle. ``--tracking-bound``
plans with the given ``r_e`` instead of computing the default one (the shipped plan is accepted only if that is
not smaller than the default: :func:`stp_env.assembly.plan_mismatch`).

A plan written to ``--out`` is checked like a shipped one with ``stp-env data check-plan DIR/NAME.npz --scenario
SCENARIO`` and read with :func:`stp_env.planning.plan.plan_from_arrays`. ``--ship`` writes the package's data and
is refused outside a source checkout (:func:`stp_env.data_tools.shipping.checkout_data`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description, shipping

DEFAULT = ("tiny", "tiny-intruder", "town-kbar1", "town-kbar2", "town-kbar3")
"""The plans made when ``--names`` is not given: the ones of a few minutes each (the city's and the bay area's take
from minutes to hours, see the module docstring)."""

NOT_HERE = ("fig6-kbar3",)
"""Entries of :data:`stp_env.assembly.SHIPPED_PLANS` that another program makes (``examples/fig6_reproduction.py``)."""


HORIZONS = {**{f"city-case{c}": 1200.0 for c in (1, 2, 3, 4)}, **{f"city-kbar{k}": 3600.0 for k in (3, 4)},
            "city-kbar2": 3800.0, "city-intruder-kbar2": 1200.0}
"""Planning horizons [s] other than the default (twice the longest straight flight at the top planning speed, 676 s
for the city): with STA spacing 5 s, city Case 2's 45th vehicle has no departure within 676 s (the 44 before it
hold the shared origin), and at 11 m/s Case 1's 31st; with 1200 s every vehicle of Case 2 arrives. The
intruder-aware city (``city-kbar{k}``: every vehicle leaves the one origin, all STAs equal) spaces departures by
the buffer: at k̄ = 3 the first 21 vehicles left 61 s apart (t_LDT -241 .. -1466 s) and the 22nd had no
departure within 1500 s, so 50 vehicles need about 50 x 61 s: 3600 s. At k̄ = 2 they leave 67.5 s apart (t_LDT
-241 .. -3545 s for the first 49) and the 50th has no departure within 3600 s: 3800 s. ``city-intruder-kbar2``
(one departure slot per 150 s): with 676 s its 46th vehicle had no departure (a departure held back at the origin
goes back past the earlier ones: up to 382 s before its slot in the 1200 s plan); ``city-intruder-kbar3`` plans at
676 s."""


SLICE_DT = {"city-case3": 3.0, **{f"city-{kind}{k}": 3.0 for kind in ("kbar", "intruder-kbar") for k in (2, 3, 4)},
            "bay-area": 5.0}
"""A cap on the BRS slice spacing [s] (``PlanningProblem.max_slice_dt``): with the 1200 s horizon the default is 6 s,
and Case 3 then had one pair of trajectories 0.16 m beyond the planner's separation tolerance; with 3 s it passes
(Cases 2 and 4 were planned with 6 s slices and pass; Case 1 fails either way, see :data:`HOLD_SLICES`)."""


HOLD_SLICES = {"city-case1": 1}
"""Plans made with ``PlanningProblem.hold_slices`` (every higher-priority disk kept that many BRS slices longer before
its departure and after its arrival). City Case 1 (11 m/s, all STAs equal) had a pair 41.8 m inside the separation at
the instant the higher-priority vehicle arrived (6 s slices; with 3 s slices three pairs up to 32 m); with one slice
held its worst pair is 9.0 m inside, within the half-cell tolerance. Not the default: it costs a shared origin a
slice per departure (city Case 0 then has no departure for its 48th vehicle within the 676 s horizon), and holding
at the arrival only left Case 0 with a pair 19.6 m inside (BENCHMARKS.md)."""


KEEP_AFTER_ARRIVAL = {**{f"city-{kind}{k}": 30.0 for kind in ("kbar", "intruder-kbar") for k in (2, 3, 4)},
                      "city-case1": 30.0, "bay-area": 30.0}
"""Plans whose trajectories are stored only up to ``arrival + KEEP_AFTER_ARRIVAL`` [s]
(:func:`stp_env.planning.plan.trim_after_arrival`), packed by :func:`stp_env.planning.plan.pack_trajectories`.
A vehicle leaves the airspace when it reaches its target (``SinglePlan.arrival_time``), but the planner integrates
every trajectory to its BRS horizon: at k̄ = 2 in the city, where departures are spaced 67.5 s apart back from one
STA, 58 % of the samples of the first 49 vehicles lie after their arrival and the file would be about 14 MB (2.6 MB
trimmed and packed; city Case 1, whose vehicles arrive up to 822 s before their STAs, 6.0 MB and 1.3 MB). The 30 s
kept after the arrival are the reference a vehicle delayed by an avoidance manoeuvre
(t_IAT = 10 s) tracks until it reaches its target; after the last sample the reference stays there."""


def names() -> list[str]:
    """The plans this command makes: :data:`stp_env.assembly.SHIPPED_PLANS` but :data:`NOT_HERE`."""
    from stp_env.assembly import SHIPPED_PLANS

    return [name for name in SHIPPED_PLANS if name not in NOT_HERE]


def generate(name: str, *, tracking_bound: float | None = None, checkpoint=None, horizon: float | None = None,
             max_slice_dt: float | None = None, hold_slices: int = 0, progress: bool = False) -> dict:
    """The arrays of the plan ``name`` (an entry of :data:`stp_env.assembly.SHIPPED_PLANS`), untrimmed."""
    from stp_env.assembly import SHIPPED_PLANS, load_artifacts
    from stp_env.planning.stp import plan_scenario, plan_to_arrays
    from stp_env.scenarios import make

    scenario_name, overrides = SHIPPED_PLANS[name]
    scenario = make(scenario_name, **overrides)
    if tracking_bound is None:
        _, tracking = load_artifacts(scenario, progress=progress)
        tracking_bound = tracking.bound
    return plan_to_arrays(plan_scenario(scenario, tracking_bound=tracking_bound, progress=progress,
                                        checkpoint=checkpoint, horizon=horizon, max_slice_dt=max_slice_dt,
                                        hold_slices=hold_slices))


def add_parser(sub) -> None:
    """Add ``plans`` to the ``stp-env data`` subcommands (building it imports no JAX)."""
    p = sub.add_parser("plans", help="plan registered scenarios as the package ships them (into --out, or with "
                                     "--ship into stp_env/data/plans)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("--names", nargs="+", default=list(DEFAULT), metavar="NAME",
                   help="plans to make: entries of stp_env.assembly.SHIPPED_PLANS (tiny, tiny-intruder, "
                        "town-kbar{1,2,3}, city, city-case{1..4}, city-kbar{2,3,4}, city-intruder-kbar{2,3,4}, "
                        "bay-area; the city's and the bay area's take from minutes to hours)")
    p.add_argument("--tracking-bound", type=kit.positive, metavar="R_E",
                   help="r_e [m] (> 0; default: the scenario's default bound)")
    p.add_argument("--horizon", type=kit.positive, metavar="SECONDS",
                   help="planning horizon before each STA [s] (> 0; default: the plan's own in HORIZONS, else twice "
                        "the longest straight flight at the top planning speed)")
    p.add_argument("--checkpoint-dir", type=Path, metavar="DIR",
                   help="save each vehicle's plan in DIR/NAME.ckpt.npz as it is made; a rerun resumes")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--out", default="plans", metavar="DIR",
                       help="directory to write NAME.npz in (made if missing; checked to be writable before anything "
                            "is planned)")
    where.add_argument("--ship", action="store_true",
                       help="write into the package's own stp_env/data/plans instead of --out (a source checkout "
                            "only: what the package ships)")
    kit.add_progress(p)
    p.set_defaults(run=run, command="data plans")


def run(args) -> int:
    """Run ``stp-env data plans``: one JSON line per plan written."""
    import numpy as np

    from stp_env.evaluation.pipeline import check_output_dir
    from stp_env.files import atomic_open
    from stp_env.planning.plan import pack_trajectories, trim_after_arrival

    known = names()
    unknown = [name for name in args.names if name not in known]
    if unknown:
        raise ValueError(f"--names: unknown plan(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(known)}.")
    if args.ship:
        out = shipping.checkout_data(shipping.PLANS, "--ship", "write the plans elsewhere with --out DIR")
        out.mkdir(parents=True, exist_ok=True)
    else:
        out = check_output_dir(args.out)
    if args.checkpoint_dir is not None:
        check_output_dir(args.checkpoint_dir, "--checkpoint-dir")
    progress = not args.no_progress
    for name in dict.fromkeys(args.names):
        t0 = time.perf_counter()
        checkpoint = None if args.checkpoint_dir is None else args.checkpoint_dir / f"{name}.ckpt.npz"
        horizon = args.horizon if args.horizon is not None else HORIZONS.get(name)
        arrays = generate(name, tracking_bound=args.tracking_bound, checkpoint=checkpoint, horizon=horizon,
                          max_slice_dt=SLICE_DT.get(name), hold_slices=HOLD_SLICES.get(name, 0), progress=progress)
        if name in KEEP_AFTER_ARRIVAL:
            arrays = pack_trajectories(trim_after_arrival(arrays, KEEP_AFTER_ARRIVAL[name]))
        seconds = time.perf_counter() - t0
        path = out / f"{name}.npz"
        with atomic_open(path, "wb") as fh:  # an interrupted write never leaves a broken plan
            np.savez_compressed(fh, **arrays)
        print(json.dumps({"scenario": name, "file": str(path), "bytes": path.stat().st_size,
                          "seconds": round(seconds, 1), "t_ldt": arrays["t_ldt"].round(3).tolist()}), flush=True)
    return 0
