"""The buffer game's worst vehicles, the optimal max-k intruder and the intruder paper's Fig. 6 worst case."""

from __future__ import annotations

import math
import types

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.dynamics import RelativeDubins
from stp_env.evaluation.runner import avoid_start_order_stats
from stp_env.sim import tables


def _synthetic_params():
    """A small buffer table with a closed-form value: the distance to a disk 150 m ahead of the vehicle (not
    invariant under the vehicle's turns, so that both its speed and its turn rate matter), plus a heading term."""
    grid = hj.Grid.from_bounds((-400.0, -400.0, -math.pi), (400.0, 400.0, math.pi), (81, 81, 36), periodic=2)
    x = np.asarray(grid.states())

    def value(s):
        return np.hypot(s[..., 0] - 150.0, s[..., 1]) - 50.0 + 20.0 * np.cos(s[..., 2])

    dyn = RelativeDubins(wind=0.0)
    params = types.SimpleNamespace(tables=types.SimpleNamespace(avoid_dynamics=dyn, buffer_grid=grid,
                                                                buffer_values=jnp.asarray(value(x), jnp.float32)))
    return params, value, dyn


@pytest.mark.slow
@pytest.mark.parametrize("state", [(250.0, 120.0, 2.0), (-200.0, 150.0, -1.0), (90.0, -260.0, 0.5),
                                   (-150.0, -180.0, 3.0)])
def test_worst_control_is_the_steepest_descent_by_brute_force(state):
    """Over a 41 x 41 grid of vehicle controls, none decreases the (closed-form) buffer value faster than the
    policy's control (up to the table's interpolation error, 2 %), the other players fixed at their own
    minimisers; and the control is far from the worst one (it brings the intruder in, it does not run away)."""
    params, value, dyn = _synthetic_params()
    x = jnp.asarray(state, jnp.float32)
    u = np.asarray(tables.worst_control(params, x))
    d = np.asarray(tables.buffer_pursuit(params, x))
    h = 1e-3

    def rate(v, om):
        f = np.asarray(dyn(tuple(np.asarray(state)), (v, om), tuple(d)), float)
        return (value(np.asarray(state) + h * f) - value(np.asarray(state))) / h

    vs, oms = np.linspace(dyn.v_min, dyn.v_max, 41), np.linspace(-dyn.omega_max, dyn.omega_max, 41)
    rates = [rate(v, om) for v in vs for om in oms]
    brute, worst_case = min(rates), max(rates)
    assert worst_case - brute > 10.0  # the control matters at this state: the check can fail
    assert rate(*u) <= brute + 0.02 * (worst_case - brute)


@pytest.mark.parametrize("state", [(250.0, 120.0, 2.0), (-200.0, 150.0, -1.0), (90.0, -260.0, 0.5)])
def test_descent_heading_by_brute_force(state):
    """The heading the worst vehicle turns to: over 720 directions of the vehicle's velocity, the one that lowers
    the closed-form value fastest, within 2 degrees (the table's gradient vs the exact one); its speed is the
    game's."""
    params, value, _ = _synthetic_params()
    v, phi, norm = (float(a) for a in tables.buffer_descent(params, jnp.asarray(state, jnp.float32)))
    s = np.asarray(state)
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    h = 1e-3
    rates = [value(s - h * 25.0 * np.array([np.cos(a), np.sin(a), 0.0])) for a in angles]
    best = angles[int(np.argmin(rates))]
    assert norm > 0.5
    assert abs(wrap_angle(phi - best)) < math.radians(2.0)
    assert v == pytest.approx(float(tables.worst_control(params, jnp.asarray(state, jnp.float32))[0]))


def test_worst_control_needs_the_buffer_table():
    params = types.SimpleNamespace(tables=types.SimpleNamespace(avoid_dynamics=RelativeDubins(), buffer_grid=None,
                                                                buffer_values=None))
    with pytest.raises(ValueError, match="with_buffer"):
        tables.worst_control(params, jnp.zeros(3))


def test_avoid_start_order_statistics():
    ep = {"avoid_start": np.array([[5.0, 8.3, np.inf], [np.inf, 5.5, 9.0], [np.inf, np.inf, np.inf]]),
          "t_appear": np.array([5.0, 5.0, 4.0])}
    lows, meds = avoid_start_order_stats(ep, 4)
    assert lows == [0.0, 3.3, None, None]
    assert meds == [0.25, 3.65, None, None]


@pytest.fixture(scope="module")
def fig6_setup():
    from stp_env import assembly
    from stp_env.evaluation.worst_case import fig6_params
    from stp_env.scenarios import make

    scenario = make("fig6")
    avoid, _ = assembly.load_artifacts(scenario, progress=False)
    return scenario, avoid, fig6_params(scenario)


@pytest.mark.slow
def test_fig6_placement_is_derived_from_the_tables(fig6_setup):
    """``Q1`` and ``Q2`` are where the derivation puts them on the current tables, and ``Q2`` starts on the boundary
    of ``V^B(0, t_BRD)`` as seen from the intruder's spawn (the buffer region is exactly what the first hop
    crosses)."""
    from stp_env.scenarios.catalog.fig6 import FIG6_Q1_DISTANCE, FIG6_TRAIL, derive_q1_distance, derive_q2_offset

    _, avoid, params = fig6_setup
    x2 = FIG6_TRAIL[0][0]
    assert derive_q2_offset(avoid) == pytest.approx(x2, abs=0.05)
    assert derive_q1_distance(avoid) == pytest.approx(FIG6_Q1_DISTANCE, abs=0.05)
    cell = float(params.tables.buffer_grid.spacing[0])
    vb = float(tables.buffer_value(params, jnp.asarray([x2, 0.0, -math.pi], jnp.float32)))
    assert abs(vb) < cell
    assert float(tables.buffer_value(params, jnp.asarray([x2 + 2 * cell, 0.0, -math.pi], jnp.float32))) > 0


def test_fig6_worst_vehicles_reach_kbar(fig6_setup):
    """Fig. 6: the worst vehicles against the optimal max-k intruder: Q1-Q3 forced at 0, t_BRD, 2 t_BRD (within one
    step), Q4 untouched; never more than k̄."""
    from stp_env.evaluation.worst_case import FIG6_PAPER_TIMES, reproduce
    from stp_env.policies import optimal_max_k, worst

    _, _, params = fig6_setup
    run = reproduce(params, worst, optimal_max_k, n_steps=160)
    assert run["n_forced"] == 3 <= int(params.intruder.kbar)
    assert all(run["assumption_ok"])
    assert run["collisions"] == 0
    for got, want in zip(run["avoid_start_s"][:3], FIG6_PAPER_TIMES[:3]):
        assert abs(got - want) <= 0.1
    assert math.isinf(run["avoid_start_s"][3])


def test_env_rejects_an_unknown_vehicle_policy():
    from stp_env.env import STPParallelEnv

    with pytest.raises(ValueError, match="vehicle_policy 'best'"):
        STPParallelEnv("fig6", vehicle_policy="best")
