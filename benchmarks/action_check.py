"""Microseconds per ``env.step`` spent checking the actions of every live agent: the adapter's vectorised check
(:meth:`stp_env.env.STPParallelEnv._parse_actions`) against the peer in the same run, the per-agent check it runs
for anything but plain float arrays (``_check_action`` for each agent).

    python benchmarks/action_check.py [--scenario city] [--repeats 2000]

Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from stp_env.env import parallel_env


def per_call_us(fn, repeats: int) -> float:
    fn()
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats * 1e6


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="city")
    parser.add_argument("--repeats", type=int, default=2000)
    args = parser.parse_args()
    env = parallel_env(scenario=args.scenario)
    env.reset(seed=0)
    actions = {a: np.full(2, 0.3, np.float32) for a in env.agents}
    n = env.params.vehicles.n

    def per_agent():
        arr = np.zeros((n + 1, 2), np.float32)
        for agent, a in actions.items():
            arr[env._index[agent], :2] = env._check_action(agent, a)
        return arr

    assert np.array_equal(env._parse_actions(actions), per_agent())
    ours = per_call_us(lambda: env._parse_actions(actions), args.repeats)
    peer = per_call_us(per_agent, args.repeats)
    print(json.dumps({"case": "action_check", "scenario": args.scenario, "agents": n + 1,
                      "vectorised_us": round(ours, 1), "per_agent_us": round(peer, 1), "ratio": round(peer / ours, 1)}))


if __name__ == "__main__":
    main()
