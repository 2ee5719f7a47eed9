"""One evaluation in this process against the same evaluation on Ray with 1 and 2 workers on this machine
(:mod:`stp_env.execution`), and what that projects to a 32-core machine.

    python benchmarks/ray_scaling.py [--scenario town] [--kbar 2] [--episodes 1000] [--batch-size 125]
                                     [--cores 32]

Prints one JSON line. Every case first runs one batch per worker to compile (or load from the persistent
compilation cache) the batch's program and to start the workers (``warmup_s``), then times the whole evaluation
(``seconds``; the same ``episodes`` and batches, the same results bit for bit, which the benchmark checks). The
batches are the pieces: ``piece_s`` is the in-process time of one batch, ``overhead_per_piece_s`` what Ray with
one worker adds per batch (task dispatch, the results' transfer, the params shipped once per job, spread over its
batches). The projection assumes ``cores`` workers that each run a batch as fast as one process does here (one
worker per core; this machine's 2 cores are shared with other work, and one process uses both of them when it runs
alone, so a worker per core is slower per batch than the in-process run) and no other cost: it is a projection from
the measured per-piece numbers, not a measurement.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from stp_env import execution
from stp_env.evaluation import Configuration, build_params, evaluate


def timed(config, params, episodes: int, batch_size: int, executor, workers: int) -> tuple[dict, list]:
    kwargs = {"batch_size": batch_size, "params": [params], "progress": False, "executor": executor}
    start = time.perf_counter()
    evaluate([config], episodes=batch_size * workers, **kwargs)   # compile / start every worker
    warmup = time.perf_counter() - start
    start = time.perf_counter()
    result = evaluate([config], episodes=episodes, **kwargs)[0]
    seconds = time.perf_counter() - start
    return ({"warmup_s": round(warmup, 2), "seconds": round(seconds, 2),
             "episodes_per_s": round(episodes / seconds, 1)}, result)


def same(a, b) -> bool:
    return all(np.asarray(a.episodes[k]).tobytes() == np.asarray(b.episodes[k]).tobytes() for k in a.episodes)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--kbar", type=int, default=2)
    parser.add_argument("--intruder", default="max-k")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=125)
    parser.add_argument("--cores", type=int, default=32, help="the machine the projection is for")
    parser.add_argument("--projected-episodes", type=int, default=10_000)
    args = parser.parse_args()
    import ray

    config = Configuration(scenario=args.scenario, kbar=args.kbar, intruder=args.intruder)
    params = build_params([config], progress=False)[0]
    pieces = math.ceil(args.episodes / args.batch_size)
    out = {"case": "ray_scaling", "scenario": args.scenario, "kbar": args.kbar, "intruder": args.intruder,
           "episodes": args.episodes, "batch_size": args.batch_size, "pieces": pieces,
           "cpus": os.cpu_count(), "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    out["in_process"], local = timed(config, params, args.episodes, args.batch_size, execution.LocalExecutor(), 1)
    identical = True
    for workers in (1, 2):
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(
                     filter(None, [execution._package_path(), os.environ.get("PYTHONPATH")]))}})
        try:
            out[f"ray_{workers}_workers"], result = timed(config, params, args.episodes, args.batch_size,
                                                         execution.RayExecutor(), workers)
        finally:
            ray.shutdown()
        identical = identical and same(local, result)
    t_local, t1, t2 = (out[k]["seconds"] for k in ("in_process", "ray_1_workers", "ray_2_workers"))
    piece_s = t_local / pieces
    overhead = max(t1 - t_local, 0.0) / pieces
    out.update(identical_results=identical, ratio_ray1_over_in_process=round(t1 / t_local, 3),
               ratio_ray2_over_in_process=round(t2 / t_local, 3), speedup_ray2_over_ray1=round(t1 / t2, 3),
               piece_s=round(piece_s, 3), overhead_per_piece_s=round(overhead, 3))
    projected_pieces = math.ceil(args.projected_episodes / args.batch_size)
    rounds = math.ceil(projected_pieces / args.cores)
    projected = rounds * (piece_s + overhead)
    out["projection"] = {
        "label": "projection from the measured per-piece numbers, not a measurement",
        "cores": args.cores, "episodes": args.projected_episodes, "pieces": projected_pieces,
        "in_process_s": round(projected_pieces * piece_s, 1), "ray_s": round(projected, 1),
        "speedup": round(projected_pieces * piece_s / projected, 1),
        "ideal_speedup": min(args.cores, projected_pieces)}
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
