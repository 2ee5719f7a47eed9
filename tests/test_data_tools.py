"""``stp-env data`` (``stp_env/data_tools``): its help lists every subcommand and imports no JAX; every option says
what it is; what writes the package's own data (``stp_env/data``) refuses to outside a source checkout, before
anything is computed. What each subcommand does is tested beside what it maintains (tests/test_check_plan.py,
test_planning.py, test_planning_resume.py, test_artifacts.py, test_weak_inputs.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from _cli import run_cli

from stp_env import cli
from stp_env.data_tools import cli as data_cli
from stp_env.data_tools import shipping

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("plans", "check-plan", "reconcile-controls", "convert-checkpoint", "artifacts", "ship-intruder")


def _data_subparsers():
    parser = cli._build_parser()
    data = next(a for a in parser._actions if a.dest == "command").choices["data"]
    return next(a for a in data._actions if a.dest == "data_command").choices


def test_data_help_lists_the_subcommands_and_imports_no_jax():
    """``stp-env data --help`` and every ``stp-env data COMMAND --help``, in a fresh interpreter."""
    script = (
        "import contextlib, io, json, sys\n"
        "from stp_env import cli\n"
        "texts = {}\n"
        f"for argv in [['data', '--help']] + [['data', c, '--help'] for c in {list(COMMANDS)!r}]:\n"
        "    out = io.StringIO()\n"
        "    with contextlib.redirect_stdout(out):\n"
        "        try:\n"
        "            cli.main(argv)\n"
        "        except SystemExit as exc:\n"
        "            assert exc.code == 0, argv\n"
        "    texts[' '.join(argv)] = out.getvalue()\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'torch'))\n"
        "print(json.dumps({'heavy': heavy, 'texts': texts}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    assert found["heavy"] == []
    listing = found["texts"]["data --help"]
    for command in COMMANDS:
        assert f"\n    {command}" in listing, (command, listing)
        assert found["texts"][f"data {command} --help"].startswith(f"usage: stp-env data {command}")


def test_the_subcommands_are_the_modules_and_name_their_handlers():
    """One module per subcommand, each parser naming its module's ``run`` and the command its errors name."""
    choices = _data_subparsers()
    assert tuple(choices) == COMMANDS
    for module, (name, parser) in zip(data_cli.COMMANDS, choices.items()):
        assert parser.get_default("run") is module.run and parser.get_default("command") == f"data {name}"


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_has_a_help_text(command):
    parser = _data_subparsers()[command]
    for action in parser._actions:
        if action.dest != "help":
            assert (action.help or "").strip(), f"data {command} {action.dest} has no help"


def test_data_needs_a_subcommand():
    code, _, err = run_cli(["data"])
    assert code == 2 and "COMMAND" in err


@pytest.mark.parametrize(("argv", "instead"), [
    (["plans", "--names", "tiny", "--ship"], "--out DIR"),
    (["artifacts"], "--check"),
    (["reconcile-controls", "tiny"], "--check"),
    (["ship-intruder", "no-such-run", "some-name"], "--out FILE"),
])
def test_writing_the_package_data_outside_a_checkout_is_refused(argv, instead, monkeypatch, tmp_path):
    """An installed package is never rewritten: one line, status 2, before anything is computed or read."""
    monkeypatch.setattr(shipping, "is_checkout", lambda package=shipping.PACKAGE: False)
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(["data", *argv])
    assert code == 2 and out == "", err
    assert err.startswith(f"stp-env data {argv[0]}: error:") and "\n" not in err.strip(), err
    assert "only a source checkout" in err and instead in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_checkout_is_told_from_an_installation(tmp_path):
    assert shipping.is_checkout(ROOT / "stp_env")
    installed = tmp_path / "site-packages" / "stp_env"
    installed.mkdir(parents=True)
    assert not shipping.is_checkout(installed)
