"""One evaluation in this process against the same evaluation on Ray with 1 and 2 workers on this machine
(:mod:`stp_env.execution`), and what that projects to a 32-core machine.

    python benchmarks/ray_scaling.py [--scenario town] [--kbar 2] [--episodes 1000] [--batch-size 125]
                                     [--cores 32] [--study-instances 16] [--study-levels 50 300]
                                     [--study-n-mc N]

Prints one JSON line. Every case first runs one batch per worker to compile (or load from the persistent
compilation cache) the batch's program and to start the workers (``warmup_s``), then times the whole evaluation
(``seconds``; the same ``episodes`` and batches, the same results bit for bit, which the benchmark checks), and
reports the time spent inside the pieces (``pieces_compute_s``, measured where they ran) and, per piece, the wall
time outside them (``outside_pieces_per_piece_s``: workers x wall time less the pieces' time). The batches are the
pieces: ``piece_s`` is the in-process time of one batch, ``overhead_per_piece_s`` what Ray with one worker adds
per batch outside the pieces over what the in-process run spends there (task dispatch, the params shipped once per
job, the results' transfer). The in-process run is timed again at the end (``in_process_again``): this machine is
shared, and the two in-process times show how much its speed drifted during the run.

The projection for ``cores`` cores assumes ``cores`` workers that each run a batch as fast as one process does here
(one worker per core; this machine's 2 cores are shared with other work, and one process uses both of them when it
runs alone, so a worker per core is slower per batch than the in-process run) and no cost but the measured overhead
per piece: it is a projection from the measured per-piece numbers, not a measurement.

The survivability slice (``survivability``) runs ``--study-instances`` instances of the ``--study-levels`` scenarios
of the paper's mission (the study's defaults: 2,500 Monte Carlo realisations per robustness) in this process and on Ray
with 1 and 2 workers, each after a warm-up study of 2 instances of another seed (workers started, programs
compiled), checks the missions are the same, and projects the paper's 2,401 instances of 36 scenarios
(6 x 2,401 groups) from the in-process time per group the same way.
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


def timed(config, params, episodes: int, batch_size: int, executor, workers: int) -> tuple[dict, object]:
    kwargs = {"batch_size": batch_size, "params": [params], "progress": False, "executor": executor}
    start = time.perf_counter()
    evaluate([config], episodes=batch_size * workers, **kwargs)   # compile / start every worker
    warmup = time.perf_counter() - start
    start = time.perf_counter()
    result = evaluate([config], episodes=episodes, **kwargs)[0]
    seconds = time.perf_counter() - start
    pieces = math.ceil(episodes / batch_size)
    busy = result.summary["seconds"]  # the sum of the batches' own compute times, measured where they ran
    return ({"warmup_s": round(warmup, 2), "seconds": round(seconds, 2),
             "episodes_per_s": round(episodes / seconds, 1), "pieces_compute_s": round(busy, 2),
             "outside_pieces_per_piece_s": round((seconds * workers - busy) / pieces, 3)}, result)


def same(a, b) -> bool:
    return all(np.asarray(a.episodes[k]).tobytes() == np.asarray(b.episodes[k]).tobytes() for k in a.episodes)


def study_slice(instances: int, levels, cores: int, factories, n_mc: int | None = None) -> dict:
    """A slice of the survivability study (the paper's mission, ``levels`` x ``levels`` scenarios, ``instances``
    instances) in this process and with the executor each factory makes: the seconds, the same missions (checked),
    and the same projection from the measured time per group (a group: one instance of the scenarios with one
    N_p)."""
    import tempfile

    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.records import read_study
    from stp_env.survivability.study import run_study, study_groups

    config = StudyConfig(n_partial=levels, n_unknown=levels, n_instances=instances)
    if n_mc is not None:
        config = config.with_overrides(planner=config.planner.with_overrides(n_mc=n_mc, n_survival=min(
            config.planner.n_survival, n_mc // 64 * 64)))
    groups = len(study_groups(config))
    keys = ("n_partial", "n_unknown", "instance", "policy", "outcome", "reveals", "omega_switch", "n_dp", "windows")
    out = {"levels": list(levels), "instances": instances, "groups": groups, "n_mc": config.planner.n_mc}
    missions = {}
    for name, factory in factories:
        executor = factory()
        try:
            with tempfile.TemporaryDirectory() as warm, tempfile.TemporaryDirectory() as tmp:
                # start every worker and compile its programs on other instances (another seed) first
                start = time.perf_counter()
                run_study(config.with_overrides(n_instances=2, seed=config.seed + 1), warm, progress=False,
                          executor=executor)
                warmup = time.perf_counter() - start
                start = time.perf_counter()
                run_study(config, tmp, progress=False, executor=executor)
                out[name] = {"warmup_s": round(warmup, 2), "seconds": round(time.perf_counter() - start, 2)}
                missions[name] = sorted(tuple(r[k] for k in keys) for r in read_study(tmp))
        finally:
            if isinstance(executor, execution.RayExecutor):
                executor.shutdown()
    first = next(iter(missions.values()))
    out["identical_missions"] = all(m == first for m in missions.values())
    group_s = out["in_process"]["seconds"] / groups
    out["group_s"] = round(group_s, 2)
    paper_groups = 6 * 2401
    out["projection"] = {"label": "projection from the measured per-group time, not a measurement", "cores": cores,
                         "groups": paper_groups, "in_process_h": round(paper_groups * group_s / 3600, 2),
                         "ray_h": round(math.ceil(paper_groups / cores) * group_s / 3600, 2)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--kbar", type=int, default=2)
    parser.add_argument("--intruder", default="max-k")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--batch-size", type=int, default=125)
    parser.add_argument("--cores", type=int, default=32, help="the machine the projection is for")
    parser.add_argument("--projected-episodes", type=int, default=10_000)
    parser.add_argument("--study-instances", type=int, default=16,
                        help="instances of the survivability slice (0: no slice)")
    parser.add_argument("--study-levels", type=int, nargs="+", default=[50, 300],
                        help="N_p and N_u of the slice (the grid's ends: its mean cost is near the study's)")
    parser.add_argument("--study-n-mc", type=int, default=None,
                        help="Monte Carlo realisations per robustness in the slice (default: the study's)")
    args = parser.parse_args()
    config = Configuration(scenario=args.scenario, kbar=args.kbar, intruder=args.intruder)
    params = build_params([config], progress=False)[0]
    pieces = math.ceil(args.episodes / args.batch_size)
    out = {"case": "ray_scaling", "scenario": args.scenario, "kbar": args.kbar, "intruder": args.intruder,
           "episodes": args.episodes, "batch_size": args.batch_size, "pieces": pieces,
           "cpus": os.cpu_count(), "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    out["in_process"], local = timed(config, params, args.episodes, args.batch_size, execution.LocalExecutor(), 1)
    identical = True
    for workers in (1, 2):
        executor = execution.RayExecutor(num_cpus=workers)
        try:
            out[f"ray_{workers}_workers"], result = timed(config, params, args.episodes, args.batch_size, executor,
                                                         workers)
        finally:
            executor.shutdown()
        identical = identical and same(local, result)
    # the machine is shared: the in-process run again, after the Ray runs, shows how much its speed drifted
    out["in_process_again"], _ = timed(config, params, args.episodes, args.batch_size, execution.LocalExecutor(), 1)
    t_local, t1, t2 = (out[k]["seconds"] for k in ("in_process", "ray_1_workers", "ray_2_workers"))
    piece_s = t_local / pieces
    # what Ray adds per piece (dispatch, the params shipped once per job, the results' transfer and writing):
    # with one worker, the wall time not spent inside a piece, less the same measure in this process
    overhead = max(out["ray_1_workers"]["outside_pieces_per_piece_s"]
                   - out["in_process"]["outside_pieces_per_piece_s"], 0.0)
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
    if args.study_instances:
        factories = [("in_process", execution.LocalExecutor),
                     *((f"ray_{w}_workers", lambda w=w: execution.RayExecutor(num_cpus=w)) for w in (1, 2))]
        out["survivability"] = study_slice(args.study_instances, tuple(args.study_levels), args.cores, factories,
                                           args.study_n_mc)
    out["loadavg_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
