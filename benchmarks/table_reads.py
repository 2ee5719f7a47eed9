"""Trace, compile and run time of the simulator's batch program with the library's table reader
(:mod:`stp_env.hj.interpolation`: one scalar gather and its index arithmetic per corner of the ``2^ndim`` around a
state, a central-difference gradient as six reads) against a peer in the same run that reads all corners with one
gather (flattened indices) and the six gradient reads as one batch, on ``town`` (k̄ = 2, ``switching`` vehicles,
HJ intruder by default).

    python benchmarks/table_reads.py [--envs 256] [--steps 200] [--intruder hj] [--vehicle-policy switching]

Prints one JSON line: per reader the seconds to trace and lower, to compile, the lowered program's size (lines of
StableHLO) and the episode-steps per second of the compiled rollout (compile excluded); the ratios (peer / ours:
above 1 means the library's reader is faster); and the largest difference between the two readers' final vehicle
positions (they sum the same products in another order, so they agree to float32 rounding, not bit for bit).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.evaluation import Configuration, build_params
from stp_env.hj import interpolation
from stp_env.sim.rollout import rollout_keys

LIBRARY = {"_multilinear": interpolation._multilinear, "gradient_slices": interpolation.gradient_slices}


def _take(values, idx):
    """``values[idx]`` for a tuple of index arrays, as one gather from the flattened leading axes."""
    flat = jnp.zeros(jnp.shape(idx[-1]), jnp.int32)
    for i, n in zip(idx, values.shape[:len(idx)]):
        flat = flat * n + i
    return values.reshape((-1, *values.shape[len(idx):]))[flat]


def one_gather_multilinear(grid, state, read):
    """The peer: all ``2^ndim`` corners' indices and weights as arrays, read by one gather (``read`` gets index
    arrays), then an elementwise product and a sum."""
    i0, i1, w1 = interpolation._corners(grid, state)
    bits = np.asarray(list(itertools.product((False, True), repeat=grid.ndim)), bool)
    idx = jnp.where(bits, i1[None, :], i0[None, :])
    weights = jnp.where(bits, w1[None, :], 1.0 - w1[None, :])
    w = weights[:, 0]
    for d in range(1, grid.ndim):
        w = w * weights[:, d]
    vals = read(tuple(idx[:, d] for d in range(grid.ndim)))
    return jnp.sum(w.reshape(w.shape + (1,) * (vals.ndim - 1)) * vals, axis=0)


def one_gather_slices(grid, slice_times, stack, t, state):
    k = jnp.clip(jnp.searchsorted(slice_times, t, side="right") - 1, 0, slice_times.shape[0] - 2)
    span = slice_times[k + 1] - slice_times[k]
    w = jnp.clip(jnp.where(span > 0, (t - slice_times[k]) / span, 0.0), 0.0, 1.0)
    return one_gather_multilinear(grid, state, lambda idx: (1.0 - w) * _take(stack, (k, *idx))
                                  + w * _take(stack, (k + 1, *idx)))


def batched_gradient(grid, slice_times, stack, t, state):
    """The peer's gradient: the six central-difference reads as one batch (``vmap``)."""
    steps = np.eye(grid.ndim) * np.asarray(grid.spacing)[:, None]
    points = jnp.concatenate([state + steps, state - steps])
    values = jax.vmap(lambda x: one_gather_slices(grid, slice_times, stack, t, x))(points)
    return (values[:grid.ndim] - values[grid.ndim:]) / (2 * np.asarray(grid.spacing))


PEER = {"_multilinear": one_gather_multilinear, "gradient_slices": batched_gradient,
        "interpolate_slices": one_gather_slices}
LIBRARY["interpolate_slices"] = interpolation.interpolate_slices


def measure(reader: dict, keys, params, policies, n_steps: int) -> tuple[dict, np.ndarray]:
    for name, fn in reader.items():
        setattr(interpolation, name, fn)
    jax.clear_caches()  # nothing traced with the other reader may be reused
    vehicle_policy, intruder_policy = policies

    def program(k, p):
        return rollout_keys(k, p, vehicle_policy, intruder_policy, n_steps)[0]

    t0 = time.perf_counter()
    lowered = jax.jit(program).lower(keys, params)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    jax.block_until_ready(compiled(keys, params))
    t3 = time.perf_counter()
    final = compiled(keys, params)
    jax.block_until_ready(final)
    run_s = time.perf_counter() - t3
    return ({"lower_s": round(t1 - t0, 2), "compile_s": round(t2 - t1, 2), "hlo_lines": lowered.as_text().count("\n"),
             "run_s": round(run_s, 2), "episode_steps_per_s": round(keys.shape[0] * n_steps / run_s)},
            np.asarray(final.x))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--intruder", default="hj")
    parser.add_argument("--vehicle-policy", default="switching")
    args = parser.parse_args()
    config = Configuration(scenario="town", kbar=2, intruder=args.intruder, vehicle_policy=args.vehicle_policy)
    (params,) = build_params([config], progress=False)
    policies = config.policies()
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(0), i))(jnp.arange(args.envs))
    out = {"case": "table_reads", "scenario": "town", "intruder": args.intruder,
           "vehicle_policy": args.vehicle_policy, "envs": args.envs, "steps": args.steps,
           "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    try:
        ours, x_ours = measure(LIBRARY, keys, params, policies, args.steps)
        peer, x_peer = measure(PEER, keys, params, policies, args.steps)
    finally:
        for name, fn in LIBRARY.items():
            setattr(interpolation, name, fn)
    out.update(per_corner=ours, one_gather=peer,
               lower_ratio=round(peer["lower_s"] / ours["lower_s"], 2),
               compile_ratio=round(peer["compile_s"] / ours["compile_s"], 2),
               run_ratio=round(peer["run_s"] / ours["run_s"], 2),
               max_final_position_diff_m=float(np.nanmax(np.abs(x_peer[..., :2] - x_ours[..., :2]))),
               loadavg_1min_after=round(os.getloadavg()[0], 2))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
