"""The traffic-scenario study of the survivability paper (Sections V-VI): every policy flies the mission through the
same traffic instances of every scenario ``(N_p, N_u)``; outcomes are appended to ``missions.csv`` as they finish,
so an interrupted study resumes where it stopped. Its groups of instances are the pieces of one job of the execution
seam (:mod:`stp_env.execution`): in this process, or as Ray tasks on a cluster, with the same missions.

Instances are visited round-robin (instance 0 of every scenario, then instance 1, ...), so a study stopped early
has the same number of instances in every scenario. Instance ``i`` uses the same random streams in every scenario
(see :func:`stp_env.survivability.traffic.sample_traffic`): scenario ``(N_p, N_u)`` contains the intruders of
every smaller scenario's instance ``i``, and all policies fly the same traffic (common random numbers: differences
between policies and between neighbouring scenarios are estimated with much less noise than the rates).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from stp_env.arguments import INT32_MAX
from stp_env.files import atomic_open, write_text
from stp_env.loaders import read_csv_rows, read_json
from stp_env.seeds import check_seed
from stp_env.survivability.config import (
    POLICIES,
    MissionConfig,
    PlannerConfig,
    TrafficConfig,
    _integer,
    _Overrides,
)
from stp_env.survivability.graph import build_graph
from stp_env.survivability.mission import initial_tables, make_instance, run_mission
from stp_env.survivability.network import build_network

LEVELS = (50, 100, 150, 200, 250, 300)
FIELDS = ("n_partial", "n_unknown", "instance", "policy", "outcome", "reveals", "omega_switch", "n_dp", "windows",
          "instance_s", "mission_s")

_ADDED_OPTIONS = (("traffic", "model", "local"), ("traffic", "hover_share", None), ("planner", "nf_count", "landing"),
                  ("planner", "reveal", "segment"), ("planner", "sense_km", None))


@dataclasses.dataclass(frozen=True, kw_only=True)
class StudyConfig(_Overrides):
    """The scenario sweep.

    Attributes:
        n_partial, n_unknown: the scenario grid (paper: {50, ..., 300} each, 36 scenarios).
        n_instances: traffic instances per scenario (paper: 2,500; 2,401 bound every 95 % half-width by 2 %).
        seed: base seed of the traffic, the Monte Carlo realisations and the tie-breaking.
        policies: which of ``R``, ``Nf``, ``S``, ``AvgR`` fly.
        mission, traffic, planner: the configurations (``traffic.n_partial``/``n_unknown`` are set per scenario).
    """

    n_partial: tuple[int, ...] = LEVELS
    n_unknown: tuple[int, ...] = LEVELS
    n_instances: int = 2401
    seed: int = 0
    policies: tuple[str, ...] = POLICIES
    mission: MissionConfig = dataclasses.field(default_factory=MissionConfig)
    traffic: TrafficConfig = dataclasses.field(default_factory=TrafficConfig)
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)

    def __post_init__(self) -> None:
        for name in ("n_partial", "n_unknown"):
            values = tuple(_integer(name, v) for v in getattr(self, name))
            if not values or len(set(values)) != len(values):
                raise ValueError(f"{name} must be a non-empty list of distinct integers; got {values!r}.")
            object.__setattr__(self, name, values)
        _integer("n_instances", self.n_instances, minimum=1)
        object.__setattr__(self, "seed", check_seed(self.seed))  # the one seed function: [0, 2**63 - 1]
        pols = tuple(self.policies)
        if not pols or any(p not in POLICIES for p in pols) or len(set(pols)) != len(pols):
            raise ValueError(f"policies must be distinct names among {', '.join(POLICIES)}; got {pols!r}.")
        object.__setattr__(self, "policies", pols)

    @property
    def scenarios(self) -> list[tuple[int, int]]:
        return [(p, u) for p in self.n_partial for u in self.n_unknown]

    def fingerprint(self) -> dict:
        """What must match for a study directory to be resumed (everything but ``n_instances``)."""
        d = dataclasses.asdict(self)
        d.pop("n_instances")
        # Options added after studies were written are left out at their earlier behaviour, so that those studies
        # resume with the default configuration (and a study with another option never resumes one without).
        for group, name, earlier in _ADDED_OPTIONS:
            if d[group].get(name) == earlier:
                d[group].pop(name)
        return json.loads(json.dumps(d))


def read_study(out) -> list[dict]:
    """Every mission of the study directory ``out`` (``missions.csv`` and the workers' ``missions-*.csv``)."""
    out = Path(out)
    return [r for path in sorted(out.glob("missions*.csv")) for r in read_missions(path)]


_INT_COLUMNS = ("n_partial", "n_unknown", "instance", "reveals", "omega_switch", "n_dp", "windows")


def read_missions(path: Path) -> list[dict]:
    """Rows of one missions file (a trailing partial line from an interrupted write, and any row whose values do not
    parse, is left out). Read under the loader contract (:func:`stp_env.loaders.read_csv_rows`: a regular file of
    at most 1 GiB, lines of at most 1 MiB, the header :data:`FIELDS`): a file that is not one is a one-line
    ``ValueError`` naming it, never a traceback or a wait."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return []
    rows = []
    for row in read_csv_rows(path, "study-missions", FIELDS):
        try:
            ints = {k: int(row[k]) for k in _INT_COLUMNS}
            floats = {k: float(row[k]) for k in ("instance_s", "mission_s")}
        except ValueError:
            continue
        if all(abs(v) <= INT32_MAX for v in ints.values()) and all(math.isfinite(v) for v in floats.values()):
            rows.append({**row, **ints, **floats})
    return rows


def read_study_metadata(path: Path) -> dict:
    """``study.json`` of a study directory: a JSON object with a ``fingerprint`` object (the loader contract,
    :func:`stp_env.loaders.read_json`: a regular file of at most 16 MiB, JSON nested at most 64 levels). Anything
    else is a one-line ``ValueError`` naming the file."""
    meta = read_json(path, "study-metadata")
    if not isinstance(meta, dict) or not isinstance(meta.get("fingerprint"), dict):
        what = f"a JSON {type(meta).__name__}" if not isinstance(meta, dict) else "an object without a fingerprint"
        raise ValueError(f"{path}: not a survivability study file ({what}, expected an object with a 'fingerprint' "
                         "object); remove it or choose another --out.")
    return meta


def completed(rows, policies) -> set[tuple[int, int, int]]:
    """(n_partial, n_unknown, instance) with a row for every policy."""
    seen: dict[tuple[int, int, int], set] = {}
    for r in rows:
        seen.setdefault((r["n_partial"], r["n_unknown"], r["instance"]), set()).add(r["policy"])
    return {key for key, pols in seen.items() if set(policies) <= pols}


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
              worker: tuple[int, int] = (0, 1), executor=None) -> Path:
    """Run (or resume) the study into directory ``out``; returns the path of the missions file written.

    The study is one job of the execution seam (:mod:`stp_env.execution`, :func:`study_job`): a piece is a group of
    instances that share their segment robustness (instance ``i`` of every scenario with the same ``N_p``), and
    ``executor`` runs the pieces (default in this process, in order; a
    :class:`~stp_env.execution.RayExecutor` on a cluster). Each finished group is appended to ``missions.csv`` at
    once, whatever ran it, so a study that was stopped resumes from the groups it wrote; the missions do not depend
    on where or in what order the groups ran (only the rows' order in the file and their timing columns do).

    ``max_seconds``: stop cleanly after this much wall time (the study can be resumed). ``worker = (i, n)``
    (deprecated: run one study with a Ray executor instead): run every ``n``-th group, starting at the ``i``-th,
    into ``missions-{i}of{n}.csv`` (``n`` processes with ``i = 0 .. n - 1`` and the same options share a study)."""
    from stp_env import execution

    i_worker, n_workers = worker
    if not (isinstance(n_workers, int) and n_workers >= 1 and isinstance(i_worker, int) and 0 <= i_worker < n_workers):
        raise ValueError(f"worker must be (i, n) with 0 <= i < n; got {worker!r}.")
    executor = execution.check_executor(executor)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta_path = out / "study.json"
    if meta_path.exists() or meta_path.is_symlink():
        old = read_study_metadata(meta_path)
        if not _same_config(old["fingerprint"], config.fingerprint()):
            raise ValueError(f"{out} holds a study with a different configuration; choose another --out "
                             f"(or the same options as {meta_path}).")
    path = out / ("missions.csv" if n_workers == 1 else f"missions-{i_worker}of{n_workers}.csv")
    rows = read_missions(path)  # every file is read (and refused, if it must be) before anything is written
    done = completed(read_study(out), config.policies)
    _atomic_write(meta_path, json.dumps({"fingerprint": config.fingerprint(),
                                         "n_instances": config.n_instances}, indent=1))
    groups = [g for g in study_groups(config, done) if (g[0] * len(config.n_partial)
                                                         + config.n_partial.index(g[1])) % n_workers == i_worker]
    if not groups:
        return path
    job = study_job(config, groups)
    _repair(path, rows)
    from tqdm.auto import tqdm

    start = time.perf_counter()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        bar = tqdm(total=sum(job.units), disable=not progress, unit="instance", smoothing=0.05,
                   desc=("survivability" if n_workers == 1 else f"survivability {i_worker}/{n_workers}")
                   + ("" if isinstance(executor, execution.LocalExecutor) else f" on {executor.describe()}"))

        def append(index: int, result: dict) -> None:
            i, p, _ = job.arguments[index]
            writer.writerows(piece_rows(result))
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
    """What every piece of a study shares: its configuration, and the token its workers key the graph by (each
    worker builds the graph once, about 1.5 s for the paper's mission: cheaper than shipping its 19 MB)."""

    token: str
    config: StudyConfig


def study_job(config: StudyConfig, groups):
    """The groups ``(instance, N_p, (N_u, ...))`` of a study as a :class:`stp_env.execution.Job` (one piece a
    group; :func:`study_piece`)."""
    from stp_env import execution

    return execution.Job(name="survivability", function=study_piece,
                         context=StudyContext(token=execution.new_token(), config=config),
                         arguments=tuple((int(i), int(p), tuple(int(u) for u in us)) for i, p, us in groups),
                         units=tuple(len(us) for _, _, us in groups))


def study_piece(context: StudyContext, argument) -> dict:
    """Every policy's missions through one group: instance ``i`` of the scenarios ``(N_p, N_u)`` for the ``N_u``
    given (one array per column of :data:`FIELDS`, a row per mission, in the order the study writes them)."""
    from stp_env import execution

    i, p, unknowns = argument
    config = context.config
    graph = execution.memo(context.token, "graph", lambda: build_graph(build_network(config.mission)))
    shared: dict = {}
    rows = [row for u in unknowns for row in run_instance(graph, config, p, u, i, shared)]
    return {name: np.asarray([row[name] for row in rows]) for name in FIELDS}


def piece_rows(result: dict) -> list[dict]:
    """The rows of a piece's result (:func:`study_piece`) as the missions file holds them."""
    columns = [np.asarray(result[name]).tolist() for name in FIELDS]
    return [dict(zip(FIELDS, values)) for values in zip(*columns)]


def _same_config(old, new) -> bool:
    """Equal fingerprints, up to fields added since ``old`` was written that are unset (``None``) in ``new``."""
    if isinstance(old, dict) and isinstance(new, dict):
        extra = set(new) - set(old)
        return (set(old) <= set(new) and all(new[k] is None for k in extra)
                and all(_same_config(old[k], new[k]) for k in old))
    return old == new


def _repair(path: Path, rows) -> None:
    """Rewrite ``missions.csv`` with its valid rows only (drops a torn last line) and the header."""
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def _atomic_write(path: Path, text: str) -> None:
    write_text(text, path)
