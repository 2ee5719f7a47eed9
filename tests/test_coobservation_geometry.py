"""Reachability ellipses of the co-observation paper (Sections II-A2, II-F to II-J) against brute force: the
Householder rotation and its differential (Props. 1-2), the point projection (eqs. 35-39), and the point, plane,
segment and polygon constraints (zero exactly when the ellipse misses the entity), with autodiff differentials
checked by finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env.coobservation import ellipse as E

RNG = np.random.default_rng(7)


def _random_ellipses(rng, n):
    q1, q2 = rng.uniform(-3, 3, (n, 2)), rng.uniform(-3, 3, (n, 2))
    a = np.linalg.norm(q2 - q1, axis=1) / 2 + rng.uniform(0.2, 2.5, n)
    return q1.astype(np.float32), q2.astype(np.float32), a.astype(np.float32)


def _inside_dense(points, q1, q2, a):
    return np.linalg.norm(points - q1, axis=-1) + np.linalg.norm(points - q2, axis=-1) < 2 * a


def _boundary(q1, q2, a, n):
    """Dense boundary points in numpy (independent of the module's frame code)."""
    c = np.linalg.norm(q2 - q1) / 2
    b = np.sqrt(a * a - c * c)
    u = (q2 - q1) / max(2 * c, 1e-12) if c > 0 else np.array([1.0, 0.0])
    v = np.array([-u[1], u[0]])
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)[:, None]
    return 0.5 * (q1 + q2) + a * np.cos(phi) * u + b * np.sin(phi) * v


@pytest.mark.slow
def test_householder_is_a_rotation_onto_e1():
    for _ in range(20):
        v = RNG.normal(size=3)
        v /= np.linalg.norm(v)
        h = np.asarray(E.householder(jnp.asarray(v, jnp.float32)))
        np.testing.assert_allclose(h @ h.T, np.eye(3), atol=1e-5)
        assert np.linalg.det(h) == pytest.approx(1.0, abs=1e-5)
        np.testing.assert_allclose(h @ v, [1, 0, 0], atol=1e-5)
    h = np.asarray(E.householder(jnp.array([-1.0, 0.0, 0.0])))  # antiparallel: a half turn
    np.testing.assert_allclose(h @ [-1, 0, 0], [1, 0, 0], atol=1e-6)
    assert np.linalg.det(h) == pytest.approx(1.0)


@pytest.mark.slow
def test_householder_differential_matches_autodiff():
    """Proposition 2 (eqs. 6-7) against forward-mode autodiff of the frame."""
    for _ in range(10):
        q1, q2, d1, d2 = (jnp.asarray(RNG.normal(size=3), jnp.float32) for _ in range(4))
        _, jv = jax.jvp(lambda a, b: E.frame(a, b)[0], (q1, q2), (d1, d2))
        np.testing.assert_allclose(E.householder_differential(q1, q2, d1, d2), jv, atol=2e-5)


@pytest.mark.slow
def test_point_projection_against_dense_boundary():
    n = 60
    q1, q2, a = _random_ellipses(RNG, n)
    p = RNG.uniform(-5, 5, (n, 2)).astype(np.float32)
    on_axis = np.arange(n) % 4 == 0  # on the major axis, inside: the off-axis closed form
    p[on_axis] = (0.5 * (q1 + q2) + RNG.uniform(-0.4, 0.4, (n, 1)) * (q2 - q1))[on_axis]
    proj = np.asarray(jax.jit(jax.vmap(E.project_point))(p, q1, q2, a))
    disp = np.asarray(jax.jit(jax.vmap(E.point_constraint))(p, q1, q2, a))
    quad = np.asarray(jax.vmap(E.quadratic)(proj, q1, q2, a))
    np.testing.assert_allclose(quad, 1.0, atol=2e-4)
    for k in range(n):
        bnd = _boundary(q1[k], q2[k], a[k], 100_000)
        best = np.min(np.linalg.norm(bnd - p[k], axis=1))
        assert np.linalg.norm(proj[k] - p[k]) == pytest.approx(best, abs=2e-4)
        inside = _inside_dense(p[k], q1[k], q2[k], a[k])
        assert (np.linalg.norm(disp[k]) > 0) == inside
        if inside:
            np.testing.assert_allclose(p[k] + disp[k], proj[k], atol=1e-5)


def test_plane_constraint_zero_exactly_when_the_line_misses():
    n = 80
    q1, q2, a = _random_ellipses(RNG, n)
    ang = RNG.uniform(0, 2 * np.pi, n)
    nrm = np.stack([np.cos(ang), np.sin(ang)], 1).astype(np.float32)
    d = (np.sum(nrm * 0.5 * (q1 + q2), 1) + RNG.uniform(-4, 4, n)).astype(np.float32)
    disp = np.asarray(jax.jit(jax.vmap(E.plane_constraint))(nrm, d, q1, q2, a))
    hits = 0
    for k in range(n):
        s = _boundary(q1[k], q2[k], a[k], 20_000) @ nrm[k] - d[k]
        truth = s.min() < 0 < s.max()
        hits += truth
        assert (np.linalg.norm(disp[k]) > 1e-6) == truth
        if truth:  # moving the line by the displacement makes it tangent
            s = s - nrm[k] @ disp[k]
            assert min(abs(s.min()), abs(s.max())) < 2e-3
    assert 10 < hits < 70  # both cases exercised


@pytest.mark.slow
def test_segment_and_polygon_constraints_against_sampling():
    n = 60
    q1, q2, a = _random_ellipses(RNG, n)
    ends = RNG.uniform(-5, 5, (n, 2, 2)).astype(np.float32)
    seg = np.asarray(jax.jit(jax.vmap(E.segment_constraint))(ends[:, 0], ends[:, 1], q1, q2, a))
    depth = np.asarray(jax.jit(jax.vmap(E.segment_depth))(ends[:, 0], ends[:, 1], q1, q2, a))
    s = np.linspace(0, 1, 20_001)[:, None]
    truth = np.array([_inside_dense(ends[k, 0] + s * (ends[k, 1] - ends[k, 0]), q1[k], q2[k], a[k]).any()
                      for k in range(n)])
    assert 5 < truth.sum() < 55
    np.testing.assert_array_equal(np.linalg.norm(seg, axis=1) > 1e-6, truth)
    np.testing.assert_array_equal(depth < 1.0, truth)

    square = jnp.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    q1, q2, a = _random_ellipses(RNG, n)
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201)), -1).reshape(-1, 2)
    truth = np.array([_inside_dense(grid, q1[k], q2[k], a[k]).any() for k in range(n)])
    assert 5 < truth.sum() < 55
    hits = np.asarray(jax.jit(jax.vmap(lambda f1, f2, aa: E.hits_polygon(square, f1, f2, aa)))(q1, q2, a))
    np.testing.assert_array_equal(hits, truth)
    disp = np.asarray(jax.jit(jax.vmap(lambda f1, f2, aa: E.polygon_constraint(square, f1, f2, aa)))(q1, q2, a))
    edges = np.linalg.norm(disp, axis=-1).max(axis=1) > 1e-6
    # the edge constraints see every intersection but an ellipse wholly inside the polygon (Section II-J pairs
    # them with the obstacle constraint on the foci for that case)
    centre = np.asarray(E.inside_convex(0.5 * (q1 + q2), square))
    np.testing.assert_array_equal(edges | (centre & truth), truth)


@pytest.mark.slow
def test_constraint_differentials_match_finite_differences():
    """Autodiff through the projection's root (implicit differentiation, Appendix C) and the plane constraint
    (Appendix D) against central differences, where both constraints are active."""
    p = jnp.array([0.3, 0.2])
    n, d = jnp.array([0.6, 0.8]), 0.9

    def point(q):
        return E.point_constraint(p, q[:2], q[2:], 2.0)

    def plane(q):
        return E.plane_constraint(n, d, q[:2], q[2:], 1.6)

    q = jnp.array([-1.0, 0.1, 1.2, -0.3])
    h = 1e-3
    for f in (point, plane):
        f = jax.jit(f)
        jac = np.asarray(jax.jit(jax.jacfwd(f))(q))
        num = np.stack([(f(q + h * jnp.eye(4)[i]) - f(q - h * jnp.eye(4)[i])) / (2 * h) for i in range(4)], 1)
        assert np.abs(jac).max() > 0.05  # the constraint is active here
        np.testing.assert_allclose(jac, num, atol=3e-3)
