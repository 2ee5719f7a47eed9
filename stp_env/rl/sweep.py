"""Sweeps of training runs on the execution seam: one :func:`stp_env.rl.train.train` per seed and point of a grid
of settings, each a piece of one job (:mod:`stp_env.execution`), in this process one after the other or as Ray
tasks, one per CPU of a cluster.

Plain Ray tasks, not Ray Tune: a sweep here is a fixed list of runs whose results are compared afterwards (every
run to its end, its held-out evaluations in ``sweep.json``), which is exactly a job of independent pieces; Tune's
schedulers stop runs early by how the others are doing, which makes a run's result depend on timing, and its
searchers choose the next point from the finished ones, which makes the sweep depend on their order.

The driver builds the training environment's ``EnvParams`` (reachability tables, plans, the buffer table) once and
ships them in the job's context (:func:`stp_env.execution.to_host`): workers do not rebuild them (a grid may
therefore not change what they depend on: the scenario, k̄, vehicle policy, spawn mode or rewards). Run ``s`` of
point ``p`` writes everything :func:`~stp_env.rl.train.train` writes into ``<out_dir>/<p>/seed-<s>/`` (``<p>``:
``name=value,...``; ``<out_dir>/seed-<s>/`` without a grid; on a cluster, ``out_dir`` must be a
folder every node writes to: ``docs/ray.md``); its piece returns its evaluation history, which the driver gathers
into ``<out_dir>/sweep.json``. A run is a function of its configuration and seed alone (torch on
``torch_threads`` CPU threads, JAX keys from the seed), so where it ran does not change it on machines of the same
kind; a sweep that was killed resumes: the seeds whose runs finished are read back, not trained again.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from stp_env.files import write_text

ENVIRONMENT_FIELDS = ("scenario", "kbar", "vehicle_policy", "spawn_mode", "wind_model", "backend", "control_dt",
                      "avoid_margin", "forced_reward", "collision_reward", "shaping_reward", "kbar_reward", "horizon",
                      "observation", "clone")
"""What the shipped ``EnvParams`` depend on (or the env built from them): a grid may not vary these."""


@dataclasses.dataclass(frozen=True)
class SweepContext:
    """What every run of a sweep shares: the training configuration (its ``seed``, ``out_dir`` and the grid's
    fields are replaced per run), the grid's points and the environment's ``EnvParams`` as host arrays."""

    token: str
    config: object
    points: tuple
    params: object


def grid_points(grid: dict | None) -> tuple[tuple[tuple[str, object], ...], ...]:
    """Every combination of ``grid`` (``{field: [values]}``) as a tuple of ``(field, value)`` pairs, in the grid's
    order (one empty point without a grid)."""
    import itertools

    if not grid:
        return ((),)
    if not isinstance(grid, dict) or any(not isinstance(v, (list, tuple)) or not v for v in grid.values()):
        raise ValueError(f"a grid maps field names to non-empty lists of values; got {grid!r}.")
    bad = sorted(set(grid) & set(ENVIRONMENT_FIELDS))
    if bad:
        raise ValueError(f"a sweep's grid cannot vary {', '.join(bad)}: the environment is built once for the whole "
                         "sweep; run one sweep per setting instead.")
    names = list(grid)
    return tuple(tuple(zip(names, values)) for values in itertools.product(*(grid[n] for n in names)))


def point_name(point) -> str:
    """The folder of a grid point: ``name=value,...`` (empty without a grid)."""
    return ",".join(f"{k}={v}" for k, v in point)


def run_dir(out_dir, seed: int, point=()) -> Path:
    """Where the run of ``seed`` at grid ``point`` writes."""
    base = Path(out_dir) / point_name(point) if point else Path(out_dir)
    return base / f"seed-{int(seed)}"


def run_config(config, point, seed: int):
    """The configuration of one run (``TypeError``/``ValueError`` for a field or value the config refuses)."""
    return dataclasses.replace(config, **dict(point), seed=int(seed),
                               out_dir=str(run_dir(config.out_dir, seed, point)))


def sweep_job(config, seeds, params, grid: dict | None = None):
    """The runs of every grid point and seed as a :class:`stp_env.execution.Job` (:func:`sweep_piece`; argument
    ``(point index, seed)``), resumable under ``<config.out_dir>/pieces``."""
    from stp_env import execution
    from stp_env.evaluation.report import source_hash

    seeds = tuple(int(s) for s in seeds)
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"a sweep needs distinct seeds; got {seeds!r}.")
    points = grid_points(grid)
    for point in points:
        for s in seeds:
            try:
                run_config(config, point, s)  # every run's settings checked before anything runs
            except TypeError as err:
                raise ValueError(f"grid point {point_name(point)!r}: {err}") from None
    host = execution.to_host(params)
    fingerprint = execution.digest("train-sweep", config.to_json(), [[list(p) for p in pt] for pt in points],
                                   list(seeds), host, source_hash())
    return execution.Job(name="train-sweep", function=sweep_piece,
                         context=SweepContext(token=execution.new_token(), config=config, points=points, params=host),
                         arguments=tuple((i, s) for i in range(len(points)) for s in seeds), fingerprint=fingerprint)


def sweep_piece(context: SweepContext, argument) -> dict:
    """One training run (a piece of :func:`sweep_job`): its evaluation history as one JSON string."""
    from stp_env import execution
    from stp_env.rl.trainers import train

    index, seed = (int(a) for a in argument)
    config = run_config(context.config, context.points[index], seed)
    params = execution.memo(context.token, "params", lambda: execution.to_device(context.params))
    _, history = train(config, params=params)
    return {"history": np.asarray(json.dumps(history, default=float))}


def sweep(config, seeds, *, grid: dict | None = None, executor=None, params=None, progress: bool = True) -> dict:
    """Train one intruder per seed of ``seeds`` and point of ``grid`` (``{TrainConfig field: [values]}``, e.g.
    ``{"learning_rate": [1e-4, 3e-4]}``) with ``config`` (a :class:`stp_env.rl.train.TrainConfig`) and return
    ``{seed: history}`` without a grid, ``{(point name, seed): history}`` with one; also written to
    ``<config.out_dir>/sweep.json`` with the configuration. ``executor`` runs the runs (default in this process);
    ``params``: prebuilt ``EnvParams`` (default :func:`stp_env.rl.train.build_params`)."""
    from tqdm.auto import tqdm

    from stp_env import execution
    from stp_env.rl.train import build_params

    executor = execution.check_executor(executor)
    out = Path(config.out_dir)
    if params is None:
        params = build_params(config, progress=progress)
    job = sweep_job(config, seeds, params, grid)
    points = job.context.points
    with tqdm(total=len(job), desc=f"train-intruder sweep ({executor.describe()})", unit="run",
              disable=not progress) as bar:
        pieces = executor.run(job, out_dir=out / "pieces", progress=bar.update)
    from stp_env.loaders import parse_json

    runs = [(point_name(points[i]), s, parse_json(str(p["history"]), out / "pieces", "training run's history"))
            for (i, s), p in zip(job.arguments, pieces)]
    write_text(json.dumps({"config": config.to_json(), "seeds": list(dict.fromkeys(s for _, s, _ in runs)),
                           "grid": {k: list(v) for k, v in (grid or {}).items()},
                           "runs": [{"point": name, "seed": s, "dir": str(run_dir(out, s, points[i])),
                                     "final": h[-1], "history": h}
                                    for (i, _), (name, s, h) in zip(job.arguments, runs)]},
                          indent=1, default=float), out / "sweep.json")
    if not grid:
        return {s: h for _, s, h in runs}
    return {(name, s): h for name, s, h in runs}
