"""Where the PettingZoo adapter's ``env.step`` spends its time: ``cProfile`` over a user's step loop.

    python benchmarks/step_profile.py [--scenario town] [--steps 2000] [--vehicle-policy switching] [--top 12]

Runs ``--steps`` steps of ``parallel_env(scenario, vehicle_policy=...)`` with random actions (after 300 warm-up
steps), once unprofiled (steps per second) and once under ``cProfile``; prints one JSON line with the rate and the
functions with the most time of their own (``tottime``: a jitted call's dispatch and run count in its caller's own
time, ``numpy.asarray`` of a device array is the host transfer).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import time

import numpy as np

from stp_env.env import parallel_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--vehicle-policy", default="switching")
    parser.add_argument("--top", type=int, default=12)
    args = parser.parse_args()

    env = parallel_env(scenario=args.scenario, vehicle_policy=args.vehicle_policy)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def run(n: int) -> None:
        for _ in range(n):
            env.step({a: env.action_space(a).sample() for a in env.agents})
            if not env.agents:
                env.reset(seed=int(rng.integers(1 << 30)))

    load = os.getloadavg()[0]
    run(300)
    t = time.perf_counter()
    run(args.steps)
    rate = args.steps / (time.perf_counter() - t)
    profile = cProfile.Profile()
    profile.enable()
    run(args.steps)
    profile.disable()
    stats = pstats.Stats(profile)
    rows = sorted(((tt, nc, f"{os.path.basename(fn)}:{line}({name})")
                   for (fn, line, name), (_, nc, tt, _, _) in stats.stats.items()), reverse=True)[:args.top]
    print(json.dumps({"case": "step_profile", "scenario": args.scenario, "vehicle_policy": args.vehicle_policy,
                      "steps": args.steps, "loadavg_1min_before": round(load, 2),
                      "env_steps_per_s": round(rate, 1), "profiled_s": round(stats.total_tt, 3),
                      "tottime_s": {name: round(tt, 3) for tt, _, name in rows}}))


if __name__ == "__main__":
    main()
