"""Time to the first ``step`` of ``stp_env.parallel_env()`` in a fresh process, with the reachability artifacts
already cached: a first and a second process with the persistent compilation cache off
(``STP_ENV_COMPILATION_CACHE=0``: every process compiles the environment's programs) against the same with it on
(:mod:`stp_env.compilation_cache`, in an empty folder of its own, so that the first process compiles and writes,
the second loads).

    python benchmarks/first_step.py [--scenario town] [--repeats 1]

Each process is timed from its start (``python -c``) to the end of its first ``step``: interpreter and imports,
``parallel_env()``, ``reset(seed=0)``, one ``step`` of random actions. Prints one JSON line: the seconds of each
phase per process, the totals, and the ratio of the second process's total with the cache off to that with it on.
A warm-up process computes any missing artifact first (cache off, so that it compiles nothing into the measured
cache).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import numpy as np
import stp_env
t1 = time.perf_counter()
env = stp_env.parallel_env(sys.argv[1])
t2 = time.perf_counter()
env.reset(seed=0)
t3 = time.perf_counter()
env.step({a: env.action_space(a).sample() for a in env.agents})
t4 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "parallel_env_s": t2 - t1, "reset_s": t3 - t2, "first_step_s": t4 - t3}))
"""


def run_child(scenario: str, env: dict) -> dict:
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILD, scenario], env=env, check=True, capture_output=True,
                         text=True)
    total = time.perf_counter() - start
    phases = json.loads(out.stdout.strip().splitlines()[-1])
    return {**{k: round(v, 2) for k, v in phases.items()}, "total_s": round(total, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--repeats", type=int, default=1, help="repeat the four processes; the best total is kept")
    args = parser.parse_args()
    base = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT"))}
    base["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[1]),
                                                       base.get("PYTHONPATH")]))
    off = {**base, "STP_ENV_COMPILATION_CACHE": "0"}
    run_child(args.scenario, off)  # warm-up: artifacts
    best: dict[str, dict] = {}
    entries = 0
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            on = {**base, "STP_ENV_COMPILATION_CACHE_DIR": tmp}
            runs = {"off_first": run_child(args.scenario, off), "off_second": run_child(args.scenario, off),
                    "on_first": run_child(args.scenario, on), "on_second": run_child(args.scenario, on)}
            files = [p for p in Path(tmp).rglob("*") if p.is_file()]
            entries = len(files)
            cache_mb = round(sum(p.stat().st_size for p in files) / 2**20, 2)
        for name, r in runs.items():
            if name not in best or r["total_s"] < best[name]["total_s"]:
                best[name] = r
    print(json.dumps({"case": "first_step", "scenario": args.scenario, **best, "cache_entries": entries,
                      "cache_mb": cache_mb,
                      "second_process_off_over_on": round(best["off_second"]["total_s"] / best["on_second"]["total_s"],
                                                          2),
                      "cpu_count": os.cpu_count(), "load_avg_1min": round(os.getloadavg()[0], 2)}))


if __name__ == "__main__":
    main()
