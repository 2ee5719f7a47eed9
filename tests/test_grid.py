"""Grid conventions, conversions between indices and coordinates, and grid input checks."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest
from _strategies import grids
from hypothesis import given
from hypothesis import strategies as st

from stp_env import hj

EPS32 = float(np.finfo(np.float32).eps)


# ---------------------------------------------------------------------------------------- strategies


def index_tolerance(grid: hj.Grid) -> np.ndarray:
    """Float32 round-off of a fractional index, in cells: a few ulps of the largest coordinate over dx."""
    mag = np.maximum(np.abs(grid.lo), np.abs(grid.hi)) + np.asarray(grid.spacing)
    return 8 * EPS32 * mag / np.asarray(grid.spacing) + 1e-6


@st.composite
def grid_and_index(draw):
    grid = draw(grids())
    idx = tuple(draw(st.integers(0, n - 1)) for n in grid.shape)
    return grid, idx


# ---------------------------------------------------------------------------------------- conventions
def test_spacing_conventions_non_periodic_includes_hi_periodic_excludes_hi():
    g = hj.Grid.from_bounds((-1.0, 0.0, -math.pi), (1.0, 2.0, math.pi), (5, 4, 6), periodic=2)
    assert g.spacing == pytest.approx((0.5, 2.0 / 3.0, 2 * math.pi / 6))
    np.testing.assert_allclose(g.coordinate_vector(0), [-1.0, -0.5, 0.0, 0.5, 1.0])
    assert g.coordinate_vector(1)[-1] == pytest.approx(2.0)  # non-periodic: hi is a node
    assert g.coordinate_vector(2)[-1] == pytest.approx(math.pi - g.spacing[2])  # periodic: hi is not
    assert g.period == (None, None, pytest.approx(2 * math.pi))
    assert g.is_periodic == (False, False, True)
    assert g.ndim == 3 and g.size == 5 * 4 * 6


def test_same_nodes_as_hj_reachability():
    hjr = pytest.importorskip("hj_reachability")
    lo, hi, shape = np.array([-1.0, 0.0, -np.pi]), np.array([1.0, 2.0, np.pi]), (5, 4, 6)
    ref = hjr.Grid.from_lattice_parameters_and_boundary_conditions(hjr.sets.Box(lo, hi), shape,
                                                                    periodic_dims=2)
    g = hj.Grid.from_bounds(lo, hi, shape, periodic=2)
    for i in range(3):
        np.testing.assert_allclose(g.coordinate_vector(i), np.asarray(ref.coordinate_vectors[i]),
                                   atol=1e-6 * g.spacing[i])
        assert g.spacing[i] == pytest.approx(float(ref.spacings[i]), rel=1e-6)


def test_from_bounds_periodic_forms_and_hashability():
    a = hj.Grid.from_bounds([0, 0], [1, 1], [3, 4], periodic=1)
    b = hj.Grid.from_bounds((0.0, 0.0), (1.0, 1.0), (3, 4), periodic=(1,))
    c = hj.Grid.from_bounds((0.0, 0.0), (1.0, 1.0), (3, 4), periodic=np.int64(1))
    assert a == b == c and hash(a) == hash(b) == hash(c)
    assert hj.Grid.from_bounds((0.0,), (1.0,), (3,)).periodic == ()
    assert hj.Grid.from_bounds((0.0, 0.0), (1.0, 1.0), (3, 4), periodic=(1, 0, 1)).periodic == (0, 1)
    assert len({a, b, c}) == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.shape = (5, 5)  # type: ignore[misc]


@pytest.mark.slow
def test_states_and_broadcast_states_agree():
    g = hj.Grid.from_bounds((-1.0, 2.0, 0.0), (1.0, 3.0, 1.0), (3, 4, 5), periodic=2)
    full = np.asarray(g.states())
    assert full.shape == (3, 4, 5, 3)
    bs = g.broadcast_states()
    for i in range(3):
        assert bs[i].shape == tuple(n if j == i else 1 for j, n in enumerate(g.shape))
        np.testing.assert_array_equal(np.broadcast_to(np.asarray(bs[i]), g.shape), full[..., i])
    idx = (2, 1, 3)
    np.testing.assert_allclose(full[idx], np.asarray(g.index_to_state(jnp.asarray(idx))), rtol=1e-6)


def test_contains_boundary_faces_min_and_check_values():
    g = hj.Grid.from_bounds((0.0, 0.0), (1.0, 2 * math.pi), (5, 8), periodic=1)
    assert bool(g.contains(jnp.array([0.5, 100.0])))  # periodic dimension is unbounded
    assert bool(g.contains(jnp.array([1.0, 0.0])))  # hi is inside for non-periodic dims
    assert not bool(g.contains(jnp.array([1.01, 0.0])))
    assert not bool(g.contains(jnp.array([-0.01, 0.0])))
    v = np.ones(g.shape)
    v[2, 3] = -5.0  # interior: not on a face
    v[4, 6] = -2.0  # on the hi face of dim 0
    assert g.boundary_faces_min(v) == -2.0
    v[4, 6] = 1.0
    assert g.boundary_faces_min(v) == 1.0
    periodic_only = hj.Grid.from_bounds((0.0,), (1.0,), (4,), periodic=0)
    assert periodic_only.boundary_faces_min(np.zeros(4)) == math.inf
    g.check_values(np.full(g.shape, np.inf))  # +/-inf is allowed
    with pytest.raises(ValueError, match=r"shape \(5, 7\).*grid has shape \(5, 8\)"):
        g.check_values(np.zeros((5, 7)))
    bad = np.zeros(g.shape)
    bad[1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN at 1 grid point"):
        g.check_values(bad, "target")


# ---------------------------------------------------------------------------------------- bad grids
@pytest.mark.parametrize(
    ("lo", "hi", "shape", "periodic", "pattern"),
    [
        ((0.0,), (0.0,), (5,), None, "non-positive extent.*hi must exceed lo"),
        ((1.0, 0.0), (0.0, 1.0), (5, 5), None, "dimension 0 has non-positive extent"),
        ((0.0,), (float("nan"),), (5,), None, "must be finite"),
        ((0.0,), (float("inf"),), (5,), None, "must be finite"),
        ((0.0,), (1.0,), (1,), None, "at least 2 are needed"),
        ((0.0, 0.0), (1.0,), (5, 5), None, "same non-zero length"),
        ((), (), (), None, "same non-zero length"),
        ((0.0,), (1.0,), (5,), 1, "Periodic dimension 1 is out of range"),
        ((0.0,), (1.0,), (5,), -1, "Periodic dimension -1 is out of range"),
    ],
)
def test_bad_grids_raise_clear_errors(lo, hi, shape, periodic, pattern):
    with pytest.raises(ValueError, match=pattern):
        hj.Grid.from_bounds(lo, hi, shape, periodic=periodic)


# ---------------------------------------------------------------------------------------- properties
@given(grid_and_index())
def test_index_to_state_matches_coordinate_vectors(gi):
    grid, idx = gi
    state = np.asarray(grid.index_to_state(jnp.asarray(idx)))
    expected = np.array([grid.coordinate_vector(d)[i] for d, i in enumerate(idx)])
    np.testing.assert_allclose(state, expected, rtol=0, atol=1e-5 * max(1.0, np.abs(expected).max()))


@pytest.mark.slow
@given(grid_and_index())
def test_index_coordinate_round_trip(gi):
    grid, idx = gi
    state = grid.index_to_state(jnp.asarray(idx))
    frac = np.asarray(grid.fractional_index(state), dtype=np.float64)
    idx_arr = np.asarray(idx, dtype=np.float64)
    # A periodic index 0 may come back as n - tiny: compare on the circle.
    n = np.asarray(grid.shape, dtype=np.float64)
    diff = frac - idx_arr
    per = np.asarray(grid.is_periodic)
    diff = np.where(per, (diff + n / 2) % n - n / 2, diff)
    assert np.all(np.abs(diff) <= index_tolerance(grid)), (frac, idx)
    np.testing.assert_array_equal(np.asarray(grid.nearest_index(state)), idx)


@given(grid_and_index(), st.data())
def test_nearest_index_inverts_index_to_state_within_half_a_cell(gi, data):
    grid, idx = gi
    offsets = np.array([data.draw(st.floats(-0.45, 0.45)) for _ in range(grid.ndim)])
    state = np.asarray(grid.index_to_state(jnp.asarray(idx)), np.float64) + offsets * np.asarray(grid.spacing)
    got = np.asarray(grid.nearest_index(jnp.asarray(state, jnp.float32)))
    np.testing.assert_array_equal(got, idx)


@given(grids(), st.data())
def test_nearest_index_clips_non_periodic_and_wraps_periodic(grid, data):
    k = data.draw(st.integers(-3, 3))
    idx = tuple(data.draw(st.integers(0, n - 1)) for n in grid.shape)
    shifted = np.asarray(idx) + k * np.asarray(grid.shape)
    state = np.asarray(grid.lo) + np.asarray(grid.spacing) * shifted
    got = np.asarray(grid.nearest_index(jnp.asarray(state, jnp.float32)))
    n = np.asarray(grid.shape)
    expected = np.where(grid.is_periodic, np.mod(shifted, n), np.clip(shifted, 0, n - 1))
    np.testing.assert_array_equal(got, expected)


@given(grids(), st.data())
def test_wrap_maps_into_domain_and_is_periodic(grid, data):
    k = data.draw(st.integers(-3, 3))
    frac = np.array([data.draw(st.floats(0.0, 0.999)) for _ in range(grid.ndim)])
    lo, hi = np.asarray(grid.lo), np.asarray(grid.hi)
    base = lo + frac * (hi - lo)
    per = np.asarray(grid.is_periodic)
    period = np.where(per, hi - lo, 0.0)
    wrapped = np.asarray(grid.wrap(jnp.asarray(base + k * period, jnp.float32)), np.float64)
    # Non-periodic coordinates are untouched; periodic ones land in [lo, hi] (hi only through round-off) and
    # are the base point on the circle up to float32 round-off of (|lo| + 4 periods). (A base point at lo, one
    # period up, may come back as hi - ulp: the same point on the circle.)
    tol = 8 * EPS32 * (np.abs(lo) + np.abs(hi) + 4 * period) + 1e-6
    diff = wrapped - base
    circ = np.where(per, diff - np.round(diff / np.where(per, period, 1.0)) * period, diff)
    assert np.all(np.abs(circ) <= np.where(per, tol, 1e-5 * np.maximum(1, np.abs(base)))), (wrapped, base)
    assert np.all(wrapped[per] >= lo[per] - tol[per]) and np.all(wrapped[per] <= hi[per] + tol[per])
