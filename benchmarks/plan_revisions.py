"""The sequential planner of this tree against the planner of another git revision, in the same run: seconds per
vehicle and whether the two plan the same trajectories.

    python benchmarks/plan_revisions.py --base REV [--scenario city-intruder] [--kbar K] [--vehicles 4]
        [--tracking-bound 5.337635040283203] [--max-slice-dt 3.0] [--horizon H]

for example ``--scenario city-intruder --kbar 4``, or ``--scenario bay-area --tracking-bound 35.391876220703125
--max-slice-dt 5`` (the settings ``stp-env data plans`` plans these files with).

``REV``'s ``stp_env`` package is exported with ``git archive`` into a temporary directory and imported from there
(this tree's ``stp_env`` otherwise). Each tree plans the whole scenario (every vehicle counts for the obstacle
arrays' shapes) with :func:`stp_env.planning.stp.plan_scenario` in its own process and stops after its first
``--vehicles`` single-vehicle plans (the highest priorities). Per plan: wall seconds and the process's CPU seconds
(the first includes compilation); ``same_plans`` says whether the two trees' latest departure times, sample times
and nominal states are equal bit for bit. Prints one JSON line; ``speedup`` is the base's wall time over this
tree's, summed over the plans after the first.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from core_revisions import export  # noqa: E402  (the other revision's package, by git archive)


class _Enough(Exception):
    """Stops the planner once the vehicles to time are planned."""


def run_child(args) -> dict:
    import numpy as np

    import stp_env
    import stp_env.planning.stp as stp
    from stp_env.scenarios import make

    overrides = {} if args.kbar is None else {"kbar": args.kbar}
    scenario = make(args.scenario, **overrides)
    wall, cpu, digest = [], [], hashlib.sha256()
    original = stp.plan_single

    def timed(*a, **kw):
        t0, c0 = time.perf_counter(), time.process_time()
        single = original(*a, **kw)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        for arr in (np.float64(single.t_ldt), single.times, single.states):
            digest.update(np.ascontiguousarray(np.asarray(arr)).tobytes())
        if len(wall) >= args.vehicles:
            raise _Enough
        return single

    stp.plan_single = timed
    with contextlib.suppress(_Enough):
        stp.plan_scenario(scenario, tracking_bound=args.tracking_bound, horizon=args.horizon,
                          max_slice_dt=args.max_slice_dt, progress=False)
    return {"seconds": [round(t, 2) for t in wall], "cpu_seconds": [round(t, 2) for t in cpu],
            "digest": digest.hexdigest()[:16], "package": stp_env.__file__}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--base", help="the git revision to compare against (e.g. HEAD~1)")
    parser.add_argument("--scenario", default="city-intruder")
    parser.add_argument("--kbar", type=int, help="the scenario's k̄ (passed to make() when given)")
    parser.add_argument("--vehicles", type=int, default=4, help="single-vehicle plans to time (>= 2)")
    parser.add_argument("--tracking-bound", type=float, default=5.337635040283203)
    parser.add_argument("--max-slice-dt", type=float, default=3.0)
    parser.add_argument("--horizon", type=float)
    parser.add_argument("--one", action="store_true", help="run one tree in this process (used internally)")
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_child(args)))
        return
    if not args.base:
        parser.error("--base REV is required")
    if args.vehicles < 2:
        parser.error("--vehicles must be at least 2 (the first plan includes compilation)")
    rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", args.base], capture_output=True, text=True,
                         check=True).stdout.strip()
    forward = [a for a in sys.argv[1:] if a != "--one"]
    load = round(os.getloadavg()[0], 2)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this": ROOT, "base": export(rev, tmp)}
        out = {}
        for name, path in trees.items():
            env = dict(os.environ, PYTHONPATH=os.pathsep.join([path, os.environ.get("PYTHONPATH", "")]))
            res = subprocess.run([sys.executable, __file__, "--one", *forward], capture_output=True, text=True,
                                 check=True, env=env, cwd=tmp)
            out[name] = json.loads(res.stdout.strip().splitlines()[-1])
            if not out[name]["package"].startswith(path):
                raise SystemExit(f"the {name} run imported {out[name]['package']}, not the package in {path}")
    after_first = {name: sum(o["seconds"][1:]) for name, o in out.items()}
    print(json.dumps({
        "benchmark": "plan_revisions", "scenario": args.scenario, "kbar": args.kbar, "base": rev,
        "vehicles": args.vehicles, "loadavg_1min_before": load, "loadavg_1min_after": round(os.getloadavg()[0], 2),
        **{name: {k: o[k] for k in ("seconds", "cpu_seconds")} for name, o in out.items()},
        "speedup_after_first": round(after_first["base"] / after_first["this"], 2),
        "same_plans": out["this"]["digest"] == out["base"]["digest"],
    }), flush=True)


if __name__ == "__main__":
    main()
