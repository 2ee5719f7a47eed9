"""The solver against problems with closed-form solutions, and its order of convergence on smooth problems.

Tolerances are fractions of the grid spacing ``dx`` (for values of signed-distance-like functions, whose
gradient has unit norm, an error in value is the same length as an error in the front position). Each comment
gives the error measured when the tolerance was set (float32, CPU), so that a regression is visible.
"""

from __future__ import annotations

import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import DubinsWind, SingleIntegrator
from stp_env.hj import interpolation as interp

# Jitted once per grid (the grid is static): eager calls would dispatch dozens of small operations each.
interpolate = jax.jit(interp.interpolate, static_argnums=0)
time_to_reach_at = jax.jit(interp.time_to_reach_at, static_argnums=0)
latest_departure_time = jax.jit(interp.latest_departure_time, static_argnums=0)

RAY_ANGLES = np.linspace(0.0, 2 * np.pi, 12, endpoint=False) + 0.1  # off the grid axes


@functools.partial(jax.jit, static_argnums=0)
def _along(grid, values, points):
    return jax.vmap(lambda p: interp.interpolate(grid, values, p))(points)


def zero_crossings_on_rays(grid, values, center, r_lo, r_hi, angles=RAY_ANGLES, n=801):
    """Radius of the first zero crossing of the interpolated ``values`` along rays from ``center`` (the
    interpolant is piecewise bilinear; a fine sampling plus linear root finding locates its zero to far below a
    cell)."""
    rs = np.linspace(r_lo, r_hi, n)
    out = []
    for a in angles:
        pts = np.stack([center[0] + rs * np.cos(a), center[1] + rs * np.sin(a)], -1)
        v = np.asarray(_along(grid, values, jnp.asarray(pts, jnp.float32)), np.float64)
        k = np.flatnonzero((v[:-1] <= 0) & (v[1:] > 0))
        assert k.size, f"no crossing from inside to outside along angle {a}"
        k = k[0]
        out.append(rs[k] - v[k] * (rs[k + 1] - rs[k]) / (v[k + 1] - v[k]))
    return np.asarray(out)


def band_error(grid, values, exact, half_width, keep=None):
    """Max |V - exact| over nodes with |exact| <= half_width (near the front), restricted to ``keep``."""
    band = np.abs(exact) <= half_width
    if keep is not None:
        band &= keep
    assert band.sum() > 20
    return float(np.abs(np.asarray(values, np.float64) - exact)[band].max())


# --------------------------------------------------------------------------- (a) holonomic backward tube
GRID2 = hj.Grid.from_bounds((-2.0, -2.0), (2.0, 2.0), (81, 81))  # dx = 0.05
DX2 = GRID2.spacing[0]


def _radius(grid, center):
    x, y = (np.asarray(a, np.float64) for a in grid.broadcast_states())
    return np.broadcast_to(np.hypot(x - center[0], y - center[1]), grid.shape)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("accuracy", "tube", "tube_mode", "front_tol", "band_tol"),
    [
        # measured: front 0.005 dx, band 0.006-0.009 dx
        ("very_high", True, "min_with_target", 0.02, 0.03),
        ("very_high", False, "min_with_target", 0.02, 0.03),
        ("very_high", True, "freeze", 0.02, 0.03),
        # First order lags: measured front -0.51 dx after 16 cells of travel (Lax-Friedrichs smearing).
        ("low", True, "min_with_target", 1.0, None),
    ],
)
def test_holonomic_backward_tube_is_expanded_disk(accuracy, tube, tube_mode, front_tol, band_tol):
    r, s, T = 0.5, 1.0, 0.8
    center = (0.1, -0.05)
    target = hj.shapes.ball(GRID2, center, r)
    settings = hj.SolverSettings.with_accuracy(accuracy, tube_mode=tube_mode)
    res = hj.solve(settings, SingleIntegrator(dim=2, speed=s), GRID2, [0.0, -T], target, tube=tube,
                   progress=False)
    assert res.values.shape == (2, *GRID2.shape)
    np.testing.assert_array_equal(np.asarray(res.values[0]), np.asarray(target))
    V = res.values[-1]
    crossings = zero_crossings_on_rays(GRID2, V, center, 0.8, 1.8)
    assert np.all(np.abs(crossings - (r + s * T)) <= front_tol * DX2), (crossings - (r + s * T)) / DX2
    if band_tol is not None:
        # Hopf-Lax: V = min_{|y - x| <= sT} l(y) = max(|x - c| - sT, 0) - r: a flat bottom meeting the cone in a
        # kink at |x - c| = sT, which the scheme smears over a couple of cells; compare >= 4 cells from it.
        rad = _radius(GRID2, center)
        exact = np.maximum(rad - s * T, 0.0) - r
        assert band_error(GRID2, V, exact, 0.3, keep=rad >= s * T + 4 * DX2) <= band_tol * DX2
    if tube:
        assert np.all(np.asarray(V) <= np.asarray(target) + 1e-6)  # the tube contains the target
    assert GRID2.boundary_faces_min(V) > 0


@pytest.mark.slow
def test_holonomic_forward_reachable_set_is_expanded_disk():
    """(d) FRS from an initial disk: every control is to be covered, so the control maximises."""
    r, s, T = 0.4, 0.75, 1.0
    center = (-0.2, 0.15)
    init = hj.shapes.ball(GRID2, center, r)
    dyn = SingleIntegrator(dim=2, speed=s, control_mode="max")
    res = hj.solve(hj.SolverSettings.with_accuracy("very_high"), dyn, GRID2, [0.0, T], init, progress=False)
    V = res.values[-1]
    # measured: front 0.005 dx, band 0.008 dx (>= 4 cells from the kink at |x - c| = sT, see above; 0.085 dx
    # with the nodes next to the kink included)
    crossings = zero_crossings_on_rays(GRID2, V, center, 0.6, 1.6)
    assert np.all(np.abs(crossings - (r + s * T)) <= 0.02 * DX2), (crossings - (r + s * T)) / DX2
    rad = _radius(GRID2, center)
    exact = np.maximum(rad - s * T, 0.0) - r
    assert band_error(GRID2, V, exact, 0.3, keep=rad >= s * T + 4 * DX2) <= 0.03 * DX2
    # With the control minimising instead, the forward problem shrinks the disk (W = |x - c| - r + sT): the
    # roles matter and are not silently ignored.
    res_min = hj.solve(hj.SolverSettings.with_accuracy("very_high"), dyn.with_modes(control_mode="min"), GRID2,
                       [0.0, 0.2], init, progress=False)
    crossings = zero_crossings_on_rays(GRID2, res_min.values[-1], center, 0.0, 0.6)  # measured 0.025 dx
    assert np.all(np.abs(crossings - (r - s * 0.2)) <= 0.05 * DX2), (crossings - (r - s * 0.2)) / DX2


# --------------------------------------------------------------------------- (b) pure translation
@pytest.mark.slow
@pytest.mark.parametrize("direction", [-1.0, 1.0])
def test_drift_translates_level_set(direction):
    """Speed 0 and a constant drift c: backward, V(-T, x) = l(x + cT) (the set moves upstream by cT);
    forward, W(T, x) = l(x - cT) (downstream)."""
    grid = hj.Grid.from_bounds((-1.5, -1.5), (1.5, 1.5), (61, 61))  # dx = 0.05
    dx = grid.spacing[0]
    drift = (0.3, -0.2)
    r, T = 0.5, 1.0
    target = hj.shapes.ball(grid, (0.0, 0.0), r)
    dyn = SingleIntegrator(dim=2, speed=0.0, drift=drift)
    res = hj.solve(hj.SolverSettings.with_accuracy("very_high"), dyn, grid, [0.0, direction * T], target,
                   progress=False)
    V = res.values[-1]
    moved = (direction * drift[0] * T, direction * drift[1] * T)
    exact = _radius(grid, moved) - r
    # measured: 0.006 dx, front 0.006 dx (the cone is smooth away from its apex, which stays inside the set)
    assert band_error(grid, V, exact, 0.3) <= 0.02 * dx
    crossings = zero_crossings_on_rays(grid, V, moved, 0.2, 0.8)
    assert np.all(np.abs(crossings - r) <= 0.02 * dx)
    # The sign of the motion: the centre of the set is where the set moved, not where it came from. (The
    # apex of the cone is a kink, rounded off by about one cell: measured -0.45 for the exact -0.5.)
    assert float(interpolate(grid, V, jnp.asarray(moved))) < -r + 1.5 * dx
    opposite = jnp.asarray([-moved[0], -moved[1]])
    assert float(interpolate(grid, V, opposite)) > 0.2


# --------------------------------------------------------------------------- (c) Dubins time to reach
DUBINS_GRID = hj.Grid.from_bounds((-4.0, -3.0, -math.pi), (2.0, 3.0, math.pi), (41, 41, 41), periodic=2)


@pytest.fixture(scope="module")
def dubins_ttr():
    """Backward tube with time-to-reach for a Dubins vehicle against a worst-case wind."""
    v, w = 1.0, 0.4
    dyn = DubinsWind(v_min=0.5, v_max=v, omega_max=1.5, wind=w)
    target = hj.shapes.cylinder(DUBINS_GRID, (0, 1), (0.0, 0.0), 0.75)  # 10 cells across
    res = hj.solve(hj.SolverSettings.with_accuracy("very_high"), dyn, DUBINS_GRID, [0.0, -4.5], target,
                   tube=True, time_to_reach=True, progress=False)
    return res, v, w, 0.75


@pytest.mark.slow
@pytest.mark.parametrize("distance", [1.5, 2.0, 3.0])
def test_dubins_straight_path_against_wind_time_to_reach(dubins_ttr, distance):
    """Pointing at the target from ``distance``, the best the vehicle can guarantee is full speed straight
    ahead; the worst wind blows straight against it: TTR = (D - r) / (v - w). (Sideways wind cannot do better
    for the wind: the vehicle re-aims, omega_max * r > w, and the distance still falls at >= v - w.)"""
    res, v, w, r = dubins_ttr
    dx = DUBINS_GRID.spacing[0]
    state = jnp.array([-distance, 0.0, 0.0])
    exact = (distance - r) / (v - w)
    ttr = float(time_to_reach_at(DUBINS_GRID, res.time_to_reach, state))
    # In distance units: measured 0.05-0.075 dx (slightly optimistic: the numerical tube is a bit larger).
    assert abs(ttr - exact) * (v - w) <= 0.15 * dx, (ttr, exact)
    arrival = 10.0
    ldt = float(latest_departure_time(DUBINS_GRID, res.time_to_reach, state, arrival))
    assert ldt == pytest.approx(arrival - ttr, abs=1e-5)
    assert float(interpolate(DUBINS_GRID, res.values[-1], state)) < 0  # inside the final tube


def test_dubins_time_to_reach_sanity(dubins_ttr):
    res = dubins_ttr[0]
    ttr = res.time_to_reach
    at = functools.partial(time_to_reach_at, DUBINS_GRID, ttr)
    # Inside the target: zero; pointing away: must turn first, so strictly later; out of reach: inf.
    assert float(at(jnp.array([0.3, -0.2, 1.0]))) == 0.0
    ahead = float(at(jnp.array([-2.0, 0.0, 0.0])))
    behind = float(at(jnp.array([-2.0, 0.0, math.pi - 0.05])))
    assert behind > ahead + 1.0
    assert float(at(jnp.array([-3.9, 2.9, math.pi / 2 + 0.7]))) == math.inf
    assert float(latest_departure_time(DUBINS_GRID, ttr, jnp.array([-3.9, 2.9, 2.3]), 5.0)) == -math.inf
    assert np.all(np.asarray(ttr)[np.isfinite(np.asarray(ttr))] <= 4.5 + 1e-4)
    # Time to reach is consistent with the tube: finite exactly where the final value is <= 0.
    np.testing.assert_array_equal(np.isfinite(np.asarray(ttr)), np.asarray(res.values[-1]) <= 0)


# --------------------------------------------------------------------------- convergence
def _observed_orders(errors):
    return [math.log2(a / b) for a, b in itertools.pairwise(errors)]


@pytest.mark.parametrize(
    ("accuracy", "min_order"),
    [
        ("low", 0.8),  # measured 0.99, 1.00
        ("high", 1.8),  # WENO5 + RK2: second order in time; measured 1.97, 1.99
        ("very_high", 2.5),  # WENO5 + RK3: third order in time dominates; measured 3.4, 3.3
    ],
)
def test_convergence_linear_advection(accuracy, min_order):
    """dV/dt + c dV/dx = 0 on a periodic interval (smooth everywhere): W(T, x) = sin(2 pi (x - cT))."""
    c, T = 1.0, 0.5
    dyn = SingleIntegrator(dim=1, speed=0.0, drift=(c,))
    settings = hj.SolverSettings.with_accuracy(accuracy)
    errors = []
    for n in (24, 48, 96):
        grid = hj.Grid.from_bounds((0.0,), (1.0,), (n,), periodic=0)
        x = grid.coordinate_vector(0)
        res = hj.solve(settings, dyn, grid, [0.0, T], jnp.asarray(np.sin(2 * np.pi * x), jnp.float32),
                       progress=False)
        errors.append(float(np.abs(np.asarray(res.values[-1], np.float64) - np.sin(2 * np.pi * (x - c * T)))
                            .max()))
    orders = _observed_orders(errors)
    assert min(orders) >= min_order, (errors, orders)
    assert errors[-1] > 1e-5  # still far above float32 round-off: the orders are meaningful


@pytest.mark.slow
@pytest.mark.parametrize(("accuracy", "min_order"), [("low", 0.8), ("very_high", 2.5)])
def test_convergence_nonlinear_hamiltonian(accuracy, min_order):
    """dV/dt - s |dV/dx| = 0 backward (reach with |u| <= s): Hopf-Lax, V(-T, x) = min_{|y - x| <= sT} l(y).
    With l = cos(2y) on [-1, 1] the minimum is at |y| = |x| + sT, so V = cos(2(|x| + sT)), smooth away from
    x = 0. Errors are measured on 0.1 <= |x| <= 0.6 (away from the kink and the boundary).
    Measured orders: low 1.12, 1.07; very_high 5.2, 3.7."""
    s, T = 0.5, 0.5
    dyn = SingleIntegrator(dim=1, speed=s)
    settings = hj.SolverSettings.with_accuracy(accuracy)
    errors = []
    for n in (21, 41, 81):
        grid = hj.Grid.from_bounds((-1.0,), (1.0,), (n,))
        x = grid.coordinate_vector(0)
        res = hj.solve(settings, dyn, grid, [0.0, -T], jnp.asarray(np.cos(2 * x), jnp.float32), progress=False)
        exact = np.cos(2 * (np.abs(x) + s * T))
        m = (np.abs(x) >= 0.1) & (np.abs(x) <= 0.6)
        errors.append(float(np.abs(np.asarray(res.values[-1], np.float64) - exact)[m].max()))
    orders = _observed_orders(errors)
    assert min(orders) >= min_order, (errors, orders)
    assert errors[-1] > 1e-6
