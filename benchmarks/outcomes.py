"""Whether a change that moves last bits keeps every episode's outcome: the evaluator's episodes on one CPU device
against those on several, or those of this tree against another git revision's.

    python benchmarks/outcomes.py [--episodes 1000] [--devices 2]
    python benchmarks/outcomes.py --base REV [--episodes 1000]

Evaluates town (k̄ = 2) and city-intruder (k̄ = 3) against the max-k intruder (seed 0, batches of 250) twice, each
run in its own process: on one CPU device and on ``--devices`` (:func:`stp_env.set_cpu_devices`, the count being
fixed when JAX starts); or, with ``--base REV``, with this tree's package and with ``REV``'s (exported with ``git
archive`` as ``benchmarks/core_revisions.py`` does), both on one device. Compares the episodes: how many are the
same bit for bit, how many are the same outcome (:func:`stp_env.evaluation.same_outcome`), in how many any discrete
field differs (statuses, modes, the forced set, compliance, violations, step counts), the largest difference of the
final positions and of the avoid start times, and the time of each run. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from core_revisions import export  # the same export of a revision's package (this folder is on sys.path)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = (("town", 2), ("city-intruder", 3))


def run_one(devices: int, episodes: int, out: str) -> None:
    import stp_env

    print(f"package: {stp_env.__file__}", file=sys.stderr)  # which tree's package ran (checked by the caller)
    stp_env.set_cpu_devices(devices)
    from stp_env.evaluation import Configuration, evaluate

    arrays, seconds = {}, {}
    for scenario, kbar in CASES:
        start = time.perf_counter()
        (result,) = evaluate([Configuration(scenario=scenario, kbar=kbar, intruder="max-k")], episodes=episodes,
                             seed=0, batch_size=250, progress=False, showcase=False)
        seconds[scenario] = round(time.perf_counter() - start, 1)
        arrays.update({f"{scenario}/{k}": np.asarray(v) for k, v in result.episodes.items()})
    np.savez(out, **arrays)
    print(json.dumps(seconds))


def compare(a, b, scenario: str) -> dict:
    from stp_env.evaluation import same_outcome

    one = {k.split("/", 1)[1]: a[k] for k in a.files if k.startswith(scenario + "/")}
    two = {k.split("/", 1)[1]: b[k] for k in b.files if k.startswith(scenario + "/")}
    n = len(one["index"])
    discrete = [k for k, v in one.items() if v.dtype.kind in "biu"]
    dx = np.abs(one["x"][..., :2] - two["x"][..., :2]).max(axis=(1, 2))
    both = np.isfinite(one["avoid_start"]) & np.isfinite(two["avoid_start"])
    return {
        "episodes": n,
        "bit_for_bit": sum(all(np.array_equal(one[k][i], two[k][i], equal_nan=True) for k in one) for i in range(n)),
        "same_outcome": sum(same_outcome({k: v[i] for k, v in one.items()}, {k: v[i] for k, v in two.items()})
                            for i in range(n)),
        "discrete_differs": int(np.sum(np.any(np.stack([np.any((one[k] != two[k]).reshape(n, -1), axis=1)
                                                        for k in discrete]), axis=0))),
        "positions_apart_over_1mm": int(np.sum(dx > 1e-3)), "positions_apart_over_1m": int(np.sum(dx > 1.0)),
        "max_position_apart_m": round(float(dx.max()), 4),
        "max_avoid_start_apart_s": round(float(np.max(np.abs(np.where(both, one["avoid_start"] - two["avoid_start"],
                                                                       0.0)))), 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--base", help="compare with this git revision (both on one device) instead of --devices")
    parser.add_argument("--one", nargs=2, metavar=("DEVICES", "OUT"), help="one run in this process (internal)")
    args = parser.parse_args()
    if args.one:
        run_one(int(args.one[0]), args.episodes, args.one[1])
        return
    out = {"case": "outcomes", "episodes": args.episodes, "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    with tempfile.TemporaryDirectory() as tmp:
        if args.base:
            rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", args.base], capture_output=True,
                                 text=True, check=True).stdout.strip()
            os.mkdir(os.path.join(tmp, "base"))
            base_tree = export(rev, os.path.join(tmp, "base"))
            runs = {"this": (1, ROOT), "base": (1, base_tree)}
            out["base"] = rev
        else:
            runs = {"devices_1": (1, ROOT), f"devices_{args.devices}": (args.devices, ROOT)}
        paths = {}
        for name, (devices, tree) in runs.items():
            paths[name] = os.path.join(tmp, f"{name}.npz")
            env = dict(os.environ, PYTHONPATH=os.pathsep.join([tree, os.environ.get("PYTHONPATH", "")]))
            res = subprocess.run([sys.executable, os.path.abspath(__file__), "--episodes", str(args.episodes),
                                  "--one", str(devices), paths[name]], capture_output=True, text=True, check=True,
                                 env=env, cwd=tmp)
            package = next(line for line in res.stderr.splitlines() if line.startswith("package: "))[9:]
            if not package.startswith(tree):
                raise SystemExit(f"the {name} run imported {package}, not the package in {tree}")
            out[f"seconds_{name}"] = json.loads(res.stdout.strip().splitlines()[-1])
        first, second = paths.values()
        with np.load(first) as a, np.load(second) as b:
            for scenario, _ in CASES:
                out[scenario] = compare(a, b, scenario)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
