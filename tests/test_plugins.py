"""Plug-ins from an installed distribution (:mod:`stp_env.catalog`): a scenario, an intruder, a vehicle policy and
a wind model declared as entry points are listed by ``stp-env --help`` and every subcommand's help without
importing them or JAX, and run when named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PLUGIN = textwrap.dedent('''
    """A third party's plug-ins for stp_env (the test's distribution)."""
    import dataclasses

    import jax.numpy as jnp

    from stp_env.scenarios import make
    from stp_env.sim.winds.base import WindModel
    from stp_env.sim.winds.uniform import Uniform


    def quiet_town():
        return make("town")  # the shipped scenario under another name: its tables are in the package


    def circling(key, state, params):
        return jnp.array([0.0, 1.0], jnp.float32)


    def hold(key, state, params):
        return jnp.zeros((params.vehicles.n, params.vehicles.model.action_dim), state.x.dtype)


    @dataclasses.dataclass(frozen=True)
    class Breeze(Uniform):
        name = "breeze"
        help = "a third party's uniform wind"
''')

ENTRY_POINTS = textwrap.dedent('''
    [stp_env.scenarios]
    quiet-town = thirdparty_stp:quiet_town

    [stp_env.intruders]
    circling = thirdparty_stp:circling

    [stp_env.vehicle_policies]
    hold = thirdparty_stp:hold

    [stp_env.wind_models]
    breeze = thirdparty_stp:Breeze
''')


def _install(root: Path) -> dict:
    """The plug-in module and its distribution's metadata on a path of their own; the environment that sees it."""
    (root / "thirdparty_stp.py").write_text(PLUGIN, encoding="utf-8")
    info = root / "thirdparty_stp-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-stp\nVersion: 0.1\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(ENTRY_POINTS, encoding="utf-8")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(ROOT)])}


def _run(script: str, env: dict) -> str:
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


def test_help_lists_installed_plugins_without_importing_them_or_jax(tmp_path):
    script = textwrap.dedent('''
        import contextlib, io, json, sys
        from stp_env import cli
        texts = {}
        for argv in (["--help"], ["evaluate", "--help"], ["falsify", "--help"], ["train-intruder", "--help"]):
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                try:
                    cli.main(argv)
                except SystemExit as exc:
                    assert exc.code == 0, argv
            texts[" ".join(argv)] = " ".join(out.getvalue().split())
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib", "thirdparty_stp"))
        print(json.dumps({"texts": texts, "heavy": heavy}))
    ''')
    found = json.loads(_run(script, _install(tmp_path)))
    assert found["heavy"] == []
    evaluate = found["texts"]["evaluate --help"]
    for name in ("quiet-town", "circling", "hold", "breeze"):
        assert name in evaluate, name
    assert "breeze: a plug-in" in evaluate


@pytest.mark.slow
def test_named_plugins_run(tmp_path):
    """Each plug-in by its name: the scenario is made, the intruder and vehicle policy fly an episode of the env, the
    wind model is made; a name read from a data file does not load one."""
    script = textwrap.dedent('''
        import json
        import numpy as np
        from stp_env import scenarios
        from stp_env.policies.intruders import resolve_intruder
        from stp_env.env import parallel_env
        from stp_env.sim import winds

        scenario = scenarios.make("quiet-town")
        wind = winds.make("breeze")
        env = parallel_env("quiet-town", intruder="circling", vehicle_policy="hold", max_cycles=3,
                           progress=False)
        env.reset(seed=0)
        steps = 0
        while env.agents:
            env.step({a: np.zeros(2, np.float32) for a in env.agents})
            steps += 1
        try:
            resolve_intruder("circling", allow_plugins=False)
            refused = False
        except ValueError:
            refused = True
        print(json.dumps({"scenario": scenario.name, "wind": type(wind).__name__, "steps": steps,
                          "intruder_agent": "intruder" in env.possible_agents, "refused": refused,
                          "in_names": "quiet-town" in scenarios.names() and "breeze" in winds.names()}))
    ''')
    found = json.loads(_run(script, _install(tmp_path)))
    assert found == {"scenario": "town", "wind": "Breeze", "steps": 3, "intruder_agent": False, "refused": True,
                     "in_names": True}
