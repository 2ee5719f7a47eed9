"""Batches shared among devices (stp_env.sim.engine.across_devices, stp_env.set_cpu_devices): every episode computed
once, in order, padding cut off, the work actually spread; the device count refused once fixed; a real rollout
on two CPU devices keeps every episode's outcome."""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from stp_env import cpu_threads

_TOY = """
import json, sys
import jax, jax.numpy as jnp, numpy as np
import stp_env
stp_env.set_cpu_devices(int(sys.argv[1]))
from stp_env.sim import engine

def init(k):
    return {"n": jax.random.randint(k, (), 0, 1000), "sum": jnp.zeros((), jnp.int32)}

def step(c, k):
    n = c["n"] + jax.random.randint(k, (), 0, 7)
    return {"n": n, "sum": c["sum"] + n * n}, n % 5

stop = lambda c: c["sum"] > 40000
out = {}
for b in (1, 2, 3, 7, 8):
    keys = jax.random.split(jax.random.key(b), b)
    run = jax.jit(lambda ks: engine.episodes(ks, init, step, 12, stop=stop, record=lambda c, i: (c["n"], i)))
    final, rec = run(keys)
    # the reference: each episode alone (one device, a batch of one: integers, so exact in any program)
    alone = [engine.episode(k, init, step, 12, stop=stop, record=lambda c, i: (c["n"], i)) for k in keys]
    out[b] = {
        "devices": len(final["n"].sharding.device_set),
        "final": np.asarray(final["sum"]).tolist(), "records": [np.asarray(r).tolist() for r in rec],
        "alone_final": [int(f["sum"]) for f, _ in alone],
        "alone_records": [[np.asarray(r[j]).tolist() for _, r in alone] for j in range(2)],
    }
# vmap_across_devices: any positional batch, spread over the devices; a share is not shared again
f = lambda a, b: (a * b, jnp.sum(jax.vmap(lambda x: x + 1)(jnp.arange(3)) * a))
inner = lambda a, b: engine.vmap_across_devices(lambda x, y: x - y)(jnp.full((4,), a), jnp.full((4,), b))
a, b = jnp.arange(7, dtype=jnp.int32), jnp.arange(7, 14, dtype=jnp.int32)
got, total = jax.jit(engine.vmap_across_devices(f))(a, b)
nested = jax.jit(engine.vmap_across_devices(inner))(a, b)
out["vmap"] = {"devices": len(got.sharding.device_set), "got": np.asarray(got).tolist(),
               "total": np.asarray(total).tolist(), "nested": np.asarray(nested).tolist()}
errors = []
for n in (int(sys.argv[1]), int(sys.argv[1]) + 1):
    try:
        stp_env.set_cpu_devices(n)
        errors.append(None)
    except RuntimeError as err:
        errors.append(str(err))
print(json.dumps({"out": out, "errors": errors, "n_devices": len(jax.devices())}))
"""


def _run(code: str, *args, env_vars: dict | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    for k, v in (env_vars or {}).items():
        if v is None:
            env.pop(k, None)
        else:
            env[k] = v
    out = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_episodes_shared_among_three_devices_are_each_computed_once_in_order():
    got = _run(_TOY, 3)
    assert got["n_devices"] == 3
    v = got["out"].pop("vmap")
    assert v["devices"] == 3 and v["got"] == [i * (i + 7) for i in range(7)]
    assert v["total"] == [6 * i for i in range(7)] and v["nested"] == [[-7] * 4] * 7
    for b, case in got["out"].items():
        b = int(b)
        # below the device count the batch stays on one device; from it on, it is spread over all three
        assert case["devices"] == (1 if b < 3 else 3), (b, case["devices"])
        assert case["final"] == case["alone_final"]
        assert case["records"] == case["alone_records"]
        assert len(case["final"]) == b  # the padding (7 -> 9 episodes) is cut off
    assert got["errors"][0] is None and "already started with 3 device(s)" in got["errors"][1]


_ROLLOUT = """
import json, sys
import jax, numpy as np
import stp_env
stp_env.set_cpu_devices(int(sys.argv[1]))
from stp_env import assembly, sim
from stp_env.policies import INTRUDERS, switching
from stp_env.scenarios import make
scenario = make("town")
avoid, tracking = assembly.load_artifacts(scenario, progress=False)
plan = assembly.load_plan(scenario, tracking_bound=tracking.bound, progress=False)
params = assembly.make_params(scenario, plan, avoid, tracking, sim.EnvConfig())
final, _ = sim.rollout(jax.random.key(5), params, switching, INTRUDERS["hj"], 10, 80)
print(json.dumps({"devices": len(final.x.sharding.device_set), "status": np.asarray(final.status).tolist(),
                  "mode": np.asarray(final.mode).tolist(), "intruder": np.asarray(final.intruder_status).tolist(),
                  "x": np.asarray(final.x).tolist()}))
"""


@pytest.mark.slow
def test_a_rollout_on_two_cpu_devices_keeps_every_episodes_outcome():
    one, two = _run(_ROLLOUT, 1), _run(_ROLLOUT, 2)
    assert (one["devices"], two["devices"]) == (1, 2)
    for field in ("status", "mode", "intruder"):
        assert one[field] == two[field], field
    # another compiled program: positions agree to well under the 1 m the closed loops can amplify a last bit into
    # at a tie (docs/numerics.md); these ten episodes have none
    import numpy as np

    assert np.max(np.abs(np.asarray(one["x"]) - np.asarray(two["x"]))) < 1e-2


@pytest.mark.parametrize("bad", [0, -2, True, 1.5, "2"])
def test_bad_device_counts_are_refused(bad):
    with pytest.raises(ValueError, match="positive integer"):
        cpu_threads.set_cpu_devices(bad)


def test_the_device_count_in_effect_is_accepted():
    cpu_threads.set_cpu_devices(cpu_threads.cpu_devices())  # a no-op, also after the backend started


_VEC_ENV = """
import json, sys
import jax, numpy as np
import stp_env
stp_env.set_cpu_devices(int(sys.argv[1]))
from stp_env.rl import IntruderVecEnv
env = IntruderVecEnv(6, "tiny-intruder")
env.seed(3)
obs = [env.reset()]
rewards, dones = [], []
rng = np.random.default_rng(0)
for _ in range(130):
    o, r, d, _ = env.step(rng.uniform(-1, 1, (6, 2)).astype(np.float32))
    obs.append(o); rewards.append(r); dones.append(d)
print(json.dumps({"devices": len(jax.tree.leaves(env._states)[0].sharding.device_set),
                  "obs": np.asarray(obs).tolist(), "rewards": np.asarray(rewards).tolist(),
                  "dones": np.asarray(dones).tolist()}))
"""


@pytest.mark.slow
def test_the_training_vec_env_shares_its_batch_and_keeps_every_episode():
    """The vectorised training environment's step (with its auto-reset) on two devices: the states stay spread over
    both between calls, and every env's episode is the one it flies on one device (dones the same, observations and
    rewards within float rounding)."""
    import numpy as np

    one, two = _run(_VEC_ENV, 1), _run(_VEC_ENV, 2)
    assert one["devices"] == 1 and two["devices"] == 2
    assert one["dones"] == two["dones"] and any(any(d) for d in one["dones"])  # an auto-reset happened
    np.testing.assert_allclose(two["obs"], one["obs"], atol=1e-4)
    np.testing.assert_allclose(two["rewards"], one["rewards"], atol=1e-4)


_ATTACKER_VEC_ENV = """
import json, sys
import numpy as np
import stp_env
stp_env.set_cpu_devices(int(sys.argv[1]))
import jax
from stp_env.coobservation import threat
from stp_env.coobservation.learned import make_vec_env
from stp_env.coobservation.uav import FormationScenario
sc = FormationScenario()
params = sc.params(artifacts=sc.coarse_artifacts())
tp = threat.threat_params(sc.schedule(sc.uniform_times(90.0)), sc.forbidden, sc.observation_radius)
venv = make_vec_env(4, params, tp, (100.0, 100.0), action_repeat=5, seed=1)
obs = [venv.reset()]
for _ in range(20):
    venv.step_async(np.full((4, 2), 0.3, np.float32))
    obs.append(venv.step_wait()[0])
print(json.dumps({"devices": len(jax.tree.leaves(venv._states)[0].sharding.device_set),
                  "obs": np.asarray(obs).tolist()}))
"""


@pytest.mark.slow
def test_the_co_observation_attackers_vec_env_shares_its_batch():
    """The learned attacker's VecEnv takes the environment and the threat whole on every device (copied there once):
    on two devices its states stay spread over both and its observations are those of one device."""
    import numpy as np

    one, two = _run(_ATTACKER_VEC_ENV, 1), _run(_ATTACKER_VEC_ENV, 2)
    assert one["devices"] == 1 and two["devices"] == 2
    np.testing.assert_allclose(two["obs"], one["obs"], atol=1e-4)


_COMPUTING_DEPENDENCIES = ("gymnax", "jaxmarl")
"""Dependencies that make a JAX array at import themselves (gymnax 1.0's ``frozen_lake`` module; JaxMARL imports
gymnax): a module of this package that imports one at its top starts the backend through it, and says so in its
docstring (set the device count before importing it)."""

_IMPORT_ALL = """
import importlib, importlib.abc, json, pkgutil, sys
import stp_env
from stp_env.cpu_threads import _backend_started
blocked = tuple(sys.argv[1].split(","))

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"blocked: {name}", name=name)
        return None

sys.meta_path.insert(0, Block())
started, needs = None, {}
for m in pkgutil.walk_packages(stp_env.__path__, "stp_env."):
    if m.name.endswith("__main__"):
        continue
    try:
        importlib.import_module(m.name)
    except ModuleNotFoundError as e:
        if (e.name or "").split(".")[0] not in blocked:
            raise
        needs[m.name] = e.name.split(".")[0]
        continue
    if _backend_started():
        started = m.name
        break
print(json.dumps({"started": started, "needs": needs}))
"""

_IMPORT_ONE = """
import importlib, json, sys
from stp_env.cpu_threads import _backend_started
importlib.import_module(sys.argv[1])
print(json.dumps({"started": _backend_started()}))
"""


@pytest.mark.slow
def test_importing_any_module_leaves_the_backend_unstarted():
    """The device count and the thread pools are fixed by JAX's first computation: no module may compute at import
    (a JAX constant made at module level did), or they could not be set after ``import stp_env.evaluation``. The
    modules that import a dependency which computes at import itself are checked without it, and the dependency is
    checked to compute (when it stops, this test says so, and the modules' docstrings should drop their warning)."""
    got = _run(_IMPORT_ALL, ",".join(_COMPUTING_DEPENDENCIES))
    assert got["started"] is None
    for module, dependency in got["needs"].items():
        if importlib.util.find_spec(dependency) is not None:  # installed (the jax-rl extra)
            assert _run(_IMPORT_ONE, dependency)["started"], f"{dependency} no longer computes at import ({module})"
        doc = ast.get_docstring(ast.parse(Path(importlib.util.find_spec(module).origin).read_text()))
        assert "set_cpu_devices" in doc and dependency in doc, f"{module} does not say it starts JAX's backend"


_EVALUATE = """
import json, sys, warnings
import numpy as np
from stp_env.cli import main
from stp_env.evaluation import replay_event
from stp_env.evaluation.events import load_event_state
out = sys.argv[1]
code = main(["evaluate", "--scenario", "tiny-intruder", "--kbar", "2", "--intruder", "greedy", "--vehicle-policy",
             "nominal", "--seed", "1", "--episodes", "5", "--batch-size", "5", "--cpu-devices", "2", "--out", out,
             "--no-figures", "--no-progress"])
summary = json.load(open(out + "/results.json"))["configurations"][0]
events = json.load(open(out + "/events.json"))
with warnings.catch_warnings():
    warnings.simplefilter("error")  # a replay on the evaluation's device count says nothing
    replayed, _ = replay_event(events[0])
saved = load_event_state(out + "/events.npz", events[0])
print(json.dumps({"code": code, "devices": summary["devices"], "event_devices": [e["devices"] for e in events],
                  "bit_for_bit": all(np.array_equal(saved[k], replayed[k], equal_nan=True) for k in saved)}))
"""


@pytest.mark.slow
def test_an_evaluation_on_two_devices_records_them_and_replays_bit_for_bit(tmp_path):
    got = _run(_EVALUATE, tmp_path)
    assert got["code"] == 0 and got["devices"] == 2
    assert got["event_devices"] and set(got["event_devices"]) == {2}  # the nominal vehicles collide: events exist
    assert got["bit_for_bit"]


def test_cpu_devices_are_refused_with_ray():
    import argparse

    from stp_env import cli_kit

    with pytest.raises(ValueError, match="with --ray"):
        cli_kit.apply_cpu_devices(argparse.Namespace(cpu_devices=2, ray=True, ray_address=None))


_DEFAULT = """
import argparse, json, sys
import jax
from stp_env import cli_kit
from stp_env.cpu_threads import available_cores, cpu_devices
args = argparse.Namespace(cpu_devices=json.loads(sys.argv[1]), ray=sys.argv[2] == "ray", ray_address=None,
                          cpu_devices_unset=json.loads(sys.argv[3]))
try:
    cli_kit.apply_cpu_devices(args)
    error = None
except ValueError as err:
    error = str(err)
print(json.dumps({"error": error, "devices": len(jax.devices()), "cores": available_cores()}))
"""


@pytest.mark.parametrize(("flag", "variable", "ray", "expected"), [
    (None, None, "", "cores"),        # the command line's default: one device per core
    (None, None, "unset=1", 1),       # a command whose default is one device (train-intruder)
    (None, "auto", "unset=1", "cores"),
    ("auto", "1", "", "cores"),       # the flag wins over the environment variable
    (None, "auto", "", "cores"),
    (None, "3", "", 3),
    (1, None, "", 1),
    (None, None, "ray", 1),           # auto with --ray: Ray's workers run the batches, this process stays at one
    (None, "1", "ray", 1),
])
def test_the_default_device_count_is_one_per_core_or_the_environment_variable(flag, variable, ray, expected):
    unset = 1 if ray == "unset=1" else "auto"
    got = _run(_DEFAULT, json.dumps(flag), ray, json.dumps(unset), env_vars={cpu_threads.DEVICES_ENV_VAR: variable})
    assert got["error"] is None
    assert got["devices"] == (got["cores"] if expected == "cores" else expected)


@pytest.mark.parametrize(("flag", "variable", "ray", "message"), [
    (None, "two", "", "STP_ENV_CPU_DEVICES must be a positive integer or 'auto'"),
    (None, "0", "", "STP_ENV_CPU_DEVICES must be a positive integer or 'auto'"),
    (None, "2", "ray", "STP_ENV_CPU_DEVICES shares the batches"),
    (2, None, "ray", "--cpu-devices shares the batches"),
])
def test_bad_default_device_counts_are_one_line_errors(flag, variable, ray, message):
    got = _run(_DEFAULT, json.dumps(flag), ray, json.dumps("auto"), env_vars={cpu_threads.DEVICES_ENV_VAR: variable})
    assert message in got["error"] and "\n" not in got["error"]
    assert got["devices"] == 1  # nothing was set


def test_auto_follows_a_backend_already_started():
    """In a process whose JAX has started (a notebook, the test suite), ``auto`` keeps the count it has."""
    import argparse

    import jax

    from stp_env import cli, cli_kit

    jax.numpy.zeros(1).block_until_ready()
    before = len(jax.devices())
    cli_kit.apply_cpu_devices(argparse.Namespace(cpu_devices="auto", ray=False, ray_address=None))
    assert cli._build_parser().parse_args(["train-intruder"]).cpu_devices_unset == 1
    assert cli._build_parser().parse_args(["evaluate"]).cpu_devices_unset == "auto"
    assert len(jax.devices()) == before


@pytest.mark.parametrize(("value", "ok"), [("auto", "auto"), ("2", 2), ("0", None), ("many", None), ("1.5", None)])
def test_the_cpu_devices_option_takes_a_positive_integer_or_auto(value, ok, capsys):
    from stp_env import cli

    parser = cli._build_parser()
    if ok is not None:
        assert parser.parse_args(["evaluate", "--cpu-devices", value]).cpu_devices == ok
        return
    with pytest.raises(SystemExit):
        parser.parse_args(["evaluate", "--cpu-devices", value])
    assert "expected a positive integer or 'auto'" in capsys.readouterr().err
