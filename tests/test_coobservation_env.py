"""The compromised-vehicle threat in the UAV simulator: under the secured schedule even the attacker the ellipses
are built against (the fastest ground speed, a tailwind) never finds a window; under a schedule that leaves the
wind out, or the unsecured one (every 90 s), it gets in undetected, so the check can fail. And the PettingZoo
adapter passes PettingZoo's API test."""

from __future__ import annotations

import dataclasses
import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from stp_env.coobservation import attackers, checkpoints, threat
from stp_env.coobservation import env as coobs_env
from stp_env.coobservation.env import parallel_env
from stp_env.coobservation.uav import FormationScenario

SCENARIO = FormationScenario()


@functools.lru_cache(maxsize=1)
def _params():
    """Coarse tracking and (unused) avoid artifacts: seconds on an empty cache instead of minutes."""
    return SCENARIO.params(artifacts=SCENARIO.coarse_artifacts())


@functools.lru_cache(maxsize=1)
def _setup():
    params = _params()
    secure = checkpoints.ellipse_test(SCENARIO.forbidden, SCENARIO.attacker_speed, SCENARIO.ellipse_radius)
    times = {"secured": SCENARIO.secured_times(secure), "unsecured": SCENARIO.uniform_times(90.0)}
    m = max(len(SCENARIO.schedule(t)) for t in times.values())
    threats = {k: threat.threat_params(SCENARIO.schedule(t), SCENARIO.forbidden, SCENARIO.observation_radius,
                                       pad_to=m) for k, t in times.items()}
    return params, threats, times


@pytest.mark.slow
def test_secured_schedule_ellipses_miss_the_zones_and_the_unsecured_do_not():
    secure = checkpoints.ellipse_test(SCENARIO.forbidden, SCENARIO.attacker_speed, SCENARIO.ellipse_radius)
    times = {"secured": SCENARIO.secured_times(secure), "unsecured": SCENARIO.uniform_times(90.0)}
    for name, expect in (("secured", True), ("unsecured", False)):
        t = times[name]
        ok = [all(secure(*SCENARIO.segment_foci(s)[:1], a, SCENARIO.segment_foci(s)[1], b)
                  for s in SCENARIO.segments_between(a, b)) for a, b in itertools.pairwise(t)]
        assert all(ok) if expect else not all(ok)


@pytest.mark.slow
def test_the_ellipses_worst_case_attacker_beats_only_schedules_that_leave_something_out():
    """The optimistic attacker (ground speed ``v_max + wind``, back to the nearest point its observers still see)
    under the ``tailwind`` model, which gives it that speed: the schedule secured by the ellipses holds; the one
    secured as if there were no wind, and the unsecured one, do not (so the check can fail)."""
    sc = dataclasses.replace(SCENARIO, wind_model="tailwind")
    params = sc.params(artifacts=SCENARIO.coarse_artifacts())
    speeds = {"secured": sc.attacker_speed, "windless": sc.v_max}
    times = {k: sc.secured_times(checkpoints.ellipse_test(sc.forbidden, v, sc.ellipse_radius))
             for k, v in speeds.items()}
    times["unsecured"] = sc.uniform_times(90.0)
    assert len(times["windless"]) < len(times["secured"])
    m = max(len(sc.schedule(t)) for t in times.values())
    n_steps = threat.steps_for(params)
    attacker = attackers.ATTACKERS["optimistic"]  # one function object: one compilation for every schedule
    out = {}
    for name, t in times.items():
        tp = threat.threat_params(sc.schedule(t), sc.forbidden, sc.observation_radius, pad_to=m)
        final, _ = threat.rollout(jax.random.key(3), params, tp, attacker, 12, n_steps, (90.0, 96.0))
        out[name] = threat.outcomes(jax.device_get(final))
    sec = out["secured"]
    assert sec["entered"].sum() == 0 and sec["detected"].sum() == 0 and sec["success"].sum() == 0
    assert out["windless"]["success"].sum() > 0 and out["unsecured"]["success"].sum() > 0
    for o in out.values():
        assert o["all_checked"].all() and o["honest_entries"].sum() == 0
        # other vehicles' observations fail only where the attacker rammed a teammate (both are lost)
        assert o["false_alarms"][o["collisions"] == 0].sum() == 0
        assert o["max_track_error"].max() < SCENARIO.tracking_margin


@pytest.mark.slow
def test_the_tailwind_blows_along_each_heading_at_full_strength():
    from stp_env.sim import winds

    params = SCENARIO.params(artifacts=SCENARIO.coarse_artifacts())
    state = threat.reset(jax.random.key(0), params, _setup()[1]["secured"], -1, 0.0).sim
    w = winds.make("tailwind").inner(state, params, None)
    heading = np.asarray(state.x[:, 2])
    np.testing.assert_allclose(np.asarray(w[:-1]), SCENARIO.wind * np.stack([np.cos(heading), np.sin(heading)], 1),
                               rtol=1e-6, atol=1e-6)


@pytest.mark.slow
def test_the_optimistic_attacker_returns_where_every_observer_still_sees_it():
    centres = jnp.asarray([[0.0, 0.0], [100.0, 0.0], [1e4, 1e4]])
    mask = jnp.asarray([True, True, False])  # the third disk is not due: ignored
    a = attackers.toward_within(jnp.asarray([50.0, 0.0]), jnp.asarray([50.0, 1000.0]), centres, mask, 80.0)
    np.testing.assert_allclose(np.asarray(a), [50.0, np.sqrt(80.0**2 - 50.0**2)], rtol=1e-5)
    inside = attackers.toward_within(jnp.asarray([50.0, 0.0]), jnp.asarray([50.0, 10.0]), centres, mask, 80.0)
    np.testing.assert_allclose(np.asarray(inside), [50.0, 10.0], rtol=1e-6)  # already seen: the point itself


@pytest.mark.slow
def test_parallel_env_api_and_infos():
    env = parallel_env(schedule="unsecured", max_cycles=30, params=_params())
    parallel_api_test(env, num_cycles=30)
    obs, infos = env.reset(seed=1, options={"compromised": 0, "compromise_time": 0.0})
    assert infos["attacker"]["compromised"] == "vehicle_0" and infos["attacker"]["active"]
    first = [e for e in infos["vehicle_0"]["observations"] if e["time"] == 0.0]
    assert first and all(e["seen"] for e in first)  # the start observation, at the base station
    for _ in range(5):  # the attacker turns away at full speed
        obs, _rew, _term, _trunc, infos = env.step({"attacker": np.array([1.0, 1.0], np.float32)})
    assert obs["attacker"].shape == (attackers.OBS_SIZE,) and np.abs(obs["attacker"]).max() > 0
    with pytest.raises(ValueError, match="finite"):
        env.step({"attacker": np.array([np.nan, 0.0])})


@pytest.mark.slow
def test_the_packed_step_is_the_unpacked_one_bit_for_bit():
    """The env keeps its key and threat state packed on the device and fetches each step's outputs and infos'
    fields as one array (stp_env.sim.packing): the same observations, rewards and states as the unpacked step."""
    env = parallel_env(schedule="unsecured", max_cycles=60, params=_params())
    env.reset(seed=2, options={"compromised": 1, "compromise_time": 0.0})
    key, ts = env._key, env.threat_state
    n = env.scenario.n_vehicles
    rng = np.random.default_rng(4)
    for i in range(40):
        att = rng.uniform(-1, 1, 2).astype(np.float32)
        acts = {"attacker": att}
        given = np.zeros(n, bool)
        arr = np.zeros((n, 2), np.float32)
        if i % 3 == 0 and "vehicle_0" in env.agents:  # sometimes a vehicle's own action, else the plan's tracker
            arr[0] = rng.uniform(-1, 1, 2).astype(np.float32)
            given[0] = True
            acts["vehicle_0"] = arr[0]
        obs, rewards, *_ = env.step(acts)
        key, ts, out, reward, _newly = coobs_env._step_jit(key, ts, arr, given, att, True, env.params, env.threat)
        np.testing.assert_array_equal(obs["attacker"], np.asarray(out["attacker_obs"]))
        for agent in obs:
            if agent != "attacker":
                np.testing.assert_array_equal(obs[agent], np.asarray(out["vehicle_obs"])[env._index[agent]])
        assert rewards["attacker"] == float(reward)
        for a, b in zip(jax.tree.leaves((key, ts)), jax.tree.leaves((env._key, env.threat_state))):
            if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
                a, b = jax.random.key_data(a), jax.random.key_data(b)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        if not env.agents:
            break


def test_training_outcome_rates_count_only_finished_episodes():
    from stp_env.coobservation.learned import outcome_rates

    infos = [{"entered": True, "detected": False}, {"entered": True, "detected": True},
             {"entered": False, "detected": True}, {}, {"entered": True, "detected": False}]
    dones = [True, True, True, False, False]  # the last one has not ended: not counted
    assert outcome_rates(infos, dones) == (3, 2, 2, 1)


def _zero_mlp(path, **meta):
    import json

    from stp_env.policies.learned import FORMAT_VERSION

    arrays = {"w0": np.zeros((4, attackers.OBS_SIZE), np.float32), "b0": np.zeros(4, np.float32),
              "w1": np.zeros((2, 4), np.float32), "b1": np.zeros(2, np.float32)}
    header = {"format_version": FORMAT_VERSION, "activation": "tanh", "n_layers": 2, **meta}
    np.savez(path, metadata=np.asarray(json.dumps(header)), **arrays)
    return path


@pytest.mark.slow
def test_a_residual_attacker_with_zero_output_flies_the_plan(tmp_path):
    from stp_env.coobservation.learned import RESIDUAL_SCALE, mlp_attacker

    params, threats, _ = _setup()
    ts = threat.reset(jax.random.key(0), params, threats["unsecured"], 0, 0.0)
    planned = jnp.asarray([0.3, -0.7])
    residual = mlp_attacker(_zero_mlp(tmp_path / "r.npz", residual=True, residual_scale=RESIDUAL_SCALE))
    direct = mlp_attacker(_zero_mlp(tmp_path / "d.npz"))  # files without the entry: the action is the command
    key = jax.random.key(1)
    np.testing.assert_array_equal(np.asarray(residual(key, ts, params, threats["unsecured"], planned)), planned)
    np.testing.assert_array_equal(np.asarray(direct(key, ts, params, threats["unsecured"], planned)), [0.0, 0.0])
    with pytest.raises(ValueError, match="residual_scale"):
        mlp_attacker(_zero_mlp(tmp_path / "bad.npz", residual=True, residual_scale=1.0))
    with pytest.raises(ValueError, match="residual"):
        mlp_attacker(_zero_mlp(tmp_path / "bad2.npz", residual="yes"))


@pytest.mark.slow
def test_teacher_residuals_reproduce_the_teachers_commands_and_cloning_fits_them():
    import gymnasium as gym
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy

    from stp_env.coobservation import learned
    from stp_env.policies import nominal_tracking

    params, threats, _ = _setup()
    tp = threats["unsecured"]
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(0), i))(jnp.arange(4))
    _, states, _obs = learned.batch_reset(keys, params, tp, jnp.asarray([100.0, 100.0]))
    res = learned.teacher_residuals(keys, states, params, tp, attackers.reckless)
    honest = learned.teacher_residuals(keys, states, params, tp, attackers.honest)
    np.testing.assert_array_equal(np.asarray(honest), 0.0)  # flying the plan is the zero residual
    for i in range(4):
        ts = jax.tree.map(lambda a, i=i: a[i], states)
        k_v, k_t = jax.random.split(keys[i])
        planned = nominal_tracking(k_v, ts.sim, params)[ts.compromised]
        want = attackers.reckless(k_t, ts, params, tp, planned)
        np.testing.assert_allclose(np.asarray(learned.command(planned, res[i], True)), np.asarray(want), atol=1e-6)
    # behaviour cloning fits a smooth target to a small loss
    torch.manual_seed(0)
    space = gym.spaces.Box(-2.0, 2.0, (attackers.OBS_SIZE,), np.float32)
    policy = ActorCriticPolicy(space, gym.spaces.Box(-1.0, 1.0, (2,), np.float32), lambda _: 1e-3,
                               net_arch=[32, 32], activation_fn=torch.nn.Tanh)
    x = np.random.default_rng(0).uniform(-1, 1, (4096, attackers.OBS_SIZE)).astype(np.float32)
    y = np.stack([np.tanh(x[:, 0] - x[:, 1]), 0.5 * x[:, 2]], axis=1).astype(np.float32)
    before = learned.imitate(policy, x, y, epochs=1, lr=0.0)
    after = learned.imitate(policy, x, y, epochs=60, lr=3e-3, batch=256)
    assert after < 0.05 * before


@pytest.mark.slow
def test_a_failed_reset_changes_nothing_and_seeds_do_not_wrap():
    """The reset contract of every environment (``docs/threat-model.md``): seeds through ``stp_env.seeds`` (no
    wrap-around at ``2**32``; ``1.5``, ``"1"``, ``True`` and negative seeds refused) and options checked before
    anything changes, so that the key, the state and the agents after a failed reset are what they were."""
    env = parallel_env(schedule="unsecured", max_cycles=30, params=_params())

    def snapshot():
        ts = [np.asarray(jax.random.key_data(a) if jnp.issubdtype(a.dtype, jax.dtypes.prng_key) else a).tolist()
              for a in jax.tree.leaves(env.threat_state)]
        return np.asarray(jax.random.key_data(env._key)).tolist(), ts, list(env.agents), env._steps

    keys = {}
    for seed in (0, 2**32):
        env.reset(seed=seed)
        keys[seed] = np.asarray(jax.random.key_data(env._key)).tolist()
    assert keys[0] != keys[2**32]
    env.reset(seed=3, options={"compromised": 1, "compromise_time": 50.0})
    env.step({"attacker": np.array([0.5, 0.0], np.float32)})
    before = snapshot()
    for seed, options in [(1.5, None), ("1", None), (True, None), (-1, None), (2**63, None),
                          (4, {"compromised": 99}), (4, {"compromised": True}), (4, {"compromise_time": "soon"}),
                          (4, {"compromise_time": float("nan")}), (4, {"compromise_time": 1e9}), (4, "options")]:
        with pytest.raises(ValueError):
            env.reset(seed=seed, options=options)
        assert snapshot() == before, (seed, options)


def test_the_attackers_vec_env_keeps_the_batched_vec_env_contract():
    """The attacker's SB3 VecEnv (one batched JAX state): actions checked before anything is stored, the zero
    residual flies the plan for as many steps as asked, shared attributes, finished episodes' infos."""
    from stp_env.coobservation.attacker_vec_env import AttackerVecEnv
    from stp_env.coobservation.learned import make_vec_env
    from stp_env.rl.jax_vec_env import JaxVecEnv

    params, threats, _ = _setup()
    venv = make_vec_env(3, params, threats["unsecured"], (100.0, 100.0), action_repeat=5, seed=1)
    assert isinstance(venv, AttackerVecEnv) and isinstance(venv, JaxVecEnv)
    obs = venv.reset()
    assert obs.shape == (3, attackers.OBS_SIZE) and np.all(np.isfinite(obs))
    for bad in (np.zeros((2, 2)), np.full((3, 2), np.nan)):
        with pytest.raises(ValueError, match="actions"):
            venv.step_async(bad)
        assert venv._actions is None
    infos_done = []
    for _ in range(40):
        venv.step_async(np.zeros((3, 2), np.float32))
        obs, rew, done, infos = venv.step_wait()
        assert obs.shape == (3, attackers.OBS_SIZE) and rew.shape == (3,) and done.dtype == bool
        infos_done += [info for info, d in zip(infos, done) if d]
    for info in infos_done:  # the honest flight: no entry, and the episode's return and length for the logger
        assert not info["entered"] and info["episode"]["l"] > 0
    assert venv.get_attr("action_repeat") == [5, 5, 5] and venv.env_is_wrapped(object) == [False] * 3
    venv.set_attr("shaping", 0.5)
    assert venv.shaping == 0.5
    with pytest.raises(ValueError, match="share"):
        venv.set_attr("shaping", 1.0, indices=[0])
    with pytest.raises(ValueError, match="cannot be set"):
        venv.set_attr("_keys", None)
    venv.close()
    with pytest.raises(RuntimeError, match="reset"):
        venv.step_wait()


@pytest.mark.slow
def test_the_margin_reward_grows_with_the_attempts_time_margin():
    """An attacker that must try is paid by its attempt's time margin: on reckless episodes, the bonus is 0 without an
    entry and ``m (1 + clip(margin, -60, 3) / 60)`` with one, the margin being the evaluation's (``threat.attempts``);
    a lost attempt (margin ``-inf``) earns nothing."""
    import jax

    from stp_env.coobservation import learned, threat

    params, threats, _ = _setup()
    tp = threats["unsecured"]
    final, _ = threat.rollout(jax.random.key(4), params, tp, attackers.reckless, 24, threat.steps_for(params),
                              (0.0, 200.0))
    o = threat.outcomes(jax.device_get(final))
    margin = threat.attempts(jax.device_get(final), params, tp)["margin"]
    bonus = np.asarray(jax.vmap(lambda ts: learned.margin_bonus(ts, params, tp, 3.0))(final))
    entered = o["entered"]
    assert entered.any() and (~entered).any()
    assert np.all(bonus[~entered] == 0.0)
    want = 3.0 * (1.0 + np.clip(margin[entered], -learned.MARGIN_SCALE, 3.0) / learned.MARGIN_SCALE)
    np.testing.assert_allclose(bonus[entered], want, rtol=1e-5, atol=1e-5)
    assert np.all((bonus >= 0) & (bonus <= 3.0 * (1 + 3.0 / learned.MARGIN_SCALE) + 1e-6))
