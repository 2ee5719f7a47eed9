"""Adding an intruder that reads a new table is one file plus the table's builder: the file below, written as a
user would (a builder registered with ``stp_env.requirements.register_table`` and an ``Intruder`` record that lists
the table), runs by its ``module:attribute`` spec in the PettingZoo environment, the evaluator and the falsifier's
environment, which build the table once and hand it to the policy (``stp_env.sim.tables.table_value``). An unknown
table is refused before anything is loaded, a name is registered once, and a run that does not read the table does
not build it."""

from __future__ import annotations

import importlib
import math
import re
import sys
import textwrap

import jax
import numpy as np
import pytest

from stp_env import assembly, requirements, sim
from stp_env.evaluation.config import Configuration

SCENARIO = "tiny-intruder"
MODULE = "stp_table_plugin_under_test"
TABLE = "test-centre-distance"

PLUGIN = textwrap.dedent('''
    """A third party's intruder that reads a table of its own: the distance to the domain's centre, which it
    descends (the whole plug-in: the table's builder, its registration and the intruder's record)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from stp_env.hj.grid import Grid
    from stp_env.policies.record import Intruder
    from stp_env.requirements import register_table
    from stp_env.sim import tables
    from stp_env.sim.physics import wrap_angle

    TABLE = "test-centre-distance"
    BUILDS = []  # (scenario name, kbar) of every build: what the test counts


    def centre_distance(scenario, *, kbar, store, progress):
        """The distance [m] to the centre of the scenario's domain on a 21 x 21 grid over it."""
        BUILDS.append((scenario.name, kbar))
        grid = Grid(scenario.domain_lo, scenario.domain_hi, (21, 21))
        axes = [np.linspace(lo, hi, n) for lo, hi, n in zip(grid.lo, grid.hi, grid.shape)]
        x, y = np.meshgrid(*axes, indexing="ij")
        centre = [(lo + hi) / 2 for lo, hi in zip(grid.lo, grid.hi)]
        return np.hypot(x - centre[0], y - centre[1]), grid


    register_table(TABLE, centre_distance, "distance to the domain's centre [m]")


    def toward_centre(key, state, params):
        """Full speed, turning by the heading error to the table's steepest descent (action ``error / pi``)."""
        g = jax.grad(lambda p: tables.table_value(params, TABLE, p))(state.intruder_x[:2])
        error = wrap_angle(jnp.arctan2(-g[1], -g[0]) - state.intruder_x[2])
        return jnp.stack([jnp.ones_like(error), error / jnp.pi])


    INTRUDER = Intruder(toward_centre, tables=(TABLE,), description="descends the distance to the centre")
    UNKNOWN = Intruder(toward_centre, tables=("no-such-table",))
''')


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The plug-in module, imported from a folder of its own on ``sys.path``; unregistered afterwards."""
    root = tmp_path_factory.mktemp("plugin")
    (root / f"{MODULE}.py").write_text(PLUGIN, encoding="utf-8")
    with pytest.MonkeyPatch.context() as patch:
        patch.syspath_prepend(str(root))
        module = importlib.import_module(MODULE)
        try:
            yield module
        finally:
            requirements.TABLES.pop(TABLE, None)
            sys.modules.pop(MODULE, None)


def _expected_action(state):
    """The action of the record from the analytic table: heading error to the centre of the 2 km domain / pi."""
    x, y, heading = (float(v) for v in np.asarray(state.intruder_x))
    error = (math.atan2(1000.0 - y, 1000.0 - x) - heading + math.pi) % (2 * math.pi) - math.pi
    return np.array([1.0, error / math.pi])


def test_a_table_is_registered_once(plugin):
    assert requirements.TABLES[TABLE].description == "distance to the domain's centre [m]"
    assert requirements.register_table(TABLE, plugin.centre_distance) is plugin.centre_distance  # the same: no-op
    with pytest.raises(ValueError, match="already registered"):
        requirements.register_table(TABLE, lambda scenario, **kw: None)
    with pytest.raises(ValueError, match="already registered"):
        requirements.register_table("buffer", plugin.centre_distance)
    with pytest.raises(ValueError, match="table name"):
        requirements.register_table("a table", plugin.centre_distance)
    with pytest.raises(ValueError, match="tuple of table names"):
        plugin.Intruder(plugin.toward_centre, tables=TABLE)  # a string, not a tuple of names


def test_an_unknown_table_is_refused_before_anything_is_loaded(plugin, monkeypatch):
    from stp_env import env as env_module
    from stp_env.env import parallel_env
    from stp_env.evaluation.runner import evaluate
    from stp_env.falsify.counterexample import AttackSpec, environment

    def refuse(*args, **kwargs):
        raise AssertionError("params were loaded before the tables were checked")

    monkeypatch.setattr(assembly, "params_for", refuse)
    monkeypatch.setattr(env_module, "_cached_params", refuse)
    spec = f"{MODULE}:UNKNOWN"
    builds = len(plugin.BUILDS)
    with pytest.raises(ValueError, match=r"unknown table.*'no-such-table'.*register_table"):
        parallel_env(SCENARIO, intruder=spec, progress=False)
    with pytest.raises(ValueError, match=r"unknown table.*'no-such-table'"):
        evaluate([Configuration(scenario=SCENARIO, kbar=2, intruder=spec)], episodes=2, batch_size=2,
                 progress=False, showcase=False)
    with pytest.raises(ValueError, match=r"unknown table.*'no-such-table'"):
        environment(AttackSpec(target="kbar", scenario=SCENARIO, kbar=2, options=(("intruder", spec),)))
    assert len(plugin.BUILDS) == builds


def test_a_run_that_does_not_read_the_table_does_not_build_it(plugin):
    from stp_env.evaluation.runner import build_params, required_tables

    builds = len(plugin.BUILDS)
    config = Configuration(scenario=SCENARIO, kbar=2, intruder="hj")
    assert required_tables(config) == () and required_tables(Configuration(intruder=f"{MODULE}:INTRUDER")) == (TABLE,)
    (params,) = build_params([config], progress=False)
    assert params.tables.extra == () and params.tables.buffer_values is None
    assert len(plugin.BUILDS) == builds


def test_the_falsifier_builds_the_table_of_its_intruder(plugin):
    """The k̄ attack's environment carries the table its intruder reads; an attack on params without it is refused
    and names the table (nothing compiles here)."""
    from stp_env.falsify.counterexample import AttackSpec, environment
    from stp_env.falsify.kbar import KbarAttack

    spec = f"{MODULE}:INTRUDER"
    builds = len(plugin.BUILDS)
    params = environment(AttackSpec(target="kbar", scenario=SCENARIO, kbar=2, options=(("intruder", spec),)))
    assert [t.name for t in params.tables.extra] == [TABLE] and len(plugin.BUILDS) == builds + 1
    assert KbarAttack(base=params, intruder=spec).required_tables == (TABLE,)
    bare = params.replace(tables=dict(extra=()))
    with pytest.raises(ValueError, match=re.escape(f"'{TABLE}' (distance to the domain's centre")):
        KbarAttack(base=bare, intruder=spec)


@pytest.mark.slow  # compiles the environment's step and an evaluation batch of the smallest scenario
def test_a_table_reading_intruder_from_one_file_flies_in_the_environment_and_the_evaluator(plugin):
    from stp_env.env import parallel_env
    from stp_env.evaluation.runner import evaluate

    spec = f"{MODULE}:INTRUDER"
    builds = len(plugin.BUILDS)
    # the environment: the table is built once, for the scenario's k̄, and lands in the params by name
    env = parallel_env(SCENARIO, intruder=spec, appear_window=(0.0, 0.0), progress=False)
    assert plugin.BUILDS[builds:] == [(SCENARIO, None)] and "intruder" not in env.possible_agents
    (table,) = env.params.tables.extra
    values, grid = plugin.centre_distance(env.scenario, kbar=None, store=None, progress=False)
    del plugin.BUILDS[-1]
    assert table.name == TABLE and table.grid == grid and np.allclose(np.asarray(table.values), values)
    assert env.params.tables.buffer_values is None  # it reads its own table only
    env.reset(seed=0)
    checked = 0
    for _ in range(5):
        if not env.agents:
            break
        env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
        state = env._state
        if int(state.intruder_status) == sim.PRESENT:
            # the policy reads the table the env built: its action is the analytic table's descent direction
            action = np.asarray(plugin.INTRUDER(jax.random.key(0), state, env.params))
            np.testing.assert_allclose(action, _expected_action(state), atol=0.02)
            checked += 1
    assert checked >= 3 and len(plugin.BUILDS) == builds + 1
    # the evaluator: built once for the configuration, read by the compiled rollout (which could not trace without
    # it: stp_env.sim.tables.extra_table raises for a table the params lack)
    (result,) = evaluate([Configuration(scenario=SCENARIO, kbar=2, intruder=spec)], episodes=4, batch_size=4,
                         progress=False, showcase=False)
    assert result.summary["episodes"] == 4 and plugin.BUILDS[builds + 1:] == [(SCENARIO, 2)]
    with pytest.raises(ValueError, match=re.escape(f"table '{TABLE}' is not in the params")):
        plugin.INTRUDER(jax.random.key(0), env._state, env.params.replace(tables=dict(extra=())))
