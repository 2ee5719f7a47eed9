"""Interpolation of values, gradients, optimal inputs and times-to-reach at arbitrary states."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _strategies import grids
from hypothesis import given
from hypothesis import strategies as st

from stp_env import hj
from stp_env.dynamics import DubinsWind, SingleIntegrator
from stp_env.hj import interpolation as interp

EPS32 = float(np.finfo(np.float32).eps)




def index_tolerance(grid: hj.Grid, extra_periods: int = 0) -> np.ndarray:
    """Float32 round-off of a fractional index (in cells) for states up to ``extra_periods`` periods away."""
    dx = np.asarray(grid.spacing)
    period = np.array([p or 0.0 for p in grid.period])
    mag = np.maximum(np.abs(grid.lo), np.abs(grid.hi)) + dx + extra_periods * period
    return 8 * EPS32 * mag / dx + 1e-6


def random_values(grid: hj.Grid, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, grid.shape).astype(np.float32)


# ------------------------------------------------------------------------------------------ properties
@pytest.mark.slow
@given(grids(max_n=9), st.integers(0, 2**31 - 1), st.data())
def test_exact_on_nodes(grid, seed, data):
    values = random_values(grid, seed)
    idx = tuple(data.draw(st.integers(0, n - 1)) for n in grid.shape)
    state = grid.index_to_state(jnp.asarray(idx))
    got = float(interp.interpolate(grid, jnp.asarray(values), state))
    # The only error is the float32 fractional index times the largest jump to a neighbour (<= 2).
    tol = 2.0 * float(np.sum(index_tolerance(grid)))
    assert abs(got - float(values[idx])) <= tol, (got, values[idx], tol)


@pytest.mark.slow
@given(grids(max_n=9), st.integers(0, 2**31 - 1), st.integers(-2, 2), st.data())
def test_periodic_shift_gives_same_value(grid, seed, k, data):
    values = jnp.asarray(random_values(grid, seed))
    lo, hi = np.asarray(grid.lo), np.asarray(grid.hi)
    frac = np.array([data.draw(st.floats(0.0, 1.0)) for _ in range(grid.ndim)])
    state = lo + frac * (hi - lo)
    period = np.array([p or 0.0 for p in grid.period])
    shifted = state + k * period
    a = float(interp.interpolate(grid, values, jnp.asarray(state, jnp.float32)))
    b = float(interp.interpolate(grid, values, jnp.asarray(shifted, jnp.float32)))
    tol = 2.0 * float(np.sum(index_tolerance(grid, extra_periods=abs(k) + 1)))
    assert abs(a - b) <= tol, (a, b, tol)


@pytest.mark.slow
@given(grids(max_n=9), st.data())
def test_reproduces_affine_functions_inside(grid, data):
    coef = np.array([data.draw(st.floats(-3.0, 3.0)) for _ in range(grid.ndim)])
    c0 = data.draw(st.floats(-5.0, 5.0))
    coords = [grid.coordinate_vector(i) for i in range(grid.ndim)]
    mesh = np.meshgrid(*coords, indexing="ij")
    values = c0 + sum(b * m for b, m in zip(coef, mesh))
    # Periodic dimensions: an affine function is not periodic, so stay out of the wrap-around cell.
    lo = np.asarray(grid.lo)
    top = np.array([c[-1] for c in coords])
    frac = np.array([data.draw(st.floats(0.0, 1.0)) for _ in range(grid.ndim)])
    state = lo + frac * (top - lo)
    got = float(interp.interpolate(grid, jnp.asarray(values, jnp.float32), jnp.asarray(state, jnp.float32)))
    exact = c0 + float(coef @ state)
    # float32 storage of the values plus float32 round-off of the state and its fractional index.
    tol = (4 * EPS32 * float(np.abs(values).max())
           + float(np.sum(index_tolerance(grid) * np.abs(coef) * np.asarray(grid.spacing))) + 1e-6)
    assert abs(got - exact) <= tol, (got, exact, tol)


@pytest.mark.slow
@given(grids(max_dim=2, max_n=9), st.integers(0, 2**31 - 1), st.data())
def test_value_is_between_corner_values(grid, seed, data):
    """Multilinear weights are a convex combination: no overshoot anywhere, including outside (clamped)."""
    values = random_values(grid, seed)
    state = np.array([data.draw(st.floats(a - 5.0, b + 5.0)) for a, b in zip(grid.lo, grid.hi)])
    got = float(interp.interpolate(grid, jnp.asarray(values), jnp.asarray(state, jnp.float32)))
    assert values.min() - 1e-6 <= got <= values.max() + 1e-6


# ------------------------------------------------------------------------------------------ examples
def test_outside_clamps_or_fills():
    g = hj.Grid.from_bounds((0.0, 0.0), (1.0, 1.0), (3, 3))
    values = jnp.arange(9.0).reshape(3, 3)
    assert float(interp.interpolate(g, values, jnp.array([5.0, 0.0]))) == pytest.approx(6.0)  # node (2, 0)
    assert float(interp.interpolate(g, values, jnp.array([-5.0, -1.0]))) == pytest.approx(0.0)
    assert float(interp.interpolate(g, values, jnp.array([5.0, 0.0]), fill_value=jnp.inf)) == math.inf
    assert math.isnan(float(interp.interpolate(g, values, jnp.array([0.5, -0.1]), fill_value=jnp.nan)))
    assert float(interp.interpolate(g, values, jnp.array([0.25, 0.75]), fill_value=jnp.inf)) == pytest.approx(
        0.5 * 3 + 1.5)


def test_vector_valued_fields_jit_and_vmap():
    g = hj.Grid.from_bounds((-1.0, 0.0), (1.0, 2 * math.pi), (11, 16), periodic=1)
    x, _ = np.meshgrid(g.coordinate_vector(0), g.coordinate_vector(1), indexing="ij")
    field = jnp.asarray(np.stack([2 * x + 1, -x], -1), jnp.float32)  # affine in x, constant in theta
    f = jax.jit(jax.vmap(functools.partial(interp.interpolate, g, field)))
    pts = jnp.array([[0.13, 0.0], [-0.77, 7.0], [0.9, -20.0]])
    got = np.asarray(f(pts))
    assert got.shape == (3, 2)
    p = np.asarray(pts)
    np.testing.assert_allclose(got, np.stack([2 * p[:, 0] + 1, -p[:, 0]], -1), atol=1e-5)


@pytest.mark.slow
def test_gradient_field_exact_for_quadratics():
    """Central differences are exact for quadratics at interior nodes; the linear extrapolation at faces makes
    them exact for affine functions everywhere."""
    g = hj.Grid.from_bounds((-1.0, -2.0), (1.0, 2.0), (21, 17))
    x, y = np.meshgrid(g.coordinate_vector(0), g.coordinate_vector(1), indexing="ij")
    quad = jnp.asarray(x**2 + 3 * x * y - 0.5 * y**2 + x, jnp.float32)
    gx, gy = interp.gradient_field(g, quad)
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(np.asarray(gx)[inner], (2 * x + 3 * y + 1)[inner], atol=2e-5 * 20)
    np.testing.assert_allclose(np.asarray(gy)[inner], (3 * x - y)[inner], atol=2e-5 * 20)
    affine = jnp.asarray(0.5 * x - 2 * y + 3, jnp.float32)
    grads = interp.gradient_field(g, affine)
    np.testing.assert_allclose(np.asarray(grads[0]), 0.5, atol=1e-4)
    np.testing.assert_allclose(np.asarray(grads[1]), -2.0, atol=1e-4)
    state = jnp.array([0.33, -1.21])
    v, p = interp.value_and_gradient(g, affine, grads, state)
    assert float(v) == pytest.approx(0.5 * 0.33 + 2 * 1.21 + 3, abs=1e-5)
    np.testing.assert_allclose(np.asarray(p), [0.5, -2.0], atol=1e-4)
    with pytest.raises(ValueError, match="shape"):
        interp.gradient_field(g, jnp.zeros((3, 3)))


@pytest.mark.slow
def test_gradient_field_periodic_dimension_wraps():
    g = hj.Grid.from_bounds((0.0,), (2 * math.pi,), (64,), periodic=0)
    th = g.coordinate_vector(0)
    (d,) = interp.gradient_field(g, jnp.asarray(np.sin(th), jnp.float32))
    # Central difference of sin: cos(th) * sin(dx) / dx, including the two wrap-around nodes.
    dx = g.spacing[0]
    np.testing.assert_allclose(np.asarray(d), np.cos(th) * math.sin(dx) / dx, atol=1e-5)


@pytest.mark.slow
def test_optimal_inputs_from_interpolated_gradient():
    g = hj.Grid.from_bounds((-2.0, -2.0), (2.0, 2.0), (41, 41))
    values = hj.shapes.ball(g, (0.0, 0.0), 0.5)
    grads = interp.gradient_field(g, values)
    dyn = SingleIntegrator(dim=2, speed=1.5)
    state = jnp.array([1.05, -0.65])
    u = np.asarray(jax.jit(interp.optimal_control, static_argnums=(0, 1))(g, dyn, grads, state))
    direction = np.asarray(state) / np.linalg.norm(state)
    # Reaching (min): head straight for the centre at full speed. The interpolated gradient of a cone is
    # within a few per cent of the unit normal one cell or more from the apex.
    np.testing.assert_allclose(u, -1.5 * direction, atol=0.03)
    assert np.asarray(interp.optimal_disturbance(g, dyn, grads, state)).shape == (0,)
    dub = DubinsWind(v_min=0.2, v_max=1.0, omega_max=1.0, wind=0.3)
    g3 = hj.Grid.from_bounds((-2.0, -2.0, -math.pi), (2.0, 2.0, math.pi), (21, 21, 12), periodic=2)
    grads3 = interp.gradient_field(g3, hj.shapes.cylinder(g3, (0, 1), (0.0, 0.0), 0.5))
    opt_d = jax.jit(interp.optimal_disturbance, static_argnums=(0, 1))
    d = np.asarray(opt_d(g3, dub, grads3, jnp.array([1.0, 0.0, 0.3])))
    # The wind (max) blows away from the target, at full strength.
    np.testing.assert_allclose(d, [0.3, 0.0], atol=0.01)


@pytest.mark.slow
def test_interpolate_in_time_both_directions_and_clamping():
    stack = jnp.stack([jnp.full((2,), 0.0), jnp.full((2,), 10.0), jnp.full((2,), 30.0)])
    for times, sign in ((jnp.array([0.0, 1.0, 3.0]), 1.0), (jnp.array([0.0, -1.0, -3.0]), -1.0)):
        def at(t, times=times):
            return float(interp.interpolate_in_time(times, stack, t)[0])

        assert at(sign * 0.0) == pytest.approx(0.0)
        assert at(sign * 0.5) == pytest.approx(5.0)
        assert at(sign * 1.0) == pytest.approx(10.0)
        assert at(sign * 2.0) == pytest.approx(20.0)
        assert at(sign * 3.0) == pytest.approx(30.0)
        assert at(sign * 7.0) == pytest.approx(30.0)  # clamped beyond the last time
        assert at(-sign * 1.0) == pytest.approx(0.0)  # clamped before the first time


def test_time_to_reach_at_and_latest_departure():
    g = hj.Grid.from_bounds((0.0,), (4.0,), (5,))
    ttr = jnp.array([0.0, 1.0, 2.0, jnp.inf, jnp.inf])
    assert float(interp.time_to_reach_at(g, ttr, jnp.array([1.5]))) == pytest.approx(1.5)
    assert float(interp.time_to_reach_at(g, ttr, jnp.array([2.0]))) == pytest.approx(2.0)
    # Any infinite corner: not reached for certain.
    assert float(interp.time_to_reach_at(g, ttr, jnp.array([2.5]))) == math.inf
    assert float(interp.time_to_reach_at(g, ttr, jnp.array([-1.0]))) == math.inf  # outside the grid
    # Exactly on a node (including the last one, whose lower neighbour is a corner of zero weight), the node's
    # own time is returned even if a neighbour is infinite.
    assert float(interp.time_to_reach_at(g, ttr[::-1], jnp.array([4.0]))) == pytest.approx(0.0)
    assert float(interp.time_to_reach_at(g, ttr[::-1], jnp.array([2.0]))) == pytest.approx(2.0)
    assert float(interp.latest_departure_time(g, ttr, jnp.array([0.5]), 10.0)) == pytest.approx(9.5)
    assert float(interp.latest_departure_time(g, ttr, jnp.array([3.0]), 10.0)) == -math.inf
