"""Arguments that ask for a share of the machine are bounded by it (``stp_env/resources.py``,
``docs/threat-model.md``): CPU devices and XLA threads at most ``max(64, 4 x cores)``, batches, episodes, training
environments and solver grids within the memory available, sweeps at most ``MAX_SWEEP_RUNS`` runs, and every
numeric training setting a ``--grid`` varies within its range. Each is refused before any work, in one line naming
the argument (or the file) and the machine's limit, within 2 s where the value used to hang.

Nothing here compiles a JAX program: the checks run while parsing, or on the functions directly.
"""

from __future__ import annotations

import json
import os
import time

import pytest
from _cli import run_cli

from stp_env import cli, cpu_threads, resources
from stp_env.rl import sweep

FAST_S = 2.0
"""Every refusal of a count that used to hang answers within this [s]."""

GB = 10**9


def timed(fn, *args, **kwargs):
    """``(result or raised exception, seconds)`` of ``fn(*args, **kwargs)``."""
    start = time.perf_counter()
    try:
        out = fn(*args, **kwargs)
    except Exception as err:  # returned to the test, which asserts on it
        out = err
    return out, time.perf_counter() - start


@pytest.fixture
def memory(monkeypatch):
    """The memory available, fixed at 8 GB, so that the bounds do not depend on the machine running the test."""
    monkeypatch.setattr(resources, "available_memory", lambda: 8 * GB)
    return 8 * GB


@pytest.fixture
def no_devices_var(monkeypatch):
    monkeypatch.delenv(cpu_threads.DEVICES_ENV_VAR, raising=False)


def one_line(message: str, *words: str) -> None:
    assert "\n" not in message.strip() and "Traceback" not in message, message
    for word in words:
        assert word in message, (word, message)


# ------------------------------------------------------------------------------------------------ the limits
def test_the_cpu_limits_are_four_per_core_and_at_least_64(monkeypatch):
    monkeypatch.setattr(resources, "available_cores", lambda: 2)
    assert resources.max_cpu_devices() == resources.max_cpu_threads() == 64
    monkeypatch.setattr(resources, "available_cores", lambda: 48)
    assert resources.max_cpu_devices() == resources.max_cpu_threads() == 192
    assert "48 cores" in resources.cpu_limit_reason()


def test_available_memory_is_what_the_system_reports():
    have = resources.available_memory()
    assert have is None or 0 < have <= os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def test_check_count_names_the_argument_and_the_limit():
    assert resources.check_count("--x", 3, limit=4, why="here") == 3
    with pytest.raises(ValueError, match=r"^--x 5: at most 4 here\.$"):
        resources.check_count("--x", 5, limit=4, why="here")
    for bad in (0, True, 2.0, "3"):
        with pytest.raises(ValueError, match="--x must be an integer"):
            resources.check_count("--x", bad, limit=4, why="here")


# ------------------------------------------------------------------------------------------------ CPU devices
@pytest.mark.parametrize("n", [65_536, 100_000, 2**63])
def test_a_device_count_beyond_the_machine_is_refused_at_once(n, no_devices_var):
    before = os.environ.get("XLA_FLAGS")
    err, seconds = timed(cpu_threads.set_cpu_devices, n)
    assert isinstance(err, ValueError) and seconds < FAST_S, (err, seconds)
    one_line(str(err), f"at most {resources.max_cpu_devices()}", "cores")
    assert os.environ.get("XLA_FLAGS") == before


def test_the_device_count_variable_is_bounded_by_the_machine(monkeypatch):
    monkeypatch.setenv(cpu_threads.DEVICES_ENV_VAR, "100000")
    with pytest.raises(ValueError, match=f"{cpu_threads.DEVICES_ENV_VAR} 100000: at most") as err:
        cpu_threads.default_cpu_devices()
    one_line(str(err.value), "cores")
    monkeypatch.setenv(cpu_threads.DEVICES_ENV_VAR, str(resources.max_cpu_devices()))
    assert cpu_threads.default_cpu_devices() == resources.max_cpu_devices()


@pytest.mark.parametrize("command", [["evaluate"], ["falsify"], ["coobservation"], ["train-intruder"]])
def test_cpu_devices_beyond_the_machine_are_refused_while_parsing(command, tmp_path, no_devices_var):
    (code, _, stderr), seconds = timed(run_cli, [*command, "--cpu-devices", "100000", "--out", str(tmp_path / "o")])
    assert code == 2 and seconds < FAST_S, (code, seconds, stderr)
    one_line(stderr.strip().splitlines()[-1], "--cpu-devices", "100000", f"at most {resources.max_cpu_devices()}",
             "cores")
    assert not (tmp_path / "o").exists()


def test_cpu_devices_within_the_machine_still_parse(no_devices_var):
    parser = cli._build_parser()
    n = resources.max_cpu_devices()
    assert parser.parse_args(["evaluate", "--cpu-devices", str(n)]).cpu_devices == n
    assert parser.parse_args(["evaluate", "--cpu-devices", "auto"]).cpu_devices == "auto"


# ------------------------------------------------------------------------------------------------ threads
@pytest.mark.parametrize("n", [8192, 2**63])
def test_a_thread_count_beyond_the_machine_is_refused_at_once(n, monkeypatch):
    """``set_cpu_threads(2**63)`` was accepted, and XLA's first computation then hung starting the threads (8,192
    did not start in 60 s on the 2-core machine)."""
    monkeypatch.delenv(cpu_threads.ENV_VAR, raising=False)
    monkeypatch.delenv("NPROC", raising=False)
    err, seconds = timed(cpu_threads.set_cpu_threads, n)
    assert isinstance(err, ValueError) and seconds < FAST_S, (err, seconds)
    one_line(str(err), f"at most {resources.max_cpu_threads()}", "cores")
    assert cpu_threads.ENV_VAR not in os.environ


# ------------------------------------------------------------------------------------------------ memory
@pytest.mark.parametrize("argv, option", [
    (["evaluate", "--batch-size", str(2**31 - 1)], "--batch-size"),
    (["render", "--batch-size", str(2**31 - 1)], "--batch-size"),
    (["falsify", "--batch-size", str(2**31 - 1)], "--batch-size"),
    (["coobservation", "--batch-size", str(2**31 - 1)], "--batch-size"),
    (["evaluate", "--episodes", str(2**31 - 1)], "--episodes"),
    (["train-intruder", "--n-envs", str(1 << 20)], "--n-envs"),
    (["avoid-region", "--grid", "1001"], "--grid"),
])
def test_counts_beyond_the_memory_are_refused_while_parsing(argv, option, memory, tmp_path):
    (code, _, stderr), seconds = timed(run_cli, [*argv, "--out", str(tmp_path / "o")])
    assert code == 2 and seconds < FAST_S, (code, seconds, stderr)
    one_line(stderr.strip().splitlines()[-1], option, "needs at least", "8 GB available")


def test_counts_within_the_memory_still_parse(memory):
    parser = cli._build_parser()
    assert parser.parse_args(["evaluate", "--batch-size", "1000", "--episodes", "100000"]).batch_size == 1000
    assert parser.parse_args(["train-intruder", "--n-envs", "4096"]).n_envs == 4096
    assert parser.parse_args(["avoid-region", "--grid", "301"]).grid == 301  # 27 million points: 1.3 GB


# ------------------------------------------------------------------------------------------------ events
def _event(**changes):
    record = {"config": {"scenario": "tiny-intruder", "kbar": 2, "intruder": "greedy", "vehicle_policy": "nominal"},
              "seed": 1, "index": 0, "n_steps": 100, "plan_samples": 100, "batch_size": 1, "recorded": True,
              "npz_prefix": "0/"}
    record.update(changes)
    return record


def test_an_events_file_asking_for_more_devices_than_the_machine_is_refused_naming_it(tmp_path):
    from stp_env.evaluation.events import load_events

    path = tmp_path / "events.json"
    path.write_text(json.dumps([_event(devices=65_536)]))
    err, seconds = timed(load_events, path)
    assert isinstance(err, ValueError) and seconds < FAST_S, (err, seconds)
    one_line(str(err), str(path), "record 0", "devices 65536", f"at most {resources.max_cpu_devices()}")
    path.write_text(json.dumps([_event(devices=2)]))
    assert load_events(path)[0]["devices"] == 2


# ------------------------------------------------------------------------------------------------ sweeps
@pytest.mark.parametrize("item, words", [
    ("gamma=2", ["gamma=2", "(0, 1]"]),
    ("gamma=0", ["gamma=0", "(0, 1]"]),
    ("gae_lambda=1.5", ["gae_lambda", "(0, 1]"]),
    ("learning_rate=0", ["learning_rate", "[1e-09, 1]"]),
    ("learning_rate=Infinity", ["learning_rate", "finite"]),
    ("clip_range=0", ["clip_range", "> 0"]),
    ("ent_coef=-0.1", ["ent_coef", ">= 0"]),
    ("n_steps=1.5", ["n_steps", "integer"]),
    ("batch_size=0", ["batch_size", "integer >= 1"]),
    ("n_epochs=true", ["n_epochs", "bool"]),
    ("torch_threads=100000", ["torch_threads 100000", "at most"]),
    (" learning_rate=1e-4", ["spaces"]),
    ("learning_rate =1e-4", ["spaces"]),
    ("learning_rate=1e-4,0.0001", ["given twice"]),
    ("learning_rate=1e-4,,3e-4", ["empty value"]),
    ("seed=1,2", ["cannot vary seed"]),
])
def test_a_grid_value_outside_its_range_or_malformed_is_refused(item, words):
    with pytest.raises(ValueError) as err:
        sweep.parse_grid([item])
    one_line(str(err.value), "--grid", *words)


def test_a_grid_field_given_twice_is_refused_whatever_its_spelling():
    """``--grid " learning_rate=..."`` was stored as ``learning_rate`` and silently replaced the values of an
    earlier ``--grid learning_rate=...``."""
    with pytest.raises(ValueError, match="given twice"):
        sweep.parse_grid(["learning_rate=1e-4", "learning_rate=3e-4"])
    with pytest.raises(ValueError, match="spaces"):
        sweep.parse_grid(["learning_rate=1e-4", " learning_rate=3e-4"])


def test_a_valid_grid_keeps_its_values():
    grid = sweep.parse_grid(["learning_rate=1e-4, 3e-4", "gamma=0.99,1", "algo=ppo,a2c", "net_arch=[64]"])
    assert grid == {"learning_rate": [1e-4, 3e-4], "gamma": [0.99, 1], "algo": ["ppo", "a2c"], "net_arch": [[64]]}


def test_a_sweep_beyond_its_cap_is_refused_at_once():
    values = ",".join(f"{(i + 1) * 1e-6:.6g}" for i in range(resources.MAX_SWEEP_RUNS // 10 + 1))
    start = time.perf_counter()
    grid = sweep.parse_grid([f"learning_rate={values}"])
    cap = f"{resources.MAX_SWEEP_RUNS:,}"
    with pytest.raises(ValueError, match=f"make 10,010 training runs; a sweep runs at most {cap}"):
        sweep.check_sweep_size(list(range(10)), grid)
    assert time.perf_counter() - start < FAST_S
    sweep.check_sweep_size(list(range(9)), grid)  # 9,009 runs
    with pytest.raises(ValueError, match="--seeds: 3 given twice"):
        sweep.check_sweep_size([1, 3, 3], {})


def test_the_command_line_refuses_a_bad_grid_before_any_work(tmp_path, monkeypatch):
    """``train-intruder --seeds 0 --grid gamma=2`` trained (a discount of 2); now it is refused before the output
    folder is made or JAX is touched."""
    from stp_env.rl import cli as train_cli

    monkeypatch.setattr(train_cli, "_missing_trainer_modules", lambda trainer: [])
    monkeypatch.setattr(train_cli.kit, "apply_cpu_devices", lambda args: pytest.fail("reached the device setting"))
    out = tmp_path / "sweep"
    for grid, words in ((["gamma=2"], ["gamma", "(0, 1]"]), (["scenario=town,tiny"], ["cannot vary scenario"]),
                        (["no_such_field=1,2"], ["'no_such_field' is not a training setting"])):
        code, _, stderr = run_cli(["train-intruder", "--seeds", "0", "1", *(f"--grid={g}" for g in grid),
                                   "--out", str(out)])
        assert code == 2, stderr
        one_line(stderr.strip(), "train-intruder: error", *words)
        if grid == ["gamma=2"]:
            assert not out.exists()
    code, _, stderr = run_cli(["train-intruder", "--seeds", "0", "0", "--out", str(out)])
    assert code == 2 and "--seeds: 0 given twice" in stderr
