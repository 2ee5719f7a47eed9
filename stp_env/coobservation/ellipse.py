"""Ellipsoidal reachability regions and their constraints (co-observation paper, Sections II-A2 and II-F to II-J).

A robot seen at ``q1`` at time ``t1`` and due at ``q2`` at ``t2`` can only have visited points ``x`` with
``|x - q1| + |x - q2| <= v (t2 - t1)`` (the reachability ellipsoid of Def. 3, ``v`` the fastest it can move). The
constraints keep a forbidden point, line, segment or convex polygon outside that ellipsoid; each is written as a
function ``D`` of the foci whose value is zero exactly when the constraint holds (the generalised ADMM's ``D(q)``
with ``Z = {0}``, eqs. 32-34, 44-47, 53-55, 56-58).

Conventions (see ``docs/coobservation.md``):

* Everything is computed in 3-D, as in the paper; a 2-D problem is embedded in the ``z = 0`` plane (the paper's
  ``P = [I 0]``) and the results are projected back. All functions accept 2-D or 3-D points (last axis).
* The canonical frame: ``x_E = H (x - o)`` with ``o = (q1 + q2) / 2`` and ``H`` the Householder rotation (eqs. 3-4)
  that maps the focal direction ``nu_F = (q2 - q1) / |q2 - q1|`` to ``e1``, so that ``q2_E = (c, 0, 0)`` and
  ``q1_E = (-c, 0, 0)`` (eq. 28 prints the opposite signs; the ellipsoid is symmetric, nothing depends on it).
  ``H`` is symmetric and orthogonal, so ``H^-1 = H^T = H``.
* The semi-major axis ``a`` is a parameter. For two observations it is ``v (t2 - t1) / 2`` plus the observation
  radius (:func:`semi_major`): the robot is only known to be within ``r`` of each observer.
* ``D`` is a displacement (a vector that vanishes when the constraint holds). Eq. (44) adds ``o`` to it, which
  would make ``D = 0`` unreachable; it is left out here.
* Differentials: every function is differentiable with JAX (``jax.jacfwd``). The root ``s`` of eq. (37) is found
  by bisection and polished by one Newton step through which the derivative flows (implicit function theorem, as
  in Appendix C); :func:`householder_differential` is eqs. (6)-(7) written out, for comparison with autodiff.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

E1 = np.array([1.0, 0.0, 0.0])  # numpy: a JAX array at import would start the backend too early
_BISECTION_STEPS = 32
B_FLOOR = 0.2
_TINY = 1e-12


# ------------------------------------------------------------------------------------------------ helpers
def _safe_norm(v, axis=-1, keepdims=False):
    """``|v|``, differentiable at 0 (gradient 0 there)."""
    sq = jnp.sum(v * v, axis=axis, keepdims=keepdims)
    ok = sq > _TINY
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def _safe_sqrt(v):
    """``sqrt(max(v, 0))`` with a finite gradient everywhere (0 where ``v <= 0``)."""
    ok = v > _TINY
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, v, 1.0)), 0.0)


def to3(x):
    """Embed 2-D points in ``z = 0`` (3-D points unchanged)."""
    x = jnp.asarray(x)
    if x.shape[-1] == 3:
        return x
    if x.shape[-1] != 2:
        raise ValueError(f"points must have 2 or 3 coordinates; got shape {x.shape}.")
    return jnp.concatenate([x, jnp.zeros((*x.shape[:-1], 1), x.dtype)], axis=-1)


def _like(x, ref):
    """``x`` (3-D) back to the dimension of ``ref``."""
    return x[..., : jnp.shape(ref)[-1]]


def cross_matrix(v):
    """``[v]_x`` of eq. (5): ``cross_matrix(v) @ w == cross(v, w)``."""
    return jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def semi_major(v_max, t1, t2, radius=0.0):
    """Semi-major axis of the reachability ellipse between observations at ``t1`` and ``t2``: ``v_max (t2 - t1) / 2``
    (Def. 3) grown by the observation radius ``radius`` (the robot is within ``radius`` of each observer, so
    ``|x - o1| + |x - o2| <= v_max (t2 - t1) + 2 radius``)."""
    return 0.5 * v_max * (t2 - t1) + radius


# ------------------------------------------------------------------------------------------------ frame
def householder(nu_f, nu_e=E1):
    """The Householder rotation ``H = 2 u u^T - I``, ``u = (nu_F + nu_E) / |nu_F + nu_E|`` (eqs. 3-4): a proper
    rotation (in 3-D) with ``H nu_F = nu_E`` (Proposition 1). When ``nu_F = -nu_E`` (no unique ``u``) it is the
    half turn about an axis perpendicular to ``nu_E``."""
    nu_f, nu_e = to3(nu_f), to3(nu_e)
    u_prime = nu_f + nu_e
    n = _safe_norm(u_prime)
    # an axis perpendicular to nu_e: e1 x nu_e, or e2 x nu_e when nu_e is along e1
    perp = jnp.cross(jnp.where(jnp.abs(nu_e[0]) < 0.9, E1, jnp.array([0.0, 1.0, 0.0])), nu_e)
    perp = perp / _safe_norm(perp)
    ok = n > 1e-6
    u = jnp.where(ok, u_prime / jnp.where(ok, n, 1.0), perp)
    return 2.0 * jnp.outer(u, u) - jnp.eye(3)


def householder_differential(q1, q2, q1_dot, q2_dot):
    """``dH/dt`` along ``q1(t), q2(t)`` from Proposition 2: ``H [-2 M nu_dot]_x`` with ``nu = q2 - q1`` (the
    unnormalised focal direction ``nu'_F``) and ``M = [u]_x (I - u u^T) (I - nu_F nu_F^T) / (|u'| |nu'_F|)``
    (eq. 7, whose ``|nu_F|`` must be the norm of the unnormalised vector: ``nu_F`` itself is a unit vector)."""
    q1, q2, q1_dot, q2_dot = to3(q1), to3(q2), to3(q1_dot), to3(q2_dot)
    nu_raw = q2 - q1
    nu = nu_raw / jnp.linalg.norm(nu_raw)
    u_prime = nu + E1
    u = u_prime / jnp.linalg.norm(u_prime)
    eye = jnp.eye(3)
    m = cross_matrix(u) @ (eye - jnp.outer(u, u)) @ (eye - jnp.outer(nu, nu)) / (
        jnp.linalg.norm(u_prime) * jnp.linalg.norm(nu_raw))
    h = householder(nu)
    return h @ cross_matrix(-2.0 * m @ (q2_dot - q1_dot))


def frame(q1, q2):
    """``(H, o, c)``: rotation, centre and focal half-distance of the canonical frame (eqs. 25-28)."""
    q1, q2 = to3(q1), to3(q2)
    d = q2 - q1
    dist = _safe_norm(d)
    ok = dist > 1e-9
    nu_f = jnp.where(ok, d / jnp.where(ok, dist, 1.0), E1)
    return householder(nu_f), 0.5 * (q1 + q2), 0.5 * dist


def semi_minor(a, c):
    """``b = sqrt(a^2 - c^2)`` (Def. 4), kept at or above ``B_FLOOR a``. Foci farther apart than that are an
    infeasible pair of observations (the velocity constraints rule them out once they hold); without the floor a
    planner could satisfy a reachability constraint by pushing the foci apart until the ellipse is a needle."""
    return jnp.sqrt(jnp.maximum(a * a - c * c, (B_FLOOR * a) ** 2))


def canonical(x, q1, q2):
    """Points ``x`` (..., 2|3) in the canonical frame of the ellipse with foci ``q1, q2`` (3-D)."""
    h, o, _ = frame(q1, q2)
    return (to3(x) - o) @ h.T


def quadratic(x, q1, q2, a):
    """``E^F(x) + 1 = (x - o)^T H^T Q H (x - o)`` (Lemma 1, eq. 31): < 1 inside, 1 on the boundary."""
    h, o, c = frame(q1, q2)
    b = semi_minor(a, c)
    y = (to3(x) - o) @ h.T
    return y[..., 0] ** 2 / a**2 + (y[..., 1] ** 2 + y[..., 2] ** 2) / b**2


def contains(x, q1, q2, a):
    """Strictly inside the ellipsoid: ``|x - q1| + |x - q2| < 2 a``."""
    x = to3(x)
    return _safe_norm(x - to3(q1)) + _safe_norm(x - to3(q2)) < 2 * a


def boundary_points(q1, q2, a, n: int = 720):
    """``n`` points on the (2-D) ellipse boundary, for plots and brute-force checks: ``(n, 2)``."""
    h, o, c = frame(q1, q2)
    b = semi_minor(a, c)
    phi = jnp.linspace(0.0, 2 * jnp.pi, n, endpoint=False)
    y = jnp.stack([a * jnp.cos(phi), b * jnp.sin(phi), jnp.zeros_like(phi)], axis=-1)
    return (y @ h + o)[:, :2]


def area(q1, q2, a):
    """Area of the 2-D ellipse ``pi a b``."""
    _, _, c = frame(q1, q2)
    return jnp.pi * a * semi_minor(a, c)


# ------------------------------------------------------------------------------------------------ point
def _closest_on_ellipse_2d(x0, y0, a, b):
    """Closest point of the ellipse ``x^2/a^2 + y^2/b^2 = 1`` (``a >= b > 0``) to ``(x0, y0)``, ``x0, y0 >= 0``
    (Eberly, "Distance from a point to an ellipse"): ``x = a^2 x0 / (s + a^2)``, ``y = b^2 y0 / (s + b^2)`` with
    ``s`` the root of eq. (37) on ``s > -b^2``; the cases on an axis in closed form."""
    pos_y = y0 > 1e-9 * b
    pos_x = x0 > 1e-9 * a
    general = pos_x & pos_y
    # the general case with safe inputs elsewhere (no NaN in the branches jnp.where discards, nor in their gradients)
    xg = jnp.where(general, x0, 0.5 * a)
    yg = jnp.where(general, y0, 0.5 * b)

    def f(s):
        return (a * xg / (s + a * a)) ** 2 + (b * yg / (s + b * b)) ** 2 - 1.0

    lo0 = -b * b + b * yg
    hi0 = -b * b + jnp.sqrt((a * xg) ** 2 + (b * yg) ** 2)

    def bisect(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        pos = f(mid) > 0
        return jnp.where(pos, mid, lo), jnp.where(pos, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _BISECTION_STEPS, bisect,
                               (jax.lax.stop_gradient(lo0), jax.lax.stop_gradient(hi0)))
    s0 = jax.lax.stop_gradient(0.5 * (lo + hi))
    # one Newton step: exact first derivatives of the root (implicit function theorem)
    df = jax.grad(f)(s0)
    s = s0 - f(s0) / jnp.where(jnp.abs(df) > _TINY, df, 1.0)
    general_x = a * a * xg / (s + a * a)
    general_y = b * b * yg / (s + b * b)
    # on the minor axis (x0 = 0): (0, b); on the major axis (y0 = 0): the off-axis point when the point is close
    # enough to the centre, else the vertex (a, 0)
    inner = x0 < (a * a - b * b) / a
    xa = a * a * x0 / jnp.maximum(a * a - b * b, _TINY)
    ya = b * _safe_sqrt(1.0 - (xa / a) ** 2)
    on_major_x = jnp.where(inner, xa, a)
    on_major_y = jnp.where(inner, ya, 0.0)
    x = jnp.where(pos_y, jnp.where(pos_x, general_x, 0.0), on_major_x)
    y = jnp.where(pos_y, jnp.where(pos_x, general_y, b), on_major_y)
    return x, y


def project_to_boundary_canonical(p, a, b):
    """Closest boundary point of the canonical ellipsoid ``diag(a, b, b)`` to ``p`` (3-D), using the symmetry
    about the major axis (a 2-D problem in ``(x, sqrt(y^2 + z^2))``)."""
    rho = _safe_norm(p[1:])
    x, r = _closest_on_ellipse_2d(jnp.abs(p[0]), rho, a, b)
    direction = jnp.where(rho > 1e-9 * b, p[1:] / jnp.where(rho > 1e-9 * b, rho, 1.0), jnp.array([1.0, 0.0]))
    return jnp.concatenate([(jnp.sign(p[0]) * x)[None], r * direction])


def project_point(p, q1, q2, a):
    """``pi_pE`` (eqs. 35-39): the closest point to ``p`` on the boundary of the ellipse with foci ``q1, q2`` and
    semi-major axis ``a`` (for a point inside, the closest point outside)."""
    h, o, c = frame(q1, q2)
    b = semi_minor(a, c)
    y = h @ (to3(p) - o)
    y_b = project_to_boundary_canonical(y, a, b)
    return _like(h @ y_b + o, p)


def point_constraint(p, q1, q2, a):
    """ADMM constraint 5 (eq. 32): ``pi_pE(p) - p`` if ``p`` is inside the ellipse, else 0."""
    inside = contains(p, q1, q2, a)
    d = project_point(p, q1, q2, a) - jnp.asarray(p)
    return jnp.where(inside, d, 0.0)


# ------------------------------------------------------------------------------------------------ plane
def _plane_terms(n, d, q1, q2, a):
    """Canonical-frame quantities of the plane ``n . x = d``: ``(H, n_E, d_E, d_Et, Q^-1 n_E)`` (eqs. 41-43)."""
    h, o, c = frame(q1, q2)
    b = semi_minor(a, c)
    n3 = to3(n)
    n_e = h @ n3
    d_e = d - n3 @ o
    qinv_n = jnp.array([a * a, b * b, b * b]) * n_e
    d_et = jnp.sqrt(n_e @ qinv_n)
    return h, n_e, d_e, d_et, qinv_n


def plane_constraint(n, d, q1, q2, a):
    """ADMM constraint 6 (eqs. 44-47) for the plane (a line in 2-D) ``n . x = d``, ``|n| = 1``: the displacement
    from the tangent interpolation point ``p_L`` (eq. 43) to the nearer tangent point ``p_t1`` or ``p_t2`` (eq. 42)
    when the plane cuts the ellipse (``|d_E| <= d_Et``), else 0; returned in the world frame."""
    h, _, d_e, d_et, qinv_n = _plane_terms(n, d, q1, q2, a)
    p_t1 = qinv_n / d_et
    p_l = d_e * qinv_n / d_et**2
    disp = jnp.where(d_e >= 0, p_t1 - p_l, -p_t1 - p_l)
    cuts = jnp.abs(d_e) < d_et
    return _like(jnp.where(cuts, h @ disp, 0.0), n)


def plane_gap(n, d, q1, q2, a):
    """``|d_E| - d_Et``: negative when the plane cuts the ellipse (a signed clearance in the plane's units)."""
    _, _, d_e, d_et, _ = _plane_terms(n, d, q1, q2, a)
    return jnp.abs(d_e) - d_et


# ------------------------------------------------------------------------------------------------ segment
def _line_through(p1, p2):
    """Unit normal ``n`` and offset ``d`` of the 2-D line through ``p1, p2`` (embedded in 3-D)."""
    p1, p2 = to3(p1), to3(p2)
    t = p2 - p1
    n = jnp.array([-t[1], t[0], 0.0])
    n = n / _safe_norm(n)
    return n, n @ p1


def segment_parameter(p1, p2, q1, q2, a):
    """Where the tangent interpolation point ``p_L`` of the segment's line lies along ``p1 -> p2`` (0 at ``p1``, 1
    at ``p2``). ``p_L`` is the point of the line with the smallest ellipse norm ``x^T Q x`` (in the canonical
    frame), so the segment's deepest point is ``p_L`` clipped to ``[0, 1]``."""
    n, d = _line_through(p1, p2)
    h, _, d_e, d_et, qinv_n = _plane_terms(n, d, q1, q2, a)
    _, o, _ = frame(q1, q2)
    p_l = d_e * qinv_n / d_et**2
    e1, e2 = h @ (to3(p1) - o), h @ (to3(p2) - o)
    return (p_l - e1) @ (e2 - e1) / jnp.maximum((e2 - e1) @ (e2 - e1), _TINY)


def segment_constraint(p1, p2, q1, q2, a):
    """ADMM constraint 7 (eq. 53) for the 2-D segment ``[p1, p2]``: the plane constraint of its line when ``p_L``
    falls inside the segment, else the point constraint of the endpoint on ``p_L``'s side. (Eq. 53 pairs the
    conditions with the opposite endpoints; the endpoint nearer to ``p_L`` is the segment's deepest point.)"""
    lam = segment_parameter(p1, p2, q1, q2, a)
    n, d = _line_through(p1, p2)
    d_plane = plane_constraint(n[:2], d, q1, q2, a)
    d1 = point_constraint(jnp.asarray(p1)[:2], q1, q2, a)
    d2 = point_constraint(jnp.asarray(p2)[:2], q1, q2, a)
    out = jnp.where(lam < 0, d1, jnp.where(lam > 1, d2, d_plane))
    return _like(to3(out), q1)


def segment_depth(p1, p2, q1, q2, a):
    """``min_{x in [p1, p2]} x^T Q x`` in the canonical frame: < 1 exactly when the segment enters the ellipse."""
    lam = jnp.clip(segment_parameter(p1, p2, q1, q2, a), 0.0, 1.0)
    x = to3(p1) + lam * (to3(p2) - to3(p1))
    return quadratic(x, q1, q2, a)


# ------------------------------------------------------------------------------------------------ polygon
def polygon_constraint(vertices, q1, q2, a):
    """ADMM constraint 8 (eq. 56): the segment constraints of every edge of the convex polygon ``vertices``
    ``(K, 2)``, stacked ``(K, m)``. It must be paired with the obstacle constraint on the foci (Section II-C), which
    rules out the ellipse lying wholly inside the polygon."""
    v = jnp.asarray(vertices)
    w = jnp.roll(v, -1, axis=0)
    return jax.vmap(lambda p1, p2: segment_constraint(p1, p2, q1, q2, a))(v, w)


def polygon_depth(vertices, q1, q2, a):
    """``min_{x in P} x^T Q x`` over the convex polygon (canonical frame): 0 if the ellipse's centre is inside,
    else the smallest edge depth. The ellipse and the polygon intersect exactly when it is < 1."""
    v = jnp.asarray(vertices)
    w = jnp.roll(v, -1, axis=0)
    edges = jax.vmap(lambda p1, p2: segment_depth(p1, p2, q1, q2, a))(v, w)
    centre = 0.5 * (to3(q1) + to3(q2))
    return jnp.where(inside_convex(centre[:2], v), 0.0, jnp.min(edges))


def inside_convex(p, vertices):
    """``p`` (..., 2) inside the convex polygon (either orientation), boundary included."""
    v = jnp.asarray(vertices)
    w = jnp.roll(v, -1, axis=0)
    e = w - v
    rel = jnp.asarray(p)[..., None, :] - v
    cross = e[:, 0] * rel[..., 1] - e[:, 1] * rel[..., 0]
    return jnp.all(cross >= 0, axis=-1) | jnp.all(cross <= 0, axis=-1)


def hits_polygon(vertices, q1, q2, a):
    """Whether the (open) ellipse and the convex polygon intersect."""
    return polygon_depth(vertices, q1, q2, a) < 1.0
