"""The multi-agent clients take the PettingZoo env as it comes (docs/training.md, "Multi-agent clients"):
PettingZoo's own tests with no warning about the env's API, SuperSuit's vector env into SB3's PPO (one policy for
the vehicles, the intruder scripted), TorchRL's ``PettingZooWrapper`` and RLlib's ``ParallelPettingZooEnv`` with a
two-policy PPO, each across an agent's finish and an episode's end. Where a client's own bug is in the way, the
test shows the client's message (the docs give the workaround)."""

from __future__ import annotations

import contextlib
import os
import types
import warnings

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
)
from pettingzoo.utils.wrappers import BaseParallelWrapper

import stp_env.env as stp_module
from stp_env.env import INFO_CODES, env, parallel_env

# ------------------------------------------------------------------------------------------ PettingZoo's tests

# What pettingzoo.test warns about on this env by design, not about its API (every other warning of those modules
# fails the test):
ALLOWED_PETTINGZOO_WARNINGS = (
    # the intruder observes 36 numbers and the vehicles 40: two kinds of agent (RLlib and TorchRL take one policy
    # or group per kind; SuperSuit needs pad_observations_v0 or a scripted intruder)
    "Observations are different shapes",
    "Agents have different observation space sizes",
    # "intruder" is one of a kind, so it has no "_<number>"
    "We recommend agents to be named in the format",
    # the intruder's observation once it has left the airspace (it is terminated with it)
    "Observation numpy array is all zeros.",
)
_PETTINGZOO_TESTS = os.path.join("pettingzoo", "test", "")


@contextlib.contextmanager
def no_api_warnings():
    """Fails if a PettingZoo test module warned about anything but ``ALLOWED_PETTINGZOO_WARNINGS``. (The env's own
    "ignoring unknown reset option(s) 'options'" is not PettingZoo's: its tests pass a dummy option to check that
    ``reset`` takes ``options``.)"""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    about_api = sorted({str(w.message) for w in caught
                        if _PETTINGZOO_TESTS in w.filename and not str(w.message).startswith(
                            ALLOWED_PETTINGZOO_WARNINGS)})
    assert not about_api, about_api


KEEP_FINISHED = pytest.mark.parametrize("options", [{}, {"keep_finished": True}], ids=["default", "keep_finished"])
SCENARIOS = pytest.mark.parametrize("scenario", ["town", "crossing"])
"""The default scenario (3 vehicles of 7 fly in its episode, 925 steps) and the crossing (4 of 20, 260 steps)."""


@pytest.mark.slow
@SCENARIOS
@KEEP_FINISHED
def test_pettingzoo_api_test(scenario, options):
    with no_api_warnings():
        api_test(env(scenario, **options), num_cycles=1000)


@SCENARIOS
@KEEP_FINISHED
def test_pettingzoo_parallel_api_test_across_the_episode_end(scenario, options):
    """1,000 cycles cross the intruder's leaving and the end of the episode (925 or 260 steps): every possible agent
    has finished when none is left (before: "No agents present but not all possible_agents are terminated or
    truncated", for the vehicles that had arrived before the episode)."""
    par = parallel_env(scenario, **options)
    with no_api_warnings():
        parallel_api_test(par, num_cycles=1000)
    assert not par.agents  # the test ran to the end of the episode


@SCENARIOS
def test_pettingzoo_seed_tests(scenario):
    with no_api_warnings():
        seed_test(lambda: env(scenario, max_cycles=60), num_cycles=60)
        parallel_seed_test(lambda: parallel_env(scenario, max_cycles=60), num_cycles=60)


@SCENARIOS
def test_pettingzoo_max_cycles_test_on_the_default_episode(scenario):
    """PettingZoo's check counts each possible agent's turns: all of them take part (before: the vehicles that had
    arrived before the default episode were possible agents that never played, and the median count failed)."""
    module = types.SimpleNamespace(env=lambda **kw: stp_module.env(scenario, **kw),
                                   parallel_env=lambda **kw: stp_module.parallel_env(scenario, **kw))
    with no_api_warnings():
        max_cycles_test(module)


@pytest.mark.slow
@SCENARIOS
def test_pettingzoo_render_test(scenario):
    with no_api_warnings():
        render_test(lambda render_mode=None: env(scenario, render_mode=render_mode, max_cycles=20))


# ------------------------------------------------------------------------------------------ SuperSuit -> SB3


# The vehicles that fly in each scenario's default episode, and the steps at which (with zero actions and seed 0)
# the first of them arrives and the intruder leaves: each test below crosses both before the episode's end.
FLYING = {"town": ["vehicle_0", "vehicle_1", "vehicle_6"],
          "crossing": ["vehicle_16", "vehicle_17", "vehicle_18", "vehicle_19"]}
FIRST_ARRIVAL = {"town": "vehicle_0", "crossing": "vehicle_16"}


@pytest.mark.slow
@SCENARIOS
def test_supersuit_vector_env_trains_sb3_ppo_for_the_vehicles(scenario):
    """The vehicles as one vector env, the intruder scripted (not an agent, so every agent is a vehicle with the
    same spaces), ``keep_finished`` (no agent death): SB3's PPO runs past the episode's end, and VecMonitor's
    episode records are SB3's (before: the env's own ``episode`` info made ``KeyError: 'r'``)."""
    ss = pytest.importorskip("supersuit")
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    par = parallel_env(scenario, intruder="greedy", keep_finished=True)
    vehicles = FLYING[scenario]
    assert par.possible_agents == vehicles
    venv = VecMonitor(ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(par), 1, num_cpus=0,
                                            base_class="stable_baselines3"))
    assert venv.num_envs == len(vehicles)
    # SuperSuit 3.11's ConcatVecEnv has no seed(), which SB3's seed= (and its reset(seed=)) calls; with one copy,
    # seeding the env's first reset seeds the episodes after it (the docs seed several copies through the
    # ConcatVecEnv's reset(seed=))
    with pytest.raises(AttributeError, match="'ConcatVecEnv' object has no attribute 'seed'"):
        PPO("MlpPolicy", venv, seed=0, device="cpu")
    par.reset(seed=0)
    model = PPO("MlpPolicy", venv, n_steps=256, batch_size=256, n_epochs=1, device="cpu")
    length = par.max_cycles - 1  # the episode window ends one step before the default max_cycles
    rollouts = length // 256 + 1  # the first episode ends in the last of them
    model.learn(total_timesteps=rollouts * 256 * len(vehicles))
    assert model.num_timesteps == rollouts * 256 * len(vehicles)
    episodes = list(model.ep_info_buffer)
    assert len(episodes) == len(vehicles) and all(e["l"] == length and np.isfinite(e["r"]) for e in episodes)


@SCENARIOS
def test_supersuit_vector_env_with_the_intruder_as_an_agent_needs_padding(scenario):
    """With the intruder an agent, the spaces differ: SuperSuit says to pad, and padded the env rolls past the
    intruder's leaving, a vehicle's arrival and the episode's end, every agent done in the same step."""
    ss = pytest.importorskip("supersuit")

    with pytest.raises(AssertionError, match="pad_observations_v0"):
        ss.pettingzoo_env_to_vec_env_v1(parallel_env(scenario, keep_finished=True))
    par = parallel_env(scenario, keep_finished=True)
    venv = ss.pettingzoo_env_to_vec_env_v1(ss.pad_observations_v0(par))
    n = len(par.possible_agents)
    assert par.possible_agents == [*FLYING[scenario], "intruder"]
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (n, 40)
    arrival = par.possible_agents.index(FIRST_ARRIVAL[scenario])
    done_at, finished = [], {}
    end = par.max_cycles - 1
    for step in range(1, end + 15):
        _, _, terms, truncs, infos = venv.step(np.zeros((n, 2), np.float32))
        done = terms | truncs
        assert done.all() or not done.any()
        if done.any():
            done_at.append(step)
        elif "intruder" not in finished and infos[-1]["status"] == INFO_CODES["intruder_status"].index("gone"):
            finished["intruder"] = step
        elif "vehicle" not in finished and infos[arrival]["status"] == INFO_CODES["status"].index("arrived"):
            finished["vehicle"] = step
    assert done_at == [end]
    assert sorted(finished) == ["intruder", "vehicle"] and max(finished.values()) < end, finished


@pytest.mark.slow
def test_the_intruder_alone_through_its_gymnasium_id_trains_sb3_ppo():
    """The intruder's single-agent view by its Gymnasium id, as SB3's ``make_vec_env`` builds it (Monitor and
    DummyVecEnv; tests/test_rl.py trains PPO on the native IntruderVecEnv): its reset observation is an array of
    its own (before: a read-only view, which ``torch.from_numpy`` warns about), and the Monitor's episode
    records come out."""
    import gymnasium
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    single = gymnasium.make("stp_env/Intruder-v0", scenario="tiny-intruder")
    obs, _ = single.reset(seed=0)
    assert obs.flags.writeable and obs.flags.owndata
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "The given NumPy array is not writable"
        torch.from_numpy(obs)
    venv = make_vec_env("stp_env/Intruder-v0", n_envs=2, seed=0, env_kwargs={"scenario": "tiny-intruder"})
    model = PPO("MlpPolicy", venv, n_steps=128, batch_size=128, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)  # episodes of 100 steps (t_IAT) end in it
    episodes = list(model.ep_info_buffer)
    assert episodes and all({"r", "l"} <= set(e) for e in episodes)


# ------------------------------------------------------------------------------------------ TorchRL


@pytest.mark.slow
@SCENARIOS
def test_torchrl_rolls_across_an_agents_finish_and_the_episode_end(scenario):
    """TorchRL's wrapper (groups by name: the vehicles, the intruder) over ``keep_finished``: the infos are
    tensors, and the episode is done once, at its end, not when the intruder leaves."""
    pytest.importorskip("torchrl")
    import torch
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper

    par = parallel_env(scenario, keep_finished=True)
    tenv = PettingZooWrapper(env=par, seed=0)
    assert tenv.group_map == {"vehicle": FLYING[scenario], "intruder": ["intruder"]}
    end = par.max_cycles - 1  # steps in an episode
    td = tenv.rollout(max_steps=end + 10, break_when_any_done=False)
    assert td.batch_size == torch.Size([end + 10])
    # done once per episode: at its end (every vehicle arrived, or the step cap), not when the intruder left
    first = torch.nonzero(td["next", "done"].squeeze(-1)).flatten().tolist()[0]
    assert first <= end - 1
    # INFO_CODES["status"] codes
    assert td["next", "vehicle", "info", "status"].shape == (end + 10, len(FLYING[scenario]))
    gone = INFO_CODES["intruder_status"].index("gone")
    assert (td["next", "intruder", "info", "status"].squeeze(-1)[:first] == gone).any()  # it left midway


# ------------------------------------------------------------------------------------------ RLlib

RLLIB_MISSING = "RLlib's dependencies are not installed: pip install 'ray[rllib]'"


def _rllib():
    pytest.importorskip("pyarrow", reason=RLLIB_MISSING)
    pytest.importorskip("pydantic", reason=RLLIB_MISSING)
    pytest.importorskip("ray.rllib.algorithms.ppo", reason=RLLIB_MISSING)
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    return ParallelPettingZooEnv


class SeedZero(BaseParallelWrapper):
    """Every episode with seed 0 (RLlib reseeds only the first reset): the intruder leaves at the same step."""

    def reset(self, seed=None, options=None):
        return self.env.reset(seed=0, options=options)


def _intruder_leaves_at(scenario: str) -> int:
    """The step at which the intruder leaves with seed 0 (``t_IAT`` after it appears, whatever the actions)."""
    par = parallel_env(scenario)
    par.reset(seed=0)
    steps = 0
    while "intruder" in par.agents:
        par.step({})
        steps += 1
    return steps


@SCENARIOS
def test_rllib_sees_the_end_when_the_intruder_leaves_in_the_last_step(scenario):
    """The episode truncated in the step in which the intruder terminates: every agent is truncated, so RLlib's
    ``__all__`` ends the episode (before: the vehicles truncated, the intruder terminated, ``__all__`` False in
    both, and RLlib stepped the finished env)."""
    wrapper_class = _rllib()
    last = _intruder_leaves_at(scenario)
    wrapper = wrapper_class(SeedZero(parallel_env(scenario, max_cycles=last)))
    wrapper.reset()
    for _ in range(last):
        _, _, terms, truncs, _ = wrapper.step({a: np.zeros(2, np.float32) for a in wrapper.par_env.agents})
    assert terms["intruder"] and truncs["intruder"] and truncs["__all__"]
    assert not wrapper.par_env.agents


def test_rllib_wrapper_renders_with_an_argument():
    """RLlib's wrapper calls ``render(self.render_mode)``; PettingZoo's ``render()`` takes none (the docs give the
    one-line subclass that renders)."""
    wrapper_class = _rllib()
    wrapper = wrapper_class(parallel_env("tiny-intruder", render_mode="rgb_array", max_cycles=5))
    wrapper.reset(seed=0)
    with pytest.raises(TypeError, match=r"render\(\) takes 1 positional argument but 2 were given"):
        wrapper.render()


@pytest.fixture
def local_ray():
    import ray

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.mark.slow
@SCENARIOS
def test_rllib_multi_agent_ppo_with_a_vehicles_and_an_intruder_policy(scenario, request):
    """Two PPO iterations, a policy for the vehicles and one for the intruder, in episodes that end in the step the
    intruder leaves (the case above): RLlib ends them and trains on them."""
    wrapper_class = _rllib()
    request.getfixturevalue("local_ray")
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.tune.registry import register_env

    last = _intruder_leaves_at(scenario)
    register_env("stp_clients_test",
                 lambda config: wrapper_class(SeedZero(parallel_env(scenario, max_cycles=last))))
    config = (PPOConfig().environment("stp_clients_test")
              .multi_agent(policies={"vehicles", "intruder"},
                           policy_mapping_fn=lambda agent, *args, **kwargs: (
                               "intruder" if agent == "intruder" else "vehicles"))
              .env_runners(num_env_runners=0, rollout_fragment_length=last + 20)
              .training(train_batch_size=last + 20, minibatch_size=64, num_epochs=1)
              .debugging(seed=0))
    algo = config.build_algo()
    try:
        results = [algo.train() for _ in range(2)]
    finally:
        algo.stop()
    assert results[-1]["num_env_steps_sampled_lifetime"] >= 2 * (last + 20)
    assert sum(r["env_runners"].get("num_episodes", 0) for r in results) >= 1
    assert {"vehicles", "intruder"} <= set(results[-1]["learners"])
