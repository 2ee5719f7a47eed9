"""Planar geometry of static obstacles: exact signed distance to simple polygons, and building tables on grids.

Buildings are simple polygons in the position plane ``(p_x, p_y)`` [m]. The static obstacle of a scenario is the
union of its buildings, represented as a signed-distance table over the planning grid (negative inside a building,
zero on its walls, the Euclidean distance to the nearest wall outside), broadcast over heading: the form the HJ
solver takes as an obstacle (``{g <= 0}``) and the simulator interpolates under jit.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Protocol

import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:
    from stp_env.hj import Grid


class Polygon(Protocol):
    """Anything with polygon ``vertices`` (:class:`stp_env.scenarios.config.Building` is one): this module is
    below the scenario configuration, which uses it, and does not import it."""

    vertices: Sequence[Sequence[float]]

NO_OBSTACLE_DISTANCE = 1.0e6
"""Signed distance [m] reported where there are no buildings at all: finite (so that differences and gradients of
obstacle tables stay finite) and larger than any domain of the registered scenarios (1000 km)."""


def _vertex_list(vertices) -> list[tuple[float, float]]:
    verts = [(float(v[0]), float(v[1])) for v in vertices]
    if len(verts) < 3:
        raise ValueError(f"a polygon needs at least 3 vertices; got {len(verts)}.")
    return verts


def polygon_signed_distance(vertices: Sequence[Sequence[float]], points, xp=np):
    """Exact signed distance from ``points`` to the simple polygon with ``vertices`` (negative inside).

    ``|sd|`` is the Euclidean distance to the nearest edge segment; the sign comes from the even-odd (crossing)
    rule, which for a simple polygon is its interior. Either vertex order (clockwise or counter-clockwise) is fine.

    Args:
        vertices: ``(n, 2)`` polygon vertices [m], without repeating the first vertex at the end.
        points: array of shape ``(..., 2)`` [m].
        xp: array namespace, ``numpy`` (default, computed in float64) or ``jax.numpy`` (jittable: the vertices are
            Python constants and the loop over edges unrolls).

    Returns:
        array of shape ``points.shape[:-1]``.
    """
    verts = _vertex_list(vertices)
    points = xp.asarray(points, dtype=np.float64) if xp is np else xp.asarray(points)
    if points.shape[-1] != 2:
        raise ValueError(f"points must have shape (..., 2); got {tuple(points.shape)}.")
    px, py = points[..., 0], points[..., 1]
    dist_sq = None
    inside = xp.zeros(px.shape, dtype=bool)
    n = len(verts)
    for k in range(n):
        ax, ay = verts[k]
        bx, by = verts[(k + 1) % n]
        ex, ey = bx - ax, by - ay
        wx, wy = px - ax, py - ay
        edge_sq = ex * ex + ey * ey
        if edge_sq > 0.0:
            t = xp.clip((wx * ex + wy * ey) / edge_sq, 0.0, 1.0)
            dx, dy = wx - t * ex, wy - t * ey
        else:  # degenerate edge: the distance to its point
            dx, dy = wx, wy
        d = dx * dx + dy * dy
        dist_sq = d if dist_sq is None else xp.minimum(dist_sq, d)
        if ay != by:  # horizontal edges never cross a horizontal ray
            straddles = (ay > py) != (by > py)
            x_cross = ax + (py - ay) * (ex / ey)
            inside = xp.logical_xor(inside, straddles & (px < x_cross))
    distance = xp.sqrt(dist_sq)
    return xp.where(inside, -distance, distance)


def polygon_area(vertices: Sequence[Sequence[float]]) -> float:
    """Signed area (shoelace formula) [m^2]: positive for counter-clockwise vertices."""
    verts = _vertex_list(vertices)
    s = 0.0
    for k, (ax, ay) in enumerate(verts):
        bx, by = verts[(k + 1) % len(verts)]
        s += ax * by - bx * ay
    return 0.5 * s


def _orientation(a, b, c) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _on_segment(a, b, c, tol: float) -> bool:
    """``c`` (collinear with ``a``-``b``) lies within the bounding box of segment ``a``-``b``."""
    return (min(a[0], b[0]) - tol <= c[0] <= max(a[0], b[0]) + tol
            and min(a[1], b[1]) - tol <= c[1] <= max(a[1], b[1]) + tol)


def segments_intersect(a, b, c, d, tol: float = 0.0) -> bool:
    """Closed segments ``a``-``b`` and ``c``-``d`` share at least one point (touching counts)."""
    o1, o2 = _orientation(a, b, c), _orientation(a, b, d)
    o3, o4 = _orientation(c, d, a), _orientation(c, d, b)
    if ((o1 > 0 and o2 < 0) or (o1 < 0 and o2 > 0)) and ((o3 > 0 and o4 < 0) or (o3 < 0 and o4 > 0)):
        return True
    return ((o1 == 0 and _on_segment(a, b, c, tol)) or (o2 == 0 and _on_segment(a, b, d, tol))
            or (o3 == 0 and _on_segment(c, d, a, tol)) or (o4 == 0 and _on_segment(c, d, b, tol)))


def self_intersections(vertices: Sequence[Sequence[float]]) -> list[tuple[int, int]]:
    """Pairs ``(k, l)`` of non-adjacent edges (edge ``k`` runs from vertex ``k`` to ``k + 1``) that touch or cross.
    Empty for a simple polygon. ``O(n^2)``: meant for buildings with a handful of vertices."""
    verts = _vertex_list(vertices)
    n = len(verts)
    bad = []
    for k in range(n):
        for l in range(k + 2, n):
            if k == 0 and l == n - 1:  # adjacent through the closing edge
                continue
            if segments_intersect(verts[k], verts[(k + 1) % n], verts[l], verts[(l + 1) % n]):
                bad.append((k, l))
    return bad


def buildings_sdf(buildings: Iterable[Polygon | Sequence[Sequence[float]]], grid: Grid, dtype=jnp.float32):
    """Signed distance to the union of ``buildings`` on ``grid``: ``min_b sd_b(p_x, p_y)``, shape ``grid.shape``.

    The first two grid dimensions are ``(p_x, p_y)`` [m]; the value is broadcast over every further dimension
    (heading). Negative inside a building. With no buildings the table is :data:`NO_OBSTACLE_DISTANCE` everywhere.
    Computed in float64 with numpy, returned as a ``jax.numpy`` array of ``dtype`` (like :mod:`stp_env.hj.shapes`).

    Args:
        buildings: :class:`~stp_env.scenarios.config.Building` objects or raw vertex lists.
        grid: a grid whose dimensions 0 and 1 are positions.
    """
    if grid.ndim < 2:
        raise ValueError(f"buildings_sdf needs a grid with at least 2 (position) dimensions; got {grid.ndim}.")
    xs, ys = grid.coordinate_vector(0), grid.coordinate_vector(1)
    points = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1)
    sdf = np.full(points.shape[:-1], NO_OBSTACLE_DISTANCE, dtype=np.float64)
    for building in buildings:
        verts = getattr(building, "vertices", building)
        sdf = np.minimum(sdf, polygon_signed_distance(verts, points))
    sdf = sdf.reshape(sdf.shape + (1,) * (grid.ndim - 2))
    return jnp.broadcast_to(jnp.asarray(sdf, dtype=dtype), grid.shape)


def rotate(points: np.ndarray, angle: float) -> np.ndarray:
    """Rotates ``(..., 2)`` points counter-clockwise by ``angle`` [rad] about the origin."""
    c, s = math.cos(angle), math.sin(angle)
    points = np.asarray(points, dtype=np.float64)
    return np.stack([c * points[..., 0] - s * points[..., 1], s * points[..., 0] + c * points[..., 1]], axis=-1)
