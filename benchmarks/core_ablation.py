"""Where the batched core's step time goes: the same rollout with one part of the step replaced by a constant of the
same shape (a profile by ablation; XLA fuses across the parts, so a per-op profile would not separate them).

    python benchmarks/core_ablation.py [--scenario city] [--envs 256] [--steps 50]

Ablations (each in its own process, the full step as the peer): ``avoid`` (the avoid-table reads: ``V^A`` and its
gradient for ``u^A`` and the HJ intruder), ``track`` (the tracking-gradient reads of the tracker), ``pairs`` (the
vehicle-vehicle distances over the inner steps), ``building`` (the signed distance to the buildings), ``all``.
The ablated programs compute wrong episodes; only their run time is used. Prints one JSON line: the compiled
rollout's run time per variant (fastest of three) and each part's share of the full step, ``1 - t_ablated / t``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

MODES = ("none", "avoid", "track", "pairs", "building", "all")


def ablate(mode: str) -> None:
    """Replace the part ``mode`` names (``avoid``, ``track``, ``pairs``, ``building`` or ``all``) by a constant of
    its shape, before anything is traced (``benchmarks/adapter_ablation.py`` uses the same replacements)."""
    import jax.numpy as jnp

    from stp_env.sim import core, tables

    if mode in ("avoid", "all"):
        tables._avoid_read = lambda grid, taus, values, tau, x: (x[0] * 0.0 + tables.FAR, x * 0.0)
    if mode in ("track", "all"):
        tables._tracking_read = lambda grid, padded, e: e * 0.0 + 1.0
    if mode in ("pairs", "all"):
        def no_pairs(closest, s, params):
            p = s.x[:, :2]
            return core.Closest(pair_sq=closest.pair_sq,
                                intruder=jnp.minimum(closest.intruder, jnp.hypot(*(p - s.intruder_x[None, :2]).T)),
                                building=jnp.minimum(closest.building, core.building_distance(params, p)))
        core._closest_approach = no_pairs
    if mode in ("building", "all"):
        core.building_distance = lambda params, p: jnp.full(p.shape[:-1], 1.0e6, p.dtype)


def run_one(scenario: str, mode: str, n_envs: int, n_steps: int) -> float:
    import jax

    sys.path.insert(0, os.path.dirname(__file__))
    import env_throughput

    from stp_env import sim
    from stp_env.baselines import INTRUDERS, switching

    _, params = env_throughput._params(scenario)
    ablate(mode)

    def go(seed):
        return jax.block_until_ready(sim.rollout(jax.random.key(seed), params, switching, INTRUDERS["hj"], n_envs,
                                                 n_steps))

    go(0)
    times = []
    for i in range(3):
        t0 = time.perf_counter()
        go(i + 1)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="city")
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--mode", choices=MODES, help="run one variant and print its seconds (used internally)")
    args = parser.parse_args()
    if args.mode:
        print(run_one(args.scenario, args.mode, args.envs, args.steps))
        return
    out = {"benchmark": "core_ablation", "scenario": args.scenario, "envs": args.envs, "steps": args.steps,
           "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    seconds = {}
    for mode in MODES:
        res = subprocess.run([sys.executable, __file__, "--scenario", args.scenario, "--envs", str(args.envs),
                              "--steps", str(args.steps), "--mode", mode], capture_output=True, text=True,
                             check=True)
        seconds[mode] = float(res.stdout.strip().splitlines()[-1])
    out["run_s"] = {k: round(v, 3) for k, v in seconds.items()}
    out["share"] = {k: round(1.0 - v / seconds["none"], 2) for k, v in seconds.items() if k != "none"}
    out["env_steps_per_s_full"] = round(args.envs * args.steps / seconds["none"])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
