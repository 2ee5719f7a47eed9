"""Assumptions fail closed: a value that is not finite never makes an episode look clean, and a setting that breaks
an assumption of the papers is refused unless ``allow_uncertified``."""

from __future__ import annotations

import dataclasses
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import assembly, scenarios, sim
from stp_env.evaluation import Configuration, replays, runner
from stp_env.sim import winds
from stp_env.sim.winds.base import WindModel

SCENARIO = "tiny-intruder"


@dataclasses.dataclass(frozen=True)
class Broken(WindModel):
    """A plug-in wind model gone wrong: NaN for the vehicles and an infinite wind for the intruder."""

    name = "test-broken"
    help = "NaN and inf"

    def draw(self, key, state, params):
        del key
        n = params.vehicles.n
        w = jnp.full((n + 1, 2), jnp.nan).at[n].set(jnp.inf)
        return w, state.wind


@pytest.mark.slow
def test_a_wind_model_that_returns_nan_or_inf_makes_the_episode_an_assumption_failure(monkeypatch):
    """Before: the states went NaN, every comparison with them was false, and the episode was booked clean (no
    collision, no violation, no assumption failure)."""
    monkeypatch.setitem(winds.WIND_MODELS, Broken.name, Broken)
    config = Configuration(scenario=SCENARIO, kbar=2, intruder="greedy", wind_model=Broken.name)
    (result,) = runner.evaluate([config], episodes=2, seed=0, batch_size=2, progress=False)
    summary = result.summary
    assert summary["assumption_failures"] == 2, summary
    assert summary["violation_episodes"] == 0 and summary["tracking_violations"] == 0
    assert len(result.events) == 2 and all("assumption_failed" in e["kinds"] for e in result.events)
    final, _ = replays.replay_event(result.events[0])                   # counted, and replayable
    assert not np.all(np.asarray(final["assumption_ok"]))


def _params(dt: float, **config):
    scenario = scenarios.make(SCENARIO, kbar=2)
    return scenario, assembly.params_for(scenario, sim.EnvConfig(dt=dt, **config), progress=False)


@pytest.mark.parametrize("dt", [10.5, 12.0])
def test_a_decision_step_longer_than_t_iat_is_refused_unless_allowed(dt):
    """One step longer than ``t_IAT`` keeps the intruder a whole step, past Assumption 1's ``t_IAT`` (before: the
    intruder stayed ``dt`` seconds, every vehicle still certified, no warning)."""
    assert scenarios.make(SCENARIO, kbar=2).t_iat < dt
    with pytest.raises(ValueError, match=r"longer than t_IAT.*allow_uncertified=True"):
        _params(dt)
    with pytest.warns(UserWarning, match="longer than t_IAT"):
        _, params = _params(dt, allow_uncertified=True)
    assert not np.any(np.asarray(params.vehicles.certified))


def test_a_decision_step_that_divides_t_iat_stays_certified():
    scenario = scenarios.make(SCENARIO, kbar=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        _, params = _params(float(scenario.t_iat) / 4)
    assert np.all(np.asarray(params.vehicles.certified))
