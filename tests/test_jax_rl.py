"""Learning in JAX (stp_env.rl.gymnax_env, jaxmarl_env, jax_ppo, jax_train): the game's JAX environments run under
gymnax's and JaxMARL's own wrappers, a gymnax rollout is the core's episode bit for bit, the trainer's batched step is
gymnax's step, a tiny PPO run improves on its untrained start, the exported policy flies as the trainer flew it in
the evaluator, and a resumed run continues the run it resumes (a foreign or altered checkpoint is not taken)."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

gymnax = pytest.importorskip("gymnax")

from gymnax.wrappers.purerl import FlattenObservationWrapper, LogWrapper  # noqa: E402

from stp_env import assembly, sim  # noqa: E402
from stp_env.evaluation.runner import episode_key, run_batch  # noqa: E402
from stp_env.policies import INTRUDERS  # noqa: E402
from stp_env.policies.learned import load_intruder, load_mlp  # noqa: E402
from stp_env.rl import jax_ppo  # noqa: E402
from stp_env.rl.gymnax_env import IntruderGymnaxEnv  # noqa: E402
from stp_env.rl.jax_train import held_out_keys, load_runner, save_runner, train_jax  # noqa: E402
from stp_env.rl.train import TrainConfig  # noqa: E402
from stp_env.seeds import prng_key  # noqa: E402


@pytest.fixture(scope="module")
def town():
    return assembly.params_for("town", sim.EnvConfig(), progress=False)


@pytest.fixture(scope="module")
def params(town):
    """``town`` with a short-lived intruder (t_IAT 3 s, appearing within 4 s of the window start, the time limit
    5 s after it; only array fields change, as in tests/test_rl.py): episodes of 30 steps that end both ways."""
    base = town
    lo = base.intruder.appear_window[0]
    return base.replace(intruder=dict(t_iat=jnp.asarray(3.0, jnp.float32), appear_window=jnp.stack([lo, lo + 4.0])),
                        episode=dict(t_end=lo + 5.0))


def _assert_trees_equal(a, b):
    def data(x):
        return jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x

    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(data(x)), np.asarray(data(y)))


def _assert_trees_close(a, b, atol=1e-6):
    """Integers, booleans and keys equal; floats to float32 rounding (two compiled programs: docs/numerics.md)."""
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        if jnp.issubdtype(x.dtype, jnp.floating):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=atol)
        else:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.slow
def test_gymnax_wrappers_run_the_intruder_env_and_batch_step_is_their_step(params):
    """gymnax's ``LogWrapper(FlattenObservationWrapper(env))`` runs the intruder's view under ``vmap`` (gymnax's own
    ``step``, auto-resets included) for 40 steps of 30-step episodes; the trainer's :meth:`batch_step`, fed the same
    states, keys and actions, makes the same transitions (floats to float32 rounding: another compiled program)."""
    env = IntruderGymnaxEnv(params)
    wrapped = LogWrapper(FlattenObservationWrapper(env))
    n = 4
    obs, state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(jax.random.PRNGKey(0), n), None)
    space = wrapped.observation_space(env.default_params)
    assert obs.shape == (n, *space.shape) and obs.dtype == jnp.float32
    assert bool(jnp.all(jax.vmap(space.contains)(obs)))
    act_space = env.action_space(env.default_params)
    step = jax.jit(jax.vmap(wrapped.step, in_axes=(0, 0, 0, None)))
    fast = jax.jit(env.batch_step)
    key = jax.random.PRNGKey(1)
    ended = np.zeros(n, bool)
    for _ in range(40):
        key, k_act, k_step = jax.random.split(key, 3)
        actions = jax.vmap(act_space.sample)(jax.random.split(k_act, n))
        keys = jax.random.split(k_step, n)
        fast_states = state.env_state
        obs, state, reward, terminated, truncated, info = step(keys, state, actions, None)
        fast_out = fast(keys, fast_states, actions, params)[:5]
        mine = (obs, state.env_state, reward, terminated, truncated)
        for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(mine), jax.tree.leaves(fast_out), strict=True):
            if "track_action" in jax.tree_util.keystr(path):
                continue  # bang-bang: a last-bit difference at the switching surface flips it (docs/numerics.md)
            _assert_trees_close(x, y, atol=1e-3)  # metres: a few float32 ulps of km-sized coordinates
        ended |= np.asarray(terminated | truncated)
        assert bool(jnp.all(jax.vmap(space.contains)(obs)))
        assert set(info) >= {"n_forced", "collisions", "guarantee_violations", "discount", "final_observation",
                             "returned_episode", "returned_episode_returns"}
    assert ended.all()  # every env went through an auto-reset (30-step episodes)
    assert np.all(np.asarray(info["returned_episode_lengths"]) > 0)


@pytest.mark.slow
def test_gymnax_rollout_is_the_core_episode_bit_for_bit(params):
    """Episodes of an evaluator run (seed 5, the ``greedy`` intruder), each keyed as the evaluator keys it: the gymnax
    view (horizon "episode"), reset with the episode's reset key and stepped with its step keys (the script's action
    from the first half of each, the step from the second), is the core's episode: every leaf of every state equal
    to :func:`stp_env.sim.reset` and :func:`stp_env.sim.step` flown in the same loop. Against the evaluator's own
    program (``run_batch``: another compiled program, docs/numerics.md) the outcomes are the same and the states
    agree to float32 rounding."""
    env = IntruderGymnaxEnv(params, horizon="episode")
    policy = INTRUDERS["greedy"].policy
    vp = env._vehicle_policy
    n_steps = sim.steps_for(params)
    run_key = prng_key(5)
    indices = jnp.arange(3, dtype=jnp.int32)

    def flown(reset, step):
        @jax.jit
        def fly(k_episode):
            k_reset, k_run = jax.random.split(k_episode)
            state = reset(k_reset)

            def body(state, k):
                k_i, k_s = jax.random.split(k)
                over = sim.episode_over(state, params)
                new = step(k_s, state, policy(k_i, state, params))
                return jax.tree.map(lambda a, b: jnp.where(over[0] | over[1], a, b), state, new), None

            return jax.lax.scan(body, state, jax.random.split(k_run, n_steps))[0]

        return jax.vmap(fly)(jax.vmap(lambda i: episode_key(run_key, i))(indices))

    gymnax_view = flown(lambda k: env.reset_env(k, params)[1], lambda k, s, a: env.step_env(k, s, a, params)[1])

    def core_step(k, s, a):
        actions = jnp.concatenate([jnp.zeros((params.vehicles.n, 2), jnp.float32), a[None, :]], axis=0)
        return sim.step(k, s, actions, params, vehicle_policy=vp)[0]

    _assert_trees_equal(gymnax_view, flown(lambda k: sim.reset(k, params), core_step))
    evaluator, _ = run_batch(run_key, indices, params, vp, policy, n_steps)
    for name in ("status", "mode", "avoid_start", "intruder_status", "step_count", "guarantee_violation"):
        np.testing.assert_array_equal(np.asarray(getattr(gymnax_view, name)), np.asarray(getattr(evaluator, name)))
    np.testing.assert_allclose(np.asarray(gymnax_view.intruder_x), np.asarray(evaluator.intruder_x), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(gymnax_view.x), np.asarray(evaluator.x), rtol=1e-5)


def test_jaxmarl_log_wrapper_runs_the_game(params):
    pytest.importorskip("jaxmarl")
    from jaxmarl.wrappers.baselines import LogWrapper as MARLLogWrapper

    from stp_env.rl.jaxmarl_env import GameJaxMARLEnv

    env = GameJaxMARLEnv(params)
    assert env.agents == [*(f"vehicle_{i}" for i in range(params.vehicles.n)), "intruder"]
    wrapped = MARLLogWrapper(env)
    obs, state = wrapped.reset(jax.random.PRNGKey(0))
    assert set(obs) == set(env.agents)
    for a in env.agents:
        assert obs[a].shape == env.observation_space(a).shape
    key = jax.random.PRNGKey(1)
    step = jax.jit(wrapped.step)
    episodes = 0
    for _ in range(sim.steps_for(params) + 5):
        key, k_step, *k_act = jax.random.split(key, 2 + env.num_agents)
        actions = {a: env.action_space(a).sample(k) for a, k in zip(env.agents, k_act)}
        obs, state, rewards, dones, infos = step(k_step, state, actions)
        assert set(dones) == {*env.agents, "__all__"} and set(rewards) == set(env.agents)
        for name, value in infos.items():
            assert value.shape == (env.num_agents,), name
            np.asarray(value, float)  # numbers only
        episodes += int(dones["__all__"])
        if dones["__all__"]:
            assert np.all(np.asarray(infos["returned_episode"]))
    assert episodes >= 1  # through an auto-reset


ROLLOUT = 64 * 64


def _tiny(out_dir, **over) -> TrainConfig:
    """The training tests' settings (the same programs in each: compiled once, then from the compilation cache)."""
    fields = dict(scenario="town", trainer="jax", n_envs=64, n_steps=64, batch_size=1024, n_epochs=10,
                  total_timesteps=ROLLOUT * 4, eval_every=0, eval_episodes=256, checkpoint_every=0, seed=0,
                  out_dir=str(out_dir))
    return TrainConfig(**{**fields, **over})


@pytest.mark.slow
def test_tiny_training_on_the_command_line_improves_on_its_start_and_exports_what_it_flew(tmp_path):
    """``stp-env train-intruder --trainer jax``: 24 PPO iterations of 64 x 64 steps on the default ``town`` (the
    intruder's 10 s) write the run's files, print the last evaluation, and on its 256 held-out episodes the trained
    intruder forces more vehicles than its own untrained start (0.03 -> 0.13-0.14 when written); the exported file is
    the trained actor (the final checkpoint's), and ``learned:`` flies it in the evaluator as the trainer's
    deterministic policy flies. ``--resume`` is refused for SB3 runs."""
    from _cli import run_cli

    from stp_env.rl.jax_train import episode_steps, make_env, make_evaluator
    from stp_env.rl.train import build_params

    out = tmp_path / "run"
    config = _tiny(out, total_timesteps=ROLLOUT * 24, checkpoint_every=ROLLOUT * 24)
    code, stdout, err = run_cli(["train-intruder", "--trainer", "jax", "--scenario", "town", "--timesteps",
                                 str(config.total_timesteps), "--n-envs", "64", "--n-steps", "64", "--minibatch-size",
                                 "1024", "--eval-every", "0", "--eval-episodes", "256", "--checkpoint-every",
                                 str(config.checkpoint_every), "--seed", "0", "--out", str(out)])
    assert code == 0, err
    last = json.loads(stdout.strip().splitlines()[-1])
    assert last["episodes"] == 256 and last["out"] == str(out)
    for name in ("config.json", "progress.csv", "evaluations.csv", "intruder.npz", "learning_curves.png"):
        assert (out / name).is_file(), name
    written = json.loads((out / "config.json").read_text())
    assert {k: written[k] for k in config.to_json()} == json.loads(json.dumps(config.to_json()))
    town = build_params(config)
    env = make_env(config, town)
    settings = jax_ppo.PPOSettings.of(config)
    template = jax_ppo.init_runner(jax.random.PRNGKey(config.seed), env, town, settings, config.net_arch,
                                   config.log_std_init)
    keys = held_out_keys(config.eval_seed, config.eval_episodes, episode_steps(config, town))
    before = float(np.mean(make_evaluator(env, ("n_forced",))(template.policy, town, *keys)["n_forced"]))
    assert last["mean_n_forced"] >= before + 0.05
    policy = load_runner(out / "checkpoints" / "runner.npz", template, written["fingerprint"])[0].policy
    # the exported file is the trained actor, and learned: flies it as the trainer's deterministic policy does
    mlp = load_mlp(out / "intruder.npz")
    assert mlp.metadata["trainer"] == "jax" and mlp.metadata["total_timesteps"] == config.trained_timesteps
    for (w, b), (tw, tb) in zip([*mlp.hidden, mlp.action], policy["actor"], strict=True):
        np.testing.assert_array_equal(w, np.asarray(tw))
        np.testing.assert_array_equal(b, np.asarray(tb))
    code, _, err = run_cli(["train-intruder", "--resume", "--out", str(tmp_path / "sb3")])
    assert code != 0 and "--resume" in err
    record = load_intruder(str(out / "intruder.npz"))
    run_key = prng_key(11)
    indices = jnp.arange(4, dtype=jnp.int32)
    n_steps = sim.steps_for(town)
    final, _ = run_batch(run_key, indices, town, env._vehicle_policy, record.policy, n_steps)
    episode = IntruderGymnaxEnv(town, horizon="episode")

    @jax.jit
    def fly(k_episode):
        k_reset, k_run = jax.random.split(k_episode)
        obs, state = episode.reset_env(k_reset, town)

        def body(carry, k):
            obs, state = carry
            _, k_s = jax.random.split(k)
            over = sim.episode_over(state, town)
            obs2, new, _, _, _ = episode.step_env(k_s, state, jax_ppo.deterministic_action(policy, obs), town)
            keep = over[0] | over[1]
            return jax.tree.map(lambda a, b: jnp.where(keep, a, b), (obs, state), (obs2, new)), None

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, n_steps))[0][1]

    # the trainer's deterministic policy on the evaluator's episodes (keyed as it keys them) against `stp-env
    # evaluate`'s program flying the exported file: the same outcomes. The paths agree to within a metre, not to the
    # last bit: two compiled programs round differently (docs/numerics.md) and the closed loop of a learned policy
    # carries the difference forward (0.1 m after 100 steps in one of these episodes when written)
    mine = jax.vmap(fly)(jax.vmap(lambda i: episode_key(run_key, i))(indices))
    for name in ("status", "mode", "avoid_start", "intruder_status", "collided_with_intruder"):
        np.testing.assert_array_equal(np.asarray(getattr(mine, name)), np.asarray(getattr(final, name)))
    np.testing.assert_allclose(np.asarray(mine.intruder_x[:, :2]), np.asarray(final.intruder_x[:, :2]), atol=1.0)


def test_resume_continues_the_run_and_refuses_foreign_checkpoints(params, tmp_path, capsys):
    """A run of three iterations equals one of one iteration resumed for two more (every leaf of the policy, and
    the progress log continued); a checkpoint of another configuration, or altered, is refused and the run starts
    afresh."""
    rollout = ROLLOUT

    def tiny(name, iterations, **over):
        return _tiny(tmp_path / name, total_timesteps=iterations * rollout, **over)

    straight, _ = train_jax(tiny("a", 3), params=params, progress=False)
    _tiny_b = tiny("b", 1, checkpoint_every=rollout)
    train_jax(_tiny_b, params=params, progress=False)
    resumed, _ = train_jax(tiny("b", 3, checkpoint_every=rollout), params=params, resume=True, progress=False)
    _assert_trees_equal(straight, resumed)
    rows = (tmp_path / "b" / "progress.csv").read_text().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == [rollout * i for i in range(1, 4)]
    # a checkpoint of another configuration, or altered, is not resumed: the run starts afresh and says why
    ckpt = tmp_path / "b" / "checkpoints" / "runner.npz"
    env = IntruderGymnaxEnv(params)
    settings = jax_ppo.PPOSettings.of(_tiny_b)
    template = jax_ppo.init_runner(jax.random.PRNGKey(0), env, params, settings, (64, 64), 0.0)
    with pytest.raises(ValueError, match="another configuration"):
        load_runner(ckpt, template, "another-fingerprint")
    from stp_env.rl.jax_train import fingerprint

    fp = fingerprint(_tiny_b)
    save_runner(template, ckpt, fingerprint_=fp, iteration=1, timesteps=rollout)
    arrays = dict(np.load(ckpt))
    arrays["leaf0"] = arrays["leaf0"] + 1.0
    np.savez(ckpt, **arrays)
    with pytest.raises(ValueError, match="digest"):
        load_runner(ckpt, template, fp)
    capsys.readouterr()
    again, _ = train_jax(tiny("b", 3, checkpoint_every=rollout), params=params, resume=True, progress=False)
    assert "not resumed" in capsys.readouterr().err
    _assert_trees_equal(straight, again)



@pytest.mark.slow
def test_vehicle_gymnax_env_steps_the_ego_episode():
    """The ego vehicle's gymnax view (town, the whole episode, the ``greedy`` intruder on a vehicle's avoid boundary):
    a reset hands over the vehicle forced first (flying, after its avoidance) and a step flies it, with the ego
    env's numbers in ``info`` (what the self-play's vehicle training reads). (gymnax's own ``step`` and wrappers
    are run on the intruder's view above: the same base class.)"""
    from stp_env.rl import ego
    from stp_env.rl.gymnax_env import VehicleGymnaxEnv

    params = assembly.params_for("town", sim.EnvConfig(spawn_mode="boundary", episode="full"), progress=False)
    env = VehicleGymnaxEnv(params, INTRUDERS["greedy"].policy, late_limit=2.0)
    key = jax.random.PRNGKey(7)
    obs, state = jax.jit(env.reset)(key)
    assert obs.shape == env.observation_space(params).shape and bool(env.observation_space(params).contains(obs))
    e = int(state.ego)
    assert e >= 0 and int(state.sim.status[e]) == sim.FLYING and int(state.sim.mode[e]) == sim.AFTER_AVOIDANCE
    obs, state2, reward, _, info = jax.jit(env.step_env)(key, state, jnp.asarray([0.3, -0.2]), params)
    assert set(info) >= {*ego.STAT_NAMES, "discount"}
    assert int(state2.ego) == e and float(state2.sim.t) > float(state.sim.t) and np.isfinite(float(reward))


_SHARDED = r"""
import json, sys
import stp_env
stp_env.set_cpu_devices(int(sys.argv[1]))
import gymnax, jax, numpy as np
from stp_env.rl import jax_ppo
env, env_params = gymnax.make("Pendulum-v1")
s = jax_ppo.PPOSettings(n_envs=8, n_steps=16, batch_size=128, n_epochs=1, learning_rate=1e-3, gamma=0.99,
                        gae_lambda=0.95, ent_coef=0.01, clip_range=0.2)
runner = jax_ppo.init_runner(jax.random.PRNGKey(0), env, env_params, s, (16, 16), 0.0)
step, runner = jax_ppo.compile_iteration(jax_ppo.make_iteration(env, s), runner, s.n_envs)
for _ in range(3):
    runner, metrics = step(runner, env_params)
leaves = [np.asarray(x).ravel().tolist() for x in jax.tree.leaves(runner.policy)]
print(json.dumps({"devices": len(jax.devices()), "shares": jax_ppo.data_shares(s), "policy": leaves,
                  "obs": np.asarray(runner.obs).tolist()}))
"""


@pytest.mark.slow
def test_the_update_shared_among_two_devices_is_the_update_on_one():
    """PPO on gymnax's own Pendulum (the trainer takes any gymnax env) with one minibatch per epoch, on one CPU device
    and split into two (each device its envs' share of the rollout and of the gradient, summed): the same
    rollouts and the same policy after three iterations, to float32 rounding (the sums run in another order)."""
    import os
    import subprocess
    import sys

    def run(devices):
        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "STP_ENV_CPU_DEVICES")}
        out = subprocess.run([sys.executable, "-c", _SHARDED, str(devices)], capture_output=True, text=True, env=env)
        assert out.returncode == 0, out.stderr[-3000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    one, two = run(1), run(2)
    assert (one["devices"], one["shares"], two["devices"], two["shares"]) == (1, 1, 2, 2)
    np.testing.assert_allclose(np.asarray(one["obs"]), np.asarray(two["obs"]), rtol=1e-4, atol=1e-5)
    for a, b in zip(one["policy"], two["policy"], strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
