"""Missions in batches (:mod:`stp_env.survivability.batch`) against the per-mission path
(:func:`stp_env.survivability.mission.run_mission`, :func:`stp_env.survivability.study.run_instance`): the same
instances (robustness, realisation bits, occupied cells), the same missions field by field, the same rows of the
study, on a small mission where every outcome, reveals, ``Omega`` widenings and random tie-breaks occur."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_survivability import small

from stp_env.survivability import batch, mission, ties
from stp_env.survivability.config import POLICIES, PlannerConfig, StudyConfig, TrafficConfig
from stp_env.survivability.graph import build_graph
from stp_env.survivability.network import build_network
from stp_env.survivability.records import read_study
from stp_env.survivability.study import run_instance, run_study, study_groups, study_job

KEYS = ("n_partial", "n_unknown", "instance", "policy", "outcome", "reveals", "omega_switch", "n_dp", "windows")


@pytest.mark.slow
def test_tie_streams_repeat_numpy_s_choice():
    """``Generator.choice`` of ``n`` items, call after call, equals Lemire's method on the pre-drawn 32-bit
    outputs (``tie_streams``, ``lemire``), for every ``n`` a state can have ties among."""
    seeds = [(0, i) for i in range(6)] + [(123, 4), 7]
    rng_n = np.random.default_rng(1)
    sizes = rng_n.integers(2, 26, size=(len(seeds), 40))
    streams = jnp.asarray(ties.tie_streams(seeds))

    @jax.jit
    def draws(stream, ns):
        def step(cursor, n):
            pick, nxt = ties.lemire(stream, cursor, n)
            return nxt, pick
        return jax.lax.scan(step, jnp.int32(0), ns)[1]

    got = np.asarray(jax.vmap(draws)(streams, jnp.asarray(sizes, jnp.int32)))
    for k, seed in enumerate(seeds):
        rng = np.random.default_rng(seed)
        want = [int(rng.choice(np.arange(n))) for n in sizes[k]]
        assert got[k].tolist() == want


@pytest.mark.slow
def test_a_batch_flies_the_per_mission_missions(monkeypatch, tmp_path):
    """Two values of N_p and of N_u, four instances, every policy: the study run in one batch (``batch_groups``)
    writes the rows of :func:`run_instance`; the batch's instances are the per-mission path's; its missions equal
    ``run_mission``'s in every field (path, reveals in order with their minutes, Omega widening, sweeps)."""
    config = StudyConfig(n_partial=(3, 6), n_unknown=(4, 20), n_instances=4, mission=small(),
                         traffic=TrafficConfig(reach_km=4), planner=PlannerConfig(n_mc=64, n_survival=64))
    g = build_graph(build_network(config.mission))
    groups = study_groups(config)
    keys = [(p, u, i) for i, p, us in groups for u in us]
    traffics = [config.traffic.with_overrides(n_partial=p, n_unknown=u) for p, u, _ in keys]
    seeds = [(config.seed, i) for _, _, i in keys]

    # The study: its 8 groups in one piece of 16 instances (the shapes of the batch below: one compilation).
    run_study(config, tmp_path, progress=False, batch_groups=len(groups))
    rows = sorted(tuple(r[k] for k in KEYS) for r in read_study(tmp_path))
    ref_rows = []
    for i, p, us in groups:
        shared: dict = {}
        ref_rows += [tuple(r[k] for k in KEYS) for u in us for r in run_instance(g, config, p, u, i, shared)]
    assert len(rows) == 16 * len(POLICIES) and rows == sorted(ref_rows)

    instances = batch.make_instances(g, traffics, config.planner, seeds)
    alone = [mission.make_instance(g, t, config.planner, s) for t, s in zip(traffics, seeds)]
    for a, b in zip(instances, alone):
        assert np.array_equal(a.robustness, b.robustness) and np.array_equal(a.blocked_bits, b.blocked_bits)
        assert np.array_equal(a.occupancy, b.occupancy) and a.known_key == b.known_key
    assert min(inst.robustness.min() for inst in instances) < 1.0          # the partially known traffic matters

    ties = collections.Counter()
    choose = mission.choose

    class Spy:
        def __init__(self, rng, key):
            self.rng, self.key = rng, key

        def choice(self, a):
            ties[self.key] += 1
            return self.rng.choice(a)

    def spying(graph, g_, policy, beta, tables, feasible, robustness, omega, rng):
        return choose(graph, g_, policy, beta, tables, feasible, robustness, omega, Spy(rng, policy))

    monkeypatch.setattr(mission, "choose", spying)
    got = batch.run_batch(g, instances, config.policies, config.planner, seeds)
    want = []
    for inst, seed in zip(instances, seeds):
        first = mission.initial_tables(g, inst, config.policies, config.planner.nf_count)
        want.append({q: mission.run_mission(g, inst, q, config.planner, seed=seed, initial_tables=first[q])
                     for q in config.policies})
    assert got == want
    # What the comparison covers: every outcome, reveals, widenings of Omega, several sweeps, random tie-breaks.
    results = [r for d in want for r in d.values()]
    assert {r.outcome for r in results} == {"G", "A", "L"}
    assert sum(len(r.revealed) for r in results) > 20 and any(len(r.revealed) > 1 for r in results)
    assert sum(r.omega_switch is not None for r in results) > 5 and max(r.n_dp for r in results) >= 2
    assert sum(ties.values()) > 5 and len(ties) == len(POLICIES)


def test_a_batched_study_s_pieces_are_whole_groups():
    """``batch_groups``: 0 or 1, one group a piece (its argument the group, as before batches); ``k``, ``k``
    consecutive groups a piece; the units are the instances."""
    config = StudyConfig(n_partial=(3, 6), n_unknown=(4, 20, 60), n_instances=3, mission=small())
    groups = study_groups(config)
    for k in (0, 1):
        job = study_job(config, groups, k)
        assert job.arguments == tuple(groups) and job.units == (3,) * 6 and job.context.batch_groups == k
    job = study_job(config, groups, 4)
    assert job.arguments == (tuple(groups[:4]), tuple(groups[4:])) and job.units == (12, 6)
    with pytest.raises(ValueError, match="batch_groups"):
        study_job(config, groups, -1)


@pytest.mark.slow
def test_a_batch_without_realisation_bits_and_with_landing_counts_flies_the_per_mission_missions():
    """The other planner options the batch compiles differently: ``pi_S``'s tree recursion (no realisation bits,
    ``n_survival=0``) and ``pi_Nf`` counting trajectories to any landing site (``nf_count="landing"``); and
    ``reveal="step"``, flown one mission at a time inside the batch. Each equals ``run_mission``."""
    traffic = TrafficConfig(reach_km=4)
    g = build_graph(build_network(small()))
    seeds = [(5, i) for i in range(4)] * 2
    for planner in (PlannerConfig(n_mc=64, n_survival=0, nf_count="landing"),
                    PlannerConfig(n_mc=64, n_survival=64, reveal="step")):
        traffics = [traffic.with_overrides(n_partial=p, n_unknown=12) for p in (3, 6) for _ in range(4)]
        instances = batch.make_instances(g, traffics, planner, seeds)
        assert all((inst.blocked_bits is None) == (planner.n_survival == 0) for inst in instances)
        got = batch.run_batch(g, instances, POLICIES, planner, seeds)
        want = []
        for inst, seed in zip(instances, seeds):
            first = mission.initial_tables(g, inst, POLICIES, planner.nf_count)
            want.append({q: mission.run_mission(g, inst, q, planner, seed=seed, initial_tables=first[q])
                         for q in POLICIES})
        assert got == want
        results = [r for d in want for r in d.values()]
        assert sum(len(r.revealed) for r in results) > 5 and len({r.outcome for r in results}) >= 2
