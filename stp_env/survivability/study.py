"""The traffic-scenario study of the survivability paper (Sections V-VI): every policy flies the mission through the
same traffic instances of every scenario ``(N_p, N_u)``; outcomes are appended to ``missions.csv`` as they finish,
so an interrupted study resumes where it stopped. Its groups of instances are the pieces of one job of the execution
seam (:mod:`stp_env.execution`): in this process, or as Ray tasks on a cluster, with the same missions.

Instances are visited round-robin (instance 0 of every scenario, then instance 1, ...), so a study stopped early
has the same number of instances in every scenario. Instance ``i`` uses the same random streams in every scenario
(see :func:`stp_env.survivability.traffic.sample_traffic`): scenario ``(N_p, N_u)`` contains the intruders of
every smaller scenario's instance ``i``, and all policies fly the same traffic (common random numbers: differences
between policies and between neighbouring scenarios are estimated with much less noise than the rates).

Every row of a missions file proves which study wrote it: it carries the study's fingerprint (:func:`study_id`) and a
SHA-256 digest of that fingerprint and of the row's values, its key ``(N_p, N_u, instance, policy)`` among them
(:func:`row_digest`). A study resumes from, and reports, only the rows that are its own: its fingerprint, a key of
its scenarios, policies and instances that no earlier row had, the digest recomputed and equal. Any other row (of
another study, edited, of an older format without the fingerprint, beyond the study's instances) is left out with one
warning per file, and the missions it stood for are flown again.

With ``run_study(..., batch_groups=k)``, ``k >= 1``, the missions of a piece (``k`` groups) fly in batches
(:func:`run_groups`): every instance and policy of the piece in one compiled program
(:mod:`stp_env.survivability.batch`), with the missions of the per-mission path (the default, :data:`BATCH_GROUPS`,
:func:`run_instance`), so the rows are the same but for the timing columns.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from stp_env.survivability.config import StudyConfig
from stp_env.survivability.graph import build_graph
from stp_env.survivability.mission import initial_tables, make_instance, run_mission
from stp_env.survivability.names import BATCH_GROUPS
from stp_env.survivability.network import build_network
from stp_env.survivability.records import (
    FIELDS,
    RECORD_FIELDS,
    Provenance,
    _check_missions,
    _Checked,
    _keep_aside,
    _missions_files,
    _repair,
    _warn,
    check_study_metadata,
    completed,
    stamp_rows,
    write_study_metadata,
)


def run_instance(graph, config: StudyConfig, n_partial: int, n_unknown: int, i: int,
                 shared: dict | None = None) -> list[dict]:
    """Every policy's mission through instance ``i`` of scenario ``(n_partial, n_unknown)``. ``shared``: a dict
    kept between calls; instance ``i`` of scenarios with the same ``N_p`` then computes its segment robustness and
    the policies' first tables once (they depend only on the partially known traffic, see
    :func:`stp_env.survivability.mission.make_instance`); the missions are the same as without it."""
    t0 = time.perf_counter()
    traffic = config.traffic.with_overrides(n_partial=n_partial, n_unknown=n_unknown)
    shared = {} if shared is None else shared
    prev = shared.get("instance")
    inst = make_instance(graph, traffic, config.planner, (config.seed, i), reuse=prev)
    key = (config.policies, config.planner.nf_count)
    if prev is not None and inst.robustness is prev.robustness and shared.get("policies") == key:
        first = shared["first"]
    else:
        first = initial_tables(graph, inst, config.policies, config.planner.nf_count)
    shared.update(instance=inst, first=first, policies=key)
    t_inst = time.perf_counter() - t0
    rows = []
    for policy in config.policies:
        t1 = time.perf_counter()
        res = run_mission(graph, inst, policy, config.planner, seed=(config.seed, i), initial_tables=first[policy])
        rows.append({"n_partial": n_partial, "n_unknown": n_unknown, "instance": i, "policy": policy,
                     "outcome": res.outcome, "reveals": len(res.revealed),
                     "omega_switch": -1 if res.omega_switch is None else res.omega_switch, "n_dp": res.n_dp + 1,
                     "windows": len(res.path) - 1, "instance_s": round(t_inst, 4),
                     "mission_s": round(time.perf_counter() - t1, 4)})
    return rows


def run_study(config: StudyConfig, out: str | os.PathLike, *, progress: bool = True, max_seconds=None,
              executor=None, batch_groups: int = BATCH_GROUPS) -> Path:
    """Run (or resume) the study into directory ``out``; returns the path of the missions file written.

    The study is one job of the execution seam (:mod:`stp_env.execution`, :func:`study_job`): a piece is a group of
    instances that share their segment robustness (instance ``i`` of every scenario with the same ``N_p``), and
    ``executor`` runs the pieces (default in this process, in order; a
    :class:`~stp_env.execution.RayExecutor` on a cluster). Each finished group is appended to ``missions.csv`` at
    once, whatever ran it, so a study that was stopped resumes from the groups it wrote; the missions do not depend
    on where or in what order the groups ran (only the rows' order in the file and their timing columns do). It
    resumes only from rows that prove they are its own (the module's docstring): the others are left out with one
    warning per file, and its own missions file is rewritten without them (the file as it was is kept as
    ``missions.csv.rejected-<hex>``, never read again). Every file is read before anything is written.

    ``max_seconds``: stop cleanly after this much wall time (the study can be resumed). The missions of a folder
    are every ``missions*.csv`` in it: the ``missions-{i}of{n}.csv`` of release 0.1's ``worker = (i, n)`` are read
    and resumed from like ``missions.csv``.

    ``batch_groups``: how the missions are flown (default :data:`BATCH_GROUPS`). ``0``: one mission at a time
    (:func:`stp_env.survivability.mission.run_mission`, :func:`run_instance`); ``k >= 1``: in batches, a piece of
    ``k`` groups whose instances and policies fly in one compiled program (:mod:`stp_env.survivability.batch`,
    :func:`run_groups`), with the same missions (only the timing columns differ). The progress bar counts
    instances (rate in instances per second, time left)."""
    from stp_env import execution

    executor = execution.check_executor(executor)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_study_metadata(config, out)
    path = out / "missions.csv"
    provenance = Provenance.of(config)
    seen: set = set()
    # Every file is read (and refused, if it must be) before anything is written.
    checked = [_check_missions(f, provenance, seen) for f in _missions_files(out)]
    own = next((c for c in checked if c.path == path), _Checked(path))
    done = completed([r for c in checked for r in c.rows], config.policies)
    for c in checked:
        problem = c.problem(provenance)
        if c is own and problem is not None:
            problem += _keep_aside(path)
        _warn(problem, c.path)
    write_study_metadata(config, out)
    groups = study_groups(config, done)
    if own.refused or groups:
        # Only this study's rows stay, those of instances whose every policy flew (the others fly again).
        _repair(path, [t for t, r in zip(own.texts, own.rows)
                       if (r["n_partial"], r["n_unknown"], r["instance"]) in done])
    if not groups:
        return path
    job = study_job(config, groups, batch_groups)
    study = provenance.study
    from tqdm.auto import tqdm

    start = time.perf_counter()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, RECORD_FIELDS)
        bar = tqdm(total=sum(job.units), disable=not progress, unit="instance", smoothing=0.05,
                   desc="survivability" + ("" if isinstance(executor, execution.LocalExecutor)
                                           else f" on {executor.describe()}"))

        def append(index: int, result: dict) -> None:
            i, p, _ = piece_groups(job.arguments[index])[-1]
            writer.writerows(stamp_rows(study, piece_rows(result)))
            f.flush()
            os.fsync(f.fileno())
            bar.set_postfix_str(f"instance {i}, N_p = {p}", refresh=False)
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                raise _Deadline

        try:
            with contextlib.suppress(_Deadline):  # max_seconds passed: the groups written so far stay
                executor.run(job, progress=bar.update, on_piece=append)
        finally:
            bar.close()
    return path


class _Deadline(Exception):
    """``max_seconds`` has passed: the study stops after the group that just finished."""


def study_groups(config: StudyConfig, done=frozenset()) -> list[tuple[int, int, tuple[int, ...]]]:
    """The groups of the study still to fly, as ``(instance, N_p, (N_u, ...))``: instance ``i`` of the scenarios with
    the same ``N_p`` (they share the segment robustness), round-robin over the instances (instance 0 of every
    ``N_p``, then instance 1, ...), leaving out the scenarios in ``done``."""
    groups = []
    for i in range(config.n_instances):
        for p in config.n_partial:
            unknowns = tuple(u for u in config.n_unknown if (p, u, i) not in done)
            if unknowns:
                groups.append((i, p, unknowns))
    return groups


@dataclasses.dataclass(frozen=True)
class StudyContext:
    """What every piece of a study shares: its configuration, the token its workers key the graph by (each
    worker builds the graph once, about 1.5 s for the paper's mission: cheaper than shipping its 19 MB) and how
    its missions fly (``batch_groups``, :func:`run_study`: 0 one at a time, else in batches)."""

    token: str
    config: StudyConfig
    batch_groups: int = 0


def study_job(config: StudyConfig, groups, batch_groups: int = 0):
    """The groups ``(instance, N_p, (N_u, ...))`` of a study as a :class:`stp_env.execution.Job` (:func:`study_piece`):
    one piece a group (its argument the group) with ``batch_groups`` 0 or 1, else ``batch_groups`` consecutive
    groups a piece (its argument the tuple of groups). The units are instances."""
    from stp_env import execution

    if not (isinstance(batch_groups, int) and not isinstance(batch_groups, bool) and batch_groups >= 0):
        raise ValueError(f"batch_groups must be an integer >= 0; got {batch_groups!r}.")
    groups = [(int(i), int(p), tuple(int(u) for u in us)) for i, p, us in groups]
    if batch_groups > 1:
        arguments = tuple(tuple(groups[k:k + batch_groups]) for k in range(0, len(groups), batch_groups))
    else:
        arguments = tuple(groups)
    return execution.Job(name="survivability", function=study_piece,
                         context=StudyContext(token=execution.new_token(), config=config, batch_groups=batch_groups),
                         arguments=arguments,
                         units=tuple(sum(len(us) for _, _, us in piece_groups(a)) for a in arguments))


def piece_groups(argument) -> list[tuple[int, int, tuple[int, ...]]]:
    """The groups ``(instance, N_p, (N_u, ...))`` of a piece's argument (one group, or a tuple of groups)."""
    return [argument] if isinstance(argument[0], int) else list(argument)


def study_piece(context: StudyContext, argument) -> dict:
    """Every policy's missions through a piece's groups: instance ``i`` of the scenarios ``(N_p, N_u)`` for the
    ``N_u`` given (one array per column of :data:`FIELDS`, a row per mission, in the order the study writes them),
    one mission at a time (``context.batch_groups`` 0, :func:`run_instance`) or in one batch (:func:`run_groups`)."""
    from stp_env import execution

    config = context.config
    graph = execution.memo(context.token, "graph", lambda: build_graph(build_network(config.mission)))
    groups = piece_groups(argument)
    if context.batch_groups:
        rows = run_groups(graph, config, groups, pad_instances=len(config.n_unknown) * max(context.batch_groups, 1))
    else:
        rows = []
        for i, p, unknowns in groups:
            shared: dict = {}
            rows += [row for u in unknowns for row in run_instance(graph, config, p, u, i, shared)]
    return {name: np.asarray([row[name] for row in rows]) for name in FIELDS}


def run_groups(graph, config: StudyConfig, groups, pad_instances: int | None = None) -> list[dict]:
    """The rows of :func:`run_instance` for every ``(instance, N_p, (N_u, ...))`` of ``groups`` (in that order:
    group by group, ``N_u`` by ``N_u``, policy by policy), flown in batches: the instances drawn with their Monte
    Carlo robustness in one program (:func:`stp_env.survivability.batch.make_instances`; instance ``i`` of the
    scenarios of one ``N_p`` shares it, as ``run_instance``'s ``shared`` does) and every policy's mission through
    all of them in one program (:func:`stp_env.survivability.batch.run_batch`). The missions are those of
    :func:`run_instance` (``tests/test_survivability_batch.py``); the timing columns are the batch's, shared out:
    ``instance_s`` the set-up per instance, ``mission_s`` the missions' time per mission. ``pad_instances``: fly
    at least this many instances (copies of the last, dropped), so that batches of different sizes share one
    compiled program."""
    from stp_env.survivability import batch

    keys, traffics, seeds = [], [], []
    for i, p, unknowns in groups:
        for u in unknowns:
            keys.append((p, u, i))
            traffics.append(config.traffic.with_overrides(n_partial=p, n_unknown=u))
            seeds.append((config.seed, i))
    if not keys:
        return []
    t0 = time.perf_counter()
    instances = batch.make_instances(graph, traffics, config.planner, seeds)
    t_inst = (time.perf_counter() - t0) / len(keys)
    t1 = time.perf_counter()
    missions = batch.run_batch(graph, instances, config.policies, config.planner, seeds, pad_instances=pad_instances)
    t_mission = (time.perf_counter() - t1) / (len(keys) * len(config.policies))
    rows = []
    for (p, u, i), results in zip(keys, missions):
        for policy in config.policies:
            res = results[policy]
            rows.append({"n_partial": p, "n_unknown": u, "instance": i, "policy": policy,
                         "outcome": res.outcome, "reveals": len(res.revealed),
                         "omega_switch": -1 if res.omega_switch is None else res.omega_switch, "n_dp": res.n_dp + 1,
                         "windows": len(res.path) - 1, "instance_s": round(t_inst, 4),
                         "mission_s": round(t_mission, 4)})
    return rows


def piece_rows(result: dict) -> list[dict]:
    """The rows of a piece's result (:func:`study_piece`) as the missions file holds them."""
    columns = [np.asarray(result[name]).tolist() for name in FIELDS]
    return [dict(zip(FIELDS, values)) for values in zip(*columns)]


