"""Trace and compile time of the evaluator's batch program (:func:`stp_env.sim.rollout.rollout_keys`: a scan over
steps of the step vmapped over episodes) against two peers in the same run, the same episodes written as a vmap over
episodes of a per-episode scan (``vmap_of_scan``), and as the evaluator wrote them before (``nested``: a vmap over
episodes of a one-episode rollout that is itself a vmap of a scan), on ``town`` (k̄ = 2).

    python benchmarks/rollout_compile.py [--intruder optimal-max-k] [--vehicle-policy worst] [--batch 16] [--steps 20]

Prints one JSON line: seconds to trace (``lower``) and to compile each, the ratios (peer / ours), and whether the
two programs' final states agree bit for bit on the batch.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.evaluation import Configuration, build_params
from stp_env.sim import core
from stp_env.sim.rollout import episode_step, rollout_keys


def vmap_of_scans(keys, params, vehicle_policy, intruder_policy, n_steps: int):
    """The peer: every episode a ``lax.scan`` over its steps, ``vmap``-ed over the episodes."""

    def one(ep_key):
        k_reset, k_run = jax.random.split(ep_key)
        s0 = core.reset(k_reset, params)

        def body(state, k):
            new, _ = episode_step(k, state, params, vehicle_policy, intruder_policy)
            term, trunc = core.episode_over(state, params)
            return jax.tree.map(lambda a, b: jnp.where(term | trunc, a, b), state, new), None

        return jax.lax.scan(body, s0, jax.random.split(k_run, n_steps))[0]

    return jax.vmap(one)(keys)


def nested(keys, params, vehicle_policy, intruder_policy, n_steps: int):
    """The evaluator's earlier batch: per episode key a one-episode rollout (its own vmap of a scan)."""
    one = jax.vmap(lambda k: jax.random.fold_in(k, 0))
    return jax.tree.map(lambda a: a[:, 0], jax.vmap(
        lambda k: vmap_of_scans(one(k[None]), params, vehicle_policy, intruder_policy, n_steps))(keys))


def timed(fn, *args) -> tuple[dict, object]:
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return {"lower_s": round(t1 - t0, 1), "compile_s": round(t2 - t1, 1)}, compiled


def _same(a, b) -> bool:
    def raw(v):
        return jax.random.key_data(v) if jnp.issubdtype(v.dtype, jax.dtypes.prng_key) else v

    return all(np.array_equal(np.asarray(x), np.asarray(y))
               for x, y in zip(jax.tree.leaves(jax.tree.map(raw, a)), jax.tree.leaves(jax.tree.map(raw, b))))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--intruder", default="optimal-max-k")
    parser.add_argument("--vehicle-policy", default="worst")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--steps", type=int, default=20)
    args = parser.parse_args()
    config = Configuration(scenario="town", kbar=2, intruder=args.intruder, vehicle_policy=args.vehicle_policy)
    (params,) = build_params([config], progress=False)
    vehicle_policy, intruder_policy = config.policies()
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(0), i))(jnp.arange(args.batch))
    out = {"case": "rollout_compile", "scenario": "town", "intruder": args.intruder,
           "vehicle_policy": args.vehicle_policy, "batch": args.batch, "steps": args.steps,
           "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    ours, f_ours = timed(lambda k, p: rollout_keys(k, p, vehicle_policy, intruder_policy, args.steps)[0], keys, params)
    peer, f_peer = timed(lambda k, p: vmap_of_scans(k, p, vehicle_policy, intruder_policy, args.steps), keys, params)
    old, f_old = timed(lambda k, p: nested(k, p, vehicle_policy, intruder_policy, args.steps), keys, params)
    # ours and the peer see the episode keys as given; the nested form folds 0 in first, as the evaluator did
    k0 = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    same = _same(f_ours(keys, params), f_peer(keys, params)) and _same(f_ours(k0, params), f_old(keys, params))
    out.update(scan_of_vmap=ours, vmap_of_scan=peer, nested=old, same_final_states=bool(same),
               lower_ratio_vmap_of_scan=round(peer["lower_s"] / max(ours["lower_s"], 1e-9), 2),
               compile_ratio_vmap_of_scan=round(peer["compile_s"] / max(ours["compile_s"], 1e-9), 2),
               lower_ratio_nested=round(old["lower_s"] / max(ours["lower_s"], 1e-9), 2),
               compile_ratio_nested=round(old["compile_s"] / max(ours["compile_s"], 1e-9), 2),
               loadavg_1min_after=round(os.getloadavg()[0], 2))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
