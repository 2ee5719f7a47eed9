"""Attackers that try: the searched attacker (the cross-entropy search of ``stp_env.falsify.search`` over its
departure time, entry point, return point and speed) gets into a forbidden zone undetected where the schedule's
reachability ellipses (Def. 3) meet the zone, and against the schedule whose ellipses miss them (Section II-F) it
attempts entries and every attempt is detected. And the attempt counting of ``threat.attempts`` against a hand
count."""

from __future__ import annotations

import functools
import math
import types

import jax
import numpy as np
import pytest

from stp_env.coobservation import checkpoints, evaluation, searched, threat
from stp_env.coobservation.uav import FormationScenario
from stp_env.evaluation.stats import clopper_pearson_upper
from stp_env.falsify.search import SearchConfig
from stp_env.sim.bounds import V_MAX, WIND

SCENARIO = FormationScenario()
# 4 iterations of 2 restarts x 40 attacks: the unsecured schedule's search concentrates on undetected entries by
# the last iteration (about 1.5 % of uniformly random attacks get in undetected there)
CONFIG = SearchConfig(method="cem", budget=320, population=40, restarts=2, batch=80)


@functools.lru_cache(maxsize=1)
def _setup():
    params = SCENARIO.params(artifacts=SCENARIO.coarse_artifacts())
    secure = checkpoints.ellipse_test(SCENARIO.forbidden, SCENARIO.attacker_speed, SCENARIO.ellipse_radius)
    times = {"secured": SCENARIO.secured_times(secure), "unsecured": SCENARIO.uniform_times(90.0)}
    m = max(len(SCENARIO.schedule(t)) for t in times.values())
    threats = {k: threat.threat_params(SCENARIO.schedule(t), SCENARIO.forbidden, SCENARIO.observation_radius,
                                       pad_to=m) for k, t in times.items()}
    return params, threats


@functools.lru_cache(maxsize=2)
def _search(schedule: str):
    params, threats = _setup()
    attack = searched.SearchedAttack(params, threats[schedule], wind_seed=0)
    out = searched.run(attack, CONFIG, seed=0)
    return attack, out, threat.outcomes(out.finals), threat.attempts(out.finals, params, threats[schedule])


def _check_replay(attack, out, o, a):
    """The search's objective agrees with the replayed final states: a value >= 0 exactly for an undetected
    entry, and each attack departs no earlier than the time it chose."""
    r = out.result
    assert r.samples.shape == (r.evaluations, searched.DIM) and len(r.values) == r.evaluations
    np.testing.assert_array_equal(r.values >= 0, a["undetected"])
    np.testing.assert_array_equal(a["undetected"], o["success"])
    chosen = np.array([attack.decision(z).departure for z in r.samples])
    departed = a["departed"]
    assert np.all(np.asarray(out.finals.departure_time)[departed] >= chosen[departed] - 0.2 - 1e-4)


@pytest.mark.slow
def test_the_searched_attacker_gets_in_undetected_where_the_ellipses_meet_the_zones():
    """On the unsecured schedule (every 90 s) the search finds an undetected entry (positive margin) that replays,
    and its last iteration concentrates on them: a random pick of an attack gets in undetected about 1.5 % of
    the time, so replacing the search by one fails this test."""
    attack, out, o, a = _search("unsecured")
    _check_replay(attack, out, o, a)
    r = out.result
    assert r.best_value > 0
    last = slice(r.evaluations - CONFIG.population * CONFIG.restarts, None)
    assert a["undetected"][last].mean() >= 0.3
    # the best attack replays (same wind draw) to an undetected entry
    final = jax.device_get(jax.jit(attack.episode)(r.best_z))
    c = int(final.compromised)
    assert bool(final.entered[c]) and math.isinf(float(final.detect_time))
    assert out.best.vehicle == c
    # its entry falls in an observation gap whose ellipse (speed v_max + wind) meets the zones
    secure = checkpoints.ellipse_test(SCENARIO.forbidden, SCENARIO.attacker_speed, SCENARIO.ellipse_radius)
    times = SCENARIO.uniform_times(90.0)
    t_entry = float(final.entry_time[c])
    k = int(np.searchsorted(times, t_entry))
    gap = (times[k - 1], times[k])
    assert not all(secure(*SCENARIO.segment_foci(s)[:1], gap[0], SCENARIO.segment_foci(s)[1], gap[1])
                   for s in SCENARIO.segments_between(*gap))


@pytest.mark.slow
def test_against_the_secured_schedule_the_searched_attacker_tries_and_is_always_detected():
    """The searched attacker attempts entries in most of its attacks (it goes whatever the inequality says), gets
    into a zone in some, and every attempt misses an observation (margin < 0)."""
    attack, out, o, a = _search("secured")
    _check_replay(attack, out, o, a)
    assert a["attempt"].mean() > 0.5
    assert o["entered"].sum() > 0
    assert np.all(a["margin"][a["attempt"]] < 0)
    assert a["undetected"].sum() == 0 and out.result.best_value < 0
    row = evaluation.summarize("secured", "searched", {**o, **{f"attempt_{k}": v for k, v in a.items()}})
    assert row.attempts == a["attempt"].sum() and row.undetected_entries == 0
    assert row.margin_quantiles["max"] < 0


def _hand_made():
    """Six episodes of two vehicles under observations of the pair at 10 and 20 s and base stations at 0 and
    30 s (and one placeholder), radius 200 m, ground speed 25 + 5 m/s."""
    from stp_env.coobservation.schedule import Observation

    obs = [Observation(time=0.0, agent=0, point=(0.0, 0.0)), Observation(time=0.0, agent=1, point=(0.0, 100.0)),
           Observation(time=10.0, agent=0, partner=1), Observation(time=20.0, agent=0, partner=1),
           Observation(time=30.0, agent=0, point=(0.0, 0.0)), Observation(time=30.0, agent=1, point=(0.0, 100.0))]
    tp = threat.threat_params(obs, [((0.0, 500.0), (100.0, 500.0), (100.0, 600.0))], 200.0, pad_to=7)
    inf = np.inf
    # per episode: compromised, departure, entered (of it), detect time, distances at the 7 observations, missed,
    # the compromised vehicle's status (1 flying, 3 collided)
    eps = [(-1, inf, False, inf, [0, 0, 120, 120, 0, 0, inf], 1),        # nobody compromised: no attempt
           (0, 12.0, True, 20.0, [0, 0, 120, 260, 0, 0, inf], 1),       # in, caught at 20 s: -60 m / 30 m/s
           (1, 5.0, True, inf, [0, 0, 150, 190, 5, 3, inf], 1),         # in, never caught: +10 m / 30 m/s
           (1, 5.0, False, inf, [0, 0, 180, 120, 0, 0, inf], 1),        # came back, never in: no attempt
           (0, 3.0, False, 10.0, [0, 0, 50, 50, 0, 0, inf], 3),         # rammed its observer: lost, caught
           (0, inf, False, inf, [0, 0, 120, 120, 0, 0, inf], 1)]        # flew its plan: no attempt
    n_ep = len(eps)
    c = np.array([e[0] for e in eps])
    entered = np.zeros((n_ep, 2), bool)
    for i, e in enumerate(eps):
        if e[2]:
            entered[i, e[0]] = True
    dist = np.array([e[4] for e in eps], float)
    status = np.ones((n_ep, 2), int)
    for i, e in enumerate(eps):
        status[i, max(e[0], 0)] = e[5]
    missed = (dist > 200.0) & np.isfinite(dist)
    missed[4, 2:4] = True  # the lost pair's observations at 10 and 20 s
    final = types.SimpleNamespace(
        compromised=c, departure_time=np.array([e[1] for e in eps]), entered=entered,
        entry_time=np.where(entered, 15.0, inf), detect_time=np.array([e[3] for e in eps]),
        checked=np.ones((n_ep, 7), bool), missed=missed, obs_distance=dist,
        false_alarms=np.zeros(n_ep, int), max_track_error=np.zeros((n_ep, 2)),
        sim=types.SimpleNamespace(status=status), closest_zone=np.zeros(n_ep))
    bounds = np.zeros(8)
    bounds[V_MAX], bounds[WIND] = 25.0, 5.0
    params = types.SimpleNamespace(vehicles=types.SimpleNamespace(bounds=bounds),
                                   episode=types.SimpleNamespace(dt=0.2))
    return final, params, tp


@pytest.mark.slow
def test_attempt_counting_on_a_hand_made_rollout_equals_a_hand_count():
    final, params, tp = _hand_made()
    a = threat.attempts(final, params, tp)
    np.testing.assert_array_equal(a["departed"], [False, True, True, True, True, False])
    np.testing.assert_array_equal(a["attempt"], [False, True, True, False, True, False])
    np.testing.assert_array_equal(a["undetected"], [False, False, True, False, False, False])
    np.testing.assert_array_equal(a["lost"], [False, False, False, False, True, False])
    # episode 1: departed at 12 s, so only the observations at 20 s (260 m) and 30 s count; episode 2: from 5 s on,
    # the closest is 190 m at 20 s
    np.testing.assert_allclose(a["margin"][[1, 2]], [(200 - 260) / 30, (200 - 190) / 30], rtol=1e-6)
    assert np.isneginf(a["margin"][4]) and np.isnan(a["margin"][[0, 3, 5]]).all()
    o = threat.outcomes(final)
    row = evaluation.summarize("hand", "made", {**o, **{f"attempt_{k}": v for k, v in a.items()}})
    assert (row.attempts, row.undetected_entries, row.lost_attempts, row.episodes) == (3, 1, 1, 6)
    assert row.undetected_upper95 == clopper_pearson_upper(1, 6)
    assert row.margin_quantiles["min"] == pytest.approx(-2.0) and row.margin_quantiles["max"] == pytest.approx(1 / 3)
    table = evaluation.attempts_markdown([row])
    assert "| hand | made | 6 | 3 | 0.5000 |" in table
