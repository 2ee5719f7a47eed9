"""The extension points of docs/architecture.md, each used by one small piece written here as a user would: a wind
model, an intruder, a falsifier target, a scenario (a catalog module found automatically) and a vehicle model (a
double integrator in place of the Dubins plant), each run through the environment or the registry that picks it
up."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import assembly, scenarios, sim
from stp_env.env import parallel_env
from stp_env.evaluation.config import Configuration
from stp_env.evaluation.runner import required_tables
from stp_env.falsify import harness
from stp_env.falsify.kbar import attack_tables
from stp_env.falsify.targets import register as register_target
from stp_env.policies.intruders import (
    BUFFER_GAME_INTRUDERS,
    INTRUDERS,
    Intruder,
    capabilities,
    register_intruder,
    resolve_intruder,
)
from stp_env.policies.vehicles import nominal_tracking
from stp_env.sim import winds
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN, WIND
from stp_env.sim.jit import sim_jit
from stp_env.sim.physics import dubins_step
from stp_env.sim.vehicle_models import Dubins, VehicleModel
from stp_env.sim.winds.base import WindModel

SCENARIO = "tiny-intruder"


# ------------------------------------------------------------------------------------------------ a wind model
@dataclasses.dataclass(frozen=True)
class Steady(WindModel):
    """A steady wind of ``speed`` [m/s] from the west for every agent, whatever its bound."""

    speed: float = 2.0
    name = "test-steady"
    help = "a steady west wind"

    def draw(self, key, state, params):
        del key, params
        w = jnp.zeros_like(state.wind).at[:, 0].set(self.speed)
        return w, state.wind


@pytest.fixture
def steady_registered(monkeypatch):
    monkeypatch.setitem(winds.WIND_MODELS, Steady.name, Steady)
    return Steady


@pytest.mark.slow  # compiles the core step
def test_a_registered_wind_model_is_configurable_by_spec_and_moves_the_vehicles(steady_registered):
    assert Steady.name in winds.names() and "test-steady (speed=2.0)" in winds.describe()
    config = sim.EnvConfig(wind_model="test-steady:speed=3")
    assert config.wind_model == Steady(speed=3.0)
    with pytest.raises(ValueError, match="wind_model"):
        sim.EnvConfig(wind_model="test-steady:gust=3")
    env = parallel_env(SCENARIO, config, max_cycles=40)
    env.reset(seed=0)
    params = env.params
    for _ in range(30):
        before = env.env_state
        fly = np.asarray(before.status) == sim.FLYING
        actions = {a: np.asarray([0.3, -0.2], np.float32) for a in env.agents}
        env.step(actions)
        after = env.env_state
        moving = fly & (np.asarray(after.status) == sim.FLYING) & (np.asarray(after.mode) == sim.NOMINAL)
        if moving.any():
            break
    assert moving.any(), "no vehicle flew a whole step"
    # The motion is exact Dubins with the steady wind over the inner steps (tiny has no heading disturbance).
    b = params.vehicles.bounds
    v = b[V_MIN] + 0.5 * 1.3 * (b[V_MAX] - b[V_MIN])
    omega = -0.2 * b[OMEGA_MAX]
    x = before.x
    h = params.episode.dt / params.episode.control_substeps
    for _ in range(params.episode.control_substeps):
        x = dubins_step(x, v, omega, jnp.asarray([3.0, 0.0]), h)
    np.testing.assert_allclose(np.asarray(after.x)[moving], np.asarray(x)[moving], atol=1e-3)
    x_calm = dubins_step(before.x, v, omega, jnp.zeros(2), params.episode.dt)
    assert np.all(np.abs(np.asarray(after.x)[moving, 0] - np.asarray(x_calm)[moving, 0] - 0.3) < 1e-2)


# ------------------------------------------------------------------------------------------------ an intruder
def circling(key, state, params):
    """An intruder that flies full speed in its tightest left turn."""
    del key, state, params
    return jnp.asarray([1.0, 1.0])


@pytest.mark.slow  # compiles the core step
def test_an_intruder_module_is_found_by_its_import_spec():
    policy = resolve_intruder(f"{__name__}:circling")
    assert policy is circling
    params = assembly.params_for(SCENARIO, sim.EnvConfig(appear_window=(5.0, 5.0)), progress=False)
    key = jax.random.key(0)

    @sim_jit
    def run(state):
        def body(s, k):
            a = jnp.concatenate([s.track_action, policy(key, s, params)[None]])
            s, _ = sim.step(jax.random.fold_in(key, k), s, a, params)
            return s, (s.intruder_status, s.intruder_x[2])

        return jax.lax.scan(body, state, jnp.arange(120))[1]

    status, heading = jax.device_get(run(sim.reset(key, params)))
    headings = heading[status == sim.PRESENT]
    assert len(headings) > 20
    turn = np.diff(np.unwrap(headings)) / float(params.episode.dt)
    assert np.all(turn > 0.0) and np.median(turn) == pytest.approx(float(params.intruder.bounds[OMEGA_MAX]), rel=0.05)


# A plug-in intruder with its capabilities: a record, not a bare function, in this file only. The environment, the
# evaluator and the falsifier read where it spawns and the tables it reads from the record.
CIRCLING = Intruder(circling, spawn="boundary", description="full speed in its tightest left turn")


def test_an_intruder_record_says_what_running_it_takes():
    spec = f"{__name__}:CIRCLING"
    assert resolve_intruder(spec) is CIRCLING and resolve_intruder(spec) is resolve_intruder(spec)  # once
    assert capabilities(spec) is CIRCLING and capabilities(circling) == Intruder(circling)   # a bare policy: defaults
    assert capabilities("optimal-max-k").tables == ("buffer",) and capabilities("max-k").spawn == "boundary"
    assert BUFFER_GAME_INTRUDERS == {"optimal-max-k"}
    reader = Intruder(circling, tables=("buffer",))
    assert required_tables(Configuration(intruder=spec)) == ()
    assert Configuration(intruder=spec).effective_spawn_mode == "boundary"
    assert Configuration(intruder="hj").effective_spawn_mode == "outside"
    with pytest.raises(ValueError, match="spawn must be one of"):
        Intruder(circling, spawn="sky")
    with pytest.raises(ValueError, match="a function"):
        Intruder("circling")
    register_intruder("test-circling-reader", reader)
    try:
        assert required_tables(Configuration(intruder="test-circling-reader")) == ("buffer",)
        assert attack_tables("switching", "test-circling-reader") == ("buffer",)
        assert attack_tables("switching", spec) == ()
        with pytest.raises(ValueError, match="already registered"):
            register_intruder("test-circling-reader", Intruder(circling))
    finally:
        del INTRUDERS["test-circling-reader"]


@pytest.mark.slow  # compiles the environment's step, an evaluation batch and a falsifier search
def test_a_plugin_intruder_flies_in_the_environment_the_evaluator_and_the_falsifier():
    from stp_env.evaluation.runner import evaluate
    from stp_env.falsify.counterexample import AttackSpec, run
    from stp_env.falsify.search import SearchConfig

    spec = f"{__name__}:CIRCLING"
    # the environment flies it (a scripted intruder is not an agent) from where it spawns by default
    env = parallel_env(SCENARIO, intruder=spec, appear_window=(0.0, 0.0), progress=False)
    assert env.config.spawn_mode == "boundary" and "intruder" not in env.possible_agents
    omega = float(env.params.intruder.bounds[OMEGA_MAX])
    env.reset(seed=0)
    headings = []
    for _ in range(150):
        if int(env._state.intruder_status) == sim.GONE or not env.agents:  # it left (t_IAT after it appeared)
            break
        env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
        if int(env._state.intruder_status) == sim.PRESENT:
            headings.append(float(env._state.intruder_x[2]))
    turn = np.diff(np.unwrap(headings)) / float(env.params.episode.dt)
    assert len(headings) > 10 and np.median(turn) == pytest.approx(omega, rel=0.05)
    # the evaluator runs it, spawned on the boundary by its record
    (result,) = evaluate([Configuration(scenario=SCENARIO, kbar=2, intruder=spec)], episodes=4, batch_size=4,
                         progress=False, showcase=False)
    assert result.summary["episodes"] == 4 and "boundary" in result.config.label
    # the falsifier's k̄ attack flies it from the spawn it searches
    outcome = run(AttackSpec(target="kbar", scenario=SCENARIO, kbar=2, options=(("intruder", spec),)),
                  SearchConfig(budget=8, population=8, restarts=1, batch=8), progress=False)
    assert outcome.evaluations == 8 and math.isfinite(outcome.worst)


# ---------------------------------------------------------------------------------------- a falsifier target
@register_target
@dataclasses.dataclass(frozen=True)
class SteadyWindAttack:
    """A falsifier target written as a user would: the wind held constant over ``horizon`` seconds (its direction
    and strength searched) against the tracker of a straight 12 m/s reference; the bound is ``r_e``."""

    base: sim.EnvParams
    horizon: float = 3.0
    name: str = "test-steady-wind"

    @property
    def n_steps(self) -> int:
        return round(self.horizon / float(self.base.episode.dt))

    @property
    def dim(self) -> int:
        return 2

    @property
    def bound(self) -> float:
        return float(self.base.tables.tracking_bound)

    def margin(self, value: float) -> float:
        return self.bound - value

    def simulate(self, z, record: bool = False):
        n = self.n_steps + 2
        params = harness.one_vehicle(self.base, n, wind_model="constant")
        params = params.replace(intruder=dict(appear_window=jnp.full((2,), 1.0e9, jnp.float32)))  # no intruder
        controls = jnp.tile(jnp.asarray([12.0, 0.0], jnp.float32), (n, 1))
        params = harness.with_reference(params, harness.reference(jnp.zeros(3), controls, float(self.base.episode.dt)),
                                        controls)
        w = harness.disk(z, self.base.vehicles.bounds[WIND], 1, self.n_steps)
        state = sim.reset(jax.random.key(0), params)
        return harness.run(params, state, self.n_steps, vehicle_policy=nominal_tracking,
                           winds=jnp.stack([w, jnp.zeros_like(w)], axis=1), record=record)

    def objective(self, z):
        final, _ = self.simulate(z)
        return final.max_tracking_error[0]

    def details(self, z) -> dict:
        return {"max_error_m": round(float(self.objective(jnp.asarray(z, jnp.float32))), 4)}

    def draw(self, ax, ax2, z) -> None:
        final, (x, _, t) = self.simulate(jnp.asarray(z, jnp.float32), record=True)
        ax.plot(np.asarray(x[:, 0, 0]), np.asarray(x[:, 0, 1]), label="vehicle")
        ax2.axhline(self.bound, ls="--", label="r_e")
        ax2.plot(np.asarray(t), np.full(len(t), float(final.max_tracking_error[0])), label="largest error")


def test_a_falsifier_target_from_one_file_searches_saves_draws_and_replays(tmp_path):
    from stp_env.falsify import targets
    from stp_env.falsify.cli import add_parser
    from stp_env.falsify.counterexample import AttackSpec, replay, run, save
    from stp_env.falsify.search import SearchConfig

    assert targets.attack_class("test-steady-wind") is SteadyWindAttack
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    args = parser.parse_args(["falsify", "--target", "test-steady-wind", "--option", "horizon=2"])
    assert args.target == "test-steady-wind"
    spec = AttackSpec(target="test-steady-wind", scenario=SCENARIO, options=(("horizon", 2.0),))
    outcome = run(spec, SearchConfig(budget=8, population=8, restarts=1, batch=8), progress=False)
    assert outcome.evaluations == 8 and 0.0 < outcome.worst < outcome.bound
    assert outcome.details == {"max_error_m": round(outcome.worst, 4)}
    path = save(outcome, tmp_path, plot=True, progress=False)
    assert (tmp_path / "counterexample.png").stat().st_size > 0
    recorded, recomputed = replay(path)
    assert recorded == recomputed
    with pytest.raises(ValueError, match="unknown target"):
        targets.attack_class("test-no-such-target")
    with pytest.raises(ValueError, match="already registered"):
        register_target(dataclasses.make_dataclass("Other", [("base", object)], bases=(SteadyWindAttack,),
                                                   frozen=True))


# ------------------------------------------------------------------------------------------------ a scenario
CATALOG_MODULE = '''
from stp_env.scenarios.catalog.tiny import tiny
from stp_env.scenarios.registry import register


@register("test-crossing-late")
def crossing_late(*, delay: float = 40.0):
    """tiny, with the second vehicle due ``delay`` seconds later."""
    return tiny(sta_spacing=delay).with_overrides(name="test-crossing-late")
'''


def test_a_scenario_module_in_a_catalog_package_is_found(tmp_path, monkeypatch):
    from stp_env.scenarios import registry

    package = tmp_path / "my_catalog"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "crossing_late.py").write_text(textwrap.dedent(CATALOG_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "CATALOG", "my_catalog")
    monkeypatch.setattr(registry, "_catalog_loaded", False)
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    try:
        assert "test-crossing-late" in scenarios.names()
        s = scenarios.make("test-crossing-late", delay=25.0)
        assert s.name == "test-crossing-late" and [v.sta for v in s.vehicles] == [0.0, 25.0]
        assert scenarios.factory_parameters("test-crossing-late") == ("delay",)
    finally:
        sys.modules.pop("my_catalog.crossing_late", None)
        sys.modules.pop("my_catalog", None)


# ------------------------------------------------------------------------------------------------ a vehicle model
@dataclasses.dataclass(frozen=True)
class DoubleIntegrator(VehicleModel):
    """A point mass: state ``(x, y, v_x, v_y)``, action the acceleration over ``accel_max``, speed capped at
    ``v_max``; it flies toward the papers' ``(v, omega)`` commands by matching the velocity they would give after
    ``horizon`` seconds."""

    accel_max: float = 4.0
    v_max: float = 15.0
    horizon: float = 1.0
    name = "double-integrator"
    state_dim = 4

    def action_to_control(self, action, bounds):
        del bounds
        return jnp.clip(action, -1.0, 1.0) * self.accel_max

    def step(self, x, control, wind, heading_disturbance, dt):
        del heading_disturbance
        vel = x[..., 2:4]
        new = vel + control * dt
        speed = jnp.linalg.norm(new, axis=-1, keepdims=True)
        new = new * jnp.minimum(1.0, self.v_max / jnp.maximum(speed, 1e-9))
        p = x[..., :2] + 0.5 * (vel + new) * dt + wind * dt
        return jnp.concatenate([p, new], axis=-1)

    def pose(self, x):
        heading = jnp.arctan2(x[..., 3], x[..., 2])
        return jnp.concatenate([x[..., :2], heading[..., None]], axis=-1)

    def from_pose(self, pose):
        c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
        return jnp.stack([pose[..., 0], pose[..., 1], 0.8 * self.v_max * c, 0.8 * self.v_max * s], axis=-1)

    def command_to_action(self, x, v, omega, bounds):
        del bounds
        heading = jnp.arctan2(x[..., 3], x[..., 2]) + omega * self.horizon
        want = v[..., None] * jnp.stack([jnp.cos(heading), jnp.sin(heading)], axis=-1)
        return jnp.clip((want - x[..., 2:4]) / (self.horizon * self.accel_max), -1.0, 1.0)


@pytest.mark.slow  # compiles the core step
def test_a_second_vehicle_model_runs_in_the_environment():
    model = DoubleIntegrator()
    dubins = parallel_env(SCENARIO, max_cycles=5)
    env = parallel_env(SCENARIO, sim.EnvConfig(vehicle_model=model, safety_filter=False), max_cycles=150)
    assert env.params.vehicles.model == model
    obs, _ = env.reset(seed=1)
    assert env.env_state.x.shape == (env.params.vehicles.n, 4)
    assert env.observation_space("vehicle_0") == dubins.observation_space("vehicle_0")
    assert env.action_space("vehicle_0").shape == (model.action_dim,)
    speeds, checked = [], 0
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, *_ = env.step(actions)
        x = np.asarray(env.env_state.x)
        fly = np.asarray(env.env_state.status) == sim.FLYING
        speeds.extend(np.linalg.norm(x[fly, 2:4], axis=1))
        for i in np.nonzero(fly)[0]:
            name = f"vehicle_{i}"
            if name in obs:  # the observation's heading is the model's pose: the velocity's direction
                unit = x[i, 2:4] / np.linalg.norm(x[i, 2:4])
                np.testing.assert_allclose(obs[name][2:4], unit, atol=1e-5)
                checked += 1
        assert all(np.isfinite(r) for r in rewards.values())
    assert checked > 10 and speeds and max(speeds) <= model.v_max * (1 + 1e-5)
    # The papers' tracker drives the plant through command_to_action: with the vehicles on the tracker, they
    # follow their plans to a few hundred metres (the plans are Dubins; the plant is not).
    params = env.params
    key = jax.random.key(0)

    @sim_jit
    def run(state):
        def body(s, k):
            a = jnp.concatenate([s.track_action, jnp.zeros((1, 2))])
            s, _ = sim.step(jax.random.fold_in(key, k), s, a, params)
            return s, (s.status, s.tracking_error)

        return jax.lax.scan(body, state, jnp.arange(200))[1]

    status, error = jax.device_get(run(sim.reset(key, params)))
    errors = error[status == sim.FLYING]
    assert errors.size and float(np.median(errors)) < 150.0


# ------------------------------------------------------------------------------------------------ the bases
def test_a_model_missing_a_required_method_fails_at_instantiation_naming_it():
    """The bases are abstract: a subclass that leaves out a required method cannot be made (a clear
    ``TypeError`` naming the method, at construction, not a ``NotImplementedError`` deep inside a jitted step)."""

    @dataclasses.dataclass(frozen=True)
    class NoFromPose(VehicleModel):
        action_to_control = DoubleIntegrator.action_to_control
        step = DoubleIntegrator.step
        pose = DoubleIntegrator.pose
        command_to_action = DoubleIntegrator.command_to_action

    @dataclasses.dataclass(frozen=True)
    class NoDraw(WindModel):
        name = "test-no-draw"

    with pytest.raises(TypeError, match=r"abstract method.*from_pose"):
        NoFromPose()
    with pytest.raises(TypeError, match=r"abstract method.*draw"):
        NoDraw()
    with pytest.raises(TypeError, match="abstract method"):
        VehicleModel()
    with pytest.raises(TypeError, match="abstract method"):
        WindModel()
    # the complete ones (the package's and the ones above) are made, hashable and compared by value
    assert DoubleIntegrator() == DoubleIntegrator() and hash(Steady(speed=3.0)) == hash(Steady(speed=3.0))
    for name in winds.names():
        winds.make(name)
    assert Dubins() == Dubins()
