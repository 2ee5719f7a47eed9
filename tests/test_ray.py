"""The execution seam (``stp_env/execution.py``): jobs of independent pieces run in-process or on Ray with the same
results bit for bit; a dead worker's piece runs again; a killed job resumes from the pieces it wrote; and the
package never imports Ray unless asked.

The Ray tests start a cluster of their own (a head and two worker processes on this machine) and need the ``ray``
extra, which CI installs (``pip install -e '.[dev]'``)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest
from _cli import run_cli

from stp_env import execution
from stp_env.evaluation import Configuration, runner

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
TINY = Configuration(scenario="tiny-intruder", kbar=2, intruder="greedy", vehicle_policy="nominal")
EVALUATION = {"episodes": 5, "seed": 1, "batch_size": 2, "progress": False}  # 3 batches: 2 + 2 + 1 episodes
TIMING = ("seconds", "episodes_per_s")


def _same(a, b, where: str = "") -> None:
    """``a`` and ``b`` equal bit for bit: every array (dtype, shape, bits, NaN where NaN), every number."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (where, sorted(set(a) ^ set(b)))
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, np.generic, jax.Array)):
        x, y = np.asarray(a), np.asarray(b)
        assert x.dtype == y.dtype and x.shape == y.shape, (where, x.dtype, y.dtype, x.shape, y.shape)
        assert x.tobytes() == y.tobytes(), where
    else:
        assert a == b or (a != a and b != b), (where, a, b)


def _same_results(local, other) -> None:
    assert len(local) == len(other)
    for r, s in zip(local, other):
        _same(r.episodes, s.episodes, "episodes")
        _same(r.showcase, s.showcase, "showcase")
        _same(r.events, s.events, "events")
        _same({k: v for k, v in r.summary.items() if k not in TIMING},
              {k: v for k, v in s.summary.items() if k not in TIMING}, "summary")


@pytest.fixture(scope="module")
def local_evaluation():
    return runner.evaluate([TINY], **EVALUATION)


# ------------------------------------------------------------------------------------------------ without Ray
def test_the_package_does_not_import_ray_unless_asked():
    code = ("import sys, stp_env, stp_env.cli, stp_env.execution, stp_env.evaluation, stp_env.falsify.cli, "
            "stp_env.falsify.search, stp_env.survivability.study, stp_env.coobservation.evaluation, "
            "stp_env.rl.sweep\n"
            "stp_env.cli._build_parser()\n"
            "from stp_env import execution\n"
            "execution.executor_for(False, None)\n"
            "assert 'ray' not in sys.modules, sorted(m for m in sys.modules if m.startswith('ray'))\n"
            "print('no ray')")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0 and "no ray" in out.stdout, out.stderr


def test_without_ray_the_options_fail_in_one_line_naming_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # what an environment without the extra gives
    with pytest.raises(ValueError, match=r"pip install 'stp-env\[ray\]'"):
        execution.RayExecutor()
    for argv in (["evaluate", "--scenario", "tiny-intruder", "--kbar", "2", "--ray", "--no-progress"],
                 ["falsify", "--scenario", "tiny", "--ray-address", "127.0.0.1:6379", "--no-progress"]):
        code, stdout, stderr = run_cli([*argv, "--out", str(tmp_path / argv[0])])
        assert code == 2 and stdout == "", (argv, stderr)
        assert stderr.count("\n") == 1 and "pip install 'stp-env[ray]'" in stderr, stderr


def test_jobs_check_their_inputs():
    with pytest.raises(ValueError, match="name"):
        execution.Job(name="a/b", function=_square, context=None, arguments=(1,))
    with pytest.raises(ValueError, match="no piece"):
        execution.Job(name="j", function=_square, context=None, arguments=())
    with pytest.raises(ValueError, match="fingerprint"):
        execution.Job(name="j", function=_square, context=None, arguments=(1,), fingerprint="not hex")
    with pytest.raises(ValueError, match="units"):
        execution.Job(name="j", function=_square, context=None, arguments=(1, 2), units=(1,))
    with pytest.raises(ValueError, match="cannot be resumed"):
        execution.LocalExecutor().run(execution.Job(name="j", function=_square, context=None, arguments=(1,)),
                                      out_dir="x")
    with pytest.raises(ValueError, match="executor must be an Executor"):
        runner.evaluate([TINY], executor="ray", **EVALUATION)
    with pytest.raises(ValueError, match="dtype object"):
        execution.LocalExecutor().run(execution.Job(name="j", function=_objects, context=None, arguments=(1,)))


def _square(context, i):
    return {"x": np.asarray([i * i]), "pid": np.asarray(os.getpid())}


def _objects(context, i):
    return {"x": np.asarray([None])}


@pytest.mark.slow
def test_params_travel_to_workers_exactly():
    """``EnvParams`` as host arrays (what the object store holds) and back: the same tree, dtypes, shapes, weak
    types and bits; a weakly typed leaf stays weak (a program would otherwise compile again)."""
    params = runner.build_params([TINY], progress=False)[0]
    import pickle

    host = pickle.loads(pickle.dumps(execution.to_host(params)))
    leaves = jax.tree.leaves(host)
    assert leaves and all(isinstance(x, execution.HostLeaf) and isinstance(x.array, np.ndarray) for x in leaves)
    back = execution.to_device(host)
    (a, ta), (b, tb) = jax.tree.flatten(params), jax.tree.flatten(back)
    assert ta == tb and len(a) == len(b) > 10
    for x, y in zip(a, b):
        assert x.dtype == y.dtype and x.shape == y.shape and x.weak_type == y.weak_type
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()
    weak = execution.to_device(execution.to_host({"w": jax.numpy.asarray(1.5)}))["w"]
    assert weak.weak_type and float(weak) == 1.5


def _interrupted_at_the_third(piece, calls: list):
    """``piece``, recording its arguments in ``calls``, interrupted (as by Ctrl-C) at its third call."""

    def interrupted(context, argument):
        calls.append(argument)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return piece(context, argument)

    return interrupted


@pytest.mark.slow
def test_a_killed_job_resumes_from_the_pieces_it_wrote(tmp_path, monkeypatch, local_evaluation):
    """An evaluation interrupted in its third batch wrote the first two; run again, it computes only the third and
    gives what an uninterrupted run gives. Another seed is another job: nothing is reused."""
    calls = []
    piece = runner.evaluation_piece
    monkeypatch.setattr(runner, "evaluation_piece", _interrupted_at_the_third(piece, calls))
    with pytest.raises(KeyboardInterrupt):
        runner.evaluate([TINY], pieces_dir=tmp_path, **EVALUATION)
    folders = list(tmp_path.iterdir())
    assert len(folders) == 1 and sorted(p.name for p in folders[0].iterdir()) == ["piece-000000.npz",
                                                                                  "piece-000001.npz"]
    calls.clear()
    monkeypatch.setattr(runner, "evaluation_piece", lambda c, a: (calls.append(a), piece(c, a))[1])
    resumed = runner.evaluate([TINY], pieces_dir=tmp_path, **EVALUATION)
    assert calls == [(0, 4)]                                   # only the batch that had not finished
    _same_results(local_evaluation, resumed)
    calls.clear()
    runner.evaluate([TINY], pieces_dir=tmp_path, **{**EVALUATION, "seed": 2})
    assert len(calls) == 3 and len(list(tmp_path.iterdir())) == 2


def test_an_unreadable_piece_runs_again(tmp_path):
    job = execution.Job(name="squares", function=_square, context=None, arguments=(0, 1, 2), fingerprint="ab" * 16)
    first = execution.LocalExecutor().run(job, out_dir=tmp_path)
    path = execution.piece_path(job.folder(tmp_path), 1)
    path.write_bytes(b"not an archive")
    with pytest.warns(RuntimeWarning, match=str(path.name)):
        again = execution.LocalExecutor().run(job, out_dir=tmp_path)
    assert [int(p["x"][0]) for p in again] == [0, 1, 4] and execution.read_piece(path)["x"][0] == 1
    assert [p["x"].tobytes() for p in first] == [p["x"].tobytes() for p in again]


# ------------------------------------------------------------------------------------------------ on Ray
@pytest.fixture(scope="module")
def ray_executor():
    ray = pytest.importorskip("ray", reason="the ray extra is not installed (pip install 'stp-env[ray]'); CI "
                                            "installs it with the dev extra")
    assert not ray.is_initialized()
    # A head and two worker processes on this machine. The workers import the pieces' functions by name: the
    # package's folder and this test folder on their path (runtime_env: Ray's documented way).
    path = os.pathsep.join(filter(None, [str(ROOT), str(TESTS), os.environ.get("PYTHONPATH")]))
    with warnings.catch_warnings():  # JAX's warning at Ray's fork, which execs at once
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": path, "JAX_PLATFORMS": "cpu"}})
    try:
        yield execution.RayExecutor(max_retries=2)
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_pieces_run_on_two_worker_processes(ray_executor):
    job = execution.Job(name="squares", function=_slow_square, context=None, arguments=tuple(range(6)))
    results = ray_executor.run(job)
    assert [int(r["x"][0]) for r in results] == [i * i for i in range(6)]      # in piece order
    assert len({int(r["pid"]) for r in results}) >= 2 and os.getpid() not in {int(r["pid"]) for r in results}
    assert ray_executor.workers() == 2


def _slow_square(context, i):
    time.sleep(0.3)
    return _square(context, i)


def test_on_ray_a_piece_of_another_job_runs_again(ray_executor, tmp_path):
    """The provenance check is the executor's, on Ray as in-process: a piece of another job in this job's place is
    moved aside and computed again on a worker, with one warning naming it."""
    job = execution.Job(name="squares", function=_square, context=None, arguments=(0, 1, 2), fingerprint="ab" * 16)
    other = dataclasses.replace(job, fingerprint="cd" * 16, function=_cube)
    execution.LocalExecutor().run(other, out_dir=tmp_path / "other")
    folder = job.folder(tmp_path)
    folder.mkdir(parents=True)
    path = execution.piece_path(folder, 2)
    path.write_bytes(execution.piece_path(other.folder(tmp_path / "other"), 2).read_bytes())
    with pytest.warns(RuntimeWarning, match="piece-000002.npz: written by another job"):
        results = ray_executor.run(job, out_dir=tmp_path)
    assert [int(r["x"][0]) for r in results] == [0, 1, 4]


def _cube(context, i):
    return {"x": np.asarray([i ** 3]), "pid": np.asarray(os.getpid())}


@pytest.mark.slow
def test_an_evaluation_on_ray_is_the_in_process_one_bit_for_bit(ray_executor, local_evaluation):
    on_ray = runner.evaluate([TINY], executor=ray_executor, **EVALUATION)
    _same_results(local_evaluation, on_ray)
    assert on_ray[0].summary["episodes"] == EVALUATION["episodes"]


@pytest.mark.slow
def test_a_search_on_ray_is_the_in_process_one_bit_for_bit(ray_executor):
    from stp_env import assembly, sim
    from stp_env.falsify.search import SearchConfig, search
    from stp_env.falsify.tracking import TrackingAttack
    from stp_env.scenarios import make

    params = assembly.params_for(make("town", kbar=2), sim.EnvConfig(wind_model="worst"), progress=False)
    attack = TrackingAttack(base=params, horizon=5.0, segment=1.0, wind="search", wind_segment=1.0)
    config = SearchConfig(budget=60, population=10, restarts=3, batch=10)        # 3 restarts of 2 iterations
    local = search(attack.objective, attack.dim, jax.random.key(3), config)
    on_ray = search(attack.objective, attack.dim, jax.random.key(3), config, executor=ray_executor)
    _same(dataclasses.asdict(local), dataclasses.asdict(on_ray), "search")
    assert local.evaluations == 60 and len(local.values) == 60


def _dies_once(context, argument):
    """The evaluation's piece, except that the first worker to run batch 1 dies (a marker file says it did)."""
    marker, inner = context
    if argument[1] == 2 and not os.path.exists(marker):
        Path(marker).write_text("died")
        os._exit(1)
    return runner.evaluation_piece(inner, argument)


@pytest.mark.slow
def test_a_dead_workers_piece_runs_again_with_the_same_result(ray_executor, tmp_path):
    params = runner.build_params([TINY], progress=False)
    n_steps = max(runner.sim.steps_for(p) for p in params)
    job = runner.evaluation_job([TINY], params, seed=1, episodes=5, batch_size=2, n_steps=n_steps, record=True,
                                airborne_only=True)
    marker = tmp_path / "died"
    dying = dataclasses.replace(job, function=_dies_once, context=(str(marker), job.context))
    on_ray = ray_executor.run(dying)
    assert marker.read_text() == "died"                         # a worker did die in the job
    local = execution.LocalExecutor().run(job)
    _same([{k: v for k, v in p.items() if k != "seconds"} for p in local],
          [{k: v for k, v in p.items() if k != "seconds"} for p in on_ray], "pieces")


def test_the_command_line_options_choose_the_executor(ray_executor):
    from stp_env import cli, cli_kit

    parser = cli._build_parser()
    for argv in (["evaluate", "--ray"], ["falsify", "--ray-address", "auto"], ["survivability", "--ray"],
                 ["coobservation", "--ray"], ["train-intruder", "--seeds", "1", "2", "--ray"]):
        assert isinstance(cli_kit.executor(parser.parse_args(argv)), execution.RayExecutor), argv
    assert isinstance(cli_kit.executor(parser.parse_args(["evaluate"])), execution.LocalExecutor)
    text = json.dumps(vars(parser.parse_args(["falsify", "--ray-address", "10.0.0.1:6379"])), default=str)
    assert '"ray_address": "10.0.0.1:6379"' in text


def _tiny_study():
    from test_survivability import small

    from stp_env.survivability.config import PlannerConfig, StudyConfig, TrafficConfig

    return StudyConfig(n_partial=(3, 6), n_unknown=(4, 20), n_instances=2, mission=small(),
                       traffic=TrafficConfig(reach_km=4), planner=PlannerConfig(n_mc=64, n_survival=64))


def _missions(out):
    from stp_env.survivability.records import read_study

    keys = ("outcome", "reveals", "omega_switch", "n_dp", "windows")
    return {(r["n_partial"], r["n_unknown"], r["instance"], r["policy"]): tuple(r[k] for k in keys)
            for r in read_study(out)}


@pytest.mark.slow
def test_a_survivability_study_on_ray_is_the_in_process_one(ray_executor, tmp_path):
    """The study's groups (instance i of the scenarios with the same N_p) as Ray tasks: the same missions as in
    this process, and the same report (but for its timing)."""
    from stp_env.survivability.report import build_report
    from stp_env.survivability.study import run_study

    config = _tiny_study()
    run_study(config, tmp_path / "local", progress=False)
    run_study(config, tmp_path / "ray", progress=False, executor=ray_executor)
    local, on_ray = _missions(tmp_path / "local"), _missions(tmp_path / "ray")
    assert len(local) == 2 * 2 * 2 * len(config.policies) and local == on_ray
    reports = [build_report(config, tmp_path / w, n_boot=50) for w in ("local", "ray")]
    for r in reports:
        r.pop("timing")
    _same(json.loads(json.dumps(reports[0], default=str)), json.loads(json.dumps(reports[1], default=str)), "report")


@pytest.mark.slow
def test_a_killed_study_resumes_from_the_groups_it_wrote(tmp_path, monkeypatch):
    """A study interrupted in its third group wrote the first two groups' missions; run again, it flies only the
    groups that had not finished, and its missions are those of an uninterrupted study."""
    from stp_env.survivability import study

    config = _tiny_study()
    study.run_study(config, tmp_path / "whole", progress=False)
    calls = []
    piece = study.study_piece
    monkeypatch.setattr(study, "study_piece", _interrupted_at_the_third(piece, calls))
    with pytest.raises(KeyboardInterrupt):
        study.run_study(config, tmp_path / "killed", progress=False)
    assert len(_missions(tmp_path / "killed")) == 2 * 2 * len(config.policies)     # two groups of two scenarios
    calls.clear()
    monkeypatch.setattr(study, "study_piece", lambda c, a: (calls.append(a), piece(c, a))[1])
    study.run_study(config, tmp_path / "killed", progress=False)
    assert calls == [(1, 3, (4, 20)), (1, 6, (4, 20))]
    assert _missions(tmp_path / "killed") == _missions(tmp_path / "whole")
    study.run_study(config, tmp_path / "killed", progress=False)                     # nothing left to fly
    assert len(calls) == 2


def test_the_study_s_worker_option_is_gone(tmp_path):
    """``--worker I/N`` (release 0.1) is refused: ``--ray`` runs one study on every CPU of a cluster."""
    code, _, err = run_cli(["survivability", "--out", str(tmp_path), "--worker", "0/2"])
    assert code == 2 and "--worker" in err, err
    assert not any(tmp_path.iterdir())


def _coobservation_inputs():
    from stp_env.coobservation import threat
    from stp_env.coobservation.cli import resolve_attackers, schedules_for
    from stp_env.coobservation.uav import FormationScenario

    scenario = FormationScenario()
    params = scenario.params(progress=False)
    schedules = {k: scenario.schedule(v) for k, v in schedules_for(scenario, ["secured", "unsecured"], 90.0,
                                                                     progress=False).items()}
    m = max(len(s) for s in schedules.values())
    threats = {k: threat.threat_params(s, scenario.forbidden, scenario.observation_radius, pad_to=m)
               for k, s in schedules.items()}
    return params, threats, resolve_attackers(["reckless"]), (0.0, scenario.duration - 10.0)


@pytest.mark.slow
def test_a_coobservation_evaluation_on_ray_is_the_in_process_one(ray_executor, tmp_path):
    """Two schedules x one attacker x two batches as Ray tasks: the same rows, margins included; a killed local run
    resumes from the batches it wrote."""
    from stp_env.coobservation import evaluation

    params, threats, attackers, window = _coobservation_inputs()
    run = dict(t_window=window, batch=4, seed=3, progress=False)
    local = evaluation.run(params, threats, attackers, 6, **run)
    on_ray = evaluation.run(params, threats, attackers, 6, executor=ray_executor, **run)
    assert [r.episodes for r in local] == [6, 6] and sum(r.attempts for r in local) > 0
    _same([r.as_dict() for r in local], [r.as_dict() for r in on_ray], "rows")
    _same([r.margins for r in local], [r.margins for r in on_ray], "margins")
    fingerprint = evaluation.attackers_digest(["reckless"])
    resumed = evaluation.run(params, threats, attackers, 6, pieces_dir=tmp_path, fingerprint=fingerprint, **run)
    _same([r.as_dict() for r in local], [r.as_dict() for r in resumed], "resumed rows")
    (folder,) = tmp_path.iterdir()
    assert len(list(folder.glob("piece-*.npz"))) == 4
    with pytest.raises(ValueError, match="fingerprint"):
        evaluation.run(params, threats, attackers, 6, pieces_dir=tmp_path, **run)


@pytest.mark.slow
def test_a_training_sweep_on_ray_is_the_in_process_one(ray_executor, tmp_path):
    """Two seeds of a tiny PPO run as Ray tasks: each run's evaluations equal the in-process run's, and each run wrote
    its own folder; the environment's params are built once, by the driver."""
    pytest.importorskip("stable_baselines3", reason="the rl extra is not installed")
    from stp_env.rl.sweep import run_dir, sweep
    from stp_env.rl.train import TrainConfig, build_params

    def config(out):
        return TrainConfig(scenario="tiny-intruder", total_timesteps=64, n_envs=4, n_steps=16, batch_size=64,
                           net_arch=(8,), eval_every=0, eval_episodes=4, checkpoint_every=0, out_dir=str(out),
                           log_formats=("csv",))

    params = build_params(config(tmp_path))
    local = sweep(config(tmp_path / "local"), (1, 2), params=params, progress=False)
    on_ray = sweep(config(tmp_path / "ray"), (1, 2), params=params, executor=ray_executor, progress=False)
    drop = ("seconds", "train_seconds")
    assert set(local) == {1, 2}
    for s in (1, 2):
        assert [{k: v for k, v in r.items() if k not in drop} for r in local[s]] == \
            [{k: v for k, v in r.items() if k not in drop} for r in on_ray[s]], s
        assert (run_dir(tmp_path / "ray", s) / "intruder.npz").exists()
    written = json.loads((tmp_path / "ray" / "sweep.json").read_text())
    assert written["seeds"] == [1, 2] and [r["seed"] for r in written["runs"]] == [1, 2]
    assert written["runs"][0]["final"] == on_ray[1][-1]


def test_a_sweep_grid_runs_every_point_and_refuses_what_it_cannot_vary(tmp_path):
    pytest.importorskip("stable_baselines3", reason="the rl extra is not installed")
    from stp_env.rl.sweep import grid_points, run_dir, sweep
    from stp_env.rl.train import TrainConfig, build_params

    config = TrainConfig(scenario="tiny-intruder", total_timesteps=64, n_envs=4, n_steps=16, batch_size=64,
                         net_arch=(8,), eval_every=0, eval_episodes=4, checkpoint_every=0, out_dir=str(tmp_path),
                         log_formats=("csv",))
    assert grid_points({"n_epochs": [1, 2], "gamma": [0.9]}) == ((("n_epochs", 1), ("gamma", 0.9)),
                                                                  (("n_epochs", 2), ("gamma", 0.9)))
    params = build_params(config)
    with pytest.raises(ValueError, match="cannot vary kbar"):
        sweep(config, (1,), grid={"kbar": [1, 2]}, params=params, progress=False)
    with pytest.raises(ValueError, match="no_such_field"):
        sweep(config, (1,), grid={"no_such_field": [1]}, params=params, progress=False)
    with pytest.raises(ValueError, match="n_epochs"):
        sweep(config, (1,), grid={"n_epochs": [0]}, params=params, progress=False)
    assert not any(tmp_path.iterdir())                                     # refused before anything ran
    runs = sweep(config, (1,), grid={"n_epochs": [1, 2]}, params=params, progress=False)
    assert sorted(runs) == [("n_epochs=1", 1), ("n_epochs=2", 1)]
    for n in (1, 2):
        written = json.loads((run_dir(tmp_path, 1, (("n_epochs", n),)) / "config.json").read_text())
        assert written["n_epochs"] == n and written["seed"] == 1


def test_the_sweep_options_are_checked_before_anything_runs(tmp_path):
    from stp_env.rl.sweep import parse_grid as _parse_grid

    assert _parse_grid(["learning_rate=1e-4,3e-4", "policy=a,b"]) == {"learning_rate": [1e-4, 3e-4],
                                                                        "policy": ["a", "b"]}
    for bad in (["n_epochs"], ["=1"], ["n_epochs="], ["n_epochs=1", "n_epochs=2"]):
        with pytest.raises(ValueError, match="--grid"):
            _parse_grid(bad)
    for argv in (["--grid", "n_epochs=1,2"], ["--ray"]):
        code, _, stderr = run_cli(["train-intruder", *argv, "--out", str(tmp_path / "sweep")])
        assert code == 2 and "--seeds" in stderr and stderr.count("\n") == 1, stderr
    assert not (tmp_path / "sweep").exists() or not any((tmp_path / "sweep").iterdir())


@pytest.mark.slow
def test_a_study_past_its_time_limit_stops_after_the_group_that_passed_it(tmp_path):
    """``max_seconds``: the group that finishes past the limit is written, nothing after it; the same call without
    the limit flies the rest, and the missions are those of an uninterrupted study."""
    from stp_env.survivability import study

    config = _tiny_study()
    study.run_study(config, tmp_path / "limited", progress=False, max_seconds=0.0)
    assert len(_missions(tmp_path / "limited")) == 2 * len(config.policies)        # one group of two scenarios
    study.run_study(config, tmp_path / "limited", progress=False)
    study.run_study(config, tmp_path / "whole", progress=False)
    assert _missions(tmp_path / "limited") == _missions(tmp_path / "whole")
