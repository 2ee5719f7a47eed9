"""The compromised-vehicle threat in the UAV simulator: under the secured schedule the opportunistic attacker never
finds a window and the reckless one is always caught; under the unsecured one (every 90 s) some attacks succeed,
so the check can fail. And the PettingZoo adapter passes PettingZoo's API test."""

from __future__ import annotations

import functools
import itertools

import jax
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from stp_env.coobservation import attackers, checkpoints, threat
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


def test_secured_schedule_ellipses_miss_the_zones_and_the_unsecured_do_not():
    secure = checkpoints.ellipse_test(SCENARIO.forbidden, SCENARIO.attacker_speed, SCENARIO.ellipse_radius)
    times = {"secured": SCENARIO.secured_times(secure), "unsecured": SCENARIO.uniform_times(90.0)}
    for name, expect in (("secured", True), ("unsecured", False)):
        t = times[name]
        ok = [all(secure(*SCENARIO.segment_foci(s)[:1], a, SCENARIO.segment_foci(s)[1], b)
                  for s in SCENARIO.segments_between(a, b)) for a, b in itertools.pairwise(t)]
        assert all(ok) if expect else not all(ok)


@pytest.mark.slow
def test_attacks_succeed_only_against_the_unsecured_schedule():
    params, threats, _ = _setup()
    n_steps = threat.steps_for(params)
    attacker = attackers.ATTACKERS["opportunistic"]  # one function object: one compilation for both schedules
    out = {}
    for name, tp in threats.items():
        final, _ = threat.rollout(jax.random.key(3), params, tp, attacker, 12, n_steps, (90.0, 96.0))
        out[name] = threat.outcomes(jax.device_get(final))
    sec, uns = out["secured"], out["unsecured"]
    assert sec["entered"].sum() == 0 and sec["detected"].sum() == 0 and sec["success"].sum() == 0
    assert uns["success"].sum() > 0  # the same attacker gets in undetected when the schedule is not secured
    for o in (sec, uns):
        assert o["all_checked"].all() and o["honest_entries"].sum() == 0
        # other vehicles' observations fail only where the attacker rammed a teammate (both are lost)
        assert o["false_alarms"][o["collisions"] == 0].sum() == 0
        assert o["max_track_error"].max() < SCENARIO.tracking_margin


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


def test_training_outcome_rates_count_only_finished_episodes():
    from stp_env.coobservation.learned import outcome_rates

    infos = [{"entered": True, "detected": False}, {"entered": True, "detected": True},
             {"entered": False, "detected": True}, {}, {"entered": True, "detected": False}]
    dones = [True, True, True, False, False]  # the last one has not ended: not counted
    assert outcome_rates(infos, dones) == (3, 2, 2, 1)
