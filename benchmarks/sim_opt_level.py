"""Compile time, run time and outputs of the simulator's rollout program at XLA's backend optimisation levels.

    python benchmarks/sim_opt_level.py [--scenario town] [--levels 3,2,1] [--envs 64] [--steps 100]
                                       [--big-envs 1024] [--big-steps 20]

The simulator's programs compile with :data:`stp_env.sim.jit.SIM_COMPILER_OPTIONS`; this measures that choice
against its peers in one run. For each level: the town rollout of the suite's simulator tests (``switching``
vehicles, HJ-pursuit intruder, ``--envs`` episodes of ``--steps`` steps, the shipped plan) is lowered once and
compiled at that level (``xla_backend_optimization_level``); its run time is the best of three runs; its outputs
(final states and trajectories) are hashed. Then the batched core at ``--big-envs`` episodes (the throughput
benchmark's size) is compiled and run the same way. The levels are compiled in the order given (a second compile
of the same program is served from JAX's in-process cache, so each compile time is one measurement: compare the
load before and after); each program then runs again in the reverse order and its run time is the best of both
passes, so that a load change during the run does not favour one level.

Prints one JSON line: per level the compile and run seconds and the hash, the ratios against level 3 (XLA's
default), and whether every level's outputs equal level 3's bit for bit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np


def _digest(tree) -> str:
    h = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        a = jax.random.key_data(leaf) if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key) else leaf
        h.update(np.asarray(a).tobytes())
    return h.hexdigest()[:16]


def _measure(lowered, level: int, args) -> tuple[float, float, str]:
    t0 = time.perf_counter()
    compiled = lowered.compile(compiler_options={"xla_backend_optimization_level": level})
    compile_s = time.perf_counter() - t0
    out = compiled(*args)
    jax.block_until_ready(out)
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        runs.append(time.perf_counter() - t0)
    return compile_s, min(runs), _digest(out)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--levels", default="3,2,1")
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--big-envs", type=int, default=1024)
    parser.add_argument("--big-steps", type=int, default=20)
    args = parser.parse_args()
    levels = [int(v) for v in args.levels.split(",")]
    if 3 not in levels:
        parser.error("--levels must include 3, XLA's default, the reference of the ratios")

    from stp_env import assembly, sim
    from stp_env.baselines import INTRUDERS, switching
    from stp_env.sim.rollout import rollout

    params = assembly.params_for(args.scenario, sim.EnvConfig(), progress=False)
    # the undecorated function, jitted here without the project's options, so that each level is set explicitly
    plain = jax.jit(rollout.__wrapped__, static_argnums=(2, 3, 4, 5, 6))
    out = {"case": "sim_opt_level", "scenario": args.scenario, "envs": args.envs, "steps": args.steps,
           "big_envs": args.big_envs, "big_steps": args.big_steps, "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    for name, n_envs, n_steps in (("rollout", args.envs, args.steps), ("big", args.big_envs, args.big_steps)):
        key = jax.random.key(0)
        lowered = plain.lower(key, params, switching, INTRUDERS["hj"], n_envs, n_steps, True)
        best: dict[int, list] = {}
        for level in levels + levels[::-1]:
            c, r, d = _measure(lowered, level, (key, params))
            prev = best.get(level)
            # the second compile of a level is served from JAX's in-process cache: keep the first compile time
            best[level] = [prev[0], min(r, prev[1]), d] if prev else [c, r, d]
            if prev and prev[2] != d:
                raise SystemExit(f"level {level} compiled twice gave different outputs")
        ref = best[3]
        for level, (c, r, d) in best.items():
            out[f"{name}_level{level}"] = {"compile_s": round(c, 1), "run_s": round(r, 3), "hash": d,
                                          "compile_ratio_vs_3": round(c / ref[0], 2),
                                          "run_ratio_vs_3": round(r / ref[1], 2), "same_as_3": d == ref[2]}
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
