"""Learned-intruder plumbing (stp_env.rl): the Gymnasium env against gymnasium's and SB3's checkers, the native
VecEnv against DummyVecEnv over the Gymnasium env (same seeds, same everything, auto-resets included) and SB3's
VecEnv wrappers, a short PPO run, same seed -> same actions, and the exported MLP as a jittable intruder."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecCheckNan, VecMonitor

from stp_env import assembly, sim
from stp_env.policies.learned import export_mlp, load_mlp, mlp_intruder
from stp_env.rl import IntruderEnv, IntruderVecEnv
from stp_env.rl import functional as F
from stp_env.rl.train import TrainConfig, evaluate_on_vec_env, make_model, summarize

N_ENVS = 4


@pytest.fixture(scope="module")
def params():
    """``town`` with a short-lived intruder (``t_IAT`` = 3 s; the avoid tables stay those of 10 s) appearing within
    4 s of the window start and the time limit 5 s after it: an intruder appearing in the first 2 s leaves before
    the limit (terminated), a later one is cut by it (truncated), so short runs see both kinds of auto-reset.
    Only array fields change: the same compiled programs as the default ``town``."""
    base = assembly.params_for("town", sim.EnvConfig(), progress=False)
    lo = base.intruder.appear_window[0]
    return base.replace(intruder=dict(t_iat=jnp.asarray(3.0, jnp.float32), appear_window=jnp.stack([lo, lo + 4.0])),
                        episode=dict(t_end=lo + 5.0))


@pytest.mark.slow
def test_gym_env_passes_gymnasium_and_sb3_checks(params):
    gym_check_env(IntruderEnv(params=params), skip_render_check=True)
    sb3_check_env(IntruderEnv(params=params), warn=True)
    env = IntruderEnv(params=params)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))


@pytest.mark.slow
def test_gym_env_packed_step_is_the_functional_step_bit_for_bit(params):
    """The env keeps its key and state packed on the device and fetches each step's outputs as one array
    (stp_env.sim.packing): the same observations, rewards, ends, stats and states as the functional step."""
    env = IntruderEnv(params=params)
    env.reset(seed=4)
    key, state = env._key, env.state
    rng = np.random.default_rng(2)
    for _ in range(50):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        key, state, *want = F.env_step(key, state, action, params, env.horizon, env._vehicle_policy, env.observation)
        w_obs, w_reward, w_term, w_trunc, w_stats = jax.device_get(want)
        np.testing.assert_array_equal(obs, w_obs)
        assert (reward, terminated, truncated) == (float(w_reward), bool(w_term), bool(w_trunc))
        assert {k: info[k] for k in w_stats} == {k: (float(v) if k == "time" else int(v)) for k, v in w_stats.items()}
        for a, b in zip(jax.tree.leaves(jax.random.key_data(key)), jax.tree.leaves(jax.random.key_data(env._key))):
            np.testing.assert_array_equal(a, b)
        for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(env.state)):
            if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
                a, b = jax.random.key_data(a), jax.random.key_data(b)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        if terminated or truncated:
            break


@pytest.mark.slow
def test_vec_env_matches_dummy_vec_env_over_the_gym_env(params):
    dummy = DummyVecEnv([lambda: IntruderEnv(params=params) for _ in range(N_ENVS)])
    native = IntruderVecEnv(N_ENVS, params=params)
    dummy.seed(123)
    native.seed(123)
    np.testing.assert_array_equal(dummy.reset(), native.reset())
    assert native.reset_infos == dummy.reset_infos
    rng = np.random.default_rng(0)
    kinds = set()
    for _ in range(60):
        actions = rng.uniform(-1.2, 1.2, (N_ENVS, 2)).astype(np.float32)
        obs_d, rew_d, done_d, infos_d = dummy.step(actions)
        obs_n, rew_n, done_n, infos_n = native.step(actions)
        # The batched program and the single-episode one are compiled separately: XLA may fuse them differently,
        # so floats agree to a few ulps, not bit for bit; events (done) must agree exactly.
        np.testing.assert_allclose(obs_n, obs_d, rtol=0, atol=1e-5)
        np.testing.assert_allclose(rew_n, rew_d, rtol=0, atol=1e-5)
        np.testing.assert_array_equal(done_n, done_d)
        assert obs_n.dtype == np.float32 and rew_n.dtype == np.float32 and done_n.dtype == bool
        for i in range(N_ENVS):
            term_d = infos_d[i].pop("terminal_observation", None)
            term_n = infos_n[i].pop("terminal_observation", None)
            assert (term_d is None) == (term_n is None) == (not done_d[i])
            if done_d[i]:
                np.testing.assert_allclose(term_n, term_d, rtol=0, atol=1e-5)
                assert not np.array_equal(term_n, obs_n[i])  # the observation after the reset is returned
                kinds.add(infos_n[i]["TimeLimit.truncated"])
            else:
                infos_d[i].pop("TimeLimit.truncated")  # DummyVecEnv sets it on every step
            assert infos_n[i] == infos_d[i]
        assert native.reset_infos == dummy.reset_infos
    assert kinds == {True, False}, "expected both time-limit and terminal episode ends"


@pytest.mark.slow
def test_vec_env_sb3_api_and_seeding(params):
    venv = IntruderVecEnv(N_ENVS, params=params)
    venv.seed(7)
    first = venv.reset()
    venv.seed(7)
    np.testing.assert_array_equal(venv.reset(), first)
    single = IntruderVecEnv(N_ENVS, params=params)
    single.seed(8)  # env i gets seed 8 + i: envs 1..3 of seed 7 are envs 0..2 of seed 8
    np.testing.assert_array_equal(single.reset()[:-1], first[1:])
    assert not np.array_equal(first[0], first[1])
    assert venv.get_attr("kbar") == [int(params.intruder.kbar)] * N_ENVS
    assert venv.get_attr("n_forced", indices=[1, 3]) == [0, 0]
    assert venv.get_attr("time", indices=2) == [pytest.approx(float(venv._states.t[2]))]
    with pytest.raises(AttributeError):
        venv.get_attr("no_such_attribute")
    venv.set_attr("custom", 3)
    assert venv.get_attr("custom", indices=[0, 1]) == [3, 3]
    with pytest.raises(ValueError, match="share"):
        venv.set_attr("custom", 4, indices=[0])
    assert venv.env_method("get_attr", "kbar", indices=[0, 2]) == [[int(params.intruder.kbar)] * N_ENVS] * 2
    assert venv.env_is_wrapped(Monitor) == [False] * N_ENVS
    with pytest.raises(ValueError, match="finite"):
        venv.step(np.full((N_ENVS, 2), np.nan, np.float32))
    checked = VecMonitor(VecCheckNan(venv, raise_exception=True))
    checked.reset()
    for _ in range(3):
        checked.step(np.zeros((N_ENVS, 2), np.float32))


def _short_ppo(params, seed: int, steps: int):
    config = TrainConfig(n_envs=N_ENVS, n_steps=256, batch_size=512, n_epochs=2, seed=seed,
                         net_arch=(16, 16))
    model = make_model(config, IntruderVecEnv(N_ENVS, params=params))
    model.learn(total_timesteps=steps)
    return model


@pytest.mark.slow
def test_short_ppo_run_is_seeded_and_exports_a_jittable_intruder(params, tmp_path):
    model_a = _short_ppo(params, seed=3, steps=3072)
    model_b = _short_ppo(params, seed=3, steps=3072)
    model_c = _short_ppo(params, seed=4, steps=1024)
    assert model_a.num_timesteps == 3072
    # Same seed: the same actions and observations in the (last) rollout, the same weights after training.
    np.testing.assert_array_equal(model_a.rollout_buffer.actions, model_b.rollout_buffer.actions)
    np.testing.assert_array_equal(model_a.rollout_buffer.observations, model_b.rollout_buffer.observations)
    for pa, pb in zip(model_a.policy.parameters(), model_b.policy.parameters()):
        np.testing.assert_array_equal(pa.detach().numpy(), pb.detach().numpy())
    assert not np.array_equal(model_c.rollout_buffer.actions[:8], model_a.rollout_buffer.actions[:8])

    path = export_mlp(model_a, tmp_path / "intruder.npz", metadata={"seed": 3})
    mlp = load_mlp(path)
    assert mlp.metadata["seed"] == 3 and mlp.obs_size == 8 + 7 * params.episode.n_nearest
    venv = IntruderVecEnv(N_ENVS, params=params)
    venv.seed(11)
    obs = venv.reset()
    np.testing.assert_allclose(mlp.action_numpy(obs), model_a.predict(obs, deterministic=True)[0], atol=1e-5)
    policy = jax.jit(mlp_intruder(mlp))
    state = venv._states
    action = jax.vmap(policy, in_axes=(None, 0, None))(jax.random.PRNGKey(0), state, params)
    np.testing.assert_allclose(np.asarray(action), model_a.predict(obs, deterministic=True)[0], atol=1e-5)
    result = evaluate_on_vec_env(lambda o: model_a.predict(o, deterministic=True)[0], venv, N_ENVS, seed=5)
    assert result["n_forced"].shape == (N_ENVS,) and np.all(result["guarantee_violations"] == 0)
    row = summarize(result, int(params.intruder.kbar))  # the row of evaluations.csv: the package's one episode summary
    assert row["episodes"] == N_ENVS and row["max_n_forced"] == result["n_forced"].max()
    assert row["guarantee_violations"] == row["violation_episodes"] == 0
    assert row["violation_episodes_upper"] == pytest.approx(1 - 0.05 ** (1 / N_ENVS))
    assert row["mean_return"] == pytest.approx(result["returns"].mean())


@pytest.mark.slow
def test_shipped_intruder_matches_its_sb3_model(params):
    from importlib import resources

    from stable_baselines3 import PPO

    from stp_env.policies.learned import load_intruder, shipped_intruders
    from stp_env.rl import functional

    assert "town-kbar2" in shipped_intruders()
    policy = load_intruder("town-kbar2")
    assert load_intruder("town-kbar2") is policy
    folder = resources.files("stp_env") / "data" / "intruders"
    mlp = load_mlp(folder / "town-kbar2.npz")
    assert mlp.metadata["scenario"] == "town" and mlp.metadata["kbar"] == 2
    model = PPO.load(str(folder / "town-kbar2.zip"), device="cpu")
    for seed in range(3):
        _, state, obs = functional.env_reset(functional.key_for_seed(seed), params, "intruder")
        action = np.asarray(jax.jit(policy)(jax.random.PRNGKey(0), state, params))
        expected = model.predict(np.asarray(obs), deterministic=True)[0]
        np.testing.assert_allclose(action, expected, atol=1e-5)
        np.testing.assert_allclose(mlp.action_numpy(np.asarray(obs)), expected, atol=1e-5)
    with pytest.raises(ValueError, match="unknown intruder"):
        load_intruder("no-such-intruder")


def test_train_config_spawn_mode_and_the_buffer_of_worst_vehicles(monkeypatch):
    """Training against worst vehicles loads the buffer table of the plan's k̄ (the worst policy reads it); other
    vehicle policies do not; the spawn mode reaches the environment and an unknown one is refused."""
    import types

    from stp_env.rl import train as train_module

    assert TrainConfig(spawn_mode="boundary").env_config().spawn_mode == "boundary"
    assert TrainConfig().env_config().spawn_mode == "outside"
    with pytest.raises(ValueError, match="spawn_mode 'sky'"):
        TrainConfig(spawn_mode="sky")
    calls = []
    monkeypatch.setattr(assembly, "params_for",
                        lambda scenario, config, **kw: types.SimpleNamespace(
                            intruder=types.SimpleNamespace(kbar=scenario.kbar),
                            tables=types.SimpleNamespace(buffer_values=None)))
    monkeypatch.setattr(assembly, "load_buffer", lambda scenario, kbar, **kw: calls.append(kbar) or "V^B")
    monkeypatch.setattr(assembly, "with_buffer", lambda params, buffer: (params, buffer))
    assert train_module.build_params(TrainConfig(scenario="town", kbar=3, vehicle_policy="worst"))[1] == "V^B"
    assert calls == [3]
    assert not isinstance(train_module.build_params(TrainConfig(scenario="town", kbar=3)), tuple)
    assert calls == [3]
