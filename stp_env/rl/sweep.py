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
from collections import Counter
from pathlib import Path

import numpy as np

from stp_env.arguments import INT32_MAX, check_int, check_real
from stp_env.files import write_text
from stp_env.resources import (
    EPISODE_BYTES,
    MAX_N_ENVS,
    check_count,
    check_memory,
    check_sweep,
    cpu_limit_reason,
    max_cpu_threads,
)

ENVIRONMENT_FIELDS = ("scenario", "kbar", "vehicle_policy", "spawn_mode", "wind_model", "backend", "control_dt",
                      "avoid_margin", "forced_reward", "collision_reward", "shaping_reward", "kbar_reward", "horizon",
                      "observation", "clone")
"""What the shipped ``EnvParams`` depend on (or the env built from them): a grid may not vary these."""


# ---------------------------------------------------------------------------------------- the command line's grid
def _real(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False):
    return lambda value, name: check_real(value, name, lo, hi, lo_open=lo_open)


def _integer(lo: int, hi: int | None = INT32_MAX):
    return lambda value, name: check_int(value, name, lo, hi)


GRID_CHECKS = {
    "learning_rate": _real(1e-9, 1.0),
    "gamma": _real(0.0, 1.0, lo_open=True),
    "gae_lambda": _real(0.0, 1.0, lo_open=True),
    "clip_range": _real(0.0, lo_open=True),
    "ent_coef": _real(0.0),
    "log_std_init": _real(-20.0, 5.0),
    "total_timesteps": _integer(1),
    "n_envs": lambda value, name: check_memory(name, check_int(value, name, 1, MAX_N_ENVS),
                                               unit_bytes=EPISODE_BYTES, unit="environment"),
    "n_steps": _integer(1),
    "batch_size": _integer(1),
    "n_epochs": _integer(1, 1000),
    "torch_threads": lambda value, name: check_count(name, value, limit=max_cpu_threads(), why=cpu_limit_reason()),
    "clone_steps": _integer(1),
    "clone_rounds": _integer(0),
    "clone_epochs": _integer(1),
    "eval_every": _integer(0),
    "eval_episodes": _integer(1),
    "eval_seed": _integer(0, 2**32 - 1),
    "checkpoint_every": _integer(0),
}
"""The range of every numeric training setting a ``--grid`` may vary (those with an option have the option's):
``learning_rate`` in ``[1e-9, 1]``, ``gamma`` and ``gae_lambda`` in ``(0, 1]``, ``clip_range > 0``,
``ent_coef >= 0``, counts positive integers (``clone_rounds``, ``eval_every``, ``checkpoint_every`` and
``eval_seed`` from 0), ``n_envs`` and ``torch_threads`` within the machine (:mod:`stp_env.resources`)."""

GRID_FIXED = {"seed": "--seeds sweeps the seed", "out_dir": "every run writes under --out"}
"""Training settings a ``--grid`` cannot vary, and why (besides those the environment depends on,
:data:`stp_env.rl.sweep.ENVIRONMENT_FIELDS`)."""


def _hashable(value):
    """``value`` (a JSON value) as a key under which equal values (``1`` and ``1.0``) are equal."""
    if isinstance(value, list):
        return tuple(_hashable(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _hashable(v)) for k, v in value.items()))
    return value


def parse_grid(items) -> dict:
    """``["learning_rate=1e-4,3e-4", ...]`` as ``{"learning_rate": [0.0001, 0.0003]}`` (each value a JSON number,
    boolean or list when it reads as one, else a string). Refused with one line naming the item: a name with spaces
    around it, a field given twice, a value given twice or empty, a field a sweep cannot vary (:data:`GRID_FIXED`),
    a numeric setting outside its range (:data:`GRID_CHECKS`); the configuration checks the other values."""
    from stp_env.loaders import parse_json

    grid: dict[str, list] = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not name.strip() or not values.strip():
            raise ValueError(f"--grid takes FIELD=V1,V2,...; got {item!r}.")
        if any(c.isspace() for c in name):
            raise ValueError(f"--grid {item!r}: the field name {name!r} has spaces; write FIELD=V1,V2,... with the "
                             "field's name alone.")
        if name in grid:
            raise ValueError(f"--grid: {name} given twice (give all its values in one --grid {name}=V1,V2,...).")
        if name in GRID_FIXED:
            raise ValueError(f"--grid {item!r}: a sweep cannot vary {name} ({GRID_FIXED[name]}).")
        parsed, seen = [], set()
        for text in values.split(","):
            text = text.strip()
            if not text:
                raise ValueError(f"--grid {item!r}: an empty value.")
            try:  # a number, boolean or null when it reads as one (the configuration checks the value)
                value = parse_json(text, "--grid", "grid value")
            except ValueError:
                value = text
            check = GRID_CHECKS.get(name)
            if check is not None:
                try:
                    check(value, name)
                except ValueError as err:
                    raise ValueError(f"--grid {name}={text}: {err}") from None
            key = _hashable(value)
            if key in seen:
                raise ValueError(f"--grid {item!r}: the value {text} is given twice.")
            seen.add(key)
            parsed.append(value)
        grid[name] = parsed
    return grid


def check_sweep_size(seeds, grid: dict) -> None:
    """Distinct ``--seeds``, and at most :data:`stp_env.resources.MAX_SWEEP_RUNS` runs (seeds times grid points);
    one-line ``ValueError`` otherwise."""
    repeated = sorted(s for s, n in Counter(seeds).items() if n > 1)
    if repeated:
        raise ValueError(f"--seeds: {', '.join(map(str, repeated[:5]))} given twice; every run needs its own seed.")
    points = 1
    for values in grid.values():
        points *= len(values)
    check_sweep(len(seeds) * points, f"--seeds ({len(seeds)}) times --grid ({points:,} points)")


def check_grid_fields(grid: dict, config_type) -> None:
    """Every ``--grid`` field a field of ``config_type`` (the training configuration) that a sweep may vary."""
    fields = {f.name for f in dataclasses.fields(config_type)}
    for name in grid:
        if name not in fields:
            raise ValueError(f"--grid: {name!r} is not a training setting; fields: "
                             f"{', '.join(sorted(fields - set(GRID_FIXED) - set(ENVIRONMENT_FIELDS)))}.")
        if name in ENVIRONMENT_FIELDS:
            raise ValueError(f"--grid {name}: a sweep cannot vary {name} (the environment, built once for the whole "
                             "sweep, depends on it).")


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
