"""Replanning (Algorithm 4) while the PettingZoo environment runs, against the jittable fallback of eq. 40.

    python examples/replan_in_env.py [--scenario town] [--episodes 20] [--seed 0] [--intruder max-k] [--ray]

Runs the same full-length episodes (same seeds, so the same wind draws and intruder spawns up to the moment the
intruder leaves) twice through ``parallel_env``: vehicles on the switching controller ``u*`` (eq. 38), the
intruder scripted, spawned on a vehicle's avoid boundary. Once with ``replan=False`` (a forced vehicle flies the
fallback of eq. 40 after the intruder leaves, toward its target at top planning speed, with no new STA) and once
with ``replan=True`` (it gets a new STA and plan from :func:`stp_env.planning.replan.replan` and tracks it).
Prints one JSON line per mode: forced vehicles, how many arrived, how many by their (new) STA, collisions,
guarantee violations (:func:`stp_env.evaluation.summary.forced_summary`, with the most forced vehicles in an
episode, the episodes above k̄ and the Clopper-Pearson bound on the violation rate), and the replanning time.
Every episode is a piece of one job of the execution seam (``stp_env/execution.py``): with ``--ray`` they run as
Ray tasks, one per CPU (replanning is host-side level-set work, so episodes in parallel is where the time goes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax
import numpy as np

from stp_env import sim
from stp_env.env import parallel_env
from stp_env.evaluation.summary import forced_summary
from stp_env.policies.intruders import intruder_policy
from stp_env.policies.vehicles import vehicle_policy


def episode(context, ep: int) -> dict:
    """Episode ``ep`` of a run (a piece of the job :func:`run` builds; its keys from ``seed + ep`` alone): per vehicle
    whether it was forced, collided, broke a guarantee, arrived and arrived by its (new) STA, and the replanning
    log's numbers."""
    from stp_env import execution

    scenario, intruder, replan, seed = context.spec
    env, vpol, ipol = execution.memo(context.token, "env", lambda: (
        parallel_env(scenario, sim.EnvConfig(episode="full", spawn_mode="boundary"), replan=replan),
        jax.jit(vehicle_policy("switching")), jax.jit(intruder_policy(intruder))))
    n = env.params.vehicles.n
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
            if a != "intruder" and info["status"] == sim.ARRIVED and not np.isfinite(arrival[int(a[8:])]):
                arrival[int(a[8:])] = info["time"]
    vehicle_infos = [infos[f"vehicle_{i}"] for i in range(n)]
    out = {name: np.array([bool(info[name]) for info in vehicle_infos])
           for name in ("forced", "collision", "guarantee_violation")}
    out["arrived"] = np.isfinite(arrival)
    out["on_time"] = arrival <= np.array([info["sta"] for info in vehicle_infos]) + 1e-6
    done = [r for r in env.replan_log if "error" not in r]
    out["replans"] = np.int64(sum(len(r["vehicles"]) for r in done))
    out["replan_failures"] = np.int64(sum(len(r["vehicles"]) for r in env.replan_log if "error" in r))
    out["replan_seconds"] = np.array([r["seconds"] for r in done], float)
    out["sta_delay_s"] = np.array([s - o for r in done for s, o in zip(r["sta"], r["old_sta"])], float)
    out["kbar"] = np.int64(env.params.intruder.kbar)
    return out


@dataclasses.dataclass(frozen=True)
class Context:
    token: str
    spec: tuple


def run(scenario: str, episodes: int, seed: int, intruder: str, replan: bool, executor=None) -> dict:
    from stp_env import execution

    executor = execution.check_executor(executor)
    job = execution.Job(name="replan-in-env", function=episode,
                        context=Context(token=execution.new_token(), spec=(scenario, intruder, replan, seed)),
                        arguments=tuple(range(episodes)))
    start = time.perf_counter()
    pieces = executor.run(job)
    forced = np.array([p["forced"] for p in pieces])
    totals = {"forced": int(forced.sum()),
              "forced_arrived": int(sum((p["forced"] & p["arrived"]).sum() for p in pieces)),
              "forced_on_time": int(sum((p["forced"] & p["arrived"] & p["on_time"]).sum() for p in pieces)),
              "replans": int(sum(p["replans"] for p in pieces)),
              "replan_failures": int(sum(p["replan_failures"] for p in pieces))}
    seconds = np.concatenate([p["replan_seconds"] for p in pieces])
    delays = np.concatenate([p["sta_delay_s"] for p in pieces])
    summary = forced_summary(forced.sum(axis=1), int(pieces[0]["kbar"]), [p["collision"] for p in pieces],
                             [p["guarantee_violation"] for p in pieces])
    return {"scenario": scenario, "intruder": intruder, "replan": replan, "episodes": episodes, "seed": seed,
            **totals, "collisions": summary["collisions"], "guarantee_violations": summary["guarantee_violations"],
            "forced_max": summary["forced_max"], "episodes_above_kbar": summary["exceed"],
            "violation_episodes_upper": round(summary["violation_upper"], 4),
            "replan_seconds_median": round(float(np.median(seconds)), 2) if len(seconds) else None,
            "replan_seconds_max": round(float(np.max(seconds)), 2) if len(seconds) else None,
            "new_sta_delay_s_median": round(float(np.median(delays)), 1) if len(delays) else None,
            "wall_s": round(time.perf_counter() - start, 1), "executor": executor.describe()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--intruder", default="max-k")
    parser.add_argument("--ray", action="store_true", help="run the episodes as Ray tasks (docs/ray.md)")
    parser.add_argument("--ray-address", default=None, help="the Ray cluster's address (implies --ray)")
    args = parser.parse_args()
    from stp_env.execution import executor_for

    executor = executor_for(args.ray, args.ray_address)
    for replan in (False, True):
        print(json.dumps(run(args.scenario, args.episodes, args.seed, args.intruder, replan, executor)), flush=True)


if __name__ == "__main__":
    main()
