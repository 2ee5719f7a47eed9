"""The checkpoint graph of cross-trajectory co-observation (co-observation paper, Section III-C, Algorithms 1-2).

* :func:`secure_checkpoints` (Algorithm 1): times on one route such that the reachability region between every two
  consecutive ones misses the forbidden set (Def. 7).
* :func:`checkpoint_graph` (Algorithm 2 and Section III-C3): for every checkpoint, the earliest *arrival* node and
  the latest *departure* node on every other route (RRT* path length over ``v_max`` fits in the time, and the
  transferring robot's own reachability region misses the forbidden set), then in-route edges between consecutive
  vertices of each route.

The reachability test is a parameter (``secure(q1, t1, q2, t2) -> bool``): the ellipse of Def. 3 grown by the
observation radius (:func:`ellipse_test`), or the exact region of a Dubins vehicle in wind
(:mod:`stp_env.coobservation.exact`). Our reading of Algorithm 1, whose printed loop conditions and pointer
updates are garbled, is in ``docs/coobservation.md``.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.coobservation import ellipse
from stp_env.coobservation.rrt import Obstacles2D, connect, rrt_star

SecureFn = Callable[[np.ndarray, float, np.ndarray, float], bool]


class UnsecurableRouteError(ValueError):
    """Even two consecutive waypoints of a route have a reachability region that meets the forbidden set."""


def ellipse_test(forbidden, v_max: float, radius: float) -> SecureFn:
    """``secure(q1, t1, q2, t2)``: the ellipse with foci ``q1, q2`` and semi-major ``v_max (t2 - t1)/2 + radius``
    misses every forbidden convex polygon (:func:`stp_env.coobservation.ellipse.polygon_depth` >= 1)."""
    k = max(len(p) for p in forbidden)
    verts = jnp.asarray(np.stack([np.concatenate([np.asarray(p, float), np.repeat(np.asarray(p, float)[-1:],
                                                                                   k - len(p), 0)])
                                  for p in forbidden]), jnp.float32)

    @jax.jit
    def depth(q1, q2, a):
        return jnp.min(jax.vmap(lambda v: ellipse.polygon_depth(v, q1, q2, a))(verts))

    def secure(q1, t1, q2, t2):
        a = ellipse.semi_major(v_max, t1, t2, radius)
        return bool(depth(jnp.asarray(q1, jnp.float32), jnp.asarray(q2, jnp.float32), jnp.float32(a)) >= 1.0)

    return secure


def secure_checkpoints(route, secure: SecureFn, times=None) -> list[int]:
    """Algorithm 1 for one route ``(T + 1, 2)`` (positions at ``times``, default ``0..T``): indices of the
    checkpoints, the start and the end included.

    A front pointer ``t0`` and a back pointer ``t1`` close in on each other: from ``t0`` the farthest index still
    secured from it becomes a checkpoint and the new ``t0``; then the same from ``t1`` backward; until the two
    pointers secure each other. Raises :class:`UnsecurableRouteError` if two consecutive waypoints cannot be
    secured (no checkpoint placement can help)."""
    route = np.asarray(route, float)
    times = np.arange(len(route), dtype=float) if times is None else np.asarray(times, float)
    n = len(route)

    def ok(i, j):
        return secure(route[i], times[i], route[j], times[j])

    for i in range(n - 1):
        if not ok(i, i + 1):
            raise UnsecurableRouteError(f"waypoints {i} and {i + 1} (t = {times[i]:g}, {times[i + 1]:g}) cannot be "
                                        "secured: their reachability region meets the forbidden set.")
    chosen = {0, n - 1}
    t0, t1 = 0, n - 1
    while not ok(t0, t1):
        i = t0 + 1
        while i + 1 < t1 and ok(t0, i + 1):
            i += 1
        chosen.add(i)
        t0 = i
        if ok(t0, t1):
            break
        j = t1 - 1
        while j - 1 > t0 and ok(j - 1, t1):
            j -= 1
        chosen.add(j)
        t1 = j
    return sorted(chosen)


def greedy_checkpoints(route, secure: SecureFn, times=None) -> list[int]:
    """The one-sided greedy placement (farthest secured index from the last checkpoint). Reachability regions
    are monotone (a sub-interval's region lies inside the interval's, by the triangle inequality), so this uses
    the fewest checkpoints; Algorithm 1 may use one more."""
    route = np.asarray(route, float)
    times = np.arange(len(route), dtype=float) if times is None else np.asarray(times, float)
    n = len(route)
    chosen = [0]
    while chosen[-1] < n - 1:
        t0 = chosen[-1]
        if not secure(route[t0], times[t0], route[t0 + 1], times[t0 + 1]):
            raise UnsecurableRouteError(f"waypoints {t0} and {t0 + 1} cannot be secured.")
        i = t0 + 1
        while i + 1 < n and secure(route[t0], times[t0], route[i + 1], times[i + 1]):
            i += 1
        chosen.append(i)
    return chosen


@dataclasses.dataclass(frozen=True)
class Vertex:
    """``(route, index)``: the reference waypoint ``index`` (time ``index``) of ``route``; ``checkpoint``: an
    Algorithm-1 checkpoint (must be covered); else an arrival/departure node added by Algorithm 2."""

    route: int
    index: int
    checkpoint: bool


@dataclasses.dataclass(frozen=True)
class CheckpointGraph:
    """``vertices`` and directed ``edges`` ``(i, j, kind)`` with kind ``"route"`` (in-route) or ``"cross"``;
    ``paths[(i, j)]``: the RRT* path of a cross edge."""

    vertices: tuple[Vertex, ...]
    edges: tuple[tuple[int, int, str], ...]
    paths: dict

    def index(self, route: int, index: int) -> int:
        for k, v in enumerate(self.vertices):
            if v.route == route and v.index == index:
                return k
        raise KeyError((route, index))

    def starts(self) -> list[int]:
        return [self._first(r) for r in sorted({v.route for v in self.vertices})]

    def ends(self) -> list[int]:
        return [self._last(r) for r in sorted({v.route for v in self.vertices})]

    def _first(self, r):
        ks = [k for k, v in enumerate(self.vertices) if v.route == r]
        return min(ks, key=lambda k: self.vertices[k].index)

    def _last(self, r):
        ks = [k for k, v in enumerate(self.vertices) if v.route == r]
        return max(ks, key=lambda k: self.vertices[k].index)


def checkpoint_graph(routes, checkpoints: Sequence[Sequence[int]], secure: SecureFn, obstacles: Obstacles2D,
                     lo, hi, v_max: float, *, rrt_iterations: int = 1500, rrt_step: float = 1.0, seed: int = 0,
                     progress: bool = False) -> CheckpointGraph:
    """Algorithm 2 (cross-route edges) plus the in-route edges, for routes ``(n_p, T + 1, 2)`` sampled at unit
    time steps and their Algorithm-1 ``checkpoints``.

    For checkpoint ``v`` of route ``p`` and every other route ``r``, RRT* (obstacles: everything a robot may not
    cross, forbidden zones included) from ``q_p(t_v)`` gives ``Cost(q_r(t))`` for each waypoint of ``r``. Waypoint
    ``t > t_v`` is an arrival node if ``Cost / v_max <= t - t_v`` and the transfer's reachability region
    ``(q_p(t_v), t_v) -> (q_r(t), t)`` is secure; the earliest one gets the edge ``v -> (r, t)``. Waypoint
    ``t < t_v`` is a departure node if ``Cost / v_max <= t_v - t`` and ``(q_r(t), t) -> (q_p(t_v), t_v)`` is secure;
    the latest one gets the edge ``(r, t) -> v``. (Algorithm 2 adds the pair only when both exist; each is added on
    its own here.) In-route edges join consecutive vertices of each route in time order."""
    from tqdm.auto import tqdm

    routes = np.asarray(routes, float)
    n_p, n_t = routes.shape[:2]
    vertices: dict[tuple[int, int], bool] = {}
    for p, cps in enumerate(checkpoints):
        for t in cps:
            vertices[(p, int(t))] = True
    cross: dict[tuple[tuple[int, int], tuple[int, int]], np.ndarray] = {}
    jobs = [(p, t) for p, cps in enumerate(checkpoints) for t in cps]
    for job, (p, t_v) in enumerate(tqdm(jobs, desc="checkpoint graph", disable=not progress, leave=False)):
        start = routes[p, t_v]
        others = [r for r in range(n_p) if r != p]
        goals = np.concatenate([routes[r] for r in others])
        tree = rrt_star(start, lo, hi, obstacles, iterations=rrt_iterations, step=rrt_step, goal_bias=goals,
                        seed=seed + job)
        costs, via = connect(tree, goals, obstacles, reach=rrt_step)
        for k, r in enumerate(others):
            c = costs[k * n_t:(k + 1) * n_t]
            v = via[k * n_t:(k + 1) * n_t]
            arrival = departure = None
            for t in range(n_t):
                if not np.isfinite(c[t]):
                    continue
                travel = c[t] / v_max
                if t > t_v and travel <= t - t_v + 1e-9 and arrival is None and \
                        secure(start, t_v, routes[r, t], t):
                    arrival = t
                if t < t_v and travel <= t_v - t + 1e-9 and secure(routes[r, t], t, start, t_v):
                    departure = t
            for t, outgoing in ((arrival, True), (departure, False)):
                if t is None:
                    continue
                vertices.setdefault((r, t), False)
                path = np.concatenate([tree.path(int(v[t])), routes[r, t][None]])
                key = ((p, t_v), (r, t)) if outgoing else ((r, t), (p, t_v))
                cross[key] = path if outgoing else path[::-1]
    keys = sorted(vertices)
    verts = tuple(Vertex(r, t, vertices[(r, t)]) for r, t in keys)
    idx = {k: i for i, k in enumerate(keys)}
    edges = []
    for r in range(n_p):
        times = sorted(t for rr, t in keys if rr == r)
        edges.extend((idx[(r, a)], idx[(r, b)], "route") for a, b in itertools.pairwise(times))
    paths = {}
    for (u, w), path in sorted(cross.items()):
        edges.append((idx[u], idx[w], "cross"))
        paths[(idx[u], idx[w])] = path
    return CheckpointGraph(verts, tuple(edges), paths)
