"""Episodes per second of the evaluator (:func:`stp_env.evaluation.evaluate`) on the default scenario (``town``,
7 vehicles) and on the 50-vehicle ``city``.

    python benchmarks/evaluate_throughput.py [--town-episodes 2000] [--city-episodes 1000] [--batch-size 250]

Prints one JSON line. ``town`` runs as ``stp-env evaluate`` does (trajectories recorded for the figures); the
city without recording (a batch of 250 recorded city episodes would take ~300 MB). Each case is compiled by a
warm-up batch first (its time is reported as ``compile_s``), then timed over whole batches. The peer in the same
run is the same core driven one step at a time from Python (a jitted ``policy + step`` per call, one episode at a
time, as a gym-style loop over the pure core would run it): ``ratio`` is the evaluator's episodes/s over the peer's.

The city has no shipped plan yet (planning 50 vehicles takes long), so its case runs on **synthetic nominal
plans**: straight lines from the origin to each target at 13 m/s (the top planning speed), departures 20 s apart in
priority order. They ignore the buildings and the other vehicles, so episodes contain collisions; this measures
throughput only (every step costs the same whatever happens: the core computes every branch under ``vmap``).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import sim
from stp_env.baselines import INTRUDERS, switching
from stp_env.evaluation import Configuration, build_params, evaluate
from stp_env.planning.single import SinglePlan
from stp_env.planning.stp import Plan, VehiclePlan


def straight_line_plan(scenario, tracking_bound: float, speed: float = 13.0, spacing_s: float = 20.0,
                       sample_s: float = 0.5) -> Plan:
    """Synthetic nominal plans (throughput only): straight to each target at ``speed``, departures ``spacing_s``
    apart in priority order."""
    vehicles = []
    for i, spec in enumerate(scenario.vehicles):
        start, target = np.asarray(spec.start[:2], float), np.asarray(spec.target, float)
        heading = float(np.arctan2(*(target - start)[::-1]))
        duration = float(np.linalg.norm(target - start)) / speed
        t0 = spacing_s * spec.priority
        times = t0 + np.arange(0.0, duration + 10.0, sample_s)
        frac = np.clip((times - t0) * speed / max(np.linalg.norm(target - start), 1e-9), 0.0, 1.0)[:, None]
        pos = start + frac * (target - start)
        states = np.concatenate([pos, np.full((len(times), 1), heading)], axis=1).astype(np.float32)
        controls = np.tile(np.asarray([speed, 0.0], np.float32), (len(times), 1))
        single = SinglePlan(t_ldt=t0, sta=t0 + duration, times=times, states=states, controls=controls,
                            arrival_time=t0 + duration, n_steps=0)
        vehicles.append(VehiclePlan(index=i, priority=spec.priority, plan=single, obstacle_lags=np.zeros(1),
                                    obstacle_radii=np.zeros(1)))
    return Plan(vehicles=tuple(vehicles), tracking_bound=tracking_bound,
                collision_radius=scenario.collision_radius, kbar=scenario.kbar)


def city_params(n_vehicles: int, kbar: int):
    from stp_env.scenarios import make

    scenario = make("city", n_vehicles=n_vehicles, kbar=kbar)
    avoid, tracking = sim.load_artifacts(scenario, progress=False)
    plan = straight_line_plan(scenario, tracking.bound)
    return sim.make_params(scenario, plan, avoid, tracking, sim.EnvConfig())


def time_evaluator(config, params, episodes: int, batch_size: int, showcase: bool) -> dict:
    kwargs = {"batch_size": batch_size, "params": [params], "progress": False, "showcase": showcase}
    start = time.perf_counter()
    evaluate([config], episodes=batch_size, **kwargs)
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    result = evaluate([config], episodes=episodes, **kwargs)[0]
    seconds = time.perf_counter() - start
    return {"episodes": episodes, "n_steps": result.n_steps, "compile_s": round(compile_s - seconds * batch_size
                                                                                / episodes, 1),
            "seconds": round(seconds, 2), "episodes_per_s": round(episodes / seconds, 2),
            "env_steps_per_s": round(episodes * result.n_steps / seconds), "forced_max": result.summary["forced_max"]}


def time_step_loop(params, intruder_policy, episodes: int) -> dict:
    """The peer: a jitted ``policies + step`` called once per step from Python, one episode at a time."""

    @jax.jit
    def step(key, state):
        k_v, k_i, k_s = jax.random.split(key, 3)
        actions = jnp.concatenate([switching(k_v, state, params), intruder_policy(k_i, state, params)[None]], 0)
        return sim.step(k_s, state, actions, params)[0]

    reset = jax.jit(sim.reset)
    n_steps = sim.steps_for(params)
    state = step(jax.random.key(0), reset(jax.random.key(0), params))   # compile
    jax.block_until_ready(state)
    start = time.perf_counter()
    for e in range(episodes):
        key = jax.random.key(1000 + e)
        state = reset(key, params)
        for k in jax.random.split(key, n_steps):
            state = step(k, state)
        jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    return {"episodes": episodes, "seconds": round(seconds, 2), "episodes_per_s": round(episodes / seconds, 3)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--town-episodes", type=int, default=2000)
    parser.add_argument("--city-episodes", type=int, default=1000, help="0 to skip the city")
    parser.add_argument("--city-vehicles", type=int, default=50)
    parser.add_argument("--batch-size", type=int, default=250)
    parser.add_argument("--intruder", default="max-k")
    parser.add_argument("--peer-episodes", type=int, default=2)
    args = parser.parse_args()
    load = os.getloadavg()[0]
    config = Configuration(scenario="town", kbar=2, intruder=args.intruder)
    town = build_params([config], progress=False)[0]
    out = {"case": "evaluate_throughput", "intruder": args.intruder, "vehicle_policy": "switching",
           "batch_size": args.batch_size, "loadavg_1min_before": round(load, 2)}
    out["town"] = time_evaluator(config, town, args.town_episodes, args.batch_size, showcase=True)
    out["town_peer_step_loop"] = time_step_loop(town, INTRUDERS[args.intruder], args.peer_episodes)
    out["town_ratio"] = round(out["town"]["episodes_per_s"] / out["town_peer_step_loop"]["episodes_per_s"], 1)
    if args.city_episodes > 0:
        city_config = Configuration(scenario="city", kbar=3, intruder=args.intruder)
        city = city_params(args.city_vehicles, 3)
        out["city_synthetic_plans"] = time_evaluator(city_config, city, args.city_episodes, args.batch_size,
                                                     showcase=False)
        out["city_vehicles"] = args.city_vehicles
        out["city_10k_episodes_s"] = round(10_000 / out["city_synthetic_plans"]["episodes_per_s"], 1)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
