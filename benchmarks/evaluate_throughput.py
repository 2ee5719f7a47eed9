"""Episodes per second of the evaluator (:func:`stp_env.evaluation.evaluate`) on the default scenario (``town``,
7 vehicles) and on the 50-vehicle intruder-aware city (``city-intruder``), both on their shipped STP plans.

    python benchmarks/evaluate_throughput.py [--town-episodes 2000] [--city-episodes 1000] [--city-kbar 3]
                                             [--batch-size 250]

Prints one JSON line. ``town`` runs as ``stp-env evaluate`` does (trajectories recorded for the figures); the
city as ``stp-env evaluate --scenario city-intruder --kbar K`` does without recording (``showcase=False``: a batch
of 250 recorded city episodes would take hundreds of MB). Each case is compiled by a warm-up batch first (its time
is reported as ``compile_s``), then timed over whole batches; ``city_10k_episodes_s`` extrapolates to the 10,000
episodes of a full evaluation. The peer in the same run is the same core driven one step at a time from Python (a
jitted ``policy + step`` per call, one episode at a time, as a gym-style loop over the pure core would run it):
``ratio`` is the evaluator's episodes/s over the peer's.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp

from stp_env import sim
from stp_env.baselines import INTRUDERS, switching
from stp_env.evaluation import Configuration, build_params, evaluate


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
    parser.add_argument("--city-kbar", type=int, default=3, choices=(2, 3, 4))
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
        city_config = Configuration(scenario="city-intruder", kbar=args.city_kbar, intruder=args.intruder)
        (city,) = build_params([city_config], progress=False)  # the shipped intruder-aware plan of this k̄
        out["city"] = time_evaluator(city_config, city, args.city_episodes, args.batch_size, showcase=False)
        out["city"].update(scenario="city-intruder", kbar=args.city_kbar, vehicles=int(city.n_vehicles))
        out["city_10k_episodes_s"] = round(10_000 / out["city"]["episodes_per_s"], 1)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
