"""Implicit surface functions on grids (negative inside, zero on the boundary, signed distance where exact).

All shapes return full arrays of ``grid.shape`` and accept an optional ``dtype``.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp

from stp_env.hj.grid import Grid


def _full(grid: Grid, a):
    return jnp.broadcast_to(a, grid.shape)


def cylinder(grid: Grid, dims: Sequence[int], center: Sequence[float], radius: float, dtype=jnp.float32):
    """Signed distance to the ball of ``radius`` around ``center`` in the coordinates ``dims`` (all other
    dimensions ignored): for example a disk in position, for any heading."""
    if radius <= 0:
        raise ValueError(f"radius must be positive; got {radius}.")
    if len(dims) != len(center):
        raise ValueError(f"dims {tuple(dims)} and center {tuple(center)} must have the same length.")
    x = grid.broadcast_states(dtype)
    sq = sum((x[d] - c) ** 2 for d, c in zip(dims, center))
    return _full(grid, jnp.sqrt(sq) - radius)


def ball(grid: Grid, center: Sequence[float], radius: float, dtype=jnp.float32):
    """Signed distance to a ball in all dimensions."""
    return cylinder(grid, range(grid.ndim), center, radius, dtype)


def rectangle(grid: Grid, lo: Sequence[float], hi: Sequence[float], dims: Sequence[int] | None = None,
              dtype=jnp.float32):
    """Signed distance to the axis-aligned box ``[lo, hi]`` in ``dims`` (default: all dimensions)."""
    dims = tuple(range(grid.ndim)) if dims is None else tuple(dims)
    if not (len(dims) == len(lo) == len(hi)):
        raise ValueError("dims, lo and hi must have the same length.")
    if any(a >= b for a, b in zip(lo, hi)):
        raise ValueError(f"Each lo must be below hi; got lo={tuple(lo)}, hi={tuple(hi)}.")
    x = grid.broadcast_states(dtype)
    # Per-axis signed offsets; outside distance is the norm of positive parts, inside the max (negative).
    q = [jnp.maximum(a - x[d], x[d] - b) for d, a, b in zip(dims, lo, hi)]
    outside = jnp.sqrt(sum(jnp.maximum(qi, 0.0) ** 2 for qi in q))
    inside = q[0]
    for qi in q[1:]:
        inside = jnp.maximum(inside, qi)
    return _full(grid, outside + jnp.minimum(inside, 0.0))


def union(*values):
    """Union of sets: point-wise minimum."""
    out = values[0]
    for v in values[1:]:
        out = jnp.minimum(out, v)
    return out


def intersection(*values):
    """Intersection of sets: point-wise maximum."""
    out = values[0]
    for v in values[1:]:
        out = jnp.maximum(out, v)
    return out


def complement(values):
    """Complement of a set: negation (the boundary is shared)."""
    return -values
