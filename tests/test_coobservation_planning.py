"""The co-observation paper's planners on tiny cases: the generalised ADMM meets its constraints (and the
reachability constraint changes the answer), the multi-flow LP (60) matches brute force and the MILP, Algorithm 1
secures every interval with no more checkpoints than needed, and RRT* finds near-shortest paths."""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env.coobservation import admm, checkpoints, flows, rrt
from stp_env.coobservation.schedule import Observation, segments

SQUARE = ((1.6, 0.6), (2.4, 0.6), (2.4, 1.4), (1.6, 1.4))


def _ellipse_hits(q1, q2, a, polygon, n=60):
    xs = np.linspace(0, 1, n)
    v = np.asarray(polygon)
    lo, hi = v.min(0), v.max(0)
    pts = np.stack(np.meshgrid(lo[0] + xs * (hi[0] - lo[0]), lo[1] + xs * (hi[1] - lo[1])), -1).reshape(-1, 2)
    return bool(np.any(np.linalg.norm(pts - q1, axis=1) + np.linalg.norm(pts - q2, axis=1) < 2 * a))


@pytest.mark.slow
def test_admm_meets_velocity_coobservation_and_reachability_constraints():
    """Two robots, two steps, co-observing at t = 1 while a cost pulls them up toward a forbidden square: from a
    start whose reachability ellipses cut the square, the ADMM ends with every constraint met (measured against
    the sets, and the ellipses checked by sampling the square)."""
    square = ((0.8, 0.95), (1.2, 0.95), (1.2, 1.15), (0.8, 1.15))
    starts, goals = np.array([[0.0, 0.0], [0.0, 0.3]]), np.array([[2.0, 0.0], [2.0, 0.3]])
    q0 = np.array([[starts[0], [1.0, 0.45], goals[0]], [starts[1], [1.0, 0.6], goals[1]]])
    fixed = np.zeros((2, 3), bool)
    fixed[:, [0, -1]] = True
    target = jnp.array([1.0, 0.9])

    def cost(q):
        return jnp.sum((q[:, 1:] - q[:, :-1]) ** 2) + 2.0 * jnp.sum((q[:, 1] - target) ** 2)

    obs = [Observation(time=0, agent=i, point=tuple(starts[i])) for i in range(2)]
    obs += [Observation(time=2, agent=i, point=tuple(goals[i])) for i in range(2)]
    obs.append(Observation(time=1, agent=0, partner=1))
    radius, v_max = 0.3, 1.2
    reach = admm.Reachability(tuple(segments(obs, 2)), (square,), v_max=v_max, radius=radius, margin=0.01)
    cons = [admm.Velocity(0.99 * v_max), admm.Obstacles((square,), margin=0.05),
            admm.CoObservation(((0, 1, 1),), 0.5), reach]

    def hits(q):
        out = []
        for seg in reach.segments:
            f1, f2 = (np.asarray(o[1]) if o[0] == "point" else q[o[1], round(o[2])]
                      for o in (seg.observer1, seg.observer2))
            out.append(_ellipse_hits(f1, f2, v_max * (seg.t2 - seg.t1) / 2 + radius, square))
        return out

    assert any(hits(q0))  # the constraint is active at the start
    res = admm.solve(cost, cons, q0, fixed, admm.ADMMSettings(max_iters=80, inner_iters=30), progress=False)
    assert res.violations["velocity"] < 1e-3 and res.violations["coobservation"] < 1e-3
    assert res.violations["obstacles"] < 1e-3 and res.violations["reachability"] < 1e-2
    q = res.q
    assert np.linalg.norm(q[0, 1] - q[1, 1]) <= 0.5 + 1e-3
    assert np.all(np.linalg.norm(np.diff(q, axis=1), axis=-1) <= v_max + 1e-3)
    assert not any(hits(q))
    assert q[1, 1, 1] > 0.3  # the cost still pulls the meeting up as far as the ellipses allow


def _tiny_flow_problem():
    """Two routes of three vertices (0-2 and 3-5), cross edges both ways, checkpoints at the ends and middles."""
    edges = [(0, 1, -1.0), (1, 2, -1.0), (3, 4, -1.0), (4, 5, -1.0),
             (0, 4, 10.0), (3, 1, 10.0), (1, 5, 10.0), (4, 2, 10.0)]
    return flows.FlowProblem(n=6, edges=tuple(edges), starts=(0, 3), ends=(2, 5), required=(0, 1, 2, 3, 4, 5),
                             rho=0.01)


def test_flow_lp_matches_brute_force_and_milp():
    prob = _tiny_flow_problem()
    assert flows.solve_flows(prob, 1).status == "infeasible"  # two starts need two robots
    for k in (2, 3, 4):
        lp = flows.solve_flows(prob, k)
        assert lp.status == "optimal" and lp.integral
        assert lp.cost == pytest.approx(flows.brute_force_flows(prob, k), abs=1e-9)
        assert lp.cost == pytest.approx(flows.solve_flows_milp(prob, k).cost, abs=1e-9)
        assert lp.cost == pytest.approx(prob.path_cost(lp.paths), abs=1e-9)
        covered = {v for p in lp.paths for v in p}
        assert set(prob.required) <= covered and lp.n_used <= k
    sweep = flows.sweep(prob, k_max=6)
    assert sweep[-1].empty_flows > 0 and sweep[-1].k < 6


def test_algorithm1_secures_every_interval_with_few_checkpoints():
    route = np.stack([np.linspace(0.0, 4.0, 17), np.zeros(17)], 1)  # passes 0.6 below the square
    secure = checkpoints.ellipse_test((SQUARE,), v_max=0.5, radius=0.1)
    table = {(a, b): secure(route[a], a, route[b], b) for a in range(17) for b in range(a + 1, 17)}

    def cached(q1, t1, q2, t2):
        return table[(round(t1), round(t2))]

    cps = checkpoints.secure_checkpoints(route, cached)
    greedy = checkpoints.greedy_checkpoints(route, cached)
    assert cps[0] == 0 and cps[-1] == 16
    for a, b in (*itertools.pairwise(cps), *itertools.pairwise(greedy)):
        assert table[(a, b)]
    assert not table[(0, 16)]  # the whole route is not secure: checkpoints are needed
    # the greedy placement is the fewest (brute force over subsets of the inner times)
    best = None
    for k in range(0, 8):
        for inner in itertools.combinations(range(1, 16), k):
            ts = [0, *inner, 16]
            if all(table[(a, b)] for a, b in itertools.pairwise(ts)):
                best = len(ts)
                break
        if best is not None:
            break
    assert len(greedy) == best <= len(cps)
    with pytest.raises(checkpoints.UnsecurableRouteError):
        checkpoints.secure_checkpoints(np.stack([np.linspace(1.6, 2.4, 5), np.full(5, 1.5)], 1), secure)


def test_rrt_star_paths_are_near_shortest_and_collision_free():
    free = rrt.Obstacles2D.from_polygons([])
    tree = rrt.rrt_star((0.0, 0.0), (0, 0), (5, 5), free, iterations=800, step=0.6, seed=1)
    cost, _ = rrt.connect(tree, [(4.0, 3.0)], free, reach=0.6)
    assert 5.0 <= cost[0] <= 5.0 * 1.08
    wall = ((2.0, -1.0), (2.4, -1.0), (2.4, 3.5), (2.0, 3.5))
    obs = rrt.Obstacles2D.from_polygons([wall])
    tree = rrt.rrt_star((0.0, 0.0), (-1, -1), (5, 5), obs, iterations=1500, step=0.6, goal_bias=[(4.0, 0.0)], seed=2)
    cost, via = rrt.connect(tree, [(4.0, 0.0)], obs, reach=0.6)
    shortest = np.hypot(2.0, 3.5) + 0.4 + np.hypot(1.6, 3.5)  # over the top of the wall
    assert shortest - 1e-6 <= cost[0] <= shortest * 1.1
    path = np.concatenate([tree.path(int(via[0])), [[4.0, 0.0]]])
    assert np.all(obs.segment_free(path[:-1], path[1:]))
