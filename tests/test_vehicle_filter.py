"""The tube-keeping filter and learned vehicle policies: the free level's closed form, the filter holding ``kappa``
outside the free set (and the core counting a tube exit from the free set as a guarantee violation), the
after-avoidance ego env, and the loaders' roles."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import assembly, sim
from stp_env.policies import tube_keeping
from stp_env.policies.learned import load_intruder
from stp_env.policies.learned_vehicles import load_vehicle_mlp
from stp_env.sim import core, observations
from stp_env.sim.margins import tube_free_level


def test_tube_free_level_closed_form():
    """``level - dt * max rate`` over the sub-level set, the rate ``|V_x| (dv + dw |e_y|) + |V_y| dw |e_x| +
    |V_theta| dw`` by hand; ``-inf`` when the set is empty."""
    value = np.array([1.0, 2.0, 3.0])
    gradient = np.array([[0.5, 1.0, 9.0], [0.2, 0.0, 9.0], [0.1, 0.3, 9.0]])
    states = np.array([[1.0, -2.0, 0.0], [-3.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    lo, hi = (0.0, -2.0), (25.0, 2.0)
    rate0 = 0.5 * (25.0 + 4.0 * 3.0) + 0.2 * 4.0 * 1.0 + 0.1 * 4.0
    rate1 = 1.0 * (25.0 + 4.0 * 1.0) + 0.0 + 0.3 * 4.0
    assert tube_free_level(value, gradient, states, lo, hi, 0.02, 2.0) == pytest.approx(2.0 - 0.02 * max(rate0, rate1))
    assert tube_free_level(value, gradient, states, lo, hi, 0.02, 0.5) == -math.inf


@pytest.fixture(scope="module")
def town():
    return assembly.params_for("town", sim.EnvConfig(), progress=False)


def run_away(key, state, params):
    """Full speed, full left turn: leaves any tracking tube within a second."""
    return jnp.broadcast_to(jnp.asarray([1.0, 1.0]), (params.vehicles.n, 2))


@functools.partial(jax.jit, static_argnames=("policy", "steps"))
def _fly(params, policy, steps):
    state = core.reset(jax.random.PRNGKey(0), params)
    state = sim.types.replace(state, intruder_status=jnp.asarray(sim.types.GONE, jnp.int32))  # tracking only
    actions = jnp.zeros((params.vehicles.n + 1, 2))

    def body(s, k):
        s, _ = core.step(k, s, actions, params, vehicle_policy=policy)
        return s, None

    state, _ = jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), steps))
    return state


@pytest.mark.slow
def test_tube_keeping_holds_the_tube_and_a_tube_exit_from_the_free_set_is_a_violation(town):
    """With the crossing's (and town's) tables the free set is empty (the tracking value is flat below ``V(0)``), so
    the filter around a policy that runs away flies ``kappa``: every vehicle tracks within ``r_e``. With the free
    level raised to infinity (a filter that trusts the policy everywhere) the same policy leaves the tube, and the
    core counts it as a tracking violation (the vehicle counts as tracking), not as an assumption failure."""
    r_e = float(town.tables.tracking_bound)
    flying = np.asarray(core.reset(jax.random.PRNGKey(0), town).status) == sim.types.FLYING
    assert flying.any()
    assert float(town.tables.tracking_free_level) < float(jnp.min(town.tables.tracking_table[..., 3]))

    kept = _fly(town, tube_keeping(run_away), 100)
    assert np.all(np.asarray(kept.tracked)[flying])
    assert float(np.max(np.asarray(kept.max_tracking_error)[flying])) <= r_e
    assert not np.any(np.asarray(kept.tracking_violation))

    trusting = town.replace(tables=dict(tracking_free_level=jnp.asarray(jnp.inf, jnp.float32)))
    escaped = _fly(trusting, tube_keeping(run_away), 100)
    assert np.all(np.asarray(escaped.tracked)[flying])
    assert np.all(np.asarray(escaped.tracking_violation)[flying])
    assert np.all(np.asarray(escaped.guarantee_violation)[flying])

    unfiltered = _fly(town, run_away, 100)  # no filter: the vehicles did not track, their assumptions failed
    assert not np.any(np.asarray(unfiltered.tracked)[flying])
    assert not np.any(np.asarray(unfiltered.tracking_violation))


@pytest.mark.slow
def test_tracking_value_read_matches_the_table(town):
    """The value the core reads with kappa (the table's fourth component) is the tracking value interpolated."""
    from stp_env import hj
    from stp_env.sim import tables

    grid = town.tables.tracking_grid
    value = np.asarray(town.tables.tracking_table[..., 3])
    rng = np.random.default_rng(0)
    for e in rng.uniform(-3.0, 3.0, (8, 3)):
        _, _, v = tables.tracking_control_and_value(town, jnp.asarray(e, jnp.float32))
        lead = value.shape[-1] - grid.shape[-1]  # periodic padding on the heading axis
        ref = hj.interpolation.interpolate(grid, jnp.asarray(value[..., lead // 2: lead // 2 + grid.shape[-1]]),
                                           jnp.asarray(e, jnp.float32))
        assert float(v) == pytest.approx(float(ref), abs=1e-4)


def _write(path, role):
    import json

    meta = {"format_version": 1, "activation": "tanh", "n_layers": 2, "observation": "core"}
    if role is not None:
        meta["role"] = role
    np.savez(path, metadata=np.asarray(json.dumps(meta)), w0=np.zeros((4, 40), np.float32),
             b0=np.zeros(4, np.float32), w1=np.zeros((2, 4), np.float32), b1=np.zeros(2, np.float32))
    return str(path)


def test_loaders_refuse_the_other_role(tmp_path):
    vehicle = _write(tmp_path / "v.npz", "vehicle")
    intruder = _write(tmp_path / "i.npz", None)
    assert load_vehicle_mlp(vehicle).obs_size == 40
    with pytest.raises(ValueError, match="not an intruder"):
        load_intruder(vehicle)
    with pytest.raises(ValueError, match="not a vehicle policy"):
        load_vehicle_mlp(intruder)
    with pytest.raises(ValueError, match="unknown learned vehicle policy"):
        load_vehicle_mlp("no-such-policy")
    from stp_env.policies import vehicle_policy

    with pytest.raises(ValueError, match="not a vehicle policy"):
        vehicle_policy("learned:" + intruder)


@pytest.fixture(scope="module")
def crossing():
    from stp_env.evaluation import resolve_intruder

    params = assembly.params_for("crossing", sim.EnvConfig(spawn_mode="boundary", episode="full"), progress=False)
    return params, resolve_intruder("max-k")


@pytest.mark.slow
def test_ego_env_starts_after_the_avoidance_and_steps(crossing):
    """Every non-empty reset hands the agent a vehicle that was forced and is now after its avoidance, flying; the
    VecEnv steps with SB3's conventions; a window-only episode is refused (the ego could not reach its target)."""
    from stp_env.rl.ego import STAT_NAMES
    from stp_env.rl.vehicle_env import EgoVehicleVecEnv

    params, intruder = crossing
    env = EgoVehicleVecEnv(8, params, intruder)
    env.seed(5)
    obs = env.reset()
    assert obs.shape == (8, observations.vehicle_observation_size(params))
    egos = np.asarray(env._egos)
    status, mode = np.asarray(env._states.status), np.asarray(env._states.mode)
    for i, e in enumerate(egos):
        if e >= 0:
            assert status[i, e] == sim.types.FLYING and mode[i, e] == sim.types.AFTER_AVOIDANCE
    assert (egos >= 0).mean() >= 0.75
    obs, rewards, _, infos = env.step(np.zeros((8, 2), np.float32))
    assert obs.shape == (8, observations.vehicle_observation_size(params)) and rewards.shape == (8,)
    assert set(STAT_NAMES) <= set(infos[0])
    window = assembly.params_for("crossing", sim.EnvConfig(spawn_mode="boundary"), progress=False)
    with pytest.raises(ValueError, match="episode='full'"):
        EgoVehicleVecEnv(2, window, intruder)


@pytest.mark.slow
def test_flying_faster_after_the_avoidance_arrives_earlier_on_the_same_episodes(crossing):
    """An independent check of the ego evaluation: on the same held-out episodes (same egos), the fallback at
    ``U``'s top speed arrives no later than ``u*``'s fallback at the planning speed, ego by ego, and is on time at
    least as often; nobody collides and no guarantee is violated."""
    from stp_env.rl.ego import evaluate_ego

    params, intruder = crossing
    slow = evaluate_ego(params, intruder, "u*", episodes=16, seed=11, batch=16)
    fast = evaluate_ego(params, intruder, "fallback-vmax", episodes=16, seed=11, batch=16)
    np.testing.assert_array_equal(slow["empty"], fast["empty"])
    both = slow["arrived"] & fast["arrived"]
    assert both.sum() >= 4
    assert np.all(fast["delay"][both] <= slow["delay"][both] + 1e-3)
    assert fast["on_time"].sum() >= slow["on_time"].sum()
    assert fast["on_time"].sum() > 0
    for r in (slow, fast):
        assert r["collisions"].sum() == 0 and r["guarantee_violations"].sum() == 0



@pytest.mark.slow
def test_shipped_vehicle_policies_fly_as_recorded():
    """Every shipped learned vehicle policy replays the small batch its file records (the ego's on-time arrivals
    and delays against ``max-k`` on the crossing): the same outcomes today."""
    from stp_env.policies.learned_vehicles import shipped_vehicle_policies
    from stp_env.rl.ego import replay_check

    names = shipped_vehicle_policies()
    assert names
    for name in names:
        mlp = load_vehicle_mlp(name)
        check = mlp.metadata["check"]
        result = replay_check(mlp, check)
        same = np.mean(np.asarray(result["on_time"]) == np.asarray(check["on_time"]))
        assert same >= 0.9, name  # float rounding on another CPU may flip a borderline episode, not more
        delays = [(a, b) for a, b in zip(result["delay_s"], check["delay_s"]) if a is not None and b is not None]
        assert np.median([abs(a - b) for a, b in delays]) < 0.5, name
