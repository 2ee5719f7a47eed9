"""Tracing, compilation and run time of the simulator's programs with the library's table reads
(:mod:`stp_env.sim.tables`: the avoid table read as one ``2 x 4 x 4 x 4`` block per state, every read a nested
jitted call; the tracking gradients as one ``2 x 2 x 2 x 3`` block) against the reads they replaced (the peer, in
the same run): 112 scalar gathers per avoid-table read (:func:`stp_env.reach.avoid.avoid_table_value` and the
central differences of :func:`stp_env.hj.interpolation.gradient_slices` on the unpadded table) and 24 per tracking
read (:func:`stp_env.hj.interpolation.interpolate_gradient`), inlined at every call site.

    python benchmarks/table_reads.py [--program rollout|tracking|avoidance] [--batch 16] [--steps 20]
    python benchmarks/table_reads.py --program rollout --batch 256 --steps 200   # run speed

``rollout``: the evaluator's batch program (:func:`stp_env.sim.rollout.rollout_keys`, the baseline switching
vehicles against the HJ intruder on ``town``, k̄ = 2); ``tracking`` / ``avoidance``: a falsifier objective
(:mod:`stp_env.falsify`) vmapped over ``--batch`` inputs. Prints one JSON line: seconds to trace, lower, compile
and run each variant (the fastest of five runs) and the batch-steps per second, the ratios (peer / ours), and the
largest difference between the two programs' outputs (the same functions up to rounding).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.reach.avoid import avoid_table_value
from stp_env.sim import tables


def _scalar_avoid_read(grid, taus, values, tau, x_rel):
    return (avoid_table_value(grid, taus, values, tau, x_rel),
            hj.interpolation.gradient_slices(grid, taus, values, tau, x_rel))


PEER = {"_avoid_read": _scalar_avoid_read, "interpolate": hj.interpolation.interpolate,
        "_tracking_read": hj.interpolation.interpolate_gradient}


def _unpad(v, grid, lead: int):
    v = np.asarray(v)
    for d in grid.periodic:
        v = np.take(v, range(tables.PERIODIC_PAD[0], tables.PERIODIC_PAD[0] + grid.shape[d]), axis=lead + d)
    return v


def unpadded(params):
    """``params`` with the avoid table and the tracking gradients in their plain layouts (what the peer's scalar
    reads index)."""
    grads = _unpad(params.tables.tracking_table, params.tables.tracking_grid, 0)
    avoid = jnp.asarray(_unpad(params.tables.avoid_values, params.tables.avoid_grid, 1))
    return params.replace(tables=dict(avoid_values=avoid,
                                      tracking_table=tuple(jnp.asarray(grads[..., i]) for i in range(grads.shape[-1]))))


@contextlib.contextmanager
def peer_reads():
    """The readers of :mod:`stp_env.sim.tables` swapped for the peer's (inlined, scalar gathers)."""
    saved = {k: getattr(tables, k) for k in PEER}
    for k, f in PEER.items():
        setattr(tables, k, f)
    try:
        yield
    finally:
        for k, f in saved.items():
            setattr(tables, k, f)


def program(kind: str, batch: int, steps: int, peer: bool = False):
    """``(jitted function, arguments)`` of the program measured."""
    from stp_env import assembly, sim
    from stp_env.scenarios import make

    if kind == "rollout":
        from stp_env.baselines import INTRUDERS, VEHICLE_POLICIES
        from stp_env.sim.rollout import rollout_keys

        params = assembly.params_for(make("town", kbar=2), sim.EnvConfig(), progress=False)
        params = unpadded(params) if peer else params
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(0), i))(jnp.arange(batch))
        veh, intr = VEHICLE_POLICIES["switching"], INTRUDERS["hj"]

        def run(keys, params):
            final, _ = rollout_keys(keys, params, veh, intr, steps)
            return final.x, final.intruder_x, final.avoid_start

        return jax.jit(run), (keys, params)
    from stp_env.falsify.search import compiled

    params = assembly.params_for(make("town", kbar=2), sim.EnvConfig(control_dt=0.02, wind_model="worst"),
                            progress=False)
    params = unpadded(params) if peer else params
    if kind == "tracking":
        from stp_env.falsify.tracking import TrackingAttack

        attack = TrackingAttack(base=params, horizon=float(steps) * float(params.episode.dt), segment=1.0,
                                wind="search",
                                wind_segment=1.0)
    else:
        from stp_env.falsify.avoidance import AvoidanceAttack

        attack = AvoidanceAttack(base=params, intruder="hj", wind="worst", max_level=5.0)
    prog = compiled(attack.objective)
    z = jax.random.uniform(jax.random.key(0), (batch, attack.dim), jnp.float32)
    return prog.func, (*prog.args, z)


def measure(kind: str, batch: int, steps: int, peer: bool = False) -> tuple[dict, list]:
    f, args = program(kind, batch, steps, peer)
    t0 = time.perf_counter()
    traced = f.trace(*args)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    comp = lowered.compile()
    t3 = time.perf_counter()
    out = jax.block_until_ready(comp(*args))
    runs = []
    for _ in range(5):  # the fastest of five runs: the machine is shared
        t4 = time.perf_counter()
        out = jax.block_until_ready(comp(*args))
        runs.append(time.perf_counter() - t4)
    return ({"trace_s": round(t1 - t0, 2), "lower_s": round(t2 - t1, 2), "compile_s": round(t3 - t2, 2),
             "run_s": round(min(runs), 4), "batch_steps_per_s": round(batch * steps / min(runs))},
            [np.asarray(a) for a in jax.tree.leaves(out)])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--program", choices=("rollout", "tracking", "avoidance"), default="rollout")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--steps", type=int, default=20)
    args = parser.parse_args()
    ours, out_o = measure(args.program, args.batch, args.steps)
    with peer_reads():
        peer, out_p = measure(args.program, args.batch, args.steps, peer=True)
    diff = max(float(np.nanmax(np.abs(np.where(np.isfinite(a) & np.isfinite(b), a - b, 0.0)), initial=0.0))
               for a, b in zip(out_o, out_p))
    same_inf = all(np.array_equal(np.isfinite(a), np.isfinite(b)) for a, b in zip(out_o, out_p))
    ratio = {k[:-2] + "_ratio": round(peer[k] / max(ours[k], 1e-9), 2)
             for k in ("trace_s", "lower_s", "compile_s", "run_s")}
    print(json.dumps({"benchmark": "table_reads", "program": args.program, "batch": args.batch,
                      "loadavg_1min": round(os.getloadavg()[0], 2),
                      "steps": args.steps, "ours": ours, "peer": peer, **ratio, "max_abs_output_diff": diff,
                      "same_finite_pattern": bool(same_inf), "cpus": os.cpu_count()}), flush=True)


if __name__ == "__main__":
    main()
