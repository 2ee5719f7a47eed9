"""Milliseconds per evaluation of the planner's moving-disk obstacle: the library's running minimum (a ``scan`` over
the vehicles, :func:`stp_env.planning.obstacles.moving_disks`) against the formula it replaced (every squared
distance of a ``(J, L, nx, ny)`` array written, then reduced), in the same process.

    python benchmarks/disk_obstacles.py [--reps 20]

One JSON line per case: the bay-area grid (251 x 189) with 199 vehicle rows and the one lag disk of robust
trajectory tracking; the city grid (151 x 151) with 49 rows and the 17 lag disks of the intruder-aware obstacle at
k̄ = 4, and with 8 rows (what a time bucket lists there). Random trajectories of 2,000 samples, all vehicles in
flight. ``same`` says whether the two give the same values bit for bit; the time is the mean of ``--reps`` calls
after a compiling one.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.planning.obstacles import interpolate_positions, moving_disks


def broadcast_disks(t, params):
    """The formula before the running minimum: the whole ``(J, L, nx, ny)`` array, then its minimum."""
    tq = t + params["lags"]
    centres = interpolate_positions(params["times"], params["positions"], tq)
    active = (tq >= params["start"][:, None]) & (tq <= params["end"][:, None])
    cx = centres[..., 0][:, :, None, None]
    cy = centres[..., 1][:, :, None, None]
    d2 = (params["xs"][None, None, :, None] - cx) ** 2 + (params["ys"][None, None, None, :] - cy) ** 2
    d2 = jnp.min(jnp.where(active[:, :, None, None], d2, jnp.inf), axis=0)
    return jnp.min(jnp.sqrt(d2) - params["radii"][:, None, None], axis=0)


def make_params(nx: int, ny: int, rows: int, lags: int, samples: int = 2000, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    times = np.tile(np.arange(samples, dtype=np.float32) * 0.5 - 800.0, (rows, 1))
    return {"xs": jnp.linspace(0.0, 5000.0, nx), "ys": jnp.linspace(0.0, 5000.0, ny), "times": jnp.asarray(times),
            "positions": jnp.asarray(rng.uniform(0.0, 5000.0, (rows, samples, 2)).astype(np.float32)),
            "lags": jnp.asarray(np.tile(np.linspace(-5.2, 2.5, lags, dtype=np.float32), (rows, 1))),
            "radii": jnp.full((lags,), 100.0, jnp.float32), "start": jnp.full((rows,), -700.0, jnp.float32),
            "end": jnp.full((rows,), 100.0, jnp.float32)}


def time_ms(fn, params, reps: int) -> tuple[float, np.ndarray]:
    f = jax.jit(fn)
    first = np.asarray(f(jnp.float32(-100.0), params))
    t0 = time.perf_counter()
    for i in range(reps):
        f(jnp.float32(-100.0 + i), params).block_until_ready()
    return (time.perf_counter() - t0) / reps * 1e3, first


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--reps", type=int, default=20)
    args = parser.parse_args()
    cases = {"bay_area_199x1": (251, 189, 199, 1), "city_49x17": (151, 151, 49, 17), "city_8x17": (151, 151, 8, 17)}
    for name, (nx, ny, rows, lags) in cases.items():
        params = make_params(nx, ny, rows, lags)
        load = round(os.getloadavg()[0], 2)
        ms_new, g_new = time_ms(moving_disks, params, args.reps)
        ms_old, g_old = time_ms(broadcast_disks, params, args.reps)
        print(json.dumps({"benchmark": "disk_obstacles", "case": name, "grid": [nx, ny], "rows": rows, "lags": lags,
                          "loadavg_1min_before": load, "ms": {"scan": round(ms_new, 2), "broadcast": round(ms_old, 2)},
                          "speedup": round(ms_old / ms_new, 1), "same": bool(np.array_equal(g_new, g_old))}),
              flush=True)


if __name__ == "__main__":
    main()
