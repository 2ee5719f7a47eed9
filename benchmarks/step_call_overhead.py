"""What one call of the adapter's step costs beyond its work: the step one call at a time against the same step run
``--k`` times inside one program, and two do-nothing programs either side of XLA's sequential-execution threshold.

    python benchmarks/step_call_overhead.py [--scenarios town city] [--k 50]

At one thread (``stp_env.set_cpu_threads(1)``), compiled as the environment compiles its step (``sim_jit``).
``step_us_per_call``: the compiled step of
``parallel_env(scenario, vehicle_policy="switching")`` (its output copied to the host), one call per step;
``step_us_in_loop``: the same step function under ``lax.fori_loop`` ``--k`` times in one call, per step. The
difference is the cost of a call. ``null_small_us`` / ``null_large_us``: a program that copies 29 arrays of 7 floats
and writes one int32 output of 100 words (400 bytes) or 1,000 words (4,000 bytes): XLA's CPU runtime runs a
program's kernels one after another only when every buffer they touch is at most 512 bytes (or there are at most 8
kernels), and hands ready kernels to its thread pool otherwise. Fastest of five loops each. Prints one JSON line
per scenario.
"""

from __future__ import annotations

import argparse
import json
import os
import time


def _best_us(fn, calls: int) -> float:
    fn()
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def measure(scenario: str, k: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import stp_env.env as env_module
    from stp_env.baselines import switching
    from stp_env.sim.jit import sim_jit

    env = env_module.parallel_env(scenario=scenario, vehicle_policy="switching")
    params = env.params
    env.reset(seed=3, options={"appear_time": float(params.episode.t_start) + 0.5})
    zero = np.zeros(2, np.float32)
    for _ in range(40):
        env.step({a: zero for a in env.agents})
    actions = jnp.asarray(env._parse_actions({a: zero for a in env.agents}))
    key, state = env._key, env._state
    step = env_module._packed(env_module._advance_scripted)

    one = sim_jit(lambda key, state, actions, params: step(key, state, actions, params, vehicle_policy=switching))

    @sim_jit
    def many(key, state, actions, params):
        def body(_, carry):
            key, state, total = carry
            key, state, words = step(key, state, actions, params, vehicle_policy=switching)
            return key, state, total + words[0]

        return jax.lax.fori_loop(0, k, body, (key, state, jnp.int32(0)))

    per_call = _best_us(lambda: np.asarray(one(key, state, actions, params)[2]), 500)
    in_loop = _best_us(lambda: jax.block_until_ready(many(key, state, actions, params)), 20) / k

    small = [jnp.full((7,), float(i), jnp.float32) for i in range(29)]

    def null(words):
        return jax.jit(lambda xs: ([x + 0 for x in xs], jnp.zeros(words, jnp.int32) + xs[1][0].astype(jnp.int32)))

    null_small, null_large = null(100), null(1000)
    return {"scenario": scenario, "k": k, "step_us_per_call": round(per_call, 1),
            "step_us_in_loop": round(in_loop, 1), "call_us": round(per_call - in_loop, 1),
            "null_small_us": round(_best_us(lambda: jax.block_until_ready(null_small(small)), 2000), 1),
            "null_large_us": round(_best_us(lambda: jax.block_until_ready(null_large(small)), 2000), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["town", "city"])
    parser.add_argument("--k", type=int, default=50)
    args = parser.parse_args()
    from stp_env import set_cpu_threads

    set_cpu_threads(1)
    load = round(os.getloadavg()[0], 2)
    for scenario in args.scenarios:
        print(json.dumps({"benchmark": "step_call_overhead", "loadavg_1min_before": load,
                          **measure(scenario, args.k)}), flush=True)


if __name__ == "__main__":
    main()
