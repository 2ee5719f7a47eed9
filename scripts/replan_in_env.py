"""Replanning (Algorithm 4) while the PettingZoo environment runs, against the jittable fallback of eq. 40.

    python scripts/replan_in_env.py [--scenario town] [--episodes 20] [--seed 0] [--intruder max-k]

Runs the same full-length episodes (same seeds, so the same wind draws and intruder spawns up to the moment the
intruder leaves) twice through ``parallel_env``: vehicles on the switching controller ``u*`` (eq. 38), the
intruder scripted, spawned on a vehicle's avoid boundary. Once with ``replan=False`` (a forced vehicle flies the
fallback of eq. 40 after the intruder leaves, toward its target at top planning speed, with no new STA) and once
with ``replan=True`` (it gets a new STA and plan from :func:`stp_env.planning.replan.replan` and tracks it).
Prints one JSON line per mode: forced vehicles, how many arrived, how many by their (new) STA, collisions,
guarantee violations (:func:`stp_env.evaluation.summary.forced_summary`, with the most forced vehicles in an
episode, the episodes above k̄ and the Clopper-Pearson bound on the violation rate), and the replanning time.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from stp_env import sim
from stp_env.baselines.intruders import intruder_policy
from stp_env.baselines.vehicles import vehicle_policy
from stp_env.env import parallel_env
from stp_env.evaluation.summary import forced_summary


def run(scenario: str, episodes: int, seed: int, intruder: str, replan: bool) -> dict:
    config = sim.EnvConfig(episode="full", spawn_mode="boundary")
    env = parallel_env(scenario, config, replan=replan)
    vpol, ipol = jax.jit(vehicle_policy("switching")), jax.jit(intruder_policy(intruder))
    n = env.params.vehicles.n
    totals = {"forced": 0, "forced_arrived": 0, "forced_on_time": 0, "replans": 0, "replan_failures": 0,
              "replan_seconds": [], "sta_delay_s": []}
    per_episode = {"n_forced": [], "collisions": [], "violations": []}  # (episodes, vehicles) flags
    start = time.perf_counter()
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        key = jax.random.key(seed + ep)
        arrival = np.full(n, np.inf)
        infos = {}
        while env.agents:
            key, kv, ki = jax.random.split(key, 3)
            state, params = env.env_state, env.params
            a_v, a_i = np.asarray(vpol(kv, state, params)), np.asarray(ipol(ki, state, params))
            actions = {a: (a_i if a == "intruder" else a_v[int(a.split("_")[1])]) for a in env.agents}
            _, _, _, _, step_infos = env.step(actions)
            infos.update(step_infos)
            for a, info in step_infos.items():
                if a != "intruder" and info["status"] == "arrived" and not np.isfinite(arrival[int(a[8:])]):
                    arrival[int(a[8:])] = info["time"]
        vehicle_infos = [infos[f"vehicle_{i}"] for i in range(n)]
        for key_, name in (("n_forced", "forced"), ("collisions", "collision"), ("violations", "guarantee_violation")):
            per_episode[key_].append([bool(info[name]) for info in vehicle_infos])
        for i, info in enumerate(vehicle_infos):
            if info["forced"]:
                totals["forced"] += 1
                totals["forced_arrived"] += int(np.isfinite(arrival[i]))
                totals["forced_on_time"] += int(arrival[i] <= info["sta"] + 1e-6)
        for record in env.replan_log:
            if "error" in record:
                totals["replan_failures"] += len(record["vehicles"])
            else:
                totals["replans"] += len(record["vehicles"])
                totals["replan_seconds"].append(record["seconds"])
                totals["sta_delay_s"] += [s - o for s, o in zip(record["sta"], record["old_sta"])]
    seconds, delays = totals.pop("replan_seconds"), totals.pop("sta_delay_s")
    summary = forced_summary(np.sum(per_episode["n_forced"], axis=1), int(env.params.intruder.kbar),
                             per_episode["collisions"], per_episode["violations"])
    return {"scenario": scenario, "intruder": intruder, "replan": replan, "episodes": episodes, "seed": seed,
            **totals, "collisions": summary["collisions"], "guarantee_violations": summary["guarantee_violations"],
            "forced_max": summary["forced_max"], "episodes_above_kbar": summary["exceed"],
            "violation_episodes_upper": round(summary["violation_upper"], 4),
            "replan_seconds_median": round(float(np.median(seconds)), 2) if seconds else None,
            "replan_seconds_max": round(float(np.max(seconds)), 2) if seconds else None,
            "new_sta_delay_s_median": round(float(np.median(delays)), 1) if delays else None,
            "wall_s": round(time.perf_counter() - start, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--intruder", default="max-k")
    args = parser.parse_args()
    for replan in (False, True):
        print(json.dumps(run(args.scenario, args.episodes, args.seed, args.intruder, replan)), flush=True)


if __name__ == "__main__":
    main()
