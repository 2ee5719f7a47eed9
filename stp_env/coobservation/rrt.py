"""RRT* (Karaman and Frazzoli) in the plane among convex polygonal obstacles, from one start to many goals: the
path search of the co-observation paper's Section III-B (``Cost(v)``: the length of the tree path to ``v``).

Pure numpy, seeded. :func:`rrt_star` grows one tree from the start for ``iterations`` samples (rewiring every new
node's neighbourhood, radius ``min(gamma sqrt(log n / n), step)``), then connects every goal to the best tree node
in reach by a collision-free straight segment.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from stp_env.coobservation.admm import polygon_halfplanes


def segments_hit_polygon(p, q, normals, offsets) -> np.ndarray:
    """Whether segments ``[p_k, q_k]`` (``(n, 2)`` each) meet the convex polygon ``{n_i . x <= m_i}`` (closed),
    by clipping the segment parameter against every half-plane (Liang-Barsky)."""
    p, q = np.atleast_2d(p), np.atleast_2d(q)
    d = q - p
    num = offsets[None, :] - p @ normals.T          # n_i . (p + s d) <= m_i  <=>  s (n_i . d) <= num_i
    den = d @ normals.T
    lo = np.zeros(len(p))
    hi = np.ones(len(p))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = num / den
    pos, neg = den > 1e-15, den < -1e-15
    hi = np.minimum(hi, np.where(pos, s, np.inf).min(axis=1))
    lo = np.maximum(lo, np.where(neg, s, -np.inf).max(axis=1))
    parallel_out = np.any((np.abs(den) <= 1e-15) & (num < 0), axis=1)
    return (lo <= hi) & ~parallel_out


@dataclasses.dataclass(frozen=True)
class Obstacles2D:
    """Convex polygons for collision checks (half-plane form)."""

    halfplanes: tuple

    @classmethod
    def from_polygons(cls, polygons, margin: float = 0.0) -> Obstacles2D:
        hp = []
        for v in polygons:
            n, m = polygon_halfplanes(v)
            hp.append((n, m + margin))
        return cls(tuple(hp))

    def segment_free(self, p, q) -> np.ndarray:
        free = np.ones(len(np.atleast_2d(p)), bool)
        for n, m in self.halfplanes:
            free &= ~segments_hit_polygon(p, q, n, m)
        return free

    def point_free(self, p) -> np.ndarray:
        p = np.atleast_2d(p)
        free = np.ones(len(p), bool)
        for n, m in self.halfplanes:
            free &= ~np.all(p @ n.T <= m, axis=1)
        return free


@dataclasses.dataclass(frozen=True)
class Tree:
    """An RRT* tree: ``nodes`` ``(n, 2)``, ``parent`` (``-1`` for the root), ``cost`` (path length from the root)."""

    nodes: np.ndarray
    parent: np.ndarray
    cost: np.ndarray

    def path(self, k: int) -> np.ndarray:
        out = []
        while k >= 0:
            out.append(self.nodes[k])
            k = int(self.parent[k])
        return np.asarray(out[::-1])


def rrt_star(start, lo, hi, obstacles: Obstacles2D, *, iterations: int = 1500, step: float = 1.0,
             gamma: float = 6.0, goal_bias=None, seed: int = 0) -> Tree:
    """Grow an RRT* tree from ``start`` in the box ``[lo, hi]``. ``goal_bias``: optional points sampled with
    probability 0.1 (the goals: the tree grows toward them)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    cap = iterations + 1
    nodes = np.zeros((cap, 2))
    parent = np.full(cap, -1, int)
    cost = np.zeros(cap)
    nodes[0] = start
    n = 1
    bias = None if goal_bias is None or len(goal_bias) == 0 else np.asarray(goal_bias, float)
    for _ in range(iterations):
        if bias is not None and rng.random() < 0.1:
            x = bias[rng.integers(len(bias))]
        else:
            x = lo + rng.random(2) * (hi - lo)
        d = np.linalg.norm(nodes[:n] - x, axis=1)
        k = int(np.argmin(d))
        if d[k] < 1e-9:
            continue
        new = nodes[k] + (x - nodes[k]) * min(1.0, step / d[k])
        if not obstacles.point_free(new)[0] or not obstacles.segment_free(nodes[k], new)[0]:
            continue
        radius = min(gamma * math.sqrt(math.log(n + 1) / (n + 1)), step)
        dn = np.linalg.norm(nodes[:n] - new, axis=1)
        near = np.flatnonzero(dn <= max(radius, dn[k] + 1e-9))
        free = obstacles.segment_free(nodes[near], np.repeat(new[None], len(near), 0))
        near = near[free]
        through = cost[near] + dn[near]
        best = int(near[np.argmin(through)])
        nodes[n], parent[n], cost[n] = new, best, cost[best] + dn[best]
        # rewire: neighbours that get cheaper through the new node
        better = cost[n] + dn[near] < cost[near] - 1e-12
        for j in near[better]:
            delta = cost[n] + dn[j] - cost[j]
            parent[j] = n
            _shift_subtree(parent, cost, n + 1, int(j), delta)
        n += 1
    return Tree(nodes[:n].copy(), parent[:n].copy(), cost[:n].copy())


def _shift_subtree(parent, cost, n, root, delta):
    """Add ``delta`` to the cost of ``root`` and every descendant (after a rewire)."""
    stack = [root]
    while stack:
        j = stack.pop()
        cost[j] += delta
        stack.extend(np.flatnonzero(parent[:n] == j).tolist())


def connect(tree: Tree, goals, obstacles: Obstacles2D, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """For each goal ``(m, 2)``: ``Cost`` of the cheapest tree node within ``reach`` with a free straight segment
    to it, plus that segment (``inf`` when none), and the node's index (``-1``)."""
    goals = np.atleast_2d(np.asarray(goals, float))
    costs = np.full(len(goals), np.inf)
    via = np.full(len(goals), -1, int)
    for g, x in enumerate(goals):
        d = np.linalg.norm(tree.nodes - x, axis=1)
        cand = np.flatnonzero(d <= reach)
        if len(cand) == 0:
            continue
        free = obstacles.segment_free(tree.nodes[cand], np.repeat(x[None], len(cand), 0))
        cand = cand[free]
        if len(cand) == 0:
            continue
        total = tree.cost[cand] + d[cand]
        k = int(np.argmin(total))
        costs[g], via[g] = total[k], cand[k]
    return costs, via
