"""Replanning (Algorithm 4) inside a running simulation: ``parallel_env(..., replan=True)`` and
``assembly.with_plan``."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from stp_env import assembly, sim
from stp_env.env import parallel_env
from stp_env.policies.intruders import intruder_policy
from stp_env.policies.vehicles import vehicle_policy
from stp_env.scenarios import make
from stp_env.sim.stepping import TRACE_COUNTS

CONFIG = sim.EnvConfig(episode="full", spawn_mode="boundary")


def _run(env, seed):
    """One episode, vehicles on u*, the max-k intruder; returns the last infos, arrival times and the step trace
    count after the first step."""
    vpol, ipol = jax.jit(vehicle_policy("switching")), jax.jit(intruder_policy("max-k"))
    env.reset(seed=seed)
    key = jax.random.key(seed)
    n = env.params.vehicles.n
    arrival = np.full(n, np.inf)
    last, traces = {}, None
    while env.agents:
        key, kv, ki = jax.random.split(key, 3)
        a_v = np.asarray(vpol(kv, env.env_state, env.params))
        a_i = np.asarray(ipol(ki, env.env_state, env.params))
        actions = {a: (a_i if a == "intruder" else a_v[int(a[8:])]) for a in env.agents}
        _, _, _, _, infos = env.step(actions)
        traces = TRACE_COUNTS["step"] if traces is None else traces
        last.update(infos)
        for a, info in infos.items():
            if a != "intruder" and info["status"] == sim.ARRIVED and not np.isfinite(arrival[int(a[8:])]):
                arrival[int(a[8:])] = info["time"]
    return last, arrival, traces


@pytest.mark.slow
def test_forced_vehicles_are_replanned_and_arrive_by_their_new_sta():
    env = parallel_env("town", CONFIG, replan=True)
    base = env.params
    infos, arrival, traces = _run(env, seed=0)
    assert env.replan_log, "seed 0 should force a vehicle (the max-k intruder spawns on an avoid boundary)"
    record = env.replan_log[0]
    assert "error" not in record, record
    replanned = record["vehicles"]
    for i, sta, old in zip(replanned, record["sta"], record["old_sta"]):
        info = infos[f"vehicle_{i}"]
        assert info["forced"] and info["replanned"] and info["sta"] == pytest.approx(sta)
        assert sta > record["time"]
        assert arrival[i] <= sta + 1e-6, (i, arrival[i], sta, old)  # on time for the new STA
    others = [i for i in range(base.vehicles.n) if i not in replanned]
    # the other vehicles' plans are untouched
    assert np.array_equal(np.asarray(env.params.vehicles.nominal_states)[others],
                          np.asarray(base.vehicles.nominal_states)[others])
    assert np.array_equal(np.asarray(env.params.vehicles.sta)[others], np.asarray(base.vehicles.sta)[others])
    assert not any(infos[f"vehicle_{i}"]["replanned"] for i in others)
    assert infos["intruder"]["collisions"] == 0 and infos["intruder"]["guarantee_violations"] == 0
    # swapping plans did not retrace the step (same table shapes)
    assert TRACE_COUNTS["step"] == traces
    # reset restores the original plan
    env.reset(seed=1)
    assert env.params is base and env.replan_log == []


def test_with_plan_keeps_or_grows_the_tables_and_checks_its_input():
    scenario = make("town")
    params = assembly.params_for(scenario, CONFIG, progress=False)
    plan = assembly.load_plan(scenario, tracking_bound=float(params.tables.tracking_bound), progress=False)
    same = assembly.with_plan(params, plan)
    assert same.vehicles.nominal_states.shape == params.vehicles.nominal_states.shape
    assert np.array_equal(np.asarray(same.vehicles.nominal_states), np.asarray(params.vehicles.nominal_states))
    # a longer trajectory for vehicle 3 grows every table to a multiple of 256 samples
    v = plan.vehicles[3]
    k = params.vehicles.nominal_states.shape[1] + 10
    dt = float(params.vehicles.nominal_dt)
    longer = dataclasses.replace(v.plan, times=v.plan.times[0] + dt * np.arange(k),
                                 states=np.repeat(v.plan.states[-1:], k, axis=0),
                                 controls=np.repeat(v.plan.controls[-1:], k, axis=0), sta=v.plan.sta + 60.0)
    grown_plan = dataclasses.replace(plan, vehicles=tuple(dataclasses.replace(w, plan=longer) if w.index == 3
                                                           else w for w in plan.vehicles))
    grown = assembly.with_plan(params, grown_plan)
    assert grown.vehicles.nominal_states.shape[1] % 256 == 0 and grown.vehicles.nominal_states.shape[1] >= k
    assert int(grown.vehicles.nominal_len[3]) == k and float(grown.vehicles.sta[3]) == pytest.approx(v.plan.sta + 60.0)
    m = params.vehicles.nominal_states.shape[1]
    assert np.array_equal(np.asarray(grown.vehicles.nominal_states)[[0, 1, 2], :m],
                          np.asarray(params.vehicles.nominal_states)[[0, 1, 2]])
    with pytest.raises(ValueError, match="vehicles"):
        assembly.with_plan(params, dataclasses.replace(plan, vehicles=plan.vehicles[:-1]))
    resampled = dataclasses.replace(v.plan, times=v.plan.times[0] + 2 * dt * np.arange(len(v.plan.times)))
    with pytest.raises(ValueError, match="sample period"):
        assembly.with_plan(params, dataclasses.replace(plan, vehicles=tuple(
            dataclasses.replace(w, plan=resampled) for w in plan.vehicles)))


def test_replan_cannot_be_combined_with_prebuilt_params():
    params = assembly.params_for(make("town"), CONFIG, progress=False)
    with pytest.raises(ValueError, match="replan=True"):
        parallel_env("town", CONFIG, params=params, replan=True)
