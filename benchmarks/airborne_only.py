"""The evaluator simulating only the vehicles that can fly in the episode window (``airborne_only=True``, the
default; :mod:`stp_env.sim.fleet`) against the whole fleet (the peer, same run, same seeds).

    python benchmarks/airborne_only.py [--episodes 1000] [--batch-size 250] [--cases town crossing city]

Prints one JSON line: per case the vehicles simulated, episodes/s of both, their ratio, the compile time of both
(a warm-up batch), and how far the outcomes agree: the |N^RP| histograms, collisions and guarantee violations,
the forced sets and avoid starts, the episodes whose final states differ (:func:`stp_env.evaluation.same_outcome`:
statuses, flags, forced sets exactly; times and states within 1 mm) and by how much a final position differs. The
control: the whole fleet run again in batches of half the size (another compiled program of the same episodes),
which shows what float rounding alone does to these closed loops.

Cases: ``town`` (k̄ = 2, max-k, ``u*``, trajectories recorded as ``stp-env evaluate`` does), ``crossing`` (k̄ = 2,
optimal-max-k, worst vehicles, recorded: the default suite's binding configuration), ``city`` (the shipped Case 0
plan, 50 vehicles, max-k, not recorded), ``falsify`` (the k̄ attack of ``stp-env falsify``, crossing, k̄ = 2,
max-k intruder: ``--attacks`` random attacks as one batch, whole fleet against airborne vehicles).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from stp_env import assembly
from stp_env.evaluation import Configuration, build_params, evaluate, same_outcome


def case(name: str):
    if name == "town":
        config = Configuration(scenario="town", kbar=2, intruder="max-k")
        return config, build_params([config], progress=False)[0], True
    if name == "crossing":
        config = Configuration(scenario="crossing", kbar=2, intruder="optimal-max-k", vehicle_policy="worst")
        return config, build_params([config], progress=False)[0], True
    if name == "city":
        from stp_env.scenarios import make

        config = Configuration(scenario="city", kbar=3, intruder="max-k")
        return config, assembly.params_for(make("city"), config.env_config(), progress=False), False
    raise ValueError(f"unknown case {name!r}")


def timed(config, params, episodes: int, batch_size: int, record: bool, airborne_only: bool):
    kwargs = {"batch_size": batch_size, "params": [params], "progress": False, "showcase": record,
              "airborne_only": airborne_only}
    start = time.perf_counter()
    evaluate([config], episodes=batch_size, **kwargs)          # compile (and one batch)
    first = time.perf_counter() - start
    start = time.perf_counter()
    result = evaluate([config], episodes=episodes, **kwargs)[0]
    seconds = time.perf_counter() - start
    return result, {"episodes_per_s": round(episodes / seconds, 2), "seconds": round(seconds, 2),
                    "compile_s": round(first - seconds * batch_size / episodes, 1)}


def agreement(a: dict, b: dict) -> dict:
    """How far two runs of the same episodes agree."""
    n = len(a["n_forced"])
    differ = sum(not same_outcome({k: v[i] for k, v in a.items()}, {k: v[i] for k, v in b.items()})
                 for i in range(n))
    moved = np.max(np.linalg.norm(a["x"][..., :2] - b["x"][..., :2], axis=-1), axis=1)
    fa, fb = (np.where(np.isfinite(v), v, 0.0) for v in (a["avoid_start"], b["avoid_start"]))
    return {"same_forced_sets": bool(np.array_equal(np.isfinite(a["avoid_start"]), np.isfinite(b["avoid_start"]))),
            "max_avoid_start_difference_s": round(float(np.max(np.abs(fa - fb))), 3),
            "episodes_differing": differ,
            "episodes_position_difference_over_1m": int(np.sum(moved > 1.0)),
            "episodes_position_difference_over_10m": int(np.sum(moved > 10.0)),
            "max_position_difference_m": round(float(moved.max()), 3)}


def falsify_case(attacks: int) -> dict:
    """The falsifier's k̄ attack (crossing, k̄ = 2, max-k) on ``attacks`` random inputs, one batched program per
    fleet: seconds per batch (compile excluded) and how far the objectives agree."""
    import jax

    from stp_env.falsify.kbar import KbarAttack

    config = Configuration(scenario="crossing", kbar=2, intruder="max-k")
    params = build_params([config], progress=False)[0]
    z = jax.random.uniform(jax.random.key(0), (attacks, 5))
    out, values = {}, {}
    for which in ("whole", "airborne"):
        attack = KbarAttack(base=params, intruder="max-k", fleet=which)
        f = jax.jit(jax.vmap(attack.objective))
        start = time.perf_counter()
        jax.block_until_ready(f(z))
        first = time.perf_counter() - start
        start = time.perf_counter()
        values[which] = np.asarray(f(z * 0.999))
        seconds = time.perf_counter() - start
        out[which] = {"vehicles": attack.params.vehicles.n, "seconds": round(seconds, 2),
                      "compile_s": round(first - seconds, 1)}
    out["ratio"] = round(out["whole"]["seconds"] / out["airborne"]["seconds"], 2)
    out["same_forced"] = bool(np.array_equal(np.floor(values["whole"]), np.floor(values["airborne"])))
    out["max_objective_difference"] = float(np.max(np.abs(values["whole"] - values["airborne"])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=250)
    parser.add_argument("--cases", nargs="+", default=["town", "crossing", "city", "falsify"])
    parser.add_argument("--attacks", type=int, default=256, help="attacks per batch of the falsify case")
    args = parser.parse_args()
    out = {"case": "airborne_only", "episodes": args.episodes, "batch_size": args.batch_size,
           "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    for name in args.cases:
        if name == "falsify":
            out[name] = falsify_case(args.attacks)
            continue
        config, params, record = case(name)
        whole, t_whole = timed(config, params, args.episodes, args.batch_size, record, airborne_only=False)
        part, t_part = timed(config, params, args.episodes, args.batch_size, record, airborne_only=True)
        # the control: the whole fleet in batches of another size (another compiled program, the same episodes)
        other, _ = timed(config, params, args.episodes, args.batch_size // 2, record, airborne_only=False)
        out[name] = {
            "vehicles": params.vehicles.n, "simulated": part.summary["simulated_vehicles"],
            "whole_fleet": t_whole, "airborne_only": t_part,
            "ratio": round(t_part["episodes_per_s"] / t_whole["episodes_per_s"], 2),
            "same_forced_hist": whole.summary["forced_hist"] == part.summary["forced_hist"],
            "forced_hist": part.summary["forced_hist"][:5],
            "collisions": [whole.summary["collisions"], part.summary["collisions"]],
            "guarantee_violations": [whole.summary["guarantee_violations"], part.summary["guarantee_violations"]],
            "airborne_only_vs_whole": agreement(whole.episodes, part.episodes),
            "control_whole_half_batch_vs_whole": agreement(whole.episodes, other.episodes),
        }
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
