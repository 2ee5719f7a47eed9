"""No silent wait: every long-running command says what it is doing before its first artifact build or compilation
(stp_env/progress.py). The checks record an order of events, never a wall-clock time: what the command wrote to
standard error, each compilation request JAX makes (jax.monitoring) and each artifact computation the store starts;
a command is stopped at its first compilation or artifact build, when the order is known."""

from __future__ import annotations

import contextlib
import sys
import traceback

import jax
import numpy as np
import pytest
from jax import monitoring

from stp_env import artifacts, progress
from stp_env.cli import main

COMPILE_EVENT = "/jax/compilation_cache/compile_requests_use_cache"  # recorded before every compile or cache load


class Stop(Exception):
    """Raised at the first compilation or artifact build: the order of events is known by then."""


class Recorder:
    def __init__(self, stop: bool = True):
        self.events: list[tuple[str, str]] = []
        self.stop = stop
        self.active = False

    def write(self, text: str) -> int:  # standard error
        if self.active and text.strip():
            self.events.append(("progress", text.strip()))
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False

    def heavy(self, kind: str, what: str = "") -> None:
        if not self.active:
            return
        self.events.append((kind, what))
        if self.stop:
            self.active = False
            raise Stop(kind)

    def first(self, kind: str) -> int:
        return next(i for i, (k, _) in enumerate(self.events) if k == kind)


_LISTENING: list[Recorder] = []


def _importing() -> bool:
    """Inside an import: a module-level constant (``jnp.asarray`` at import) compiles a tiny program there; an
    import is not a wait the command could announce (it has not parsed its arguments yet)."""
    return any(frame.filename.startswith("<frozen importlib") for frame in traceback.extract_stack())


def _on_event(event: str, **kwargs) -> None:
    if event == COMPILE_EVENT and _LISTENING and not _importing():
        _LISTENING[-1].heavy("compile")


monitoring.register_event_listener(_on_event)


@pytest.fixture
def recorder(monkeypatch, tmp_path):
    """Standard error and the heavy events in one ordered list; an empty artifact and compilation cache, so that
    a command meets its artifact builds and compilations where a new user would."""
    from stp_env import compilation_cache

    rec = Recorder()
    original = artifacts.ArtifactStore._computing

    def computing(self, kind, params):
        rec.heavy("artifact", kind)
        return original(self, kind, params)

    monkeypatch.setattr(artifacts.ArtifactStore, "_computing", computing)
    monkeypatch.setenv("STP_ENV_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv(progress.ENV_VAR, "1")  # as in a terminal (the recorder is not one)
    before = jax.config.jax_compilation_cache_dir
    compilation_cache.configure(directory=tmp_path / "xla")  # nothing compiled yet there: every program is new
    jax.clear_caches()
    _LISTENING.append(rec)
    try:
        yield rec
    finally:
        _LISTENING.remove(rec)
        rec.active = False
        compilation_cache.configure(directory=before) if before else compilation_cache.disable()


@contextlib.contextmanager
def recording(rec: Recorder):
    """Standard error into ``rec`` (set in the test itself: pytest's capture sets ``sys.stderr`` at each phase)."""
    saved = sys.stderr
    sys.stderr = rec
    rec.active = True
    try:
        yield rec
    finally:
        rec.active = False
        sys.stderr = saved


def _run_until_first_heavy_event(rec: Recorder, argv: list[str]) -> None:
    with recording(rec), pytest.raises(Stop):
        main(argv)


COMMANDS = {
    "evaluate": ["evaluate", "--scenario", "tiny-intruder", "--episodes", "2", "--batch-size", "2"],
    "render": ["render", "--scenario", "tiny-intruder", "--out", "{tmp}/episode.gif"],
    "falsify": ["falsify", "--target", "tracking", "--attacks", "8", "--out", "{tmp}/falsify"],
    "precompute": ["precompute", "--figures", "{tmp}/figures"],
    "plan": ["plan", "--scenario", "tiny", "--out", "{tmp}/plan.png"],
    "avoid-region": ["avoid-region", "--grid", "21", "--out", "{tmp}/avoid.png"],
    "train-intruder": ["train-intruder", "--scenario", "tiny-intruder", "--timesteps", "64", "--out", "{tmp}/run"],
    "coobservation": ["coobservation", "--episodes", "2", "--out", "{tmp}/coobs"],
    "survivability": ["survivability", "--instances", "1", "--out", "{tmp}/surv"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_long_command_speaks_before_its_first_build_or_compilation(recorder, tmp_path, command):
    argv = [a.format(tmp=tmp_path) for a in COMMANDS[command]]
    if command == "evaluate":
        argv += ["--out", str(tmp_path / "evaluation")]
    if command == "train-intruder":
        pytest.importorskip("stable_baselines3")
    _run_until_first_heavy_event(recorder, argv)
    heavy = next(i for i, (k, _) in enumerate(recorder.events) if k in ("compile", "artifact"))
    assert any(k == "progress" for k, _ in recorder.events[:heavy]), (
        f"stp-env {command} started a {recorder.events[heavy][0]} before saying anything: {recorder.events}")


def test_the_environment_announces_its_artifact_builds(recorder):
    """``parallel_env(progress=True)`` (the default in a terminal) says what it builds before the first build."""
    from stp_env.env import parallel_env

    with recording(recorder), pytest.raises(Stop):
        parallel_env("tiny-intruder", progress=True)
    assert recorder.events[0][0] == "progress" and "tiny-intruder" in recorder.events[0][1], recorder.events


@pytest.mark.slow
def test_the_environment_announces_the_compilation_of_reset_and_step(monkeypatch):
    """Each of the first ``reset`` and ``step`` is announced before JAX compiles (or loads) its program."""
    from stp_env.env import parallel_env

    env = parallel_env("tiny-intruder", progress=False)
    monkeypatch.setattr(progress, "_COMPILED", set())  # as in a new process
    jax.clear_caches()
    rec = Recorder(stop=False)
    env._progress = True
    _LISTENING.append(rec)
    try:
        with recording(rec):
            env.reset(seed=0)
            env.step({a: np.zeros(2, np.float32) for a in env.agents})
    finally:
        _LISTENING.remove(rec)
    notes = [i for i, (k, text) in enumerate(rec.events) if k == "progress" and "compiling the environment's" in text]
    assert [rec.events[i][1].split("compiling the environment's ")[1].split()[0] for i in notes] == ["reset", "step"]
    assert rec.events[notes[0] + 1][0] == "compile" and rec.events[notes[1] + 1][0] == "compile", rec.events
    assert not any(k == "compile" for k, _ in rec.events[:notes[0]])


def test_progress_is_off_when_standard_error_is_not_a_terminal(monkeypatch):
    class Pipe:
        def isatty(self):
            return False

    monkeypatch.setattr(sys, "stderr", Pipe())
    monkeypatch.delenv(progress.ENV_VAR, raising=False)
    assert not progress.enabled()
    assert progress.enabled(True)
    monkeypatch.setenv(progress.ENV_VAR, "1")
    assert progress.enabled() and not progress.enabled(False)
    monkeypatch.setattr(sys, "stderr", type("Tty", (), {"isatty": lambda self: True})())
    monkeypatch.setenv(progress.ENV_VAR, "0")
    assert not progress.enabled()
    monkeypatch.delenv(progress.ENV_VAR)
    assert progress.enabled()
