"""The pymunk backend (stp_env.sim.vehicle_models.rigid_body): the kinematic body against the exact Dubins step
(one step, and a closed-loop episode through the core in float64), the PettingZoo API and seeding on it, and the
dynamic body against closed forms and its kinematic limit."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from stp_env import assembly, sim
from stp_env.env import parallel_env
from stp_env.sim.backends import vehicle_model, with_backend
from stp_env.sim.physics import dubins_step
from stp_env.sim.vehicle_models import Dubins
from stp_env.sim.vehicle_models.rigid_body import PymunkKinematic, PymunkRigidBody, RigidBodyConfig

pytest.importorskip("pymunk")

SCENARIO = "tiny-intruder"
ROOT = pathlib.Path(__file__).resolve().parents[1]


def _inputs(n=9, seed=0):
    rng = np.random.default_rng(seed)
    f = np.float32
    x = (rng.normal(size=(n, 3)) * [300, 300, 2]).astype(f)
    return (jnp.asarray(x), jnp.asarray(rng.uniform(5, 15, n).astype(f)), jnp.asarray(rng.uniform(-1, 1, n).astype(f)),
            jnp.asarray(rng.normal(size=(n, 2)).astype(f)), jnp.asarray((0.1 * rng.normal(size=n)).astype(f)))


@pytest.mark.slow
@pytest.mark.parametrize("substeps", [1, 4])
def test_kinematic_step_is_the_exact_dubins_step(substeps):
    x, v, w, wind, head = _inputs()
    model = PymunkKinematic(substeps=substeps)
    got = np.asarray(jax.jit(model.step)(x, (v, w), wind, head, jnp.float32(0.1)))
    want = np.asarray(dubins_step(x, v, w + head, wind, 0.1))
    np.testing.assert_allclose(got[:, :2], want[:, :2], atol=1e-4)  # float32 spacing at 500 m is 3e-5 m
    np.testing.assert_allclose(np.cos(got[:, 2] - want[:, 2]), 1.0, atol=1e-10)
    # batched (a vmap is one host call with every body)
    xs = jnp.stack([x, x.at[:, :2].add(10.0)])
    batched = np.asarray(jax.vmap(lambda xx: model.step(xx, (v, w), wind, head, 0.1))(xs))
    np.testing.assert_allclose(batched[0], got, atol=1e-4)
    np.testing.assert_allclose(batched[1, :, :2], got[:, :2] + 10.0, atol=1e-4)


@pytest.mark.slow  # two compilations of the core step, in a float64 subprocess
def test_kinematic_backend_flies_the_core_episode_to_rounding():
    """Closed loop (the switching vehicles, a scripted intruder) through the whole core, in float64: the papers'
    tracker is bang-bang, so any real difference in the motion would flip a decision and show up in metres."""
    code = ("import json, sys; sys.path.insert(0, 'examples'); import pymunk_agreement as m; "
            f"print(json.dumps(m.compare({SCENARIO!r}, seed=1, n_steps=50)))")
    env = dict(os.environ, JAX_ENABLE_X64="1", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=900, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["dtype"] == "float64" and result["flying_vehicle_steps"] > 40
    assert result["max_position_difference_m"] < 1e-6
    assert result["same_status"] and result["same_avoid_starts"]


def test_backend_names():
    assert vehicle_model("jax") == Dubins()
    assert vehicle_model("pymunk") == PymunkKinematic()
    model = vehicle_model("pymunk-dynamic:mass=2,speed_time_constant=0.3")
    assert model == PymunkRigidBody(RigidBodyConfig(mass=2.0, speed_time_constant=0.3))
    for bad, match in (("bullet", "backend 'bullet'"), ("pymunk-dynamic:size=3", "size=3"),
                       ("pymunk-dynamic:mass=heavy", "mass"),
                       ("pymunk:mass=1", r"parameter of .pymunk. \(parameters: none\)")):
        with pytest.raises(ValueError, match=match):
            vehicle_model(bad)
    with pytest.raises(ValueError, match="both choose the plant"):
        with_backend(sim.EnvConfig(vehicle_model=PymunkRigidBody()), "pymunk")


@pytest.mark.parametrize("field, value, match", [
    ("mass", 0.0, "mass must be > 0"), ("speed_time_constant", -0.1, ">= 0"), ("linear_drag", float("nan"), "finite"),
    ("max_substep", 0.02, "quarter of mass / linear_drag"), ("wind_coupling", True, "finite number")])
def test_rigid_body_config_is_checked(field, value, match):
    with pytest.raises(ValueError, match=match):
        RigidBodyConfig(**{field: value})


@pytest.mark.slow  # compiles the adapter's step for the pymunk plant
def test_pettingzoo_api_and_seeds_on_pymunk():
    par = parallel_env(SCENARIO, backend="pymunk", max_cycles=50)
    assert isinstance(par.params.vehicles.model, PymunkKinematic)
    parallel_api_test(par, num_cycles=50)
    parallel_seed_test(lambda: parallel_env(SCENARIO, backend="pymunk", max_cycles=30), num_cycles=30)


def _drive(model, commands, wind, dt=0.02, x0=(0.0, 0.0, 0.0)):
    """Positions ``(T, 2)`` of one vehicle flown open loop through ``commands`` ``(T, 2)`` of ``(v, omega)``."""
    x = model.from_pose(jnp.asarray([x0], jnp.float32))
    step = jax.jit(lambda x, v, w: model.step(x, (v, w), jnp.asarray([wind], jnp.float32), jnp.zeros(1), dt))
    out = []
    for v, w in commands:
        x = step(x, jnp.asarray([v], jnp.float32), jnp.asarray([w], jnp.float32))
        out.append(np.asarray(x[0]))
    return np.asarray(out)


@pytest.mark.slow
def test_dynamic_speed_step_response_is_two_cascaded_lags():
    """A speed step from 8 to 12 m/s: actuator lag tau_a, then the body's m / c_lin: the closed form of two
    first-order lags in series."""
    cfg = RigidBodyConfig(speed_time_constant=0.2, turn_time_constant=0.0)
    model = PymunkRigidBody(cfg)
    commands = [(8.0, 0.0)] + [(12.0, 0.0)] * 60
    x = _drive(model, commands, wind=(0.0, 0.0))
    t = 0.02 * np.arange(1, 61)
    t1, t2 = cfg.speed_time_constant, cfg.velocity_time_constant
    want = 8.0 + 4.0 * (1 - (t1 * np.exp(-t / t1) - t2 * np.exp(-t / t2)) / (t1 - t2))
    np.testing.assert_allclose(x[1:, 3], want, atol=0.02)
    np.testing.assert_allclose(x[1:, 6], 12.0 - 4.0 * np.exp(-t / t1), atol=1e-4)   # the actuator's own state


@pytest.mark.slow
def test_dynamic_body_approaches_dubins_as_lags_vanish_and_drifts_with_lag():
    """Open loop through a turning manoeuvre in wind: as the body time constants shrink (no actuator lag) the rigid
    body converges to the Dubins path at first order (a heading lag of ``omega I / c_ang`` per turn-rate change);
    with actuator lag it drifts away, more with more lag."""
    commands = [(10.0, 0.5)] * 50 + [(14.0, -0.8)] * 50 + [(8.0, 0.0)] * 50
    wind = (2.0, -1.0)
    dubins = _drive(Dubins(), commands, wind)

    def deviation(cfg):
        x = _drive(PymunkRigidBody(cfg), commands, wind)
        return float(np.max(np.hypot(*(x[:, :2] - dubins[:, :2]).T)))

    def light(scale):  # body time constants 0.005 s * scale, no actuator lag
        return RigidBodyConfig(mass=0.1 * scale, moment=0.001 * scale, speed_time_constant=0.0,
                               turn_time_constant=0.0, max_substep=0.001 * scale)

    coarse, fine = deviation(light(1.0)), deviation(light(0.5))
    assert fine < 0.2 and 1.6 < coarse / fine < 2.5, (coarse, fine)
    lag_1, lag_3 = (deviation(RigidBodyConfig(speed_time_constant=t, turn_time_constant=t)) for t in (0.1, 0.3))
    assert lag_1 > 10 * fine and lag_3 > 1.5 * lag_1, (fine, lag_1, lag_3)


def test_sensor_shapes_agree_with_the_signed_distance_events():
    """pymunk sensor shapes and collision callbacks (buildings as static polygons, R_c / 2 circles) against the
    core's collision tests (the buildings' signed-distance table, pairwise distances) at random points of town."""
    from stp_env.scenarios import make
    from stp_env.sim.core import building_distance
    from stp_env.sim.vehicle_models.contacts import SensorWorld

    scenario = make("town")
    params = assembly.params_for(scenario, sim.EnvConfig(), progress=False)
    world = SensorWorld(scenario.buildings, float(params.episode.collision_radius))
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(params.episode.domain_lo), np.asarray(params.episode.domain_hi)
    spacing = float(np.max((hi - lo) / (np.asarray(params.tables.sdf.shape) - 1)))
    checked_inside = checked_pairs = 0
    boxes = [(np.min(b.vertices, axis=0) - spacing, np.max(b.vertices, axis=0) + spacing)
             for b in scenario.buildings]
    for _ in range(10):
        p = lo + rng.uniform(size=(40, 2)) * (hi - lo)
        p[10:20] = p[:10] + rng.normal(size=(10, 2)) * float(params.episode.collision_radius)  # close pairs
        for k in range(20, 40):  # around the buildings
            b_lo, b_hi = boxes[rng.integers(len(boxes))]
            p[k] = b_lo + rng.uniform(size=2) * (b_hi - b_lo)
        active = rng.uniform(size=40) < 0.9
        hit_vehicle, hit_building = world.contacts(p, active)
        sdf = np.asarray(building_distance(params, jnp.asarray(p, jnp.float32)))
        # away from the boundary: the bilinear table's error (14 m at most near town's corners, 50 m cells)
        clear = np.abs(sdf) > 0.5 * spacing
        np.testing.assert_array_equal(hit_building[active & clear], (sdf <= 0)[active & clear])
        assert not hit_building[~active].any() and not hit_vehicle[~active].any()
        d = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)) + np.where(np.eye(40, dtype=bool), np.inf, 0.0)
        d = np.where(active[:, None] & active[None, :], d, np.inf)
        near = np.any(d <= float(params.episode.collision_radius), axis=1)
        sure = np.all(np.abs(d - float(params.episode.collision_radius)) > 1e-6, axis=1)
        np.testing.assert_array_equal(hit_vehicle[sure], near[sure])
        checked_inside += int((active & clear & (sdf <= 0)).sum())
        checked_pairs += int(near.sum())
    assert checked_inside > 20 and checked_pairs > 30, (checked_inside, checked_pairs)
