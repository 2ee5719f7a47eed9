"""Sweeps of training runs on the execution seam: one :func:`stp_env.rl.train.train` per seed, each a piece of one
job (:mod:`stp_env.execution`), in this process one after the other or as Ray tasks, one per CPU of a cluster.

The driver builds the training environment's ``EnvParams`` (reachability tables, plans, the buffer table) once and
ships them in the job's context (:func:`stp_env.execution.to_host`): workers do not rebuild them. Run ``s`` writes
everything :func:`~stp_env.rl.train.train` writes into ``<out_dir>/seed-<s>/`` (on a cluster, ``out_dir`` must be a
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


@dataclasses.dataclass(frozen=True)
class SweepContext:
    """What every run of a sweep shares: the training configuration (its ``seed`` and ``out_dir`` are replaced per
    run) and the environment's ``EnvParams`` as host arrays."""

    token: str
    config: object
    params: object


def run_dir(out_dir, seed: int) -> Path:
    """Where the run of ``seed`` writes."""
    return Path(out_dir) / f"seed-{int(seed)}"


def sweep_job(config, seeds, params):
    """The runs of ``seeds`` as a :class:`stp_env.execution.Job` (:func:`sweep_piece`), resumable under
    ``<config.out_dir>/pieces``."""
    from stp_env import execution
    from stp_env.evaluation.report import source_hash

    seeds = tuple(int(s) for s in seeds)
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"a sweep needs distinct seeds; got {seeds!r}.")
    for s in seeds:
        dataclasses.replace(config, seed=s)  # each seed checked (range) before anything runs
    host = execution.to_host(params)
    fingerprint = execution.digest("train-sweep", config.to_json(), list(seeds), host, source_hash())
    return execution.Job(name="train-sweep", function=sweep_piece,
                         context=SweepContext(token=execution.new_token(), config=config, params=host),
                         arguments=seeds, fingerprint=fingerprint, units=tuple(1 for _ in seeds))


def sweep_piece(context: SweepContext, seed) -> dict:
    """The training run of ``seed`` (a piece of :func:`sweep_job`): its evaluation history as one JSON string."""
    from stp_env import execution
    from stp_env.rl.train import train

    config = dataclasses.replace(context.config, seed=int(seed), out_dir=str(run_dir(context.config.out_dir, seed)))
    params = execution.memo(context.token, "params", lambda: execution.to_device(context.params))
    _, history = train(config, params=params)
    return {"history": np.asarray(json.dumps(history, default=float))}


def sweep(config, seeds, *, executor=None, params=None, progress: bool = True) -> dict:
    """Train one intruder per seed of ``seeds`` with ``config`` (a :class:`stp_env.rl.train.TrainConfig`) and
    return ``{seed: evaluation history}``, also written to ``<config.out_dir>/sweep.json`` with the configuration.
    ``executor`` runs the runs (default in this process); ``params``: prebuilt ``EnvParams`` (default
    :func:`stp_env.rl.train.build_params`)."""
    from tqdm.auto import tqdm

    from stp_env import execution
    from stp_env.rl.train import build_params

    executor = execution.check_executor(executor)
    out = Path(config.out_dir)
    if params is None:
        params = build_params(config, progress=progress)
    job = sweep_job(config, seeds, params)
    with tqdm(total=len(job), desc=f"train-intruder sweep ({executor.describe()})", unit="run",
              disable=not progress) as bar:
        pieces = executor.run(job, out_dir=out / "pieces", progress=bar.update)
    histories = {int(s): json.loads(str(p["history"])) for s, p in zip(job.arguments, pieces)}
    write_text(json.dumps({"config": config.to_json(), "seeds": list(job.arguments),
                           "final": {str(s): h[-1] for s, h in histories.items()},
                           "histories": {str(s): h for s, h in histories.items()}}, indent=1, default=float),
               out / "sweep.json")
    return histories
