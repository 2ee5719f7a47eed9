"""Inputs that were accepted with the wrong meaning, or refused without saying what: each is now one line naming the
argument or file (``docs/threat-model.md``).

* A full disk while writing an output: ``cannot write <path>: No space left on device``, not a bare ``[Errno 28]``.
* ``step(None)`` of a live agent in the AEC form (it was the zero action): ``ValueError`` naming the agent.
* Booleans (and strings) in actions (``True`` was the number 1): refused, naming the agent.
* A wind that is a string, a boolean or beyond 1000 m/s (``make("town", wind="6")``, an events record with
  ``wind: 1e300``): refused, naming ``wind`` (and the file).
* ``stp-env data check-plan`` on what is not a plan: one line on standard error naming it, exit status 2.

Nothing here compiles a JAX program: the adapters' checks run before their first computation.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from _cli import run_cli

from stp_env import cli, files

ROOT = Path(__file__).resolve().parents[1]
ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def one_line(message: str, *words: str) -> None:
    assert "\n" not in message.strip() and "Traceback" not in message, message
    for word in words:
        assert word in message, (word, message)


# ------------------------------------------------------------------------------------------------ a full disk
class _FullDisk:
    """A file object whose writes (``on="write"``) or final flush (``on="close"``) fail as on a full disk."""

    def __init__(self, fh, on: str):
        self._fh, self._on = fh, on

    def write(self, data):
        if self._on == "write":
            raise OSError(ENOSPC.errno, ENOSPC.strerror)
        return self._fh.write(data)

    def close(self):
        self._fh.close()
        if self._on == "close":
            raise OSError(ENOSPC.errno, ENOSPC.strerror)

    @property
    def closed(self):
        return self._fh.closed


def _full_disk(monkeypatch, on: str) -> None:
    real = os.fdopen
    monkeypatch.setattr(files.os, "fdopen", lambda fd, *a, **k: _FullDisk(real(fd, *a, **k), on))


@pytest.mark.parametrize("on", ["write", "close"])
def test_a_full_disk_names_the_file_it_could_not_write(on, tmp_path, monkeypatch):
    target = tmp_path / "results.json"
    _full_disk(monkeypatch, on)
    with pytest.raises(OSError) as err:
        files.write_text("{}", target)
    assert err.value.errno == errno.ENOSPC
    assert str(err.value) == f"cannot write {target}: No space left on device"
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temporary file


def test_a_missing_directory_names_the_file_not_the_temporary_one(tmp_path):
    target = tmp_path / "gone" / "results.json"
    with pytest.raises(OSError) as err:
        files.write_text("{}", target)
    assert str(err.value) == f"cannot write {target}: No such file or directory"


def test_another_files_error_in_the_block_keeps_its_own_message(tmp_path):
    missing = tmp_path / "input.json"
    with pytest.raises(FileNotFoundError) as err, files.atomic_open(tmp_path / "out.json") as fh:
        fh.write(missing.read_text())
    assert str(missing) in str(err.value) and "cannot write" not in str(err.value)


def test_the_command_line_reports_a_full_disk_in_one_line_naming_the_file(tmp_path, monkeypatch):
    target = tmp_path / "region.json"
    monkeypatch.setattr(cli, "_avoid_region", lambda args: files.write_text("{}", args.out) and 0)
    _full_disk(monkeypatch, "write")
    code, _, stderr = run_cli(["avoid-region", "--out", str(target)])
    assert code == 2
    one_line(stderr, f"stp-env avoid-region: error: cannot write {target}: No space left on device")


def test_append_csv_row_names_the_file(tmp_path):
    target = tmp_path / "gone" / "rows.csv"
    with pytest.raises(OSError, match=f"cannot write {target}: No such file or directory"):
        files.append_csv_row(target, {"a": 1})


# ------------------------------------------------------------------------------------------------ actions
def _aec(agent: str, *, finished: bool):
    """The AEC form with ``agent`` to act, without an environment behind it (the action check comes first)."""
    from stp_env.env import STPAECEnv

    aec = STPAECEnv.__new__(STPAECEnv)
    aec.agent_selection = agent
    aec.terminations, aec.truncations = {agent: finished}, {agent: False}
    return aec


def test_a_live_agents_step_none_is_refused_naming_it():
    """``env.step(None)`` of a live agent was silently the zero action."""
    with pytest.raises(ValueError, match="'vehicle_3' is live") as err:
        _aec("vehicle_3", finished=False).step(None)
    one_line(str(err.value), "None")


def test_a_finished_agents_step_none_is_still_the_pettingzoo_step(monkeypatch):
    from pettingzoo.utils.conversions import parallel_to_aec_wrapper

    taken = []
    monkeypatch.setattr(parallel_to_aec_wrapper, "step", lambda self, action: taken.append(action))
    _aec("vehicle_3", finished=True).step(None)
    assert taken == [None]
    with pytest.raises(ValueError, match="has finished"):
        _aec("vehicle_3", finished=True).step(np.zeros(2, np.float32))


def test_booleans_in_an_action_are_refused_naming_the_agent():
    from stp_env.env_checks import ActionChecker

    agents = ["vehicle_0", "intruder"]
    checker = ActionChecker(agents, {a: i for i, a in enumerate(agents)}, 1, 2)
    for bad in ([True, 0.5], (0.5, np.bool_(False)), np.array([True, False]), True):
        with pytest.raises(ValueError, match="'intruder' must be real numbers"):
            checker.check("intruder", bad, agents)
    assert checker.check("intruder", [1, 0.5], agents).tolist() == [1.0, 0.5]


def _coobservation_env():
    """The co-observation adapter after a reset, without its simulator (the action check comes first)."""
    from stp_env.coobservation.env import CoObservationParallelEnv

    env = CoObservationParallelEnv.__new__(CoObservationParallelEnv)
    env._carry = types.SimpleNamespace(words=np.zeros(1))
    env.scenario = types.SimpleNamespace(n_vehicles=2)
    env.possible_agents = env.agents = ["vehicle_0", "vehicle_1", "attacker"]
    env._index = {a: i for i, a in enumerate(env.possible_agents)}
    return env


@pytest.mark.parametrize("bad", [[True, 0.5], np.array([True, False]), [np.bool_(True), 0.0], ["1", "0.5"], True])
def test_coobservation_actions_refuse_booleans_and_strings(bad):
    """``[True, 0.5]`` was the action ``[1.0, 0.5]``, ``["1", "0.5"]`` too."""
    with pytest.raises(ValueError, match="'attacker' must be 2 real numbers") as err:
        _coobservation_env().step({"attacker": bad})
    one_line(str(err.value))


# ------------------------------------------------------------------------------------------------ winds
@pytest.mark.parametrize("wind", ["6", True, 1e300, float("inf")])
def test_a_scenario_wind_that_is_not_a_number_in_range_is_refused(wind):
    """``make("town", wind="6")`` made a town in a 6 m/s wind, ``wind=True`` one in 1 m/s, ``wind=1e300`` one whose
    reachability solve failed deep inside naming nothing."""
    from stp_env.scenarios import make

    with pytest.raises(ValueError, match=r"wind \[m/s\] must be a finite number in \[0, 1000\]") as err:
        make("town", wind=wind)
    one_line(str(err.value))
    assert make("town", wind=6).vehicle.wind == 6.0


def test_the_environment_takes_no_wind_keyword():
    import stp_env

    with pytest.raises(TypeError, match="'wind'"):
        stp_env.parallel_env("town", wind="6")


def test_an_events_record_with_a_wind_beyond_range_is_refused_naming_the_file(tmp_path):
    from stp_env.evaluation.events import load_events

    record = {"config": {"scenario": "tiny-intruder", "kbar": 2, "intruder": "greedy", "vehicle_policy": "nominal",
                         "wind": 1e300},
              "seed": 1, "index": 0, "n_steps": 100, "plan_samples": 100, "batch_size": 1, "recorded": True}
    path = tmp_path / "events.json"
    path.write_text(json.dumps([record]))
    with pytest.raises(ValueError, match=r"wind \[m/s\] must be a finite number in \[0, 1000\]") as err:
        load_events(path)
    one_line(str(err.value), str(path), "record 0")
    record["config"]["wind"] = 6
    path.write_text(json.dumps([record]))
    assert load_events(path)[0]["config"]["wind"] == 6


# ------------------------------------------------------------------------------------------------ check_plan
def _bad_plans(root: Path) -> dict[str, Path]:
    from stp_env.planning.plan import plan_to_arrays
    from stp_env.planning.stp import shipped_plan

    good = root / "good.npz"
    arrays = plan_to_arrays(shipped_plan("tiny"))
    np.savez(good, **arrays)
    cases = {"empty": b"", "text": b"a plan, honestly\n", "truncated": good.read_bytes()[: good.stat().st_size // 2]}
    out = {}
    for name, content in cases.items():
        out[name] = root / f"{name}.npz"
        out[name].write_bytes(content)
    out["wrong-arrays"] = root / "wrong-arrays.npz"
    np.savez(out["wrong-arrays"], **{**arrays, "times": np.asarray(["x"])})
    out["foreign-checkpoint"] = root / "foreign.npz"
    np.savez(out["foreign-checkpoint"], key=np.zeros(3), x=np.zeros(2))
    out["directory"] = root / "directory.npz"
    out["directory"].mkdir()
    out["missing"] = root / "missing.npz"
    return out


def test_check_plan_refuses_what_is_not_a_plan_in_one_line_with_status_2(tmp_path):
    """An empty file was an ``EOFError`` traceback, a truncated archive a ``BadZipFile`` one, an archive with a
    string where times belong an ``IndexError`` one, a foreign checkpoint a ``ValueError`` one."""
    for name, path in _bad_plans(tmp_path).items():
        code, out, err = run_cli(["data", "check-plan", str(path), "--scenario", "tiny", "--tracking-bound", "30"])
        assert code == 2 and out == "", name
        one_line(err, "stp-env data check-plan: error:", path.name)


def test_check_plan_refuses_a_bad_tracking_bound():
    code, _, err = run_cli(["data", "check-plan", "tiny", "--tracking-bound", "nan"])
    assert code == 2 and "--tracking-bound" in err


def test_check_plan_as_a_program_exits_2_with_one_line(tmp_path):
    path = tmp_path / "truncated.npz"
    path.write_bytes(b"PK\x03\x04 not really")
    run = subprocess.run([sys.executable, "-m", "stp_env.cli", "data", "check-plan", str(path), "--scenario", "tiny"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT,
                         env={**os.environ, "STP_ENV_PROGRESS": "0"})  # no "started" line: the error alone
    assert run.returncode == 2 and run.stdout == ""
    one_line(run.stderr, f"stp-env data check-plan: error: {path}: not a readable plan file or planning checkpoint")


@pytest.mark.parametrize("setting", [{"gamma": 2}, {"gamma": 0.0}, {"gae_lambda": 1.5}, {"learning_rate": 0},
                                     {"clip_range": 0}, {"ent_coef": -0.1}, {"log_std_init": 30.0}])
def test_ppo_settings_outside_their_ranges_are_refused_from_library_callers_too(setting):
    """The training configuration itself checks every real setting's range (the command line's grid is one caller
    of it): a discount of 2 trains nothing sensible and used to train."""
    from stp_env.rl.train import TrainConfig

    (name,) = setting
    with pytest.raises(ValueError, match=name):
        TrainConfig(**setting)
