"""Avoid region V^A (intruder paper eqs. 13-16): geometry and closed-loop checks in the world frame.

A scaled-down scenario (speeds ~1, R_c = 1) keeps the grids small; the closed-loop simulations integrate both
vehicles in the *world* frame (so eq. 44 is checked too) with the HJ controllers in the loop.
"""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.reach.avoid import (
    AvoidRegionConfig,
    compute_avoid_region,
    make_avoidance_controller,
    make_pursuit_controller,
    make_value_function,
)

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)
INTRUDER = DubinsWind(v_min=0.0, v_max=1.2, omega_max=1.0, wind=0.1)


def small_config(t_iat=2.0, **kw):
    base = dict(vehicle=VEHICLE, intruder=INTRUDER, collision_radius=1.0, t_iat=t_iat, half_width=4.5,
                grid_points=(45, 45, 44), n_slices=9, certify=False)
    base.update(kw)
    return AvoidRegionConfig(**base)


@pytest.fixture(scope="module")
def region():
    return compute_avoid_region(small_config(), progress=False)


@pytest.mark.slow
def test_contains_danger_zone_and_not_touching_boundary(region):
    grid = region.grid
    x = grid.states()
    danger = np.asarray(jnp.hypot(x[..., 0], x[..., 1]) <= region.config.collision_radius)
    assert np.all(region.values[0][danger] <= 0)
    assert region.boundary_margin > 0


@pytest.mark.slow
def test_behind_extent_matches_closed_form(region):
    # Straight behind at equal heading the intruder closes at v_I + winds - v_i (docs/numerics.md).
    value = make_value_function(region)
    exact = region.config.behind_extent()  # 1 + (1.2 + 0.2 - 1) * 2 = 1.8
    dx = region.grid.spacing[0]
    inside = float(value(0.0, jnp.array([-(exact - dx), 0.0, 0.0])))
    outside = float(value(0.0, jnp.array([-(exact + dx), 0.0, 0.0])))
    assert inside <= 0 < outside


@pytest.mark.slow
def test_grows_with_t_iat(region):
    longer = compute_avoid_region(small_config(t_iat=2.5), progress=False)
    # Same grid: every node inside the shorter-horizon set is inside the longer one.
    assert np.all(longer.values[0][region.values[0] <= 0] <= 0)
    assert (longer.values[0] <= 0).sum() > (region.values[0] <= 0).sum()
    assert longer.detection_range() > region.detection_range()


def test_slices_shrink_with_tau(region):
    sizes = [(v <= 0).sum() for v in region.values]
    assert all(a >= b for a, b in itertools.pairwise(sizes))
    assert region.taus[0] == 0.0 and region.taus[-1] == region.config.t_iat


def test_symmetry_py_theta(region):
    # (p_y, theta) -> (-p_y, -theta) maps the game onto itself.
    v = region.values[0]
    grid = region.grid
    n_theta = grid.shape[2]
    # theta nodes: -pi + k*2pi/n; -theta_k is node (n - k) mod n.
    mirrored = v[:, ::-1, :][:, :, (-np.arange(n_theta)) % n_theta]
    assert np.max(np.abs(mirrored - v)) < 1e-3 * float(np.max(np.abs(v)))


def test_detection_range_at_least_collision_radius(region):
    d_a = region.detection_range()
    assert d_a >= region.config.collision_radius
    assert d_a >= region.config.behind_extent() - region.grid.spacing[0]


def _rot(theta, v):
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _relative(xv, xi):
    p = _rot(-xv[2], xi[:2] - xv[:2])
    return jnp.array([p[0], p[1], wrap_angle(xi[2] - xv[2])])


@functools.partial(jax.jit, static_argnames=("u_avoid", "u_pursue", "n_steps", "vehicle_avoids"))
def _simulate(xv0, xi0, *, u_avoid, u_pursue, n_steps, vehicle_avoids, dt=0.01):
    """World-frame Euler-midpoint simulation of vehicle and intruder; returns min distance."""
    wv, wi = VEHICLE.wind, INTRUDER.wind

    def controls(t, xv, xi):
        rel = _relative(xv, xi)
        uv = u_avoid(t, rel) if vehicle_avoids else jnp.array([VEHICLE.v_max, 0.0])
        d = u_pursue(t, rel)  # (v_I, omega_I, w_x, w_y) with the combined wind in the vehicle frame
        w_world = _rot(xv[2], d[2:4])
        return uv, d[:2], -w_world * wv / (wv + wi), w_world * wi / (wv + wi)

    def f(x, u, w):
        return jnp.array([u[0] * jnp.cos(x[2]) + w[0], u[0] * jnp.sin(x[2]) + w[1], u[1]])

    def step(carry, k):
        xv, xi, dmin = carry
        t = k * dt
        uv, ui, wvv, wii = controls(t, xv, xi)
        xv_m = xv + 0.5 * dt * f(xv, uv, wvv)
        xi_m = xi + 0.5 * dt * f(xi, ui, wii)
        uv, ui, wvv, wii = controls(t + 0.5 * dt, xv_m, xi_m)
        xv = xv + dt * f(xv_m, uv, wvv)
        xi = xi + dt * f(xi_m, ui, wii)
        dmin = jnp.minimum(dmin, jnp.linalg.norm(xv[:2] - xi[:2]))
        return (xv, xi, dmin), None

    (_, _, dmin), _ = jax.lax.scan(step, (xv0, xi0, jnp.linalg.norm(xv0[:2] - xi0[:2])), jnp.arange(n_steps))
    return dmin


def _boundary_states(region, lo, hi, n, seed):
    """Random relative states with lo < V^A(0) < hi."""
    rng = np.random.default_rng(seed)
    value = jax.jit(jax.vmap(functools.partial(make_value_function(region), 0.0)))
    out = []
    while len(out) < n:
        cand = np.column_stack([rng.uniform(-3, 3, 4096), rng.uniform(-3, 3, 4096), rng.uniform(-np.pi, np.pi, 4096)])
        v = np.asarray(value(jnp.asarray(cand, jnp.float32)))
        out.extend(cand[(v > lo) & (v < hi)])
    return np.asarray(out[:n], np.float32)


def _world_pair(rel):
    # Vehicle at the origin heading theta0; intruder placed by the relative state.
    theta0 = 0.7
    xv = jnp.array([0.0, 0.0, theta0])
    p = _rot(theta0, jnp.asarray(rel[:2]))
    xi = jnp.array([p[0], p[1], theta0 + rel[2]])
    return xv, xi


@pytest.mark.slow
def test_closed_loop_outside_is_safe_inside_is_captured(region):
    u_avoid = make_avoidance_controller(region)
    u_pursue = make_pursuit_controller(region)
    n_steps = int(region.config.t_iat / 0.01)
    dx = region.grid.spacing[0]
    rc = region.config.collision_radius
    sim = jax.vmap(lambda a, b: _simulate(a, b, u_avoid=u_avoid, u_pursue=u_pursue, n_steps=n_steps,
                                          vehicle_avoids=True))
    # Just outside V^A(0, t_IAT): at least one cell from the zero level set.
    outside = _boundary_states(region, 1.0 * dx, 2.0 * dx, 64, 0)
    xv, xi = jax.vmap(_world_pair)(jnp.asarray(outside))
    dmin_out = np.asarray(sim(xv, xi))
    assert dmin_out.min() > rc, f"u^A failed to avoid from outside: min distance {dmin_out.min():.3f}"
    # Inside, at least one cell deep: the HJ-optimal intruder captures a vehicle applying u^A.
    inside = _boundary_states(region, -2.0 * dx, -1.0 * dx, 64, 1)
    xv, xi = jax.vmap(_world_pair)(jnp.asarray(inside))
    dmin_in = np.asarray(sim(xv, xi))
    # Capture means reaching the danger zone; half a cell of slack for the interpolated value function.
    assert dmin_in.max() <= rc + 0.5 * dx, f"not captured from inside: max min-distance {dmin_in.max():.3f}"


@pytest.mark.slow
def test_nominal_vehicle_is_caught_from_outside(region):
    # A vehicle that ignores the intruder (flies straight at full speed) is caught from states where u^A would
    # have saved it: the check above can fail.
    u_avoid = make_avoidance_controller(region)
    u_pursue = make_pursuit_controller(region)
    n_steps = int(region.config.t_iat / 0.01)
    dx = region.grid.spacing[0]
    outside = _boundary_states(region, 1.0 * dx, 2.0 * dx, 64, 2)
    xv, xi = jax.vmap(_world_pair)(jnp.asarray(outside))
    sim = jax.vmap(lambda a, b: _simulate(a, b, u_avoid=u_avoid, u_pursue=u_pursue, n_steps=n_steps,
                                          vehicle_avoids=False))
    dmin = np.asarray(sim(xv, xi))
    assert (dmin <= region.config.collision_radius).mean() > 0.25


def test_bad_parameters_rejected():
    with pytest.raises(ValueError, match="collision_radius"):
        small_config(collision_radius=-1.0)
    with pytest.raises(ValueError, match="half_width"):
        small_config(half_width=0.5)
    with pytest.raises(ValueError, match="wind"):
        DubinsWind(wind=-1.0)
    with pytest.raises(ValueError, match="preset"):
        small_config(accuracy="ultra")


@pytest.mark.slow
def test_controller_outputs_within_bounds(region):
    u_avoid = jax.jit(make_avoidance_controller(region))
    u_pursue = jax.jit(make_pursuit_controller(region))
    rng = np.random.default_rng(3)
    for _ in range(20):
        rel = jnp.asarray([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)], jnp.float32)
        tau = float(rng.uniform(0, 2))
        u = np.asarray(u_avoid(tau, rel))
        d = np.asarray(u_pursue(tau, rel))
        assert 0 <= u[0] <= VEHICLE.v_max and abs(u[1]) <= VEHICLE.omega_max
        assert 0 <= d[0] <= INTRUDER.v_max + 1e-6 and abs(d[1]) <= INTRUDER.omega_max + 1e-6
        assert np.hypot(d[2], d[3]) <= VEHICLE.wind + INTRUDER.wind + 1e-5


def _world_step(rel, controls, winds, h):
    """The pair moved for ``h`` seconds in the world frame (vehicle at the origin, heading 0; explicit Euler, fine
    for tiny ``h``), then expressed again in the vehicle's frame: independent of the relative dynamics' code."""
    (v_v, w_v, v_i, w_i), (dvx, dvy, dix, diy) = controls, winds
    xi, yi, thi = rel
    pv = np.array([v_v + dvx, dvy]) * h
    pi = np.array([xi + (v_i * np.cos(thi) + dix) * h, yi + (v_i * np.sin(thi) + diy) * h])
    th_v = w_v * h
    d = pi - pv
    c, s = np.cos(th_v), np.sin(th_v)
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], thi + w_i * h - th_v])


@pytest.mark.slow
def test_fall_rate_bounds_the_value_along_any_motion_and_exceeds_the_closing_speed():
    """The avoid region's fall-rate bound (the simulator's sampled-data avoid margin per second) against finite
    differences of the interpolated value along random extreme inputs at states near its zero level. The largest
    fall found must exceed the pair's closing speed ``v_V + v_I + d_V + d_I``: the margin the simulator used before
    (one inner step of the closing speed) could be stepped over between two checks. Turn rates of 3 rad/s at
    ``R_c = 1`` give the turn-to-speed ratio of the papers' vehicles (``omega R_c / v = 8`` there)."""
    turning = dict(v_min=0.0, omega_max=3.0, wind=0.1)
    region = compute_avoid_region(small_config(vehicle=DubinsWind(v_max=1.0, **turning),
                                               intruder=DubinsWind(v_max=1.2, **turning)), progress=False)
    value = jax.jit(make_value_function(region))
    cfg = region.config
    veh, intr = cfg.vehicle, cfg.intruder
    rng = np.random.default_rng(0)
    grid = region.grid
    lo, hi = np.asarray(grid.lo), np.asarray(grid.hi)
    n, h = 4000, 1e-4
    taus = rng.uniform(0.0, cfg.t_iat - 2 * h, n)
    states = rng.uniform(lo * 0.6, hi * 0.6, (n, 3))
    v0 = np.asarray(jax.vmap(value)(jnp.asarray(taus), jnp.asarray(states)))
    keep = np.abs(v0) <= 0.3
    taus, states, v0 = taus[keep], states[keep], v0[keep]
    assert len(v0) > 200
    worst = 0.0
    for _ in range(8):
        ctrl = np.stack([rng.choice([0.0, veh.v_max], len(v0)), rng.choice([-1, 1], len(v0)) * veh.omega_max,
                         rng.choice([0.0, intr.v_max], len(v0)), rng.choice([-1, 1], len(v0)) * intr.omega_max], 1)
        a, b = rng.uniform(0, 2 * np.pi, (2, len(v0)))
        winds = np.stack([veh.wind * np.cos(a), veh.wind * np.sin(a), intr.wind * np.cos(b), intr.wind * np.sin(b)], 1)
        nxt = np.stack([_world_step(s, c, w, h) for s, c, w in zip(states, ctrl, winds)])
        v1 = np.asarray(jax.vmap(value)(jnp.asarray(taus + h), jnp.asarray(nxt)))
        worst = max(worst, float(np.max((v0 - v1) / h)))
    closing = veh.v_max + intr.v_max + veh.wind + intr.wind
    assert worst <= region.fall_rate * (1 + 1e-3) + 1e-3
    assert worst > closing


def test_fall_rate_refuses_a_table_without_a_zero_level(region):
    from stp_env.reach.fall_rate import avoid_value_fall_rate

    far = np.full_like(region.values, 50.0)
    with pytest.raises(ValueError, match="vacuous"):
        avoid_value_fall_rate(far, region.taus, region.grid, region.config.vehicle, region.config.intruder, 1.0)
