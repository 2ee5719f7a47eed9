"""Where the PettingZoo adapter's ``env.step`` spends its time: ``cProfile`` over a user's step loop.

    python benchmarks/step_profile.py [--scenario town] [--steps 2000] [--vehicle-policy switching] [--top 12]
    python benchmarks/step_profile.py --parts [--scenario town]

Runs ``--steps`` steps of ``parallel_env(scenario, vehicle_policy=...)`` with random actions (after 300 warm-up
steps), once unprofiled (steps per second) and once under ``cProfile``; prints one JSON line with the rate and the
functions with the most time of their own (``tottime``: a jitted call's dispatch and run count in its caller's own
time, ``numpy.asarray`` of a device array is the host transfer).

``--parts``: the device side instead. The adapter's one program (step, observe, episode end) and each of its parts
compiled on its own (the core's step with the built-in vehicle policy, ``observe``, ``episode_over``) and a jitted
function that only returns its key (what dispatching the same arguments costs): per part the best of 5 runs of 300
calls [us per call, each waited for] and the compiled program's size (HLO lines, fusions: on a CPU each fusion is a
kernel launched in turn, so at batch 1 their number, not the arithmetic, sets the time).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import math
import os
import pstats
import time

import numpy as np

from stp_env.env import parallel_env


def parts(scenario: str, vehicle_policy: str) -> dict:
    """The device program's parts (``--parts``)."""
    import re

    import jax

    from stp_env.env import _advance_scripted
    from stp_env.sim import core
    from stp_env.sim.jit import sim_jit

    env = parallel_env(scenario=scenario, vehicle_policy=vehicle_policy)
    env.reset(seed=0)
    arr = env._parse_actions({a: env.action_space(a).sample() for a in env.agents})
    key, state, params = env._key, env._state, env.params
    vp, ip = env._vehicle_policy, env._intruder_policy
    programs = {
        "adapter_step": lambda k, s, a, p: _advance_scripted(k, s, a, p, vehicle_policy=vp, intruder_policy=ip),
        "core_step": lambda k, s, a, p: core.step(k, s, a, p, vehicle_policy=vp),
        "observe": lambda k, s, a, p: core.observe(s, p),
        "episode_over": lambda k, s, a, p: core.episode_over(s, p),
        "dispatch_only": lambda k, s, a, p: k,
    }
    out = {"vehicles": int(params.vehicles.n)}
    for name, fn in programs.items():
        f = sim_jit(fn)
        text = f.lower(key, state, arr, params).compile().as_text()
        for _ in range(50):
            jax.block_until_ready(f(key, state, arr, params))
        best = math.inf
        for _ in range(5):
            t = time.perf_counter()
            for _ in range(300):
                jax.block_until_ready(f(key, state, arr, params))
            best = min(best, (time.perf_counter() - t) / 300)
        out[name] = {"us_per_call": round(best * 1e6, 1), "hlo_lines": text.count("\n"),
                     "fusions": len(re.findall(r"\bfusion\b", text))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--vehicle-policy", default="switching")
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--parts", action="store_true", help="time the device program's parts instead")
    args = parser.parse_args()
    if args.parts:
        load = os.getloadavg()[0]
        print(json.dumps({"case": "step_parts", "scenario": args.scenario, "vehicle_policy": args.vehicle_policy,
                          "loadavg_1min_before": round(load, 2), **parts(args.scenario, args.vehicle_policy),
                          "loadavg_1min_after": round(os.getloadavg()[0], 2)}))
        return

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
