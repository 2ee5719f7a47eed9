"""Multi-robot trajectory optimisation by the generalised ADMM of the co-observation paper (Section II-A3).

The trajectories ``q`` (``n_p`` robots, ``T + 1`` positions each, ``q[:, 0]`` the starts) minimise a smooth cost
``Phi(q)`` subject to constraints written as ``D(q) in Z`` with a cheap projection onto ``Z`` (eq. 8)::

    q^{k+1} = argmin_q Phi(q) + rho/2 ||D(q) - z^k + u^k||^2        (9a: BFGS, warm-started)
    z^{k+1} = Pi_Z(D(q^{k+1}) + u^k)                                   (9b)
    u^{k+1} = u^k + D(q^{k+1}) - z^{k+1}                               (9c)

with primal residual ``r = D(q) - z`` (10) and dual residual ``s = rho (z^k - z^{k-1})`` (11). ``rho`` is adapted by
residual balancing (Boyd et al. Section 3.4.1; the scaled dual ``u`` is rescaled with it).

Constraints (each a small frozen dataclass with ``residual(q)`` and ``project(z)``):

* :class:`Velocity` (ADMM constraint 1, eqs. 12-14): ``|q_ij - q_i(j-1)| <= v_max``.
* :class:`Obstacles` (constraint 2, eqs. 15-18): waypoints outside convex polygons.
* :class:`Workspace`: waypoints inside a box (constraint 2 with inward normals).
* :class:`Waypoint` (constraint 3, eqs. 19-21): the path passes within ``radius`` of a point during a time window.
* :class:`CoObservation` (constraint 4, eqs. 22-24): two robots within ``d_max`` (and optionally at least
  ``d_min``, a separation the paper does not have) at a time.
* :class:`Reachability` (constraints 5-8, eqs. 32-58): every reachability ellipse of a schedule clear of the
  forbidden convex polygons.

``solve(...)`` returns an :class:`ADMMResult` whose ``violations`` are measured on the final ``q`` against the
sets themselves (not the ADMM residuals), so that "converged" cannot hold while a constraint is broken.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.optimize import minimize
from tqdm.auto import tqdm

from stp_env.coobservation import ellipse
from stp_env.coobservation.schedule import Segment

_SMOOTH = 1e-3  # [m] smoothing of |D| at 0 in the reachability constraint


def _ball(z, radius):
    n = jnp.linalg.norm(z, axis=-1, keepdims=True)
    return z * jnp.minimum(1.0, radius / jnp.maximum(n, 1e-12))


def polygon_halfplanes(vertices) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals ``n_k`` and offsets ``m_k`` of a convex polygon (either orientation): inside is
    ``n_k . p <= m_k`` for all ``k`` (eq. 15)."""
    v = np.asarray(vertices, float)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
        raise ValueError(f"a polygon needs (K >= 3, 2) vertices; got shape {v.shape}.")
    area2 = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
    if area2 < 0:
        v = v[::-1]
    e = np.roll(v, -1, axis=0) - v
    n = np.stack([e[:, 1], -e[:, 0]], axis=1)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    m = np.sum(n * v, axis=1)
    if np.any(n @ v.T - m[:, None] > 1e-9 * max(1.0, np.abs(v).max())):
        raise ValueError("the polygon is not convex (a vertex lies outside an edge's half-plane).")
    return n, m


def _padded_halfplanes(polygons):
    """Half-planes of several convex polygons, padded to the same count by repeating the first one."""
    hp = [polygon_halfplanes(p) for p in polygons]
    k = max(len(m) for _, m in hp)
    normals = np.stack([np.concatenate([n, np.repeat(n[:1], k - len(n), 0)]) for n, _ in hp])
    offsets = np.stack([np.concatenate([m, np.repeat(m[:1], k - len(m))]) for _, m in hp])
    return jnp.asarray(normals, jnp.float32), jnp.asarray(offsets, jnp.float32)


def polygon_distance(p, normals, offsets):
    """``max_k (n_k . p - m_k)`` (eq. 16): > 0 outside the polygon (a lower bound of the distance), the depth
    inside. ``p`` (..., 2); one polygon's ``normals`` (K, 2), ``offsets`` (K,)."""
    return jnp.max(jnp.einsum("...j,kj->...k", p, normals) - offsets, axis=-1)


# ------------------------------------------------------------------------------------------------ constraints
@dataclasses.dataclass(frozen=True)
class Velocity:
    """ADMM constraint 1: ``D_ij = q_ij - q_i(j-1)`` in the ball of radius ``v_max`` (per step)."""

    v_max: float
    name: str = "velocity"

    def residual(self, q):
        return q[:, 1:] - q[:, :-1]

    def project(self, z):
        return _ball(z, self.v_max)


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Every waypoint inside the box ``[lo, hi]``: ``D = (q - lo, hi - q) >= 0``."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    name: str = "workspace"

    def residual(self, q):
        return jnp.concatenate([q - jnp.asarray(self.lo), jnp.asarray(self.hi) - q], axis=-1)

    def project(self, z):
        return jnp.maximum(z, 0.0)


@dataclasses.dataclass(frozen=True, eq=False)
class Obstacles:
    """ADMM constraint 2 for each convex polygon: ``D = max_k (n_k . q_ij - m_k) >= margin`` for every waypoint.
    (Written as ``D - margin`` in ``{z >= 0}``; the margin keeps the straight path between waypoints clear too
    when it is at least ``v_max / 2`` times the sine of the sharpest corner, see ``docs/coobservation.md``.)"""

    polygons: tuple
    margin: float = 0.0
    name: str = "obstacles"

    def __post_init__(self):
        normals, offsets = _padded_halfplanes(self.polygons)
        object.__setattr__(self, "_normals", normals)
        object.__setattr__(self, "_offsets", offsets)

    def residual(self, q):
        d = jax.vmap(lambda n, m: polygon_distance(q, n, m))(self._normals, self._offsets)
        return d - self.margin

    def project(self, z):
        return jnp.maximum(z, 0.0)


@dataclasses.dataclass(frozen=True)
class Waypoint:
    """ADMM constraint 3: robot ``agent`` passes within ``radius`` of ``point`` between plan steps ``t_lo`` and
    ``t_hi`` (on a waypoint or on the straight segment between two): ``D = min_j dist(p, [q_ij, q_i(j+1)])``."""

    agent: int
    point: tuple[float, float]
    t_lo: int
    t_hi: int
    radius: float
    name: str = "waypoint"

    def residual(self, q):
        a = q[self.agent, self.t_lo:self.t_hi]
        b = q[self.agent, self.t_lo + 1:self.t_hi + 1]
        p = jnp.asarray(self.point)
        if self.t_hi == self.t_lo:
            return jnp.linalg.norm(q[self.agent, self.t_lo] - p)[None]
        ab = b - a
        lam = jnp.clip(jnp.sum((p - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
        d = jnp.linalg.norm(a + lam[:, None] * ab - p, axis=-1)
        return jnp.min(d)[None]

    def project(self, z):
        return jnp.minimum(z, self.radius)


@dataclasses.dataclass(frozen=True)
class CoObservation:
    """ADMM constraint 4: ``D = q_a(t) - q_b(t)`` in the ball of radius ``d_max`` (eqs. 22-24) for each
    ``(a, b, t)`` in ``pairs``; with ``d_min > 0`` in the annulus ``d_min <= |D| <= d_max`` (the robots observe
    each other without entering each other's danger zone)."""

    pairs: tuple[tuple[int, int, int], ...]
    d_max: float
    d_min: float = 0.0
    name: str = "coobservation"

    def residual(self, q):
        idx = np.asarray(self.pairs, int).reshape(-1, 3)
        return q[idx[:, 0], idx[:, 2]] - q[idx[:, 1], idx[:, 2]]

    def project(self, z):
        n = jnp.linalg.norm(z, axis=-1, keepdims=True)
        target = jnp.clip(n, self.d_min, self.d_max)
        return z * target / jnp.maximum(n, 1e-12)


@dataclasses.dataclass(frozen=True, eq=False)
class Reachability:
    """ADMM constraints 5-8: each segment's ellipse (foci at the two observers' positions, semi-major
    ``v_max (t2 - t1) / 2 + radius + margin``) clear of every forbidden convex polygon: ``D`` stacks the polygon
    constraint (eq. 56) of every (segment, polygon) pair, ``Z = {0}``. The obstacle constraint on the waypoints
    (which include the observers) supplies the containment case of Section II-J.

    ``D`` is the *length* of each displacement (smoothed at 0), not the vector: with ``Z = {0}`` the scaled dual
    ``u`` accumulates ``D``, and with vectors a penetration on the side opposite to earlier ones would lower
    ``|D + u|`` (the iterates diverged on the paper's experiment); with lengths ``u >= 0`` and the update is an
    augmented Lagrangian on the penetration depth."""

    segments: tuple[Segment, ...]
    polygons: tuple
    v_max: float
    radius: float
    margin: float = 0.0
    name: str = "reachability"

    def __post_init__(self):
        if not self.segments:
            raise ValueError("Reachability needs at least one segment.")
        k = max(len(p) for p in self.polygons)
        verts = np.stack([np.concatenate([np.asarray(p, float), np.repeat(np.asarray(p, float)[-1:], k - len(p), 0)])
                          for p in self.polygons])
        object.__setattr__(self, "_vertices", jnp.asarray(verts, jnp.float32))
        spec = np.zeros((len(self.segments), 2, 4), np.float32)  # per focus: is_point, agent, time, (x, y) below
        pts = np.zeros((len(self.segments), 2, 2), np.float32)
        for s, seg in enumerate(self.segments):
            for f, obs in enumerate((seg.observer1, seg.observer2)):
                if obs[0] == "point":
                    spec[s, f, 0] = 1.0
                    pts[s, f] = obs[1]
                else:
                    spec[s, f, 1], spec[s, f, 2] = obs[1], round(obs[2])
        object.__setattr__(self, "_spec", spec)
        object.__setattr__(self, "_points", jnp.asarray(pts))
        a = np.asarray([ellipse.semi_major(self.v_max, s.t1, s.t2, self.radius + self.margin)
                        for s in self.segments], np.float32)
        object.__setattr__(self, "_a", jnp.asarray(a))

    def foci(self, q):
        """``(S, 2, 2)``: the two foci of each segment's ellipse."""
        spec = self._spec
        agents = spec[:, :, 1].astype(int)
        times = spec[:, :, 2].astype(int)
        from_q = q[agents, times]
        return jnp.where(jnp.asarray(spec[:, :, 0:1] > 0), self._points, from_q)

    def semi_major_axes(self):
        return self._a

    def residual(self, q):
        f = self.foci(q)

        def one(f1, f2, a):
            return jax.vmap(lambda v: ellipse.polygon_constraint(v, f1, f2, a))(self._vertices)

        disp = jax.vmap(one)(f[:, 0], f[:, 1], self._a)          # (S, P, K, 2) displacements of eq. (56)
        return jnp.sqrt(jnp.sum(disp**2, axis=-1) + _SMOOTH**2) - _SMOOTH

    def project(self, z):
        return jnp.zeros_like(z)

    def depths(self, q):
        """``(S, P)``: the smallest ellipse norm over each polygon (< 1: the ellipse meets the polygon)."""
        f = self.foci(q)
        return jax.vmap(lambda f1, f2, a: jax.vmap(lambda v: ellipse.polygon_depth(v, f1, f2, a))(self._vertices))(
            f[:, 0], f[:, 1], self._a)


# ------------------------------------------------------------------------------------------------ solver
@dataclasses.dataclass(frozen=True)
class ADMMSettings:
    """Iteration settings.

    Attributes:
        rho: initial penalty; rho_min, rho_max: its range under residual balancing (factor ``tau`` when one
            residual exceeds ``mu`` times the other).
        max_iters: outer iterations; inner_iters: BFGS iterations of the q-update (9a).
        tol: stop when the largest primal and dual residual entries are below it [m]; the final violations are
            measured separately against ``feasibility_tol``.
        min_iters: do not stop before.
        proximal: weight of ``proximal/2 |q - q^k|^2`` added to the q-update (a proximal ADMM step, which keeps a
            nonconvex q-update from jumping between basins; 0 is the paper's update).
    """

    rho: float = 1.0
    rho_min: float = 1e-2
    rho_max: float = 1e4
    mu: float = 10.0
    tau: float = 2.0
    max_iters: int = 400
    inner_iters: int = 60
    tol: float = 1e-3
    feasibility_tol: float = 1e-3
    min_iters: int = 10
    proximal: float = 0.0

    def __post_init__(self):
        for name in ("rho", "rho_min", "rho_max", "tol", "feasibility_tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a number > 0; got {v!r}.")
        if not self.mu > 1 or not self.tau > 1:
            raise ValueError(f"mu and tau must be > 1; got {self.mu}, {self.tau}.")
        for name in ("max_iters", "inner_iters", "min_iters"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1; got {v!r}.")


@dataclasses.dataclass(frozen=True)
class ADMMResult:
    """``q`` ``(n_p, T + 1, 2)``; ``violations``: per constraint, the largest distance of ``D(q)`` from ``Z``;
    ``feasible``: all of them within ``feasibility_tol``; ``history``: per iteration ``(cost, r, s, rho)``."""

    q: np.ndarray
    cost: float
    violations: dict
    feasible: bool
    iterations: int
    history: np.ndarray


def violation(constraint, q) -> float:
    """The largest distance of ``D(q)`` from ``Z`` (``|D - Pi_Z(D)|`` per entry block)."""
    d = constraint.residual(q)
    gap = d - constraint.project(d)
    if isinstance(constraint, (Velocity, CoObservation)):
        return float(jnp.max(jnp.linalg.norm(gap, axis=-1)))
    return float(jnp.max(jnp.abs(gap)))


def solve(cost: Callable, constraints: Sequence, q0, fixed_mask=None, settings: ADMMSettings | None = None,
          progress: bool = True, callback: Callable | None = None) -> ADMMResult:
    """The generalised ADMM (eqs. 8-11).

    Args:
        cost: ``Phi(q)`` (jittable, scalar); q0: initial trajectories ``(n_p, T + 1, 2)`` (the fixed entries keep
            their values: starts and goals).
        constraints: constraint objects (see the module docstring).
        fixed_mask: ``(n_p, T + 1)`` bool, the waypoints that are not optimised (default: the starts ``q[:, 0]``).
        callback: called with ``(iteration, q)`` after every iteration (for figures of the iterations).
    """
    settings = ADMMSettings() if settings is None else settings
    q0 = jnp.asarray(q0, jnp.float32)
    if q0.ndim != 3 or q0.shape[2] != 2:
        raise ValueError(f"q0 must have shape (n_p, T + 1, 2); got {q0.shape}.")
    if fixed_mask is None:
        fixed_mask = np.zeros(q0.shape[:2], bool)
        fixed_mask[:, 0] = True
    fixed_mask = jnp.asarray(fixed_mask)
    if fixed_mask.shape != q0.shape[:2]:
        raise ValueError(f"fixed_mask must have shape {q0.shape[:2]}; got {fixed_mask.shape}.")
    constraints = tuple(constraints)

    def assemble(x):
        return jnp.where(fixed_mask[..., None], q0, x.reshape(q0.shape))

    def residuals(q):
        return [c.residual(q) for c in constraints]

    def lagrangian(x, z, u, rho, x_prev):
        q = assemble(x)
        total = cost(q) + 0.5 * settings.proximal * jnp.sum((x - x_prev) ** 2)
        for d, zi, ui in zip(residuals(q), z, u):
            total = total + 0.5 * rho * jnp.sum((d - zi + ui) ** 2)
        return total

    @jax.jit
    def q_update(x, z, u, rho):
        res = minimize(lagrangian, x, args=(z, u, rho, x), method="BFGS", options={"maxiter": settings.inner_iters})
        # BFGS may stop on a failed line search with a worse point: keep the better of the two
        better = lagrangian(res.x, z, u, rho, x) <= lagrangian(x, z, u, rho, x)
        return jnp.where(better & jnp.all(jnp.isfinite(res.x)), res.x, x)

    @jax.jit
    def zu_update(x, u):
        d = residuals(assemble(x))
        z = [c.project(di + ui) for c, di, ui in zip(constraints, d, u)]
        u_new = [ui + di - zi for ui, di, zi in zip(u, d, z)]
        r = jnp.max(jnp.stack([jnp.max(jnp.abs(di - zi)) for di, zi in zip(d, z)]))
        return z, u_new, r

    x = q0.reshape(-1)
    d0 = residuals(q0)
    z = [c.project(d) for c, d in zip(constraints, d0)]
    u = [jnp.zeros_like(d) for d in d0]
    rho = settings.rho
    history = []
    it = 0
    bar = tqdm(total=settings.max_iters, desc="ADMM", leave=False, disable=not progress)
    try:
        for it in range(1, settings.max_iters + 1):
            x = q_update(x, z, u, jnp.float32(rho))
            z_old = z
            z, u, r = zu_update(x, u)
            s = rho * max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(z, z_old))
            r = float(r)
            history.append((float(cost(assemble(x))), r, s, rho))
            bar.update(1)
            bar.set_postfix(r=f"{r:.2e}", s=f"{s:.2e}", rho=f"{rho:.3g}")
            if callback is not None:
                callback(it, np.asarray(assemble(x)))
            if it >= settings.min_iters and r < settings.tol and s < settings.tol:
                break
            # residual balancing (the scaled dual u = y / rho is rescaled with rho)
            if r > settings.mu * s and rho * settings.tau <= settings.rho_max:
                rho *= settings.tau
                u = [ui / settings.tau for ui in u]
            elif s > settings.mu * r and rho / settings.tau >= settings.rho_min:
                rho /= settings.tau
                u = [ui * settings.tau for ui in u]
    finally:
        bar.close()
    q = assemble(x)
    viol = {}
    for c in constraints:
        viol[c.name] = max(viol.get(c.name, 0.0), violation(c, q))
    return ADMMResult(q=np.asarray(q), cost=float(cost(q)), violations=viol,
                      feasible=all(v <= settings.feasibility_tol for v in viol.values()), iterations=it,
                      history=np.asarray(history))
