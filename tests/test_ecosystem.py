"""The ecosystem's entry points: Gymnasium registration of the single-agent views, a training run's directory as a
learned intruder and honest training step counts (the multi-agent clients: tests/test_clients.py)."""

from __future__ import annotations

import shutil
from importlib import resources

import gymnasium
import numpy as np
import pytest

import stp_env  # noqa: F401  (registers the environments)
from stp_env.registration import ENVIRONMENTS


@pytest.mark.slow
def test_the_intruder_view_is_made_by_its_gymnasium_id():
    from stp_env.rl.gym_env import IntruderEnv

    env = gymnasium.make("stp_env/Intruder-v0", scenario="tiny-intruder")
    assert isinstance(env.unwrapped, IntruderEnv)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, reward, _, _, _ = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs) and np.isfinite(reward)
    again = gymnasium.make("stp_env:stp_env/Intruder-v0", scenario="tiny-intruder")  # Gymnasium's module:id form
    assert again.unwrapped.kbar == env.unwrapped.kbar


def test_every_registered_entry_point_loads():
    from gymnasium.envs.registration import load_env_creator

    from stp_env.rl.gym_env import IntruderEnv
    from stp_env.survivability.gym_env import SurvivabilityEnv

    assert set(ENVIRONMENTS) <= set(gymnasium.registry)
    assert load_env_creator(gymnasium.spec("stp_env/Intruder-v0").entry_point) is IntruderEnv
    assert load_env_creator(gymnasium.spec("stp_env/Survivability-v0").entry_point) is SurvivabilityEnv


def _shipped_policy() -> str:
    return str(resources.files("stp_env") / "data" / "intruders" / "town-kbar2.npz")


def test_a_training_runs_directory_is_a_learned_intruder(tmp_path):
    from stp_env.evaluation import resolve_intruder
    from stp_env.policies.learned import load_intruder

    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(_shipped_policy(), run / "intruder.npz")
    (run / "model.zip").write_bytes(b"PK")  # SB3's archive, as train-intruder leaves it
    assert load_intruder(str(run)).__name__ == "learned:intruder"
    assert callable(resolve_intruder(f"learned:{run}"))
    with pytest.raises(ValueError, match=r"intruder\.npz"):  # the archive is refused, pointing to the export
        load_intruder(str(run / "model.zip"))
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    with pytest.raises(ValueError, match=r"intruder\.npz"):
        load_intruder(str(unfinished))


@pytest.mark.parametrize(("timesteps", "trained"), [(4096, 8192), (8192, 8192), (8193, 16384), (1, 8192)])
def test_training_counts_whole_rollouts(timesteps, trained):
    from stp_env.rl.train import TrainConfig

    assert TrainConfig(total_timesteps=timesteps, n_envs=64, n_steps=128).trained_timesteps == trained
