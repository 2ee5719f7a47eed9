"""Upwind approximations of first spatial derivatives (left and right one-sided), and boundary padding.

Schemes (Osher & Fedkiw, *Level Set Methods*, Sections 3.3-3.4):

* ``upwind1``: first order, ``D^-phi_i`` and ``D^+phi_i``;
* ``eno2``: second-order ENO, choosing the smaller second difference;
* ``weno5``: fifth-order WENO of Jiang & Peng, with ``epsilon`` added to the smoothness indicators of the
  divided differences (the choice of ``hj_reachability``, so that both can be compared at the same settings).

Everything is written as shifted slices of one padded array per dimension and element-wise arithmetic. XLA fuses
each one-sided derivative into one loop over the grid (about 12 fused loops per right-hand side at 101^3: the
ghost-cell paddings, one loop per axis and side, and one for Hamiltonian, dissipation and update); see
BENCHMARKS.md for the measured flops and bytes per node.

Boundaries (per non-periodic dimension, applied as ghost cells):

* ``"extrapolate"``: linear extrapolation with the end slope;
* ``"extrapolate_away_from_zero"``: linear extrapolation with the end slope's magnitude, away from zero, so that
  a signed-distance-like function never creates a spurious zero crossing outside the grid (the default of
  ``hj_reachability`` and the safe choice for reachable sets that must not leak in from the boundary).

Periodic dimensions wrap.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

SCHEMES = {"upwind1": 1, "eno2": 2, "weno5": 3}
BOUNDARIES = ("extrapolate", "extrapolate_away_from_zero")


def ghost_width(scheme: str) -> int:
    try:
        return SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"Unknown upwind scheme {scheme!r}; allowed: {sorted(SCHEMES)}.") from None


def pad(values: jnp.ndarray, axis: int, width: int, periodic: bool, boundary: str) -> jnp.ndarray:
    """Adds ``width`` ghost cells on both ends of ``axis``."""
    n = values.shape[axis]
    if periodic:
        return jnp.concatenate(
            [lax.slice_in_dim(values, n - width, n, axis=axis), values,
             lax.slice_in_dim(values, 0, width, axis=axis)], axis=axis)
    first = lax.slice_in_dim(values, 0, 1, axis=axis)
    second = lax.slice_in_dim(values, 1, 2, axis=axis)
    last = lax.slice_in_dim(values, n - 1, n, axis=axis)
    before_last = lax.slice_in_dim(values, n - 2, n - 1, axis=axis)
    if boundary == "extrapolate":
        slope_lo = first - second  # change per cell going outward
        slope_hi = last - before_last
    elif boundary == "extrapolate_away_from_zero":
        slope_lo = jnp.sign(first) * jnp.abs(second - first)
        slope_hi = jnp.sign(last) * jnp.abs(last - before_last)
    else:
        raise ValueError(f"Unknown boundary condition {boundary!r}; allowed: {BOUNDARIES}.")
    lo_cells = [first + slope_lo * k for k in range(width, 0, -1)]
    hi_cells = [last + slope_hi * k for k in range(1, width + 1)]
    return jnp.concatenate([*lo_cells, values, *hi_cells], axis=axis)


def _weno5_one_sided(v1, v2, v3, v4, v5, eps):
    """WENO5 from five divided differences ordered upwind -> downwind (Osher & Fedkiw eqs. 3.25-3.35)."""
    phi1 = v1 / 3.0 - 7.0 / 6.0 * v2 + 11.0 / 6.0 * v3
    phi2 = -v2 / 6.0 + 5.0 / 6.0 * v3 + v4 / 3.0
    phi3 = v3 / 3.0 + 5.0 / 6.0 * v4 - v5 / 6.0
    s1 = 13.0 / 12.0 * (v1 - 2.0 * v2 + v3) ** 2 + 0.25 * (v1 - 4.0 * v2 + 3.0 * v3) ** 2
    s2 = 13.0 / 12.0 * (v2 - 2.0 * v3 + v4) ** 2 + 0.25 * (v2 - v4) ** 2
    s3 = 13.0 / 12.0 * (v3 - 2.0 * v4 + v5) ** 2 + 0.25 * (3.0 * v3 - 4.0 * v4 + v5) ** 2
    # Weights a_k = c_k / (s_k + eps)^2, normalised. Written with products of the other two indicators and two
    # divisions in place of four (the weights are unchanged; all factors lie in [0, 1], so float32 cannot
    # overflow).
    q1 = (s1 + eps) ** 2
    q2 = (s2 + eps) ** 2
    q3 = (s3 + eps) ** 2
    inv = 1.0 / (q1 + q2 + q3)
    t1, t2, t3 = q1 * inv, q2 * inv, q3 * inv
    a1 = 0.1 * t2 * t3
    a2 = 0.6 * t1 * t3
    a3 = 0.3 * t1 * t2
    return (a1 * phi1 + a2 * phi2 + a3 * phi3) / (a1 + a2 + a3)


def _eno2_choose(a, b):
    """The second difference of smaller magnitude (``a`` on ties)."""
    return jnp.where(jnp.abs(b) < jnp.abs(a), b, a)


def one_sided_derivatives(values: jnp.ndarray, axis: int, spacing: float, periodic: bool,
                          scheme: str = "weno5", boundary: str = "extrapolate_away_from_zero",
                          weno_eps: float = 1e-6) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Left (``phi^-_x``) and right (``phi^+_x``) derivative approximations along ``axis``; same shape as
    ``values``."""
    if not spacing > 0:
        raise ValueError(f"Grid spacing must be positive; got {spacing}.")
    k = ghost_width(scheme)
    n = values.shape[axis]
    padded = pad(values, axis, k, periodic, boundary)
    diffs = (lax.slice_in_dim(padded, 1, n + 2 * k, axis=axis)
             - lax.slice_in_dim(padded, 0, n + 2 * k - 1, axis=axis)) / spacing

    def dm(offset: int):
        """``D_{i - 1/2 + offset}`` for every node ``i``."""
        start = k - 1 + offset
        return lax.slice_in_dim(diffs, start, start + n, axis=axis)

    if scheme == "upwind1":
        return dm(0), dm(1)
    if scheme == "eno2":
        left = dm(0) + 0.5 * _eno2_choose(dm(0) - dm(-1), dm(1) - dm(0))
        right = dm(1) - 0.5 * _eno2_choose(dm(1) - dm(0), dm(2) - dm(1))
        return left, right
    d = [dm(o) for o in range(-2, 4)]  # offsets -2..3
    left = _weno5_one_sided(d[0], d[1], d[2], d[3], d[4], weno_eps)
    right = _weno5_one_sided(d[5], d[4], d[3], d[2], d[1], weno_eps)
    return left, right


def central_gradient(values: jnp.ndarray, spacing, periodic, boundary: str = "extrapolate") -> tuple:
    """Second-order central differences along every axis (one-sided by linear extrapolation at non-periodic
    boundaries). Used for controllers, which need one gradient per node, not an upwind pair."""
    out = []
    for axis, (dx, per) in enumerate(zip(spacing, periodic)):
        n = values.shape[axis]
        p = pad(values, axis, 1, per, boundary)
        out.append((lax.slice_in_dim(p, 2, n + 2, axis=axis) - lax.slice_in_dim(p, 0, n, axis=axis))
                   * (0.5 / dx))
    return tuple(out)
