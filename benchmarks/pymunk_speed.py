"""The pymunk backends against the JAX core, in the same run: PettingZoo adapter env-steps per second on a scenario
with the vehicles on the papers' tracker (their ``track_action``) and a random intruder; with ``--envs N`` also
batched-core env-steps per second (``stp_env.sim.rollout`` over N episodes: one host callback per inner control step
with every vehicle of every episode a body).

    python benchmarks/pymunk_speed.py [--scenario town] [--steps 300] [--envs 0]

Prints one JSON line with the rates and the ratios ``jax / pymunk`` (compile excluded: a warm-up run first).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import numpy as np

from stp_env import assembly, sim
from stp_env.env import parallel_env
from stp_env.evaluation.config import resolve_intruder, resolve_vehicle_policy
from stp_env.sim.backends import vehicle_model

BACKENDS = ("jax", "pymunk", "pymunk-dynamic")


def adapter_rate(scenario: str, backend: str, steps: int) -> float:
    env = parallel_env(scenario, backend=backend, max_cycles=10**6)
    rng = np.random.default_rng(0)

    def run(n):
        env.reset(seed=0)
        done = 0
        start = time.perf_counter()
        while done < n:
            if not env.agents:
                env.reset(seed=done)
            track = np.asarray(env.env_state.track_action)
            actions = {a: (rng.uniform(-1, 1, 2).astype(np.float32) if a == "intruder"
                           else track[int(a.split("_")[1])]) for a in env.agents}
            env.step(actions)
            done += 1
        return n / (time.perf_counter() - start)

    run(3)  # compile
    return run(steps)


def core_rate(scenario: str, backend: str, steps: int, envs: int) -> float:
    params = assembly.params_for(scenario, sim.EnvConfig(vehicle_model=vehicle_model(backend)),
                            progress=False)
    vp, ip = resolve_vehicle_policy("switching"), resolve_intruder("max-k")
    jax.block_until_ready(sim.rollout(jax.random.key(0), params, vp, ip, envs, steps))  # compile
    start = time.perf_counter()
    jax.block_until_ready(sim.rollout(jax.random.key(1), params, vp, ip, envs, steps))
    return envs * steps / (time.perf_counter() - start)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="town")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--envs", type=int, default=0, help="batched-core episodes (0: adapter only)")
    args = p.parse_args(argv)
    out = {"scenario": args.scenario, "steps": args.steps, "envs": args.envs}
    for backend in BACKENDS:
        key = backend.replace("-", "_")
        out[f"{key}_adapter_env_steps_per_s"] = round(adapter_rate(args.scenario, backend, args.steps), 1)
        if args.envs:
            out[f"{key}_core_env_steps_per_s"] = round(core_rate(args.scenario, backend, args.steps, args.envs), 1)
        print(json.dumps(out), file=sys.stderr, flush=True)  # progress
    for backend in BACKENDS[1:]:
        key = backend.replace("-", "_")
        for kind in ("adapter", "core") if args.envs else ("adapter",):
            out[f"jax_over_{key}_{kind}"] = round(out[f"jax_{kind}_env_steps_per_s"]
                                                  / out[f"{key}_{kind}_env_steps_per_s"], 1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
