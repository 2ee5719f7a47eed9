"""Does the pymunk kinematic backend fly exactly the JAX core's Dubins vehicles? One episode, closed loop (the
papers' switching controller for the vehicles, a scripted intruder), run by both backends from the same key; prints
one JSON line: the largest position difference over the episode's flying vehicles, and whether every status and
avoid start agrees.

Run it with ``JAX_ENABLE_X64=1`` to compare in float64 (the params are cast): the papers' tracker is bang-bang, so
in float32 the different rounding of the two integrators (pymunk steps in float64, the core in float32; the
position's float32 spacing is 0.1 mm at 1 km) flips a switching decision now and then and the trajectories part by
up to a control step's worth of motion, while in float64 they agree to rounding. Example::

    JAX_ENABLE_X64=1 python examples/pymunk_agreement.py --scenario town --steps 0
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from stp_env import assembly, sim
from stp_env.evaluation.config import resolve_intruder, resolve_vehicle_policy
from stp_env.sim.rollout import episode_step
from stp_env.sim.vehicle_models.rigid_body import PymunkKinematic


def cast_params(params):
    """``params`` with its float32 arrays in float64 when x64 is on (unchanged otherwise)."""
    if not jax.config.jax_enable_x64:
        return params
    return jax.tree.map(lambda a: a.astype(jnp.float64) if getattr(a, "dtype", None) == jnp.float32 else a, params)


def run(params, seed: int, n_steps: int, vehicle: str, intruder: str, progress: bool):
    vp, ip = resolve_vehicle_policy(vehicle), resolve_intruder(intruder)
    key = jax.random.key(seed)
    k_reset, k_run = jax.random.split(key)
    step = jax.jit(lambda k, s: episode_step(k, s, params, vp, ip)[0])
    state = sim.reset(k_reset, params)
    xs, status, avoid = [], [], []
    for k in tqdm(jax.random.split(k_run, n_steps), disable=not progress, desc=type(params.vehicles.model).__name__):
        term, trunc = sim.episode_over(state, params)
        if bool(term | trunc):
            break
        state = step(k, state)
        xs.append(np.asarray(state.x[:, :2], np.float64))
        status.append(np.asarray(state.status))
        avoid.append(np.asarray(state.avoid_start))
    return np.stack(xs), np.stack(status), np.stack(avoid)


def compare(scenario: str, *, seed: int = 0, n_steps: int = 0, vehicle: str = "switching", intruder: str = "max-k",
            progress: bool = False) -> dict:
    params = cast_params(assembly.params_for(scenario, sim.EnvConfig(), progress=progress))
    n_steps = n_steps or sim.steps_for(params)
    start = time.perf_counter()
    x_j, st_j, av_j = run(params, seed, n_steps, vehicle, intruder, progress)
    pm = params.replace(vehicles=dict(model=PymunkKinematic()))
    x_p, st_p, av_p = run(pm, seed, n_steps, vehicle, intruder, progress)
    n = min(len(x_j), len(x_p))
    fly = (st_j[:n] == sim.FLYING) & (st_p[:n] == sim.FLYING)
    diff = np.hypot(*(x_j[:n] - x_p[:n]).transpose(2, 0, 1))
    return {"scenario": scenario, "seed": seed, "steps": int(n), "dtype": str(params.episode.dt.dtype),
            "flying_vehicle_steps": int(fly.sum()),
            "max_position_difference_m": float(diff[fly].max()) if fly.any() else 0.0,
            "same_status": bool(np.array_equal(st_j[:n], st_p[:n])),
            "same_avoid_starts": bool(np.array_equal(av_j[:n], av_p[:n])),
            "n_forced": int(np.isfinite(av_j[n - 1]).sum()),
            "seconds": round(time.perf_counter() - start, 1)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="town")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=0, help="steps (0: the whole episode)")
    p.add_argument("--intruder", default="max-k")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    print(json.dumps(compare(args.scenario, seed=args.seed, n_steps=args.steps, intruder=args.intruder,
                             progress=not args.no_progress)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
