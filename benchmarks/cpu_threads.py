"""XLA's CPU thread pools: one thread against one per core, for the adapter's step loop and the batched core.

    python benchmarks/cpu_threads.py [--scenarios town city] [--steps 2000] [--envs 1024] [--core-steps 50]
        [--reps 3]

Each case runs in a fresh process (the pools are sized when JAX starts), once with ``PJRT_NPROC=1``
(:func:`stp_env.set_cpu_threads` ``(1)``) and once with the variable unset (one thread per core), alternating
``--reps`` times. The adapter case is :func:`core_revisions.time_adapter` (``parallel_env(scenario,
vehicle_policy="switching")``, seeded random intruder actions, ``--steps`` steps, fastest of three loops); the core
case :func:`core_revisions.time_rollout` (``--envs`` episodes of ``--core-steps`` steps). Prints one JSON line per
scenario and case: the rates of each run, their medians, the median ratio (one thread over the default) and whether
every run computed the same episodes (digests of the outputs).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def one(case: str, scenario: str, steps: int, envs: int, core_steps: int) -> dict:
    sys.path.insert(0, HERE)
    import core_revisions

    if case == "adapter":
        out = core_revisions.time_adapter(scenario, steps)
        return {"rate": steps / out["run_s"], "digest": out["digest"]}
    import env_throughput

    _, params = env_throughput._params(scenario)
    out = core_revisions.time_rollout(params, envs, core_steps)
    return {"rate": envs * core_steps * (params.vehicles.n + 1) / out["run_s"], "digest": out["digest"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["town", "city"])
    parser.add_argument("--cases", nargs="+", choices=("adapter", "core"), default=["adapter", "core"])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--envs", type=int, default=1024)
    parser.add_argument("--core-steps", type=int, default=50)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--one", nargs=2, metavar=("CASE", "SCENARIO"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(one(args.one[0], args.one[1], args.steps, args.envs, args.core_steps)))
        return
    base_env = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    for scenario in args.scenarios:
        for case in args.cases:
            load = round(os.getloadavg()[0], 2)
            runs = {"one": [], "default": []}
            for _ in range(args.reps):
                for name in runs:
                    env = dict(base_env, PJRT_NPROC="1") if name == "one" else base_env
                    res = subprocess.run([sys.executable, __file__, "--one", case, scenario, "--steps", str(args.steps),
                                          "--envs", str(args.envs), "--core-steps", str(args.core_steps)],
                                         capture_output=True, text=True, check=True, env=env)
                    runs[name].append(json.loads(res.stdout.strip().splitlines()[-1]))
            med = {name: statistics.median(r["rate"] for r in runs[name]) for name in runs}
            unit = "env_steps_per_s" if case == "adapter" else "agent_steps_per_s"
            print(json.dumps({
                "benchmark": "cpu_threads", "scenario": scenario, "case": case, "unit": unit,
                "loadavg_1min_before": load, "reps": args.reps,
                "one_thread": [round(r["rate"]) for r in runs["one"]],
                "default_threads": [round(r["rate"]) for r in runs["default"]],
                "median_ratio_one_over_default": round(med["one"] / med["default"], 2),
                "same_episodes": len({r["digest"] for name in runs for r in runs[name]}) == 1,
            }), flush=True)


if __name__ == "__main__":
    main()
