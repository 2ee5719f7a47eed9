"""Where the adapter's step program goes at batch one: the compiled step of ``parallel_env(scenario,
vehicle_policy="switching")`` with one part replaced by a constant of the same shape (a profile by ablation, as
``benchmarks/core_ablation.py`` does for the batched core; XLA fuses across the parts, so a per-kernel profile does
not separate them, and at this size its per-kernel times are inflated several-fold).

    python benchmarks/adapter_ablation.py [--scenario town] [--reps 2] [--modes none observe ...]

Each variant runs in its own process with XLA's CPU thread pool at one thread (``stp_env.set_cpu_threads(1)``, the
setting for a loop over one environment), from the same state: an episode reset with the intruder appearing half a
second in, after 40 steps (the intruder present, so the avoid reads run). The time is the fastest of seven loops of
500 calls of the compiled step with its output copied to the host (what one ``env.step`` waits for). Ablations:
``observe`` (the observations), ``track`` (the tracking-table reads of ``kappa``), ``avoid`` (the avoid-table reads
of ``V^A`` and ``u^A``), ``pairs`` (the vehicle-vehicle distances of every inner step), ``building`` (the signed
distance to the buildings), ``rewards``, ``wind`` (the wind draw), ``refresh`` (every refresh of the controllers:
both reads and what is derived from them). The ablated programs compute wrong episodes; only their time is used.
Prints one JSON line: per variant the time per call [us], its number of fusions and ``1 - t / t_none``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

MODES = ("none", "observe", "track", "avoid", "pairs", "building", "rewards", "wind", "refresh")
HERE = os.path.dirname(os.path.abspath(__file__))


def packed_step(key, state, actions, params, vehicle_policy, intruder_policy=None):
    """The environment's step function with its outputs packed as it returns them (one int32 array)."""
    import stp_env.env as env_module
    from stp_env.sim.packing import pack

    key, state, out = env_module._advance_scripted(key, state, actions, params, vehicle_policy=vehicle_policy,
                                                   intruder_policy=intruder_policy)
    return key, state, pack(out)


def run_one(scenario: str, mode: str) -> dict:
    from stp_env import set_cpu_threads

    set_cpu_threads(1)
    import jax
    import jax.numpy as jnp
    import numpy as np

    import stp_env.env as env_module
    from stp_env.sim import core
    from stp_env.sim import wind as wind_lib
    from stp_env.sim.jit import sim_jit

    if mode == "observe":
        full = core.observe

        def observe(state, params):
            return tuple(jnp.zeros(s.shape, s.dtype) for s in jax.eval_shape(full, state, params))

        core.observe = observe
    elif mode in ("track", "avoid", "pairs", "building"):
        sys.path.insert(0, HERE)
        import core_ablation

        core_ablation.ablate(mode)
    elif mode == "rewards":
        core._rewards = lambda state, new, ev, params: jnp.zeros((params.vehicles.n + 1,), jnp.float32)
    elif mode == "wind":
        def calm(key, state, params):
            n = params.vehicles.n
            return jnp.zeros((n + 1, 2), state.x.dtype), jnp.zeros((n + 1,), state.x.dtype), state.wind

        wind_lib.sample = calm
        wind_lib.inner = lambda s, params, held: held
    elif mode == "refresh":
        core.observe_controllers = lambda state, params: state
    elif mode != "none":
        raise ValueError(f"unknown mode {mode!r}; modes: {MODES}")

    env = env_module.parallel_env(scenario=scenario, vehicle_policy="switching")
    env.reset(seed=3, options={"appear_time": float(env.params.episode.t_start) + 0.5})
    zero = np.zeros(2, np.float32)
    for _ in range(40):
        env.step({a: zero for a in env.agents})
    actions = env._parse_actions({a: zero for a in env.agents})
    key, state, params = env._key, env._state, env.params
    kwargs = {"vehicle_policy": env._vehicle_policy, "intruder_policy": None}
    step = sim_jit(packed_step, static_argnames=("vehicle_policy", "intruder_policy"))

    def call():
        return np.asarray(step(key, state, actions, params, **kwargs)[2])

    call()
    best = float("inf")
    for _ in range(7):
        t0 = time.perf_counter()
        for _ in range(500):
            call()
        best = min(best, (time.perf_counter() - t0) / 500)
    text = step.lower(key, state, actions, params, **kwargs).compile().as_text()
    return {"us": best * 1e6, "fusions": text.count(" fusion("),
            "intruder_present": bool(int(state.intruder_status) == 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.scenario, args.one)))
        return
    modes = ["none", *[m for m in args.modes if m != "none"]]
    load = round(os.getloadavg()[0], 2)
    runs: dict[str, list] = {m: [] for m in modes}
    for _ in range(args.reps):
        for mode in modes:
            out = subprocess.run([sys.executable, __file__, "--scenario", args.scenario, "--one", mode],
                                 capture_output=True, text=True, check=True)
            runs[mode].append(json.loads(out.stdout.strip().splitlines()[-1]))
    base = min(r["us"] for r in runs["none"])
    print(json.dumps({
        "benchmark": "adapter_ablation", "scenario": args.scenario, "loadavg_1min_before": load, "reps": args.reps,
        "intruder_present": runs["none"][0]["intruder_present"],
        "us": {m: round(min(r["us"] for r in runs[m]), 1) for m in modes},
        "fusions": {m: runs[m][0]["fusions"] for m in modes},
        "share": {m: round(1 - min(r["us"] for r in runs[m]) / base, 2) for m in modes if m != "none"},
    }))


if __name__ == "__main__":
    main()
