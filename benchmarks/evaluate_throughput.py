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

``--base REV`` also runs the city case on another git revision's ``stp_env`` (exported with ``git archive``, its
own process, after this tree's): ``city_speedup_vs_base`` is the base's seconds over this tree's, and
``city_same_episodes_as_base`` compares a hash of every episode's final state (in index order; ``--ignore`` leaves
fields out of it, e.g. one whose meaning changed where no episode reads it). ``--cpu-devices N`` shares each batch
among ``N`` CPU devices (:func:`stp_env.set_cpu_devices`; the digests then compare another program's episodes).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import sim
from stp_env.evaluation import Configuration, build_params, evaluate
from stp_env.policies import INTRUDERS, switching


def episodes_digest(episodes: dict, ignore=()) -> str:
    """A hash of the per-episode final states (``ConfigResult.episodes``) except the fields in ``ignore``."""
    h = hashlib.sha256()
    for name in sorted(episodes):
        if name not in ignore:
            h.update(name.encode())
            h.update(np.ascontiguousarray(np.asarray(episodes[name])).tobytes())
    return h.hexdigest()[:16]


def time_evaluator(config, params, episodes: int, batch_size: int, showcase: bool, ignore=()) -> dict:
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
            "env_steps_per_s": round(episodes * result.n_steps / seconds), "forced_max": result.summary["forced_max"],
            "digest": episodes_digest(result.episodes, ignore)}


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
    parser.add_argument("--base", help="also run the city case on this git revision (e.g. HEAD~1)")
    parser.add_argument("--ignore", nargs="*", default=[], help="final-state fields left out of the digests")
    parser.add_argument("--city-only", action="store_true", help="the city case alone (used internally)")
    parser.add_argument("--cpu-devices", type=int, default=1,
                        help="JAX CPU devices each batch is shared among (stp_env.set_cpu_devices)")
    args = parser.parse_args()
    import stp_env

    if args.cpu_devices != 1:  # (a --base revision's package may predate the setting)
        stp_env.set_cpu_devices(args.cpu_devices)  # before JAX's first computation
    if args.city_only:
        print(json.dumps({"city": time_city(args), "package": stp_env.__file__}))
        return
    load = os.getloadavg()[0]
    config = Configuration(scenario="town", kbar=2, intruder=args.intruder)
    town = build_params([config], progress=False)[0]
    out = {"case": "evaluate_throughput", "intruder": args.intruder, "vehicle_policy": "switching",
           "batch_size": args.batch_size,
           "cpu_devices": args.cpu_devices, "loadavg_1min_before": round(load, 2)}
    out["town"] = time_evaluator(config, town, args.town_episodes, args.batch_size, showcase=True)
    out["town_peer_step_loop"] = time_step_loop(town, INTRUDERS[args.intruder], args.peer_episodes)
    out["town_ratio"] = round(out["town"]["episodes_per_s"] / out["town_peer_step_loop"]["episodes_per_s"], 1)
    if args.city_episodes > 0:
        out["city"] = time_city(args)
        out["city_10k_episodes_s"] = round(10_000 / out["city"]["episodes_per_s"], 1)
        if args.base:
            out["city_base"] = base_city(args)
            out["city_speedup_vs_base"] = round(out["city_base"]["seconds"] / out["city"]["seconds"], 2)
            out["city_same_episodes_as_base"] = out["city_base"]["digest"] == out["city"]["digest"]
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


def time_city(args) -> dict:
    city_config = Configuration(scenario="city-intruder", kbar=args.city_kbar, intruder=args.intruder)
    (city,) = build_params([city_config], progress=False)  # the shipped intruder-aware plan of this k̄
    out = time_evaluator(city_config, city, args.city_episodes, args.batch_size, showcase=False,
                         ignore=tuple(args.ignore))
    out.update(scenario="city-intruder", kbar=args.city_kbar, vehicles=int(city.vehicles.n))
    return out


def base_city(args) -> dict:
    """The city case on ``args.base``'s ``stp_env`` (this script in a child process that imports it)."""
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(here)
    rev = subprocess.run(["git", "-C", root, "rev-parse", "--short", args.base], capture_output=True, text=True,
                         check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", root, "archive", rev, "stp_env"], capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([tmp, os.environ.get("PYTHONPATH", "")]))
        res = subprocess.run([sys.executable, os.path.abspath(__file__), "--city-only", "--city-episodes",
                              str(args.city_episodes), "--city-kbar", str(args.city_kbar), "--batch-size",
                              str(args.batch_size), "--intruder", args.intruder, "--ignore", *args.ignore],
                             capture_output=True, text=True, check=True, env=env, cwd=tmp)
        out = json.loads(res.stdout.strip().splitlines()[-1])
        if not out["package"].startswith(tmp):
            raise SystemExit(f"the base run imported {out['package']}, not {rev}'s package")
    return {**out["city"], "base": rev}


if __name__ == "__main__":
    main()
