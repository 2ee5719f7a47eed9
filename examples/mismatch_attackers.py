"""Learned and scripted intruders where the proofs stop: vehicles on a plant or a filter rate the guarantees do not
cover, the intruder trained *there* (PPO from a clone of the avoid game's pursuit, rewarded per collision it causes)
and the scripted ones, side by side on the same held-out episodes.

Plants (``--plants``; the vehicles on ``switching``, u* with the HJ safety filter, town at k̄ = 2, every intruder
appearing on a vehicle's avoid boundary as in docs/model_mismatch.md):

* ``lag0.1``, ``lag0.3``: the pymunk rigid body with 0.1 s / 0.3 s actuator lags (``pymunk-dynamic``), where
  every episode breaks the robust-tracking bound;
* ``filter0.1``: the Dubins plant with the tracker and the safety filter run once per 0.1 s step instead of every
  0.02 s (uncertified: collisions count as assumption failures, not guarantee violations); its certified avoid
  margin grows with the period (one inner step of the value's fastest fall: 14.7 m instead of 3.76 m);
* ``filter0.1-margin``: the same with the avoid margin kept at the 0.02 s loop's 3.761 m (a filter calibrated for
  the fine loop, run at the coarse rate);
* ``dubins``: the certified reference.

For each plant, ``train`` trains an intruder (``stp_env.rl.train``; ``--timesteps`` of PPO after cloning ``hj``)
into ``OUT/PLANT/learned``; ``evaluate`` runs the scripted intruders (``hj``, ``max-k``, ``optimal-max-k``) and the
learned one of that plant on ``--episodes`` intruder episodes (from its appearance to its departure; seeds
``--seed + i``, disjoint from training's) and appends one JSON line per (plant, intruder) to ``OUT/results.jsonl``:
episodes with a collision, with a collision the intruder caused, with a guarantee violation (each with its exact
95 % Clopper-Pearson interval), mean ``|N^RP|``, and the smallest intruder-vehicle separation (the margin to
``R_c`` = 100 m: how close the attack came, where no collision happened). A rerun skips what is there.

    python examples/mismatch_attackers.py train --plants filter0.1 lag0.1 --out runs/mismatch-attackers
    python examples/mismatch_attackers.py evaluate --plants dubins filter0.1 lag0.1 --out runs/mismatch-attackers
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.evaluation.stats import clopper_pearson_interval
from stp_env.policies import INTRUDERS
from stp_env.rl.imitation import scripted_predict
from stp_env.rl.train import TrainConfig, build_params, evaluate_on_vec_env, train
from stp_env.rl.vec_env import IntruderVecEnv
from stp_env.sim.types import FLYING, PRESENT

PLANTS = {
    "dubins": {},
    "filter0.1": {"control_dt": 0.1},
    "filter0.1-margin": {"control_dt": 0.1, "avoid_margin": 3.761},
    "lag0.1": {"backend": "pymunk-dynamic:speed_time_constant=0.1,turn_time_constant=0.1"},
    "lag0.3": {"backend": "pymunk-dynamic:speed_time_constant=0.3,turn_time_constant=0.3"},
}
SCRIPTED = ("hj", "max-k", "optimal-max-k")


def config_for(plant: str, out: Path, timesteps: int, n_envs: int) -> TrainConfig:
    return TrainConfig(scenario="town", kbar=2, spawn_mode="boundary", observation="game", clone="hj",
                       collision_reward=10.0, forced_reward=1.0, shaping_reward=0.01, log_std_init=-1.0,
                       learning_rate=1e-4, total_timesteps=timesteps, n_envs=n_envs, n_steps=64,
                       batch_size=min(4096, n_envs * 64), clone_steps=200, clone_rounds=1, eval_every=0,
                       eval_episodes=n_envs, checkpoint_every=0, out_dir=str(out / plant / "learned"),
                       log_formats=("csv",), **PLANTS[plant])


@jax.jit
def _separation(states):
    """The smallest distance between the intruder and a flying vehicle in each env's state (inf if none)."""
    def one(s):
        d = jnp.hypot(*(s.x[:, :2] - s.intruder_x[None, :2]).T)
        return jnp.min(jnp.where((s.status == FLYING) & (s.intruder_status == PRESENT), d, jnp.inf))

    return jax.vmap(one)(states)


def run_episodes(venv, predict, n_episodes: int, seed: int) -> dict:
    """Per-episode stats of ``predict`` and the smallest intruder-vehicle separation (over the states each step
    started from)."""
    result = evaluate_on_vec_env(predict, venv, n_episodes, seed, track=lambda v: _separation(v._states))
    return {**result, "min_separation": result["tracked_min"]}


def summary(result: dict) -> dict:
    e = len(result["n_forced"])
    sep = result["min_separation"]
    out = {"episodes": e, "mean_n_forced": float(result["n_forced"].mean()),
           "min_separation_m": float(sep.min()), "separation_p1_m": float(np.percentile(sep, 1)),
           "separation_median_m": float(np.median(sep))}
    for key in ("collisions", "intruder_collisions", "guarantee_violations"):
        k = int(np.sum(result[key] > 0))
        lo, hi = clopper_pearson_interval(k, e)
        out[f"{key}_episodes"] = k
        out[f"{key}_ci95"] = [round(lo, 4), round(hi, 4)]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["train", "evaluate"])
    ap.add_argument("--plants", nargs="+", choices=sorted(PLANTS), default=["filter0.1", "lag0.1"])
    ap.add_argument("--timesteps", type=int, default=262_144)
    ap.add_argument("--n-envs", type=int, default=64)
    ap.add_argument("--episodes", type=int, default=512)
    ap.add_argument("--seed", type=int, default=20_240_601)
    ap.add_argument("--out", type=Path, default=Path("runs/mismatch-attackers"))
    ap.add_argument("--intruders", nargs="+", choices=[*SCRIPTED, "learned"], default=None,
                    help="evaluate: only these (default: the scripted ones and the learned one if trained)")
    args = ap.parse_args(argv)
    for plant in args.plants:
        config = config_for(plant, args.out, args.timesteps, args.n_envs)
        if args.what == "train":
            if (Path(config.out_dir) / "intruder.npz").exists():
                continue
            print(json.dumps({"plant": plant, "training": config.out_dir}), flush=True)
            train(config)
            continue
        results = args.out / "results.jsonl"
        done = set()
        if results.exists():
            done = {(r["plant"], r["intruder"]) for r in map(json.loads, results.read_text().splitlines())}
        params = build_params(config)
        venv = IntruderVecEnv(args.n_envs, params=params, horizon="intruder", vehicle_policy="switching",
                              observation="game")
        learned = Path(config.out_dir) / "intruder.npz"
        names = [*SCRIPTED, *(["learned"] if learned.exists() else [])]
        names = [n for n in names if args.intruders is None or n in args.intruders]
        for name in names:
            if (plant, name) in done:
                continue
            if name == "learned":
                from stp_env.policies.learned import load_mlp

                predict = load_mlp(learned).action_numpy
            else:
                predict = scripted_predict(venv, INTRUDERS[name])

            row = {"plant": plant, **PLANTS[plant], "intruder": name,
                   **summary(run_episodes(venv, predict, args.episodes, args.seed))}
            print(json.dumps(row), flush=True)
            results.parent.mkdir(parents=True, exist_ok=True)
            with open(results, "a") as f:  # one whole line per row, flushed: a killed run keeps the rows written
                f.write(json.dumps(row) + "\n")
                f.flush()
                os.fsync(f.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
