"""The SPP paper's four-vehicle example with the centralized (Section IV-A) and least-restrictive (IV-B) methods.

Planned on a coarser grid than the scenario's (61 x 61 x 30: spacing 0.033, still 6 cells across a target) to keep
the test short. Each vehicle waits on the ground until its t_LDT, then flies its planning controller (eq. 13, from
its own BRS) -- under the centralized method always, under the least-restrictive one only near the boundary of its
BRS and a random control inside it (eq. 20) -- in random or worst-case wind and heading disturbance (eq. 28 bounds).
It must reach its target by its STA, and every pair of airborne vehicles must stay farther apart than R_c.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.planning.methods import SliceFeedback, plan_methods, projected_obstacle_table, tabulated_obstacles
from stp_env.planning.single import planning_control
from stp_env.scenarios import make

DT = 0.005
HORIZON = 4.0
LR_MARGIN = 0.05
"""Least-restrictive simulation: inside ``{V <= -LR_MARGIN}`` a random control, else the optimal one (eq. 20)."""


@pytest.fixture(scope="module")
def plans():
    sc = make("four-vehicle", grid_points=(61, 61, 30))
    out = {}
    for method in ("centralized", "least_restrictive"):
        out[method] = plan_methods(sc.grid(), sc.vehicle, method, sc.collision_radius, sc.starts(), sc.targets(),
                                   sc.target_radii(), sc.stas(), sc.priorities(), horizon=HORIZON,
                                   time_step=sc.time_step, progress=False)
    return sc, out


@functools.partial(jax.jit, static_argnames=("grid", "dyn", "n_steps"))
def _simulate(key, x0, t_ldt, t0, slice_times, stacks, targets, radius, worst, least_restrictive, *, grid, dyn,
              n_steps):
    """All vehicles at once (vmapped over vehicles); ``worst`` and ``least_restrictive`` are traced flags, so both
    methods and both wind modes share one compiled scan."""
    n = x0.shape[0]

    def inputs(key, times, stack, t, x):
        u, d = planning_control(grid, dyn, times, stack, t, x)
        k1, k2, k3, k4, k5 = jax.random.split(key, 5)
        v = hj.interpolation.interpolate_slices(grid, times, stack, t, x)
        free = jnp.stack([jax.random.uniform(k4, (), minval=dyn.v_min, maxval=dyn.v_max),
                          jax.random.uniform(k5, (), minval=-dyn.omega_max, maxval=dyn.omega_max)])
        u = jnp.where(least_restrictive & (v < -LR_MARGIN), free, u)
        ang = jax.random.uniform(k1, (), minval=-jnp.pi, maxval=jnp.pi)
        w = dyn.wind * jnp.sqrt(jax.random.uniform(k2)) * jnp.array([jnp.cos(ang), jnp.sin(ang)])
        dth = jax.random.uniform(k3, (), minval=-dyn.heading_disturbance, maxval=dyn.heading_disturbance)
        return u, jnp.where(worst, d[:2], w), jnp.where(worst, d[2], dth)

    def f(x, u, w, dth):
        return jnp.array([u[0] * jnp.cos(x[2]) + w[0], u[0] * jnp.sin(x[2]) + w[1], u[1] + dth])

    def move(key, times, stack, t, x, ldt, done):
        u, w, dth = inputs(key, times, stack, t, x)
        xm = x + 0.5 * DT * f(x, u, w, dth)
        u, w, dth = inputs(key, times, stack, t + 0.5 * DT, xm)  # same draw: the disturbance holds over the step
        xn = x + DT * f(xm, u, w, dth)
        xn = xn.at[2].set(wrap_angle(xn[2]))
        return jnp.where((t >= ldt) & ~done, xn, x)

    def step(carry, s):
        xs, arrived, arrival_t, key = carry
        t = t0 + s * DT
        key, sub = jax.random.split(key)
        keys = jax.vmap(lambda i: jax.random.fold_in(sub, i))(jnp.arange(n))
        xs = jax.vmap(move, in_axes=(0, 0, 0, None, 0, 0, 0))(keys, slice_times, stacks, t, xs, t_ldt, arrived)
        inside = jnp.linalg.norm(xs[:, :2] - targets, axis=1) <= radius
        newly = inside & ~arrived & (t + DT >= t_ldt)
        arrival_t = jnp.where(newly, t + DT, arrival_t)
        arrived = arrived | newly
        airborne = (t + DT >= t_ldt) & ~arrived
        d = jnp.linalg.norm(xs[:, None, :2] - xs[None, :, :2], axis=-1)
        both = airborne[:, None] & airborne[None, :] & ~jnp.eye(n, dtype=bool)
        return (xs, arrived, arrival_t, key), jnp.min(jnp.where(both, d, jnp.inf))

    carry = (x0, jnp.zeros(n, bool), jnp.full(n, jnp.inf), key)
    (_, _, arrival_t, _), dmins = jax.lax.scan(step, carry, jnp.arange(n_steps))
    return arrival_t, jnp.min(dmins)


_STACKS: dict = {}


def _stacked(mp):
    if id(mp) not in _STACKS:
        _STACKS[id(mp)] = (jnp.asarray(np.stack([r.slice_times for r in mp.reach]), jnp.float32),
                           jnp.stack([r.brs for r in mp.reach]))
    return _STACKS[id(mp)]


def simulate(sc, mp, mode, seed, n_steps: int):
    times, stacks = _stacked(mp)
    arrival, dmin = _simulate(jax.random.key(seed), jnp.asarray(sc.starts(), jnp.float32),
                              jnp.asarray(mp.plan.t_ldt(), jnp.float32), jnp.float32(float(sc.stas().max()) - HORIZON),
                              times, stacks, jnp.asarray(sc.targets(), jnp.float32),
                              jnp.float32(sc.vehicles[0].target_radius), jnp.asarray(mode == "worst"),
                              jnp.asarray(mp.method == "least_restrictive"), grid=sc.grid(), dyn=sc.vehicle,
                              n_steps=n_steps)
    return np.asarray(arrival), float(dmin)


@pytest.mark.slow
def test_least_restrictive_departs_earlier_and_top_priority_is_unchanged(plans):
    _, out = plans
    central, least = out["centralized"].plan.t_ldt(), out["least_restrictive"].plan.t_ldt()
    # Q1 sees no obstacle: the same BRS, the same t_LDT (SPP Section V-B), bit for bit.
    assert central[0] == least[0]
    # Lower priorities: the least-restrictive obstacles contain the centralized ones (eq. 23 vs eq. 19).
    assert np.all(least[1:] < central[1:]), (central, least)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["centralized", "least_restrictive"])
@pytest.mark.parametrize(("mode", "seed"), [("random", 0), ("worst", 0)])
def test_closed_loop_reaches_targets_by_sta_and_keeps_apart(plans, method, mode, seed):
    sc, out = plans
    # The scan always covers the whole horizon (one compiled scan for every case); vehicles wait until t_LDT.
    arrival, dmin = simulate(sc, out[method], mode, seed, n_steps=int(np.ceil((HORIZON + 0.2) / DT)))
    assert np.all(arrival <= sc.stas()), (method, mode, arrival)
    assert dmin > sc.collision_radius, (method, mode, dmin)


@pytest.mark.slow
def test_centralized_obstacle_is_inside_least_restrictive(plans):
    # Q1's induced obstacle: centralized (FRS under the enforced feedback) within least-restrictive (FRS of all
    # controls, both intersected with the BRS), at every common slice.
    _, out = plans
    # No fallback on this grid: every higher-priority vehicle's obstacle is its own method's.
    assert [r.obstacle_method for r in out["centralized"].reach] == ["centralized"] * 3 + [""]
    assert [r.obstacle_method for r in out["least_restrictive"].reach] == ["least_restrictive"] * 3 + [""]
    c, lr = out["centralized"].reach[0], out["least_restrictive"].reach[0]
    np.testing.assert_allclose(c.obstacle_times, lr.obstacle_times)
    inside_c, inside_lr = c.obstacle <= 0, lr.obstacle <= 0
    assert np.all(inside_lr[inside_c])
    assert inside_lr.sum() > 1.2 * inside_c.sum()  # ... and strictly smaller


def test_obstacle_table_is_a_distance_lower_bound():
    # A disk P = {|p - c| <= 0.2} (any heading): dist(p, P) - R_c, never above the exact value, within 1.5 cells.
    grid = hj.Grid.from_bounds((-1, -1, -np.pi), (1, 1, np.pi), (41, 41, 8), periodic=2)
    sets = hj.shapes.cylinder(grid, (0, 1), (0.13, -0.21), 0.2)[None]
    table = projected_obstacle_table(grid, np.broadcast_to(sets, (1, *grid.shape)), 0.1)[0]
    x, y = np.meshgrid(grid.coordinate_vector(0), grid.coordinate_vector(1), indexing="ij")
    exact = np.maximum(np.hypot(x - 0.13, y + 0.21) - 0.2, 0.0) - 0.1
    assert np.all(table <= exact + 1e-6)
    assert np.max(exact - table) <= 1.5 * grid.spacing[0]
    # The tabulated obstacle is present only in the flight window, and between slices the union is used.
    params = {"times": jnp.asarray([[0.0, 1.0]]), "tables": jnp.asarray(np.stack([table, table + 0.3]))[None],
              "start": jnp.asarray([0.0]), "end": jnp.asarray([1.0])}
    np.testing.assert_allclose(tabulated_obstacles(0.5, params), table, atol=1e-6)
    assert float(jnp.min(tabulated_obstacles(1.5, params))) > 1e3


@pytest.mark.slow
def test_slice_feedback_matches_the_planning_controller():
    # The FRS's grid feedback (SliceFeedback) is the controller the vehicles fly (planning_control) at nodes.
    dyn = make("four-vehicle").vehicle
    grid = hj.Grid.from_bounds((-1, -1, -np.pi), (1, 1, np.pi), (21, 21, 12), periodic=2)
    rng = np.random.default_rng(0)
    times = jnp.asarray([-1.0, -0.5, 0.0])
    stack = jnp.asarray(rng.normal(size=(3, *grid.shape)), jnp.float32)
    t = -0.3
    v, omega = SliceFeedback(grid, dyn)(t, grid.broadcast_states(), {"slice_times": times, "stack": stack})
    v = np.broadcast_to(v, grid.shape)
    omega = np.broadcast_to(omega, grid.shape)
    for idx in [(5, 7, 3), (10, 10, 0), (15, 3, 11)]:
        state = jnp.asarray([grid.coordinate_vector(d)[idx[d]] for d in range(3)], jnp.float32)
        u, _ = planning_control(grid, dyn, times, stack, t, state)
        np.testing.assert_allclose([v[idx], omega[idx]], np.asarray(u), atol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["centralized", "least_restrictive"])
def test_flown_positions_stay_in_the_projected_reachable_set(plans, method):
    # Q1 flown 32 times in random wind and once in the worst case (its planning controller under the centralized
    # method; random inside its BRS under the least-restrictive one) stays within one cell of P_1(t) (eqs. 19, 23)
    # until it arrives: the obstacle table there is at most -R_c - diag + dx (it is -R_c - diag on P_1's nodes).
    sc, out = plans
    mp = out[method]
    grid = sc.grid()
    times, stacks = _stacked(mp)
    r = mp.reach[0]
    n_steps = int(np.ceil((r.obstacle_times[-1] - r.obstacle_times[0]) / DT))
    x0 = jnp.asarray(sc.starts()[:1], jnp.float32)
    t_ldt = jnp.asarray(mp.plan.t_ldt()[:1], jnp.float32)
    tables = jnp.asarray(r.obstacle)
    plane = hj.Grid.from_bounds(grid.lo[:2], grid.hi[:2], grid.shape[:2])

    def worst_value(seed, worst):
        positions = _trajectory(jax.random.key(seed), x0, t_ldt, times[:1], stacks[:1], worst,
                                jnp.asarray(method == "least_restrictive"), grid=grid, dyn=sc.vehicle,
                                n_steps=n_steps)
        ts = r.obstacle_times[0] + DT * (1 + np.arange(n_steps))
        k = np.clip(np.searchsorted(r.obstacle_times, ts), 0, len(r.obstacle_times) - 1)
        vals = np.asarray(jax.vmap(lambda kk, p: hj.interpolation.interpolate(plane, tables[kk], p))(
            jnp.asarray(k), positions[:, :2]))
        # Until arrival: then the vehicle leaves the airspace (it would fly on through its target here).
        inside = np.hypot(*(np.asarray(positions[:, :2]) - sc.targets()[0]).T) <= sc.vehicles[0].target_radius
        flying = ~np.maximum.accumulate(inside)
        assert flying.sum() > n_steps // 2
        return float(np.max(vals[flying]))

    worst = max([worst_value(s, False) for s in range(32)] + [worst_value(0, True)])
    diag = np.hypot(*grid.spacing[:2]) / 4
    assert worst <= -sc.collision_radius - diag + grid.spacing[0], (method, worst)


@functools.partial(jax.jit, static_argnames=("grid", "dyn", "n_steps"))
def _trajectory(key, x0, t_ldt, slice_times, stacks, worst, least_restrictive, *, grid, dyn, n_steps):
    """One vehicle's positions from its t_LDT, one per step (as :func:`_simulate`, without arrival)."""
    def step(carry, s):
        x, key = carry
        key, sub = jax.random.split(key)
        t = t_ldt[0] + s * DT
        u, d = planning_control(grid, dyn, slice_times[0], stacks[0], t, x)
        k1, k2, k3, k4, k5 = jax.random.split(sub, 5)
        v = hj.interpolation.interpolate_slices(grid, slice_times[0], stacks[0], t, x)
        free = jnp.stack([jax.random.uniform(k4, (), minval=dyn.v_min, maxval=dyn.v_max),
                          jax.random.uniform(k5, (), minval=-dyn.omega_max, maxval=dyn.omega_max)])
        u = jnp.where(least_restrictive & (v < -LR_MARGIN), free, u)
        ang = jax.random.uniform(k1, (), minval=-jnp.pi, maxval=jnp.pi)
        w = jnp.where(worst, d[:2], dyn.wind * jnp.sqrt(jax.random.uniform(k2)) * jnp.array([jnp.cos(ang),
                                                                                             jnp.sin(ang)]))
        dth = jnp.where(worst, d[2], jax.random.uniform(k3, (), minval=-dyn.heading_disturbance,
                                                        maxval=dyn.heading_disturbance))
        xn = x + DT * jnp.array([u[0] * jnp.cos(x[2]) + w[0], u[0] * jnp.sin(x[2]) + w[1], u[1] + dth])
        return (xn, key), xn

    _, xs = jax.lax.scan(step, (x0[0], key), jnp.arange(n_steps))
    return xs
