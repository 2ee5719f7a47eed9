"""One CLI kit (``stp_env/cli_kit.py``): the options every subcommand shares have one type, one range and one help
text; ``--help`` imports no JAX; the names the help lists are the registries' names."""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from stp_env import cli, cli_kit

ROOT = Path(__file__).resolve().parents[1]
SUBCOMMANDS = ("avoid-region", "plan", "precompute", "evaluate", "render", "falsify", "train-intruder",
               "survivability", "coobservation")
SEEDED = ("evaluate", "render", "falsify", "train-intruder", "survivability", "coobservation")


def _parse(argv):
    """``(namespace or None, stderr)`` of parsing ``stp-env argv`` (nothing runs)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            return cli._build_parser().parse_args(argv), err.getvalue()
        except SystemExit as exc:
            assert exc.code == 2, err.getvalue()
            return None, err.getvalue()


def _subparsers():
    parser = cli._build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices


def test_help_imports_no_jax():
    """``stp-env --help`` and every subcommand's ``--help``, in a fresh interpreter."""
    script = (
        "import contextlib, io, json, sys\n"
        "from stp_env import cli\n"
        f"for argv in [['--help']] + [[c, '--help'] for c in {list(SUBCOMMANDS)!r}]:\n"
        "    with contextlib.redirect_stdout(io.StringIO()):\n"
        "        try:\n"
        "            cli.main(argv)\n"
        "        except SystemExit as exc:\n"
        "            assert exc.code == 0, argv\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'torch'))))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []


def test_the_names_help_lists_are_the_registries():
    """The catalog's tables (what ``--help`` lists) are the registries' names, the wind models' parameters and
    help included (each registry also checks its names against the catalog when it is imported)."""
    from stp_env import scenarios
    from stp_env.policies import INTRUDERS, VEHICLE_POLICIES
    from stp_env.sim import winds

    assert cli_kit.describe_wind_models() == winds.describe()
    assert tuple(cli_kit.wind_model_catalog()) == winds.names()
    assert cli_kit.scenario_names() == tuple(sorted(scenarios.names()))
    assert cli_kit.intruder_names() == tuple(INTRUDERS)
    assert cli_kit.vehicle_policy_names() == tuple(VEHICLE_POLICIES)


@pytest.mark.parametrize("command", ["evaluate", "render", "falsify", "coobservation"])
def test_wind_models_take_their_documented_parameters(command):
    args, err = _parse([command, "--wind-model", "gusts:time_constant=3"])
    assert args is not None and args.wind_model == "gusts:time_constant=3", err
    for bad, needle in (("gale", "unknown wind model"), ("gusts:speed=3", "is not param=value"),
                        ("gusts:time_constant=nan", "finite")):
        args, err = _parse([command, "--wind-model", bad])
        assert args is None and "--wind-model" in err and needle in err, err


def _option_helps(command):
    """``{option: its help as printed}`` of a subcommand."""
    parser = _subparsers()[command]
    formatter = parser._get_formatter()
    return {a.option_strings[0]: formatter._expand_help(a) if a.help else "" for a in parser._actions
            if a.option_strings and a.dest != "help"}


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_every_option_has_one_help_text_with_one_default(command):
    """Every option has a help text, and it says what the default is at most once (the help formatter appended
    ``(default: None)`` to texts that already said ``(default: ...)``)."""
    for option, text in _option_helps(command).items():
        assert text.strip(), f"{command} {option} has no help"
        assert len(re.findall(r"default:", text)) <= 1, f"{command} {option}: {text!r}"


def test_batch_sizes_say_what_they_count():
    """``--batch-size`` is episodes in ``evaluate`` / ``render`` / ``coobservation`` and attacks in ``falsify``; the
    PPO minibatch of ``train-intruder`` is ``--minibatch-size`` (``--batch-size``, its spelling in release 0.1, is
    refused)."""
    helps = {c: _option_helps(c)["--batch-size"] for c in ("evaluate", "render", "coobservation", "falsify")}
    assert all("episodes" in helps[c] for c in ("evaluate", "render", "coobservation"))
    assert "attacks" in helps["falsify"]
    assert "minibatch" in _option_helps("train-intruder")["--minibatch-size"]
    args, err = _parse(["train-intruder", "--minibatch-size", "512"])
    assert args is not None and args.batch_size == 512, err
    args, err = _parse(["train-intruder", "--batch-size", "512"])
    assert args is None and "--batch-size" in err
    for command in ("coobservation", "falsify"):
        args, err = _parse([command, "--batch-size", "64"])
        assert args is not None and args.batch_size == 64, err


@pytest.mark.parametrize("command", SEEDED)
def test_every_seed_is_range_checked(command):
    top = 2**32 - 1 if command == "train-intruder" else 2**63 - 1
    args, err = _parse([command, "--seed", str(top)])
    assert args is not None and args.seed == top, err
    for bad in ("-1", str(top + 1), str(2**70), "1.5", "1e3", "one"):
        args, err = _parse([command, "--seed", bad])
        assert args is None and "--seed" in err, (command, bad, err)


@pytest.mark.parametrize("argv", [
    ["evaluate", "--wind", "nan"], ["evaluate", "--wind", "inf"], ["render", "--frame-dt", "inf"],
    ["avoid-region", "--v-max", "nan"], ["avoid-region", "--grid", "0"], ["plan", "--kbar", str(10**30)],
    ["precompute", "--kbar", "1", "0"], ["coobservation", "--period", "inf"], ["falsify", "--control-dt", "nan"],
    ["falsify", "--option", "horizon=nan"], ["falsify", "--attacks", "-3"], ["survivability", "--beta", "nan"],
    ["train-intruder", "--timesteps", "0"], ["evaluate", "--episodes", str(2**31)],
])
def test_numbers_are_range_checked_where_they_enter(argv):
    args, err = _parse(argv)
    assert args is None and argv[-2] in err, err


def test_one_spec_parser_reads_names_and_parameters_and_names_what_is_wrong():
    from stp_env.arguments import parse_spec

    fields = {"a": ("x", "y"), "b": ()}
    asked = []

    def of(name):
        asked.append(name)
        return fields[name]

    assert parse_spec("a: x = 1.5 ,y=-2", "thing", fields, of) == ("a", {"x": 1.5, "y": -2.0})
    assert parse_spec("b", "thing", fields, of) == ("b", {}) and asked == ["a"]   # fields read only when needed
    for bad, needle in (("c", "unknown thing 'c'; allowed: a, b"), ("a:z=1", "(parameters: x, y)"),
                        ("b:x=1", "(parameters: none)"), ("a:x", "'x' is not param=value"),
                        ("a:x=inf", "x must be a finite number; got 'inf'"), ("a:x=", "got ''"),
                        (3, "thing must be a string")):
        with pytest.raises(ValueError, match=re.escape(needle)):
            parse_spec(bad, "thing", fields, of)


def test_vehicle_policies_on_the_command_line_are_names_or_learned_files(tmp_path):
    """``--vehicle-policy`` takes the scripted names and ``learned:NAME_OR_PATH``; an unknown name or an empty
    learned spec is refused while parsing; a learned spec naming a bad file is refused when the configuration is
    checked, before anything is computed."""
    import argparse

    from stp_env.evaluation import Configuration

    assert cli_kit.vehicle_policy_spec("switching") == "switching"
    assert cli_kit.vehicle_policy_spec("learned:crossing-after-avoidance") == "learned:crossing-after-avoidance"
    for bad, why in (("zigzag", "unknown vehicle policy"), ("learned:", "needs a shipped name")):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            cli_kit.vehicle_policy_spec(bad)
    for bad, why in (("learned:no-such-policy", "unknown learned vehicle"),
                     ("learned:crossing-kbar2", "unknown learned vehicle"),
                     (f"learned:{tmp_path / 'missing.npz'}", "missing")):
        with pytest.raises(ValueError, match=why):
            Configuration(vehicle_policy=bad)
