"""The evaluation: exact Clopper-Pearson bounds against scipy, the ``evaluate`` and ``render``
subcommands on a tiny run, bad options (exit code 2 with a clear message), and replays of saved episodes.

Compile budget: the module compiles the rollout twice, once for the run's policies (a batch of 1, which the
evaluation, the replays and ``render`` share) and once for the other vehicle policy (the Fig. 5 counterpart).
That a replay alone matches an episode run in a batch of 250 is checked at scale outside the tests (a batch
of another size is another compile); see the evaluation section of BENCHMARKS.md.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from _cli import run_cli as _cli
from scipy import special
from scipy.stats import beta

from stp_env.evaluation import (
    Configuration,
    beta_ppf,
    betainc,
    clopper_pearson_interval,
    clopper_pearson_lower,
    clopper_pearson_upper,
    replay_event,
    resolve_intruder,
    same_outcome,
)
from stp_env.evaluation.report import load_event_state
from stp_env.evaluation.summary import forced_summary
from stp_env.sim import COLLIDED

TINY = ["--scenario", "tiny-intruder", "--kbar", "2", "--intruder", "greedy", "--vehicle-policy", "nominal",
        "--seed", "1", "--no-progress"]
EPISODES = 3


# ------------------------------------------------------------------------------------------------ statistics
@pytest.mark.parametrize("n", [1, 2, 7, 30, 1000, 12345, 10**6])
@pytest.mark.parametrize("confidence", [0.9, 0.95, 0.99])
def test_clopper_pearson_matches_scipy(n, confidence):
    for k in sorted({0, 1, 2, n // 3, n // 2, n - 1, n} - {-1}):
        if k > n:
            continue
        upper = 1.0 if k == n else beta.ppf(confidence, k + 1, n - k)
        lower = 0.0 if k == 0 else beta.ppf(1 - confidence, k, n - k + 1)
        assert clopper_pearson_upper(k, n, confidence) == pytest.approx(upper, rel=1e-9, abs=1e-12)
        assert clopper_pearson_lower(k, n, confidence) == pytest.approx(lower, rel=1e-9, abs=1e-12)
        lo, hi = clopper_pearson_interval(k, n, confidence)
        tail = (1 - confidence) / 2
        assert lo == pytest.approx(0.0 if k == 0 else beta.ppf(tail, k, n - k + 1), rel=1e-9, abs=1e-12)
        assert hi == pytest.approx(1.0 if k == n else beta.ppf(1 - tail, k + 1, n - k), rel=1e-9, abs=1e-12)



def test_the_episode_summary_counts_by_hand_and_bounds_with_scipy():
    """forced_summary, the one summary every evaluator reads, on episodes whose counts are written out."""
    n_forced = np.array([0, 1, 3, 2, 0, 4, 1])                     # k̄ = 2: episodes 2 and 5 exceed, 3 reach it
    collided = np.zeros((7, 4), bool)
    collided[1, [0, 2]] = collided[5, 3] = True                     # 3 vehicles in 2 episodes
    violations = np.array([0, 0, 0, 2, 0, 0, 1])                    # per-episode counts: 3 in 2 episodes
    s = forced_summary(n_forced, 2, collided, violations, confidence=0.9)
    assert (s["episodes"], s["forced_max"], s["exceed"], s["kbar_reached"]) == (7, 4, 2, 3)
    assert (s["collisions"], s["collision_episodes"], s["guarantee_violations"], s["violation_episodes"]) == (
        3, 2, 3, 2)
    assert s["forced_mean"] == pytest.approx(11 / 7) and s["exceed_rate"] == pytest.approx(2 / 7)
    assert s["forced_ci95"] == pytest.approx(1.96 * np.std(n_forced, ddof=1) / np.sqrt(7))
    assert s["exceed_upper"] == pytest.approx(beta.ppf(0.9, 3, 5), rel=1e-9)
    assert s["violation_upper"] == pytest.approx(beta.ppf(0.9, 3, 5), rel=1e-9) and s["confidence"] == 0.9
    one = forced_summary(np.array([1]), 2, np.array([0]), np.array([0]))
    assert one["violation_upper"] == pytest.approx(0.95) and np.isnan(one["forced_ci95"])
    with pytest.raises(ValueError, match="n_forced"):
        forced_summary(np.array([]), 2, np.array([]), np.array([]))
    with pytest.raises(ValueError, match="collisions"):
        forced_summary(n_forced, 2, collided[:3], violations)

def test_the_tracking_error_column_counts_only_vehicles_that_flew_with_kappa():
    """A vehicle still waiting at the end, or already arrived when the episode started, has ``tracked`` set and
    error 0: it must not make a run in which no vehicle tracked (every one flew the ``worst`` policy) report a
    measured 0 m; such a run reports ``n/a``."""
    import types

    from stp_env.evaluation.report import markdown_table
    from stp_env.evaluation.runner import summarize
    from stp_env.sim.types import ARRIVED, WAITING

    ns = types.SimpleNamespace
    params = ns(vehicles=ns(sta=np.array([10.0, 20.0]), bounds=np.array([0.0, 0.0, 0.0, 0.0, 6.0, 0.0])),
                episode=ns(t_start=0.0, t_end=30.0, collision_radius=20.0), tables=ns(tracking_bound=5.0))
    ep = {"n_forced": np.array([0, 0]), "status": np.array([[ARRIVED, WAITING], [ARRIVED, ARRIVED]]),
          "guarantee_violation": np.zeros((2, 2), bool), "collided_with_intruder": np.zeros((2, 2), bool),
          "assumption_ok": np.ones((2, 2), bool), "tracking_violation": np.zeros((2, 2), bool),
          "max_tracking_error": np.array([[3.0, 0.0], [4.5, 7.0]]),
          "tracked": np.array([[True, True], [True, False]]), "arrival_time": np.array([[9.0, np.inf], [9.0, 19.0]]),
          "avoid_start": np.full((2, 2), np.inf), "t_appear": np.zeros(2), "min_separation": np.full((2, 2), 50.0)}
    config = Configuration(scenario="tiny-intruder", kbar=1, intruder="greedy", vehicle_policy="worst")
    assert summarize(config, ep, params)["max_tracking_error_m"] == 4.5    # 7.0 was flown without kappa
    ep["tracked"][:, 0] = False                                            # only the waiting vehicle is left
    summary = summarize(config, ep, params)
    assert summary["max_tracking_error_m"] is None
    assert "| n/a (5.00) |" in markdown_table([summary])
    # nor does a vehicle that was already in its target when the episode started (it flew nothing in it)
    ep["tracked"][1, 1], ep["arrival_time"][1, 1], ep["max_tracking_error"][1, 1] = True, 0.0, 0.0
    assert summarize(config, ep, params)["max_tracking_error_m"] is None
    ep["arrival_time"][1, 1] = 19.0                                        # arrived during the episode: counts
    assert summarize(config, ep, params)["max_tracking_error_m"] == 0.0


def test_rule_of_three_and_betainc():
    # no event in n trials: the 95 % bound is 1 - 0.05^(1/n), about 3/n
    assert clopper_pearson_upper(0, 1000) == pytest.approx(1 - 0.05 ** (1 / 1000), rel=1e-12)
    assert 2.9 / 1000 < clopper_pearson_upper(0, 1000) < 3.0 / 1000
    rng = np.random.default_rng(0)
    for a, b, x in zip(rng.uniform(0.05, 300, 200), rng.uniform(0.05, 300, 200), rng.uniform(0, 1, 200)):
        assert betainc(a, b, x) == pytest.approx(special.betainc(a, b, x), rel=1e-9, abs=1e-14)
    for q in (1e-6, 0.05, 0.5, 0.95):
        assert beta_ppf(q, 3.5, 200.0) == pytest.approx(beta.ppf(q, 3.5, 200.0), rel=1e-9)


@pytest.mark.parametrize("args", [(1, 0), (-1, 5), (6, 5), (1, 5, 1.0), (1, 5, 0.0), (1.5, 5)])
def test_clopper_pearson_rejects_bad_input(args):
    with pytest.raises(ValueError):
        clopper_pearson_upper(*args)


# ------------------------------------------------------------------------------------------------ intruders
def test_resolve_intruder_names_and_import_specs():
    from stp_env.policies import INTRUDERS

    assert resolve_intruder("max-k") is INTRUDERS["max-k"]
    from stp_env.policies.intruders import hover

    # the module's attribute itself: here the bare function, whose record INTRUDERS lists
    assert resolve_intruder("stp_env.policies.intruders:hover") is hover is INTRUDERS["hover"].policy
    # a factory called with the text after '=' (how a checkpoint loader is passed its path)
    assert resolve_intruder("stp_env.evaluation.config:resolve_intruder=greedy") is INTRUDERS["greedy"]
    for bad, message in (("nope", "unknown intruder"), ("learned:no-such-intruder", "unknown intruder"),
                         ("no_such_module_xyz:policy", "cannot import"),
                         ("stp_env.policies.intruders:nope", "has no attribute")):
        with pytest.raises(ValueError, match=message):
            resolve_intruder(bad)


def test_configuration_rejects_bad_fields():
    with pytest.raises(ValueError, match="kbar"):
        Configuration(kbar=0)
    with pytest.raises(ValueError, match="wind"):
        Configuration(wind=-1.0)
    with pytest.raises(ValueError, match="spawn mode"):
        Configuration(spawn_mode="sky")
    assert Configuration(intruder="max-k").effective_spawn_mode == "boundary"
    assert Configuration(intruder="optimal-max-k").effective_spawn_mode == "boundary"
    assert Configuration(intruder="hj").effective_spawn_mode == "outside"


# ------------------------------------------------------------------------------------------------ subcommands
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("evaluation")
    code, stdout, stderr = _cli(["evaluate", *TINY, "--episodes", str(EPISODES), "--batch-size", "1",
                                 "--out", str(out)])
    assert code == 0, stderr
    return out, stdout


@pytest.mark.slow
def test_evaluate_writes_results(tiny_run):
    out, stdout = tiny_run
    assert "| scenario | intruder | vehicles | k̄ |" in stdout
    assert "| tiny-intruder | greedy (outside) | nominal | 2 |" in stdout
    summary = json.loads((out / "results.json").read_text())["configurations"]
    assert len(summary) == 1
    s = summary[0]
    assert s["episodes"] == EPISODES and sum(s["forced_hist"]) == EPISODES
    # the summary agrees with the per-episode final states
    with np.load(out / "episodes.npz") as data:
        label = s["label"]
        n_forced, status = data[f"{label}/n_forced"], data[f"{label}/status"]
        assert list(data[f"{label}/index"]) == list(range(EPISODES))
    assert np.array_equal(np.bincount(n_forced, minlength=len(s["forced_hist"])), s["forced_hist"])
    assert s["collisions"] == int(np.sum(status == COLLIDED))
    assert s["exceed_upper"] == pytest.approx(clopper_pearson_upper(s["exceed"], EPISODES))
    # tightness: how often the bound was reached, and the k-th avoid starts (present exactly when reached)
    assert s["kbar_reached"] == int(np.sum(n_forced >= s["kbar"]))
    assert len(s["avoid_start_kth_median_s"]) == s["kbar"] + 1
    assert [m is not None for m in s["avoid_start_kth_median_s"]] == [
        bool(np.any(n_forced >= k)) for k in range(1, s["kbar"] + 2)]
    # what produced it is recorded: the source hash of the package that ran
    prov = json.loads((out / "results.json").read_text())["provenance"]
    from stp_env.artifacts import CODE_VERSION
    from stp_env.evaluation.report import source_hash

    assert prov["source_hash"] == source_hash() and prov["numerics_code_version"] == CODE_VERSION
    assert prov["git_commit"] is None or re.fullmatch(r"[0-9a-f]{40}(-dirty)?", prov["git_commit"])
    assert not (out / "pieces").exists()  # the finished batches wait there only until the results are written
    assert (out / "results.csv").read_text().count("\n") == 2
    assert (out / "results.md").read_text().startswith("| scenario | intruder |")
    for name in ("forced_histogram.png", "summary.png", "episode.png", "distance_vs_time.png"):
        assert (out / name).stat().st_size > 10_000, name


def test_saved_events_replay(tiny_run):
    out, _ = tiny_run
    records = json.loads((out / "events.json").read_text())
    # vehicles that ignore an intruder flying straight at them collide: the run has events to replay
    assert records and any("collision" in r["kinds"] for r in records)
    for record in records:
        assert record["airborne_only"] is True           # the evaluator's default, replayed the same way
        saved = load_event_state(out / "events.npz", record)
        replayed, traj = replay_event(record)
        assert same_outcome(saved, replayed), record
        assert int(replayed["n_forced"]) == record["n_forced"]
        assert np.flatnonzero(replayed["status"] == COLLIDED).tolist() == record["collided_vehicles"]
        assert traj["x"].shape[0] == record["n_steps"]
        assert record["devices"] == 1                    # one CPU device: the batch was not shared
    # a record of a run whose batches were shared among two devices replays here on one: another program, said so
    with pytest.warns(RuntimeWarning, match="shared among 2 device"):
        replayed, _ = replay_event(dict(records[0], devices=2))
    assert same_outcome(load_event_state(out / "events.npz", records[0]), replayed)


def test_replay_of_any_episode_matches_the_batch(tiny_run):
    """Episode 2 of the run, replayed from (seed, index) outside the evaluator, ends the same."""
    out, _ = tiny_run
    summary = json.loads((out / "results.json").read_text())["configurations"][0]
    with np.load(out / "episodes.npz") as data:
        saved = {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith(summary["label"] + "/")}
    from stp_env.evaluation import build_params, pad_plan, replay

    config = Configuration(scenario="tiny-intruder", kbar=2, intruder="greedy", vehicle_policy="nominal")
    params = build_params([config], progress=False)[0]
    params = pad_plan(params, params.vehicles.nominal_states.shape[1])
    final, _ = replay(1, 2, params, *config.policies(), summary["n_steps"])
    episode = {k: v[2] for k, v in saved.items()}
    assert same_outcome(episode, final)
    other = {k: v[1] for k, v in saved.items()}
    assert not same_outcome(other, final)          # and the comparison can tell episodes apart


@pytest.mark.slow
def test_render_writes_a_small_gif(tiny_run, tmp_path):
    out, _ = tiny_run
    gif = tmp_path / "episode.gif"
    code, stdout, stderr = _cli(["render", "--events", str(out / "events.json"), "--event", "0",
                                 "--frame-dt", "2", "--out", str(gif), "--no-progress"])
    assert code == 0, stderr
    info = json.loads(stdout.strip().splitlines()[-1])
    record = json.loads((out / "events.json").read_text())[0]
    assert info["index"] == record["index"] and info["n_forced"] == record["n_forced"]
    assert info["frames"] > 1
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert 1_000 < gif.stat().st_size < 2_000_000


# ------------------------------------------------------------------------------------------------ bad options
@pytest.mark.parametrize("argv, message", [
    (["evaluate", "--scenario", "nope"], "unknown scenario 'nope'"),
    (["evaluate", "--kbar", "0"], "--kbar: must be an integer in [1, 1000]"),
    (["evaluate", "--episodes", "-5"], "--episodes: must be an integer >= 1"),
    (["evaluate", "--episodes", "many"], "--episodes: expected"),
    (["evaluate", "--intruder", "nope"], "unknown intruder 'nope'"),
    (["evaluate", "--scenario", "town", "--kbar", "7"], "kbar must be one of"),
    (["evaluate", "--confidence", "1.5"], "--confidence: must be a finite number in (0, 1)"),
    (["evaluate", "--spawn-mode", "sky"], "invalid choice: 'sky'"),
    (["render", "--kbar", "0"], "--kbar: must be an integer in [1, 1000]"),
    (["render", "--index", "-1"], "--index: must be an integer >= 0"),
])
def test_bad_options_exit_2(argv, message):
    code, _, stderr = _cli(argv)
    assert code == 2
    assert message in stderr, stderr


def _configs(argv):
    from stp_env import cli

    return cli._evaluation_configs(cli._build_parser().parse_args(["evaluate", *argv]))


def test_evaluate_without_configuration_options_runs_the_default_suite():
    """The main job's default includes a configuration where the bound binds (the crossing with worst vehicles);
    any option that chooses configurations replaces the suite by its cross product; the common options apply to
    every configuration either way."""
    from stp_env.evaluation.config import DEFAULT_SUITE

    suite = _configs([])
    assert suite == list(DEFAULT_SUITE)
    assert [(c.scenario, c.kbar, c.intruder, c.vehicle_policy) for c in suite] == [
        ("town", 1, "max-k", "switching"), ("town", 2, "max-k", "switching"), ("town", 3, "max-k", "switching"),
        ("crossing", 2, "optimal-max-k", "worst")]
    assert {(c.wind, c.wind_model, c.episode) for c in _configs(["--wind", "3", "--wind-model", "gusts",
                                                                 "--episode", "full"])} == {(3.0, "gusts", "full")}
    for argv, expected in [
        (["--kbar", "2"], [("town", 2, "max-k", "switching")]),
        (["--scenario", "crossing"], [("crossing", k, "max-k", "switching") for k in (1, 2, 3)]),
        (["--vehicle-policy", "worst", "--kbar", "1"], [("town", 1, "max-k", "worst")]),
        (["--intruder", "hj", "greedy", "--kbar", "3"], [("town", 3, "hj", "switching"),
                                                        ("town", 3, "greedy", "switching")]),
    ]:
        assert [(c.scenario, c.kbar, c.intruder, c.vehicle_policy) for c in _configs(argv)] == expected, argv


def test_figures_of_a_mixed_suite_name_each_series():
    """Configurations of several scenarios or vehicle policies get distinct legend names (a run of one scenario
    keeps the plain intruder names)."""
    from stp_env.evaluation.plots import _with_series

    town = {"scenario": "town", "intruder": "max-k", "vehicle_policy": "switching"}
    cross = {"scenario": "crossing", "intruder": "max-k", "vehicle_policy": "worst"}
    assert [s["series"] for s in _with_series([town, cross])] == ["town: max-k, switching vehicles",
                                                                  "crossing: max-k, worst vehicles"]
    assert [s["series"] for s in _with_series([town, {**town, "kbar": 2}])] == ["max-k", "max-k"]


def test_render_rejects_a_missing_event(tiny_run):
    out, _ = tiny_run
    code, _, stderr = _cli(["render", "--events", str(out / "events.json"), "--event", "999"])
    assert code == 2 and "record(s)" in stderr


def test_clopper_pearson_is_monotone():
    ups = [clopper_pearson_upper(k, 50) for k in range(51)]
    assert np.all(np.diff(ups) > 0) and ups[-1] == 1.0


def test_source_hash_changes_with_any_source_file(tmp_path, monkeypatch):
    import shutil

    import stp_env
    from stp_env.evaluation import report

    copy = tmp_path / "stp_env"
    shutil.copytree(Path(stp_env.__file__).parent, copy, ignore=shutil.ignore_patterns("data", "__pycache__"))
    monkeypatch.setattr(report, "PACKAGE_ROOT", copy)
    before = report.source_hash()
    assert before == report.source_hash()
    (copy / "sim" / "core.py").write_text((copy / "sim" / "core.py").read_text() + "\n# changed\n")
    assert report.source_hash() != before
    assert report.git_commit() is None  # a copy outside any checkout
