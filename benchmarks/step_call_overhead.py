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
kernels), and hands ready kernels to its thread pool otherwise. ``reads_parallel_us`` / ``reads_chained_us``:
ten reads of one element each from a 4 MB table, each followed by a small fusion, either independent of one another
(the runtime may hand some to its pool thread: a wake-up of that thread per call) or each reading where the last
one's result says (nothing to hand over), output copied to the host. Fastest of five loops each. Prints one JSON
line per scenario.

``--profile-seconds S``: the per-call loop run again for ``S`` seconds (its pid printed first), e.g. for
``perf record -e cpu-clock -g -p <pid> -- sleep 5``. ``--xla-option NAME=VALUE``: an XLA compile option added to
the simulator's for the step's programs. ``--sync-dispatch``: JAX's CPU computations run on the calling thread
(``jax_cpu_enable_async_dispatch`` off) instead of being handed to XLA's thread; ``--pin-core``: the process held to
one core before JAX starts, so that a thread woken by the runtime runs where the caller runs (``cores`` and
``cpu_async_dispatch`` in the output).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
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


def measure(scenario: str, k: int, profile_seconds: float = 0.0) -> dict:
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
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from adapter_ablation import packed_step as step  # the environment's step, its outputs packed

    one = sim_jit(lambda key, state, actions, params: step(key, state, actions, params, vehicle_policy=switching))

    @sim_jit
    def many(key, state, actions, params):
        def body(_, carry):
            key, state, total = carry
            key, state, words = step(key, state, actions, params, vehicle_policy=switching)
            return key, state, total + words[0]

        return jax.lax.fori_loop(0, k, body, (key, state, jnp.int32(0)))

    per_call = _best_us(lambda: np.asarray(one(key, state, actions, params)[2]), 500)
    if profile_seconds:  # the per-call loop again, long enough for a sampling profiler to attach to
        print(f"profiling: pid {os.getpid()}, the {scenario} step's per-call loop for {profile_seconds:g} s",
              file=sys.stderr, flush=True)
        end = time.perf_counter() + profile_seconds
        while time.perf_counter() < end:
            for _ in range(100):
                np.asarray(one(key, state, actions, params)[2])
    in_loop = _best_us(lambda: jax.block_until_ready(many(key, state, actions, params)), 20) / k

    small = [jnp.full((7,), float(i), jnp.float32) for i in range(29)]

    def null(words):
        return jax.jit(lambda xs: ([x + 0 for x in xs], jnp.zeros(words, jnp.int32) + xs[1][0].astype(jnp.int32)))

    null_small, null_large = null(100), null(1000)
    table = jnp.arange(1_000_000, dtype=jnp.float32)
    x = jnp.arange(64, dtype=jnp.float32)

    def reads(chained: bool):
        def program(table, x):
            y, outs = x, []
            for i in range(10):
                j = (y[i] * (i + 3)).astype(jnp.int32) % table.shape[0]
                z = jnp.sin(table[j] * x + i)
                if chained:
                    y = z
                else:
                    outs.append(z)
            return y if chained else sum(outs)

        fn = jax.jit(program)
        return _best_us(lambda: np.asarray(fn(table, x)), 2000)

    return {"scenario": scenario, "k": k, "step_us_per_call": round(per_call, 1),
            "step_us_in_loop": round(in_loop, 1), "call_us": round(per_call - in_loop, 1),
            "null_small_us": round(_best_us(lambda: jax.block_until_ready(null_small(small)), 2000), 1),
            "null_large_us": round(_best_us(lambda: jax.block_until_ready(null_large(small)), 2000), 1),
            "reads_parallel_us": round(reads(chained=False), 1), "reads_chained_us": round(reads(chained=True), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["town", "city"])
    parser.add_argument("--k", type=int, default=50)
    parser.add_argument("--sync-dispatch", action="store_true",
                        help="JAX's CPU computations run on the calling thread (jax_cpu_enable_async_dispatch off)")
    parser.add_argument("--pin-core", action="store_true", help="the process held to one core before JAX starts")
    parser.add_argument("--profile-seconds", type=float, default=0.0,
                        help="run the per-call loop this long after timing it, for a profiler to attach to "
                             "(`perf record -p <pid>`; the pid is printed)")
    parser.add_argument("--xla-option", action="append", default=[], metavar="NAME=VALUE",
                        help="an XLA compile option added to the simulator's (stp_env.sim.jit), e.g. "
                             "xla_cpu_enable_concurrency_optimized_scheduler=false; repeatable")
    args = parser.parse_args()
    from stp_env.sim import jit as sim_jit_module

    for option in args.xla_option:
        name, _, value = option.partition("=")
        parsed = {"true": True, "false": False}.get(value.lower(), int(value) if value.lstrip("-").isdigit() else value)
        sim_jit_module.SIM_COMPILER_OPTIONS[name] = parsed
    import jax

    from stp_env import set_cpu_threads

    if args.sync_dispatch:
        jax.config.update("jax_cpu_enable_async_dispatch", False)
    if args.pin_core:  # before JAX starts its threads: they inherit the process's affinity
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    set_cpu_threads(1)
    load = round(os.getloadavg()[0], 2)
    for scenario in args.scenarios:
        print(json.dumps({"benchmark": "step_call_overhead", "loadavg_1min_before": load,
                          "xla_options": dict(sim_jit_module.SIM_COMPILER_OPTIONS),
                          "cpu_async_dispatch": not args.sync_dispatch, "cores": sorted(os.sched_getaffinity(0)),
                          **measure(scenario, args.k, args.profile_seconds)}), flush=True)


if __name__ == "__main__":
    main()
