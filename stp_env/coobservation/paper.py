"""The co-observation paper's experiments (Sections II-K and III-F) as typed tasks.

:class:`MapExplorationTask` is the 10 m x 10 m map-exploration task of Section II-K: three robots, ``v_max = 0.5`` m
per step, horizon 20 steps, robots 1-2 co-observing at ``t = 8`` and ``14`` and robots 2-3 at ``t = 18``, robot 3
visiting a security checkpoint at ``t = 8``, one obstacle (zone 1) and two forbidden zones (zones 2 and 3). The
paper gives no coordinates and no observation radius; ours are in ``docs/coobservation.md`` (robots are numbered
from 0 in code: robot 1 of the paper is index 0).

:func:`plan` solves it with the generalised ADMM (:mod:`stp_env.coobservation.admm`) with or without the
reachability constraints; :func:`survey_routes` plans the longer unsecured routes of Section III-F.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from stp_env.coobservation import admm
from stp_env.coobservation.exploration import ExplorationCost
from stp_env.coobservation.schedule import Observation, segments


def _box(x0, x1, y0, y1):
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


@dataclasses.dataclass(frozen=True, kw_only=True)
class MapExplorationTask:
    """Section II-K's task (our coordinates). Attributes in m and plan steps."""

    lo: tuple[float, float] = (0.0, 0.0)
    hi: tuple[float, float] = (10.0, 10.0)
    horizon: int = 20
    v_max: float = 0.5
    radius: float = 0.5
    starts: tuple = ((2.0, 2.0), (5.0, 1.5), (8.0, 2.0))
    goals: tuple = ((3.5, 7.5), (4.8, 7.5), (5.8, 7.5))
    obstacles: tuple = (_box(4.3, 5.7, 4.3, 5.3),)
    forbidden: tuple = (_box(0.3, 1.7, 4.8, 6.6), _box(8.3, 9.7, 4.8, 6.6))
    coobservations: tuple = ((0, 1, 8), (0, 1, 14), (1, 2, 18))
    checkpoint: tuple = (2, (6.6, 3.0), 8)
    obstacle_margin: float = 0.15
    reach_margin: float = 0.02
    tighten: float = 0.01

    @property
    def n_agents(self) -> int:
        return len(self.starts)

    def observations(self) -> tuple[Observation, ...]:
        """The schedule: starts and goals (base stations), the co-observations and the checkpoint."""
        obs = [Observation(time=0, agent=i, point=s) for i, s in enumerate(self.starts)]
        obs += [Observation(time=self.horizon, agent=i, point=g) for i, g in enumerate(self.goals)]
        obs += [Observation(time=t, agent=a, partner=b) for a, b, t in self.coobservations]
        agent, point, t = self.checkpoint
        obs.append(Observation(time=t, agent=agent, point=point))
        return tuple(obs)

    def cost(self) -> ExplorationCost:
        return ExplorationCost.grid(self.lo, self.hi, 1.0)

    def reachability(self) -> admm.Reachability:
        return admm.Reachability(tuple(segments(self.observations(), self.n_agents)), self.forbidden, self.v_max,
                                 self.radius, margin=self.reach_margin)

    def constraints(self, secured: bool) -> list:
        agent, point, t = self.checkpoint
        shrink = 1.0 - self.tighten  # plan a little inside the sets, check against the sets themselves
        cons = [admm.Velocity(shrink * self.v_max), admm.Workspace(self.lo, self.hi),
                admm.Obstacles(self.obstacles + self.forbidden, margin=self.obstacle_margin),
                admm.CoObservation(self.coobservations, d_max=shrink * self.radius),
                admm.Waypoint(agent, point, t, t, shrink * self.radius)]
        if secured:
            cons.append(self.reachability())
        return cons

    def initial(self, seed: int = 0) -> np.ndarray:
        """Obstacle-free paths from the starts to the goals (RRT* among the obstacles and forbidden zones, grown
        by the obstacle margin), resampled to ``horizon + 1`` evenly spaced waypoints (the paper starts from a
        grid-world plan; a straight line through an obstacle's centre would start the ADMM on the kink of the
        obstacle constraint, where it stalls)."""
        from stp_env.coobservation.rrt import Obstacles2D, connect, rrt_star

        obs = Obstacles2D.from_polygons(self.obstacles + self.forbidden, margin=2 * self.obstacle_margin)
        out = []
        for i, (s, g) in enumerate(zip(self.starts, self.goals)):
            tree = rrt_star(s, self.lo, self.hi, obs, iterations=800, step=0.6, goal_bias=[g], seed=seed + i)
            _, via = connect(tree, [g], obs, reach=0.6)
            if via[0] < 0:
                raise ValueError(f"robot {i}: no obstacle-free path from {s} to {g} found by RRT*.")
            path = np.concatenate([tree.path(int(via[0])), np.asarray(g, float)[None]])
            out.append(_resample_n(path, self.horizon + 1))
        return np.stack(out)

    def fixed_mask(self) -> np.ndarray:
        m = np.zeros((self.n_agents, self.horizon + 1), bool)
        m[:, 0] = m[:, -1] = True
        return m


def plan(task: MapExplorationTask, secured: bool, q0=None, settings: admm.ADMMSettings | None = None,
         progress: bool = True) -> admm.ADMMResult:
    """Plan the task: without (``secured=False``: Fig. 2a) or with the reachability constraints (Fig. 7),
    from ``q0`` (default: straight lines)."""
    q0 = task.initial() if q0 is None else q0
    return admm.solve(task.cost(), task.constraints(secured), q0, task.fixed_mask(), settings, progress=progress)


@dataclasses.dataclass(frozen=True, kw_only=True)
class SurveyTask:
    """Section III-F's setting (our coordinates): the same 10 m x 10 m map and robots (``v_max = 0.5`` m per step),
    three unsecured exploration routes, two forbidden rectangles, ``w_c = 10``, ``w_t = 1``, ``rho = 0.01``.

    The routes are boustrophedon (lawn-mower) sweeps, the pattern the paper names as the ideal exploration without
    security: the robots sweep the map from west to east and back in interleaved passes (robot ``p`` at the
    heights ``passes[p]``) at ``speed`` m per step (below ``v_max``: a surveillance robot must be able to catch up
    with a route to join it). The forbidden rectangles lie between passes. The observation radius of a checkpoint
    is ``radius``."""

    lo: tuple[float, float] = (0.0, 0.0)
    hi: tuple[float, float] = (10.0, 10.0)
    v_max: float = 0.5
    radius: float = 0.2
    passes: tuple = ((1.0, 4.5), (2.5, 6.0), (4.0, 7.5))
    x_range: tuple[float, float] = (0.5, 9.5)
    alternate: bool = False
    speed: float = 0.35
    forbidden: tuple = (_box(1.5, 4.5, 5.15, 5.35), _box(5.5, 8.5, 8.3, 8.5))
    w_c: float = 10.0
    w_t: float = 1.0
    rho: float = 0.01
    given_routes: tuple | None = None
    obstacles: tuple = ()

    def routes(self) -> np.ndarray:
        """``(R, T + 1, 2)``: ``given_routes`` when set (waypoints one step apart, e.g. a Section II plan), else the
        boustrophedon passes sampled every step at ``speed`` (the last waypoint held until the common end)."""
        if self.given_routes is not None:
            return np.asarray(self.given_routes, float)
        paths = []
        for p, ys in enumerate(self.passes):
            x0, x1 = self.x_range
            if self.alternate and p % 2:  # alternate directions: the robots do not all start on one side
                x0, x1 = x1, x0
            corners = []
            for k, y in enumerate(ys):
                corners += [(x0, y), (x1, y)] if k % 2 == 0 else [(x1, y), (x0, y)]
            corners = np.asarray(corners, float)
            paths.append(_resample(corners, self.speed))
        n = max(len(q) for q in paths)
        return np.stack([np.concatenate([q, np.repeat(q[-1:], n - len(q), 0)]) for q in paths])


def _resample(corners: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` along the polyline ``corners`` (the last corner included)."""
    seg = np.diff(corners, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    total = lengths.sum()
    s = np.append(np.arange(0.0, total, step), total)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    return corners[k] + (s - cum[k])[:, None] * seg[k] / lengths[k][:, None]


def _resample_n(path: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced by arc length along the polyline ``path`` (both ends included)."""
    seg = np.diff(path, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    s = np.linspace(0.0, cum[-1], n)
    return np.stack([np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])], axis=1)


def verify(task: MapExplorationTask, q) -> dict:
    """Every constraint of the task on the plan ``q``, against the sets themselves (no planning margins):
    the largest violation of each [m], and for every reachability segment the ellipse's smallest normalised depth
    over the forbidden zones (``>= 1``: clear; :func:`stp_env.coobservation.ellipse.polygon_depth`) and whether
    it is clear."""
    import jax.numpy as jnp

    from stp_env.coobservation import ellipse

    q = np.asarray(q, float)
    out = {"velocity": float(np.max(np.linalg.norm(np.diff(q, axis=1), axis=-1)) - task.v_max)}
    out["coobservation"] = max(float(np.linalg.norm(q[a, t] - q[b, t])) - task.radius
                               for a, b, t in task.coobservations)
    agent, point, t = task.checkpoint
    out["checkpoint"] = float(np.linalg.norm(q[agent, t] - np.asarray(point))) - task.radius
    worst = -np.inf
    for poly in task.obstacles + task.forbidden:
        n, m = admm.polygon_halfplanes(poly)
        worst = max(worst, float(np.max(-np.max(q @ n.T - m, axis=-1))))
    out["waypoint_in_zone"] = worst  # > 0: a waypoint inside a zone, by that depth
    out["starts_goals"] = float(max(np.abs(q[:, 0] - np.asarray(task.starts)).max(),
                                    np.abs(q[:, -1] - np.asarray(task.goals)).max()))
    depths = []
    for seg in segments(task.observations(), task.n_agents):
        f = [np.asarray(o[1]) if o[0] == "point" else q[o[1], round(o[2])] for o in (seg.observer1, seg.observer2)]
        a = task.v_max * (seg.t2 - seg.t1) / 2 + task.radius
        d = min(float(ellipse.polygon_depth(jnp.asarray(p, jnp.float32), jnp.asarray(f[0], jnp.float32),
                                            jnp.asarray(f[1], jnp.float32), a)) for p in task.forbidden)
        depths.append({"agent": seg.agent, "t1": seg.t1, "t2": seg.t2, "depth": round(d, 4), "clear": d >= 1.0})
    out["ellipses"] = depths
    out["all_met"] = (out["velocity"] <= 1e-6 and out["coobservation"] <= 1e-6 and out["checkpoint"] <= 1e-6
                      and out["waypoint_in_zone"] < 0 and out["starts_goals"] < 1e-5)
    out["all_ellipses_clear"] = all(d["clear"] for d in depths)
    return out


def survey_flows(task: SurveyTask, secure=None, *, k_max: int = 8, rrt_iterations: int = 600, seed: int = 0,
                 progress: bool = False) -> dict:
    """Section III-F end to end: Algorithm-1 checkpoints of the survey routes, the checkpoint graph (Algorithm 2,
    RRT*), the multi-flow LP (60) for ``K = 1, 2, ...`` until a flow stays empty (each ``K`` also solved as the MILP),
    with the reachability test ``secure`` (default: the ellipse of Def. 3 grown by the checkpoint radius).
    Returns the numbers (``"result"``) and the ``routes``, ``graph`` and ``sweep`` for figures."""
    from stp_env.coobservation import checkpoints, flows
    from stp_env.coobservation.rrt import Obstacles2D

    routes = task.routes()
    if secure is None:
        secure = checkpoints.ellipse_test(task.forbidden, task.v_max, task.radius)
    cps = [checkpoints.secure_checkpoints(r, secure) for r in routes]
    greedy = [checkpoints.greedy_checkpoints(r, secure) for r in routes]
    obs = Obstacles2D.from_polygons(tuple(task.forbidden) + tuple(task.obstacles), margin=0.05)
    graph = checkpoints.checkpoint_graph(routes, cps, secure, obs, task.lo, task.hi, task.v_max,
                                         rrt_iterations=rrt_iterations, rrt_step=0.8, seed=seed, progress=progress)
    prob = flows.FlowProblem.from_graph(graph, task.w_c, task.w_t, task.rho)
    sweep = flows.sweep(prob, k_max=k_max)
    rows = []
    for sol in sweep:
        cross = [sum(graph.vertices[a].route != graph.vertices[b].route for a, b in itertools.pairwise(p))
                 for p in sol.paths]
        milp = flows.solve_flows_milp(prob, sol.k)
        rows.append({"K": sol.k, "status": sol.status, "cost": round(sol.cost, 6), "flows_used": sol.n_used,
                     "empty_flows": sol.empty_flows, "cross_edges_per_flow": cross, "lp_integral": sol.integral,
                     "milp_cost": round(milp.cost, 6)})
    stop = next((s.k for s in sweep if s.status == "optimal" and s.empty_flows > 0), None)
    result = {"route_steps": int(routes.shape[1] - 1), "checkpoints_algorithm1": [len(c) for c in cps],
              "checkpoints_greedy": [len(c) for c in greedy], "vertices": len(graph.vertices),
              "route_edges": sum(e[2] == "route" for e in graph.edges),
              "cross_edges": sum(e[2] == "cross" for e in graph.edges),
              "max_single_flow_gain": round(flows.max_single_flow_gain(prob), 4),
              "robots_needed": None if stop is None else stop - 1, "sweep": rows}
    return {"result": result, "routes": routes, "graph": graph, "sweep": sweep}
