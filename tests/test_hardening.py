"""Bad input as a careless user or an attacker would give it: a clear one-line error, and nothing changed.

* Data files never run code: an events file naming a plug-in intruder (``module:attr=ARG``) is refused before any
  work, and nothing it names is imported.
* Every public call validates before it mutates: ``reset`` / ``step`` of the Parallel and AEC APIs (property
  tests over actions, seeds and options: the key, the state and the agents are unchanged after the error, and
  the next outputs are those of an env that never saw the call), and the config constructors.
* Loaders check structure and finiteness: learned-intruder ``.npz`` files, events files, cache entries.
* Outputs: ``--out`` and the cache are checked before computing; an interrupted ``evaluate`` leaves the earlier
  outputs as they were, a finished one leaves no stale outputs beside its own; a killed cache writer leaves no
  temporary file behind after the next use.

The environment fixtures reuse the default scenario's cached artifacts (computed once, about 50 s, on an empty
cache); everything else here is cheap.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib import resources
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _cli import run_cli as _cli
from hypothesis import given, settings
from hypothesis import strategies as st

from stp_env.artifacts import ArtifactStore, StaleArtifactWarning
from stp_env.env import env, parallel_env
from stp_env.evaluation import Configuration, replay_event
from stp_env.sim import EnvConfig, RewardConfig

SHIPPED_INTRUDER = str(resources.files("stp_env") / "data" / "intruders" / "town-kbar2.npz")


def _one_line_error(code, stderr, *needles):
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    for needle in needles:
        assert needle in lines[0], (needle, stderr)


@pytest.fixture
def no_work(monkeypatch):
    """Fails the test if an evaluation, a replay or a parameter build starts."""
    import stp_env.evaluation as evaluation
    from stp_env.evaluation import pipeline, runner

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the input was checked")

    for module in (evaluation, runner, pipeline):
        for name in ("build_params", "evaluate", "replay"):
            if hasattr(module, name):
                monkeypatch.setattr(module, name, forbidden)


# ------------------------------------------------------------------------------------------------ environments
@pytest.fixture(scope="module")
def par():
    return parallel_env()


@pytest.fixture(scope="module")
def aec():
    return env()


def _snapshot(par):
    """Everything a failed call must leave unchanged: the PRNG key, the core state, the live agents, the step."""
    state = jax.tree.map(lambda a: np.asarray(jax.random.key_data(a)) if jnp.issubdtype(a.dtype, jax.dtypes.prng_key)
                         else np.asarray(a), par.env_state)
    key = None if par._key is None else np.asarray(jax.random.key_data(par._key))
    return key, jax.tree.leaves(state), list(par.agents), par._steps


def _same(a, b):
    (ka, sa, aa, na), (kb, sb, ab, nb) = a, b
    return (np.array_equal(ka, kb) and aa == ab and na == nb and len(sa) == len(sb)
            and all(np.array_equal(x, y) for x, y in zip(sa, sb)))


def _zeros(par):
    return {a: np.zeros(2, np.float32) for a in par.agents}


def _next_outputs(par, steps=3):
    out = []
    for _ in range(steps):
        obs, rew, *_ = par.step({a: np.full(2, 0.3, np.float32) for a in par.agents})
        out.append((np.concatenate([obs[a] for a in sorted(obs)]), [rew[a] for a in sorted(rew)]))
    return out


# ---- case 2: a failed reset leaves the random stream (key, state, agents) as it was
@pytest.mark.slow
def test_failed_reset_keeps_the_key_state_and_next_episode(par):
    par.reset(seed=3)
    par.step(_zeros(par))
    before = _snapshot(par)
    with pytest.raises(ValueError, match="appear_time"):
        par.reset(seed=5, options={"appear_time": float("nan")})
    assert _same(before, _snapshot(par))
    after_failure = _next_outputs(par)
    par.reset(seed=3)
    par.step(_zeros(par))
    reference = _next_outputs(par)
    for (o1, r1), (o2, r2) in zip(after_failure, reference):
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2


def _bad_seeds():
    return st.one_of(st.integers(max_value=-1), st.integers(min_value=2**63, max_value=2**80), st.booleans(),
                     st.floats(), st.text(max_size=5), st.just(np.float64(3.0)), st.just(np.bool_(True)),
                     st.just([1, 2]))


def _bad_options(t_start, t_end):
    bad_time = st.one_of(st.floats(allow_nan=True).filter(lambda t: not t_start <= t <= t_end),
                         st.booleans(), st.text(max_size=4), st.none(), st.complex_numbers(), st.just([1.0]),
                         st.just(np.array([t_start, t_start])))
    return st.one_of(bad_time.map(lambda t: {"appear_time": t}), st.lists(st.integers(), max_size=2),
                     st.integers(), st.text(max_size=4))


@settings(max_examples=30)
@given(data=st.data(), use_aec=st.booleans(), bad_seed=st.booleans())
def test_bad_seeds_and_options_raise_and_change_nothing(par, aec, data, use_aec, bad_seed):
    """Property: any unrepresentable seed or bad option raises ``ValueError``; the key, state and agents (and
    for the AEC env its agent selection) are as before."""
    target = aec if use_aec else par
    target.reset(seed=11)
    inner = aec.unwrapped if use_aec else par
    before = _snapshot(inner)
    selection = aec.agent_selection if use_aec else None
    if bad_seed:
        kwargs = {"seed": data.draw(_bad_seeds(), "seed")}
        match = "seed"
    else:
        lo, hi = float(inner.params.episode.t_start), float(inner.params.episode.t_end)
        kwargs = {"seed": 2, "options": data.draw(_bad_options(lo, hi), "options")}
        match = "appear_time|options"
    with pytest.raises(ValueError, match=match):
        target.reset(**kwargs)
    assert _same(before, _snapshot(inner))
    if use_aec:
        assert aec.agent_selection == selection


@settings(max_examples=25)
@given(a=st.integers(0, 2**63 - 1), b=st.integers(0, 2**63 - 1))
def test_distinct_seeds_give_distinct_keys(a, b):
    from stp_env.seeds import prng_key

    same = np.array_equal(jax.random.key_data(prng_key(a)), jax.random.key_data(prng_key(b)))
    assert same == (a == b)
    if a < 2**32:  # small seeds keep JAX's own key (shipped numbers are unchanged)
        assert np.array_equal(jax.random.key_data(prng_key(a)), jax.random.key_data(jax.random.key(a)))


@settings(max_examples=25)
@given(a=st.integers(0, 2**63 - 1), b=st.integers(0, 2**63 - 1))
def test_rl_env_seeds_are_not_truncated_either(a, b):
    """The Gymnasium/SB3 envs' raw keys: the same data as :func:`stp_env.seeds.prng_key`, checked the same way."""
    from stp_env.rl import key_for_seed
    from stp_env.seeds import prng_key

    assert np.array_equal(key_for_seed(a), jax.random.key_data(prng_key(a)))
    assert np.array_equal(key_for_seed(a), key_for_seed(b)) == (a == b)
    for bad in (-1, 2**63, 1.0, True):
        with pytest.raises(ValueError, match="seed"):
            key_for_seed(bad)


def test_seeds_are_not_truncated(par):
    """``2**32 + 5`` is accepted, so it must be another episode than ``5``."""
    par.reset(seed=5)
    key_a, state_a, *_ = _snapshot(par)
    par.reset(seed=2**32 + 5)
    key_b, state_b, *_ = _snapshot(par)
    assert not np.array_equal(key_a, key_b)
    assert not all(np.array_equal(x, y) for x, y in zip(state_a, state_b))


def _bad_actions():
    finite = st.floats(-5, 5)
    return st.one_of(
        st.text(max_size=4), st.booleans(), st.complex_numbers(), st.floats(),
        st.lists(st.booleans(), min_size=2, max_size=2),
        st.tuples(finite, st.text(max_size=3)), st.tuples(st.none(), finite), st.just(object()),
        st.lists(finite, max_size=4).filter(lambda v: len(v) != 2),
        st.tuples(finite, st.sampled_from([np.nan, np.inf, -np.inf])),
        st.tuples(finite, finite).map(lambda v: np.asarray(v, np.complex64)),
        st.tuples(finite, finite).map(lambda v: [list(v)]),
        st.integers(min_value=10**30).map(lambda i: [i, 0]),
    )


@settings(max_examples=40)
@given(action=_bad_actions(), which=st.integers(0, 7))
def test_bad_actions_raise_naming_the_agent_and_change_nothing(par, action, which):
    par.reset(seed=1)
    before = _snapshot(par)
    agent = par.possible_agents[which % len(par.possible_agents)]
    actions = _zeros(par) | {agent: action}
    with pytest.raises(ValueError, match=repr(agent)):
        par.step(actions)
    assert _same(before, _snapshot(par))


# ---- case 3: the AEC env rejects a bad action at its agent's own step, and does not wedge
def test_aec_rejects_a_bad_action_at_its_own_step_and_goes_on(aec):
    aec.reset(seed=0)
    agent = aec.agent_selection
    before = _snapshot(aec.unwrapped)
    with pytest.raises(ValueError, match=f"{agent!r}.*not finite"):
        aec.step(np.array([np.nan, 0.0], np.float32))
    assert aec.agent_selection == agent and _same(before, _snapshot(aec.unwrapped))
    for _ in range(len(aec.agents)):  # one full cycle of good actions goes through
        aec.step(None if (aec.terminations[aec.agent_selection] or aec.truncations[aec.agent_selection])
                 else np.zeros(2, np.float32))
    assert aec.unwrapped._steps == 1


@settings(max_examples=25)
@given(action=_bad_actions(), position=st.integers(0, 7))
def test_aec_bad_actions_property(aec, action, position):
    """Property: at any position in a cycle, a bad action raises at once, names the agent, leaves the agent
    selection, the buffered actions and the core state as they were, and a good action then goes through."""
    aec.reset(seed=4)
    for _ in range(position):
        aec.step(np.zeros(2, np.float32))
    agent = aec.agent_selection
    before, buffered = _snapshot(aec.unwrapped), dict(aec.env._actions)
    with pytest.raises(ValueError, match=repr(agent)):
        aec.step(action)
    assert aec.agent_selection == agent and _same(before, _snapshot(aec.unwrapped))
    assert aec.env._actions.keys() == buffered.keys()
    aec.step(np.zeros(2, np.float32))


def test_step_after_the_episode_does_not_advance_the_core():
    short = parallel_env(max_cycles=2)
    short.reset(seed=0)
    while short.agents:
        short.step({})
    before = _snapshot(short)
    with pytest.raises(RuntimeError, match="episode is over"):
        short.step({})
    assert _same(before, _snapshot(short))


def test_appearance_window_outside_the_episode_is_refused():
    with pytest.raises(ValueError, match="appearance window"):
        parallel_env(config=EnvConfig(appear_window=(-500.0, -400.0)))


# ------------------------------------------------------------------------------------------------ configs
_FIELDS = {
    EnvConfig: {
        "dt": st.one_of(st.floats(max_value=0.0), st.just(np.nan), st.text(max_size=3), st.booleans()),
        "appear_window": st.one_of(st.integers(), st.text(max_size=3), st.tuples(st.floats(1, 2)),
                                   st.tuples(st.floats(5, 9), st.floats(0, 4)),
                                   st.tuples(st.just(np.nan), st.floats())),
        "wind_model": st.one_of(st.none(), st.integers(), st.text(max_size=4)),
        "spawn_mode": st.one_of(st.none(), st.just(["outside"])),
        "safety_filter": st.one_of(st.integers(), st.none(), st.text(max_size=3)),
        "n_nearest": st.one_of(st.integers(max_value=-1), st.floats(), st.booleans()),
        "rewards": st.one_of(st.none(), st.integers(), st.dictionaries(st.text(max_size=3), st.floats())),
        "lead": st.one_of(st.floats(max_value=-1e-3), st.just(np.inf)),
    },
    RewardConfig: {"progress": st.one_of(st.just(np.nan), st.text(max_size=3), st.none(), st.complex_numbers()),
                   "collision": st.one_of(st.just(-np.inf), st.booleans())},
    Configuration: {
        "scenario": st.one_of(st.none(), st.integers(), st.just("")),
        "kbar": st.one_of(st.integers(max_value=0), st.floats(), st.booleans(), st.text(max_size=2)),
        "intruder": st.one_of(st.none(), st.integers(), st.just(""), st.lists(st.text(max_size=2), max_size=2)),
        "wind": st.one_of(st.floats(max_value=-1e-3), st.just(np.nan), st.booleans(), st.text(max_size=2)),
        "wind_model": st.one_of(st.none(), st.text(max_size=3)),
        "vehicle_policy": st.one_of(st.none(), st.text(max_size=3)),
        "episode": st.one_of(st.none(), st.integers(), st.text(max_size=3)),
    },
}


@settings(max_examples=60)
@given(data=st.data(), cls=st.sampled_from(list(_FIELDS)))
def test_config_constructors_refuse_bad_fields_by_name(data, cls):
    name = data.draw(st.sampled_from(sorted(_FIELDS[cls])), "field")
    value = data.draw(_FIELDS[cls][name], "value")
    with pytest.raises(ValueError, match=name):
        cls(**{name: value})


# ------------------------------------------------------------------------------------------------ events files
def _event(intruder="greedy", **changes):
    record = {"config": {"scenario": "tiny-intruder", "kbar": 2, "intruder": intruder, "vehicle_policy": "nominal"},
              "seed": 1, "index": 0, "n_steps": 100, "plan_samples": 100, "batch_size": 1, "recorded": True,
              "npz_prefix": "0/"}
    record.update(changes)
    return record


# ---- case 1: an events file never runs code
def test_events_file_naming_code_is_refused_before_any_work(tmp_path, no_work):
    marker = tmp_path / "pwned"
    spec = f"os:system=touch {marker}"
    events = tmp_path / "events.json"
    events.write_text(json.dumps([_event(spec)]))
    gif = tmp_path / "x.gif"
    code, _, stderr = _cli(["render", "--events", str(events), "--event", "0", "--out", str(gif), "--no-progress"])
    _one_line_error(code, stderr, "plug-in", str(events))
    with pytest.raises(ValueError, match="plug-in"):
        replay_event(_event(spec))
    assert not marker.exists() and not gif.exists()


def test_replaying_an_event_never_imports_what_it_names(tmp_path, monkeypatch):
    """Even when everything else about the record is fine (here: the parameter build is stubbed), the named
    module is not imported and the command is not run."""
    from types import SimpleNamespace

    from stp_env.evaluation import replays

    marker = tmp_path / "pwned"
    params = SimpleNamespace(vehicles=SimpleNamespace(nominal_states=np.zeros((1, 100, 3))),
                             episode=SimpleNamespace(t_start=jnp.asarray(0.0), t_end=jnp.asarray(9.9),
                                                     dt=jnp.asarray(0.1)))
    monkeypatch.setattr(replays, "build_params", lambda *a, **k: [params])
    monkeypatch.setattr(replays, "replay", lambda *a, **k: pytest.fail("replayed an event naming code"))
    with pytest.raises(ValueError) as err:
        replay_event(_event(f"os:system=touch {marker}"))
    assert not marker.exists()
    assert "plug-in" in str(err.value)


def test_a_plugin_spec_typed_on_the_command_line_is_used(tmp_path, monkeypatch):
    """The user may replay such an event by typing the spec: then it is theirs, not the file's."""
    from stp_env.evaluation import replays
    from stp_env.policies import hover

    spec = "stp_env.policies.intruders:hover"
    events = tmp_path / "events.json"
    events.write_text(json.dumps([_event(spec)]))
    seen = {}

    def fake_prepare(record, *, intruder_policy=None, **kwargs):
        seen["policy"] = intruder_policy
        raise ValueError("stop here")

    monkeypatch.setattr(replays, "prepare_event", fake_prepare)
    code, _, stderr = _cli(["render", "--events", str(events), "--intruder", spec, "--out", str(tmp_path / "a.gif")])
    assert code == 2 and "stop here" in stderr and seen["policy"] is hover
    code, _, stderr = _cli(["render", "--events", str(events), "--intruder", "hj", "--out", str(tmp_path / "a.gif")])
    _one_line_error(code, stderr, "differs")


@pytest.mark.parametrize("content, needle", [
    (None, "no such events file"),
    ("{not json", "invalid JSON"),
    ('{"a": 1}', "expected a list"),
    ("[5]", "record 0"),
    (json.dumps([_event(seed=-1)]), "seed"),
    (json.dumps([_event(seed=True)]), "seed"),
    (json.dumps([_event(index=1.5)]), "index"),
    (json.dumps([_event(recorded="yes")]), "recorded"),
    (json.dumps([_event(airborne_only=1)]), "airborne_only"),
    (json.dumps([_event(batch_size=10**9)]), "batch_size"),
    (json.dumps([_event(devices=0)]), "devices"),
    (json.dumps([_event(devices="2")]), "devices"),
    (json.dumps([_event(config={"scenario": "tiny-intruder", "evil": 1})]), "unknown config field"),
    (json.dumps([_event(config={"scenario": "tiny-intruder", "kbar": "2"})]), "kbar"),
    (json.dumps([_event(intruder="nope")]), "unknown intruder"),
    (json.dumps([{k: v for k, v in _event().items() if k != "seed"}]), "missing field"),
])
def test_malformed_events_files_get_one_line_errors(tmp_path, no_work, content, needle):
    events = tmp_path / "events.json"
    if content is not None:
        events.write_text(content)
    code, _, stderr = _cli(["render", "--events", str(events), "--out", str(tmp_path / "a.gif")])
    _one_line_error(code, stderr, str(events), needle)


def test_event_sizes_are_checked_against_the_configuration():
    from stp_env.evaluation.events import check_replay_sizes

    class Params:
        class episode:
            t_start, t_end, dt = jnp.asarray(0.0), jnp.asarray(9.9), jnp.asarray(0.1)

        class vehicles:
            nominal_states = np.zeros((2, 50, 3))

    check_replay_sizes(_event(n_steps=100, plan_samples=50), Params)
    with pytest.raises(ValueError, match="n_steps"):
        check_replay_sizes(_event(n_steps=10**7, plan_samples=50), Params)
    with pytest.raises(ValueError, match="plan_samples"):
        check_replay_sizes(_event(n_steps=100, plan_samples=10**7), Params)


def test_event_states_are_read_without_pickle(tmp_path):
    from stp_env.evaluation.events import load_event_state

    np.savez(tmp_path / "ok.npz", **{"0/x": np.zeros(3)})
    assert set(load_event_state(tmp_path / "ok.npz", {"npz_prefix": "0/"})) == {"x"}
    np.savez(tmp_path / "obj.npz", **{"0/x": np.asarray([{"a": 1}], dtype=object)})
    for path, record, needle in ((tmp_path / "obj.npz", {"npz_prefix": "0/"}, "obj.npz"),
                                 (tmp_path / "ok.npz", {"npz_prefix": 5}, "npz_prefix"),
                                 (tmp_path / "none.npz", {"npz_prefix": "0/"}, "no such")):
        with pytest.raises(ValueError, match=needle):
            load_event_state(path, record)


# ------------------------------------------------------------------------------------------------ learned policies
def _policy_arrays():
    with np.load(SHIPPED_INTRUDER) as data:
        return {k: data[k].copy() for k in data.files}


# ---- case 4: NaN weights are rejected at load, naming the file
def test_nan_weights_are_rejected_at_load_naming_the_file(tmp_path, no_work):
    from stp_env.policies.learned import load_intruder

    arrays = _policy_arrays()
    arrays["w1"][3, 4] = np.nan
    path = tmp_path / "nan-intruder.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=r"nan-intruder\.npz.*non-finite"):
        load_intruder(str(path))
    code, _, stderr = _cli(["evaluate", "--scenario", "tiny-intruder", "--kbar", "2", "--intruder",
                            f"learned:{path}", "--out", str(tmp_path / "ev"), "--no-progress"])
    _one_line_error(code, stderr, str(path), "non-finite")


def _write_policy(path, **changes):
    arrays = _policy_arrays()
    for name, value in changes.items():
        if value is None:
            arrays.pop(name)
        else:
            arrays[name] = value
    np.savez(path, **arrays)


@pytest.mark.parametrize("changes, needle", [
    ({"metadata": np.asarray("[1, 2]")}, "not an object"),
    ({"metadata": np.asarray('{"format_version": 1, "activation": "tanh", "n_layers": "3"}')}, "n_layers"),
    ({"metadata": np.asarray('{"format_version": 1, "activation": "gelu", "n_layers": 3}')}, "activation"),
    ({"w2": None}, "missing"),
    ({"b0": np.zeros(7, np.float32)}, "layer 0"),
    ({"w1": np.zeros((64, 64), np.complex64)}, "w1"),
    ({"b2": np.full(2, np.inf, np.float32)}, "non-finite"),
    ({"w2": np.zeros((3, 64), np.float32), "b2": np.zeros(3, np.float32)}, "has 3 outputs"),
])
def test_learned_policy_files_are_checked(tmp_path, changes, needle):
    from stp_env.policies.learned import load_mlp

    path = tmp_path / "policy.npz"
    _write_policy(path, **changes)
    with pytest.raises(ValueError, match=needle) as err:
        load_mlp(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("kind", ["text", "npy", "missing", "pickle"])
def test_a_learned_file_that_is_not_an_exported_policy_gets_one_line(tmp_path, no_work, kind):
    path = tmp_path / "bad.npz"
    if kind == "text":
        path.write_text("hello")
    elif kind == "npy":
        with open(path, "wb") as fh:
            np.save(fh, np.zeros(3))
    elif kind == "pickle":
        np.savez(path, metadata=np.asarray([{"a": 1}], dtype=object))
    code, _, stderr = _cli(["evaluate", "--scenario", "tiny-intruder", "--intruder", f"learned:{path}", "--out",
                            str(tmp_path / "ev"), "--no-progress"])
    _one_line_error(code, stderr, str(path))


# ------------------------------------------------------------------------------------------------ outputs
def _readonly_dir(tmp_path):
    """A directory in which no file can be created (``/proc/self`` when running as root)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if not os.access(ro, os.W_OK):
        return ro
    if Path("/proc/self").is_dir():
        return Path("/proc/self")
    pytest.skip("no read-only directory available")


# ---- case 5: --out and the cache are checked before computing
@pytest.mark.parametrize("where", ["readonly", "file", "below-a-file"])
def test_evaluate_checks_out_before_computing(tmp_path, no_work, where):
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    out = {"readonly": _readonly_dir(tmp_path), "file": a_file, "below-a-file": a_file / "sub"}[where]
    code, _, stderr = _cli(["evaluate", "--scenario", "tiny-intruder", "--kbar", "2", "--episodes", "1",
                            "--out", str(out), "--no-progress"])
    _one_line_error(code, stderr, "--out", str(out))


def test_an_unwritable_cache_is_reported_before_computing(tmp_path, monkeypatch):
    not_a_dir = tmp_path / "cache-file"
    not_a_dir.write_text("x")
    monkeypatch.setenv("STP_ENV_CACHE_DIR", str(not_a_dir))
    calls = []

    def compute():
        calls.append(1)
        return {"x": np.zeros(3)}

    with pytest.raises(OSError, match="STP_ENV_CACHE_DIR") as err:
        ArtifactStore().load_or_compute("thing", {"a": 1}, compute)
    assert str(not_a_dir) in str(err.value) and not calls
    # the command line: one line naming the variable, before the avoid region is computed
    import stp_env.hj as hj

    monkeypatch.setattr(hj, "solve", lambda *a, **k: pytest.fail("computed before checking the cache"))
    code, _, stderr = _cli(["render", "--scenario", "tiny-intruder", "--intruder", "hover", "--cache-dir",
                            str(not_a_dir), "--out", str(tmp_path / "a.gif"), "--no-progress"])
    _one_line_error(code, stderr, "STP_ENV_CACHE_DIR", str(not_a_dir))


def _fake_results():
    from stp_env.evaluation.runner import ConfigResult

    summary = {"label": "fake", "scenario": "town", "intruder": "hover", "spawn_mode": "outside",
               "vehicle_policy": "switching", "kbar": 2, "scenario_wind_mps": 6.0,
               "wind_model": "uniform", "episodes": 1, "forced_mean": 0.0, "forced_max": 0, "exceed": 0,
               "exceed_upper": 0.95, "confidence": 0.95, "collisions": 0, "intruder_collisions": 0,
               "guarantee_violations": 0, "tracking_violations": 0, "max_tracking_error_m": 0.0,
               "tracking_bound_m": 5.0, "on_time_rate": None, "min_separation_m": None, "forced_hist": [1]}
    return [ConfigResult(config=Configuration(), seed=0, n_steps=1, plan_samples=1,
                         episodes={"n_forced": np.zeros(1, int)}, summary=summary, events=[], showcase=None)]


OLD_OUTPUTS = ("results.json", "results.csv", "results.md", "events.json", "events.npz", "episodes.npz",
               "forced_histogram.png", "summary.png")


def _old_run(out):
    out.mkdir()
    for name in OLD_OUTPUTS:
        (out / name).write_text("old")
    (out / "notes.txt").write_text("mine")


def test_an_interrupted_evaluate_leaves_the_earlier_outputs(tmp_path, monkeypatch):
    from stp_env.evaluation import pipeline, plots

    out = tmp_path / "ev"
    _old_run(out)
    monkeypatch.setattr(pipeline, "evaluate", lambda *a, **k: _fake_results())

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(plots, "plot_forced_histograms", interrupted)
    with pytest.raises(KeyboardInterrupt):
        pipeline.run([Configuration()], out, episodes=1, progress=False)
    assert sorted(p.name for p in out.iterdir()) == sorted([*OLD_OUTPUTS, "notes.txt"])
    assert all((out / name).read_text() == "old" for name in OLD_OUTPUTS)


def test_a_finished_evaluate_leaves_no_stale_outputs(tmp_path, monkeypatch):
    from stp_env.evaluation import pipeline

    out = tmp_path / "ev"
    _old_run(out)
    monkeypatch.setattr(pipeline, "evaluate", lambda *a, **k: _fake_results())
    result = pipeline.run([Configuration()], out, episodes=1, progress=False, figures=False)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(["results.json", "results.csv", "results.md", "events.json", "events.npz",
                            "episodes.npz", "notes.txt"])  # the old figures are gone, the user's file stays
    assert json.loads((out / "results.json").read_text())["configurations"][0]["label"] == "fake"
    assert sorted(Path(f).name for f in result["files"]) == sorted(n for n in names if n != "notes.txt")


# ---- case 6: a cache entry that is valid JSON but not the expected object is recomputed with a warning
@pytest.mark.parametrize("metadata", ["[]", "null", '"text"', "5", {"arrays": 5}, {"shapes": "x"},
                                      {"arrays": ["x", 3]}, {"shapes": {"x": [1, 2]}}, {"content_sha256": None}])
def test_a_cache_entry_of_the_wrong_structure_is_recomputed(tmp_path, metadata):
    store = ArtifactStore(tmp_path)
    params = {"n": 3}
    store.save("thing", params, {"x": np.arange(3.0)})
    _, json_path, _ = store.paths("thing", params)
    if isinstance(metadata, dict):  # a valid entry with one field replaced
        metadata = json.dumps(json.loads(json_path.read_text()) | metadata)
    json_path.write_text(metadata)
    with pytest.warns(StaleArtifactWarning, match="Recomputing thing"):
        art = store.load_or_compute("thing", params, lambda: {"x": np.arange(3.0)})
    assert not art.from_cache and np.array_equal(art.arrays["x"], np.arange(3.0))
    assert store.load("thing", params).from_cache


def test_non_finite_values_that_were_not_computed_are_recomputed(tmp_path):
    store = ArtifactStore(tmp_path)
    store.save("thing", {"n": 1}, {"x": np.arange(3.0), "padded": np.asarray([1.0, np.nan])})
    assert store.load("thing", {"n": 1}).from_cache  # NaN where the computation put it is kept
    npz_path, json_path, _ = store.paths("thing", {"n": 1})
    np.savez(npz_path, x=np.asarray([0.0, np.nan, 2.0]), padded=np.asarray([1.0, np.nan]))
    meta = json.loads(json_path.read_text())
    from stp_env.artifacts import _file_sha256

    json_path.write_text(json.dumps(meta | {"content_sha256": _file_sha256(npz_path)}))
    with pytest.warns(StaleArtifactWarning, match="non-finite"):
        assert store.load("thing", {"n": 1}) is None


def test_a_killed_cache_writer_leaves_no_temporary_file(tmp_path):
    """A writer killed in the middle of saving (here: it exits from inside ``np.savez``) leaves a temporary file;
    the next use of the cache removes it, and the artifact is computed and saved."""
    script = (
        "import os, sys, numpy as np\n"
        "from stp_env.artifacts import ArtifactStore\n"
        "real = np.savez\n"
        "def dying(*args, **kwargs):\n"
        "    real(*args, **kwargs)\n"
        "    os._exit(9)\n"
        "np.savez = dying\n"
        "ArtifactStore(sys.argv[1]).save('thing', {'n': 1}, {'x': np.zeros(3)})\n"
    )
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path)], cwd=Path(__file__).parents[1],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 9, proc.stderr
    assert len(list(tmp_path.iterdir())) == 1  # the dead writer's temporary file
    art = ArtifactStore(tmp_path).load_or_compute("thing", {"n": 1}, lambda: {"x": np.zeros(3)})
    assert not art.from_cache
    npz_path, json_path, _ = ArtifactStore(tmp_path).paths("thing", {"n": 1})
    # and the artifact's lock file (empty, kept: processes sharing the cache coordinate on it)
    assert sorted(tmp_path.iterdir()) == sorted([npz_path, json_path, npz_path.with_suffix(".lock")])


def test_temporary_files_of_live_writers_are_kept(tmp_path):
    from stp_env.files import TEMP_PREFIX, remove_stale_temporaries, writer_tag

    mine = tmp_path / f"{TEMP_PREFIX}{writer_tag()}abc.npz"
    mine.write_text("in progress")
    other_host = tmp_path / f"{TEMP_PREFIX}1-some_other_host-abc.npz"
    other_host.write_text("x")
    assert remove_stale_temporaries(tmp_path) == []
    assert mine.exists() and other_host.exists()


# ------------------------------------------------------------------------------------------------ other CLI input
def test_render_refuses_an_unwritable_out_before_computing(tmp_path, no_work):
    code, _, stderr = _cli(["render", "--scenario", "tiny-intruder", "--out", str(tmp_path / "no" / "x.gif")])
    _one_line_error(code, stderr, "--out", "does not exist")
    code, _, stderr = _cli(["render", "--scenario", "tiny-intruder", "--out", str(tmp_path)])
    _one_line_error(code, stderr, "--out", "is a directory")


@pytest.mark.parametrize("seed", ["-1", str(2**63), "1.5"])
def test_cli_seeds_are_checked(no_work, seed):
    code, _, stderr = _cli(["evaluate", "--seed", seed])
    assert code == 2 and "--seed" in stderr


def test_results_written_atomically_are_as_readable_as_plainly_written_files(tmp_path):
    """The temporary file behind an atomic write is private (0o600); the result moved into place gets the
    permissions a plain ``open`` would give (here 0o644 under umask 022), not the temporary's."""
    from stp_env.files import atomic_open, write_text

    old = os.umask(0o022)
    try:
        (tmp_path / "plain.json").write_text("{}")
        write_text("{}", tmp_path / "atomic.json")
        with atomic_open(tmp_path / "results.csv", newline="") as fh:
            fh.write("a,b\n")
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {"plain.json": 0o644, "atomic.json": 0o644, "results.csv": 0o644}
