"""Cross-route co-observation planning as a multi-flow problem (co-observation paper, Sections III-D and III-E,
problem 60), solved with SciPy's HiGHS.

The checkpoint graph gets a virtual source ``v+`` (edges to every route's first vertex) and a virtual sink ``v-``
(edges from every route's last vertex). A flow is one surveillance robot's path from ``v+`` to ``v-``; edge
weights (eq. 59) are ``-w_t`` on in-route edges, ``w_c`` on cross-route edges and 0 on the virtual ones, and the
cost (60a) is ``sum_k sum_(+i) f^k_(+i) - rho sum_k sum_(ij) w_ij f^k_ij``, with flow conservation (60b), every
Algorithm-1 checkpoint entered by at least one flow (60c) and ``f in {0, 1}`` (60d).

Two things are made explicit here (``docs/coobservation.md``): each flow leaves the source at most once (one robot;
without it one "flow" could be several paths), and the problem is solved in its aggregated form
``F = sum_k f^k``. All ``K`` flows are interchangeable, so ``F`` is a single-commodity flow of at most ``K`` units
with ``0 <= F_e <= K`` and a lower bound 1 on the throughput of every checkpoint (written with split vertices
``j_in -> j_out``); its constraint matrix is a network matrix, hence totally unimodular, so the linear program
(:func:`solve_flows`, HiGHS dual simplex) has an integral optimal vertex, which is decomposed into unit paths.
:func:`solve_flows_milp` solves the disaggregated (60) as written, with binary ``f^k``, for comparison.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np


@dataclasses.dataclass(frozen=True)
class FlowProblem:
    """The flow graph: ``n`` vertices, directed ``edges`` ``(i, j, weight)`` among them, the ``starts`` (joined
    from ``v+``), the ``ends`` (joined to ``v-``), the ``required`` vertices (checkpoints) and ``rho``."""

    n: int
    edges: tuple[tuple[int, int, float], ...]
    starts: tuple[int, ...]
    ends: tuple[int, ...]
    required: tuple[int, ...]
    rho: float

    @classmethod
    def from_graph(cls, graph, w_c: float = 10.0, w_t: float = 1.0, rho: float = 0.01) -> FlowProblem:
        """From a :class:`stp_env.coobservation.checkpoints.CheckpointGraph` with the weights of eq. (59)."""
        if not w_c > w_t:
            raise ValueError(f"eq. (59) needs w_c > w_t; got w_c = {w_c}, w_t = {w_t}.")
        edges = tuple((i, j, w_c if kind == "cross" else -w_t) for i, j, kind in graph.edges)
        required = tuple(k for k, v in enumerate(graph.vertices) if v.checkpoint)
        return cls(len(graph.vertices), edges, tuple(graph.starts()), tuple(graph.ends()), required, rho)

    def all_arcs(self):
        """``(tail, head, weight)`` with the source as ``n`` and the sink as ``n + 1``."""
        src, snk = self.n, self.n + 1
        return (list(self.edges) + [(src, s, 0.0) for s in self.starts] + [(e, snk, 0.0) for e in self.ends])

    def path_cost(self, paths) -> float:
        """Cost (60a) of a set of source-to-sink vertex paths (each a list of graph vertices)."""
        w = {(i, j): wt for i, j, wt in self.edges}
        total = 0.0
        for path in paths:
            if not path:
                continue
            total += 1.0 - self.rho * sum(w[(a, b)] for a, b in itertools.pairwise(path))
        return total


@dataclasses.dataclass(frozen=True)
class FlowSolution:
    """``K`` flows of which ``paths`` are the non-empty ones (vertex lists), ``cost`` (60a), ``status`` from
    HiGHS (``"optimal"`` or ``"infeasible"``), ``integral``: the LP vertex was integral (it must be)."""

    k: int
    status: str
    cost: float
    paths: tuple[tuple[int, ...], ...]
    integral: bool

    @property
    def n_used(self) -> int:
        return len(self.paths)

    @property
    def empty_flows(self) -> int:
        return self.k - len(self.paths) if self.status == "optimal" else 0


def solve_flows(problem: FlowProblem, k: int) -> FlowSolution:
    """The aggregated linear program (see the module docstring) for ``k`` flows, HiGHS dual simplex."""
    from scipy.optimize import linprog
    from scipy.sparse import lil_matrix

    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"k must be an integer >= 1; got {k!r}.")
    n = problem.n
    # split vertices: j_in = j, j_out = n + j; source 2n, sink 2n + 1
    src, snk = 2 * n, 2 * n + 1
    arcs = []  # (tail, head, cost, lower)
    req = set(problem.required)
    for j in range(n):
        arcs.append((j, n + j, 0.0, 1.0 if j in req else 0.0))
    for i, j, w in problem.edges:
        arcs.append((n + i, j, -problem.rho * w, 0.0))
    for s in problem.starts:
        arcs.append((src, s, 1.0, 0.0))
    for e in problem.ends:
        arcs.append((n + e, snk, 0.0, 0.0))
    m = len(arcs)
    c = np.asarray([a[2] for a in arcs])
    a_eq = lil_matrix((2 * n, m))
    for e, (t, h, _, _) in enumerate(arcs):
        if t < 2 * n:
            a_eq[t, e] -= 1.0
        if h < 2 * n:
            a_eq[h, e] += 1.0
    a_ub = np.zeros((1, m))
    for e, (t, _, _, _) in enumerate(arcs):
        if t == src:
            a_ub[0, e] = 1.0
    bounds = [(a[3], float(k)) for a in arcs]
    res = linprog(c, A_ub=a_ub, b_ub=[float(k)], A_eq=a_eq.tocsr(), b_eq=np.zeros(2 * n), bounds=bounds,
                  method="highs-ds")
    if res.status == 2:
        return FlowSolution(k, "infeasible", float("inf"), (), True)
    if res.status != 0:
        raise RuntimeError(f"HiGHS failed on the flow LP (k = {k}): {res.message}")
    x = res.x
    integral = bool(np.all(np.abs(x - np.round(x)) < 1e-6))
    flow = np.round(x).astype(int)
    # decompose the integral flow into unit paths v+ -> ... -> v-
    out: dict[int, list[int]] = {}
    for e, (t, _, _, _) in enumerate(arcs):
        out.setdefault(t, []).append(e)
    paths = []
    while True:
        start = [e for e in out.get(src, []) if flow[e] > 0]
        if not start:
            break
        node, path = src, []
        while node != snk:
            e = next(e for e in out[node] if flow[e] > 0)
            flow[e] -= 1
            node = arcs[e][1]
            if node < n:
                path.append(node)
        paths.append(tuple(path))
    return FlowSolution(k, "optimal", float(res.fun), tuple(paths), integral)


def solve_flows_milp(problem: FlowProblem, k: int) -> FlowSolution:
    """Problem (60) as written, binary ``f^k_ij`` per flow and edge (plus one source exit per flow), by HiGHS
    branch and bound (:func:`scipy.optimize.milp`). Exponentially harder in general; for cross-checks."""
    from scipy.optimize import Bounds, LinearConstraint, milp

    arcs = problem.all_arcs()
    m, n = len(arcs), problem.n
    src = n
    nv = k * m
    c = np.zeros(nv)
    for f in range(k):
        for e, (t, _, w) in enumerate(arcs):
            c[f * m + e] = (1.0 if t == src else 0.0) - problem.rho * w
    rows, lo, hi = [], [], []
    for f in range(k):
        for v in range(n):  # conservation (60b)
            row = np.zeros(nv)
            for e, (t, h, _) in enumerate(arcs):
                if h == v:
                    row[f * m + e] += 1
                if t == v:
                    row[f * m + e] -= 1
            rows.append(row)
            lo.append(0.0)
            hi.append(0.0)
        row = np.zeros(nv)  # one robot per flow
        for e, (t, _, _) in enumerate(arcs):
            if t == src:
                row[f * m + e] = 1
        rows.append(row)
        lo.append(0.0)
        hi.append(1.0)
    for j in problem.required:  # coverage (60c)
        row = np.zeros(nv)
        for f in range(k):
            for e, (_, h, _) in enumerate(arcs):
                if h == j:
                    row[f * m + e] = 1
        rows.append(row)
        lo.append(1.0)
        hi.append(np.inf)
    res = milp(c, constraints=LinearConstraint(np.asarray(rows), lo, hi), integrality=np.ones(nv),
               bounds=Bounds(0, 1))
    if res.status == 2 or res.x is None:
        return FlowSolution(k, "infeasible", float("inf"), (), True)
    x = np.round(res.x).reshape(k, m).astype(int)
    paths = []
    for f in range(k):
        used = [arcs[e] for e in range(m) if x[f, e]]
        if not used:
            continue
        nxt = {t: h for t, h, _ in used}
        node, path = src, []
        while node in nxt and nxt[node] != n + 1:
            node = nxt[node]
            path.append(node)
        paths.append(tuple(path))
    return FlowSolution(k, "optimal", float(res.fun), tuple(paths), True)


def brute_force_flows(problem: FlowProblem, k: int) -> float:
    """The optimal cost (60a) by enumerating every multiset of at most ``k`` source-to-sink paths (tiny graphs
    only: for tests)."""
    succ: dict[int, list[int]] = {}
    for i, j, _ in problem.edges:
        succ.setdefault(i, []).append(j)
    ends = set(problem.ends)
    paths = []

    def walk(node, acc):
        if node in ends:
            paths.append(tuple(acc))
        for j in succ.get(node, []):
            walk(j, [*acc, j])

    for s in problem.starts:
        walk(s, [s])
    best = float("inf")
    req = set(problem.required)
    for r in range(0, k + 1):
        for combo in itertools.combinations_with_replacement(range(len(paths)), r):
            chosen = [paths[i] for i in combo]
            if req <= {v for p in chosen for v in p}:
                best = min(best, problem.path_cost(chosen))
    return best


def sweep(problem: FlowProblem, k_max: int = 8) -> list[FlowSolution]:
    """The paper's iteration: ``K = 1, 2, ...`` until a solution leaves a flow empty (more robots no longer help)
    or ``k_max``."""
    out = []
    for k in range(1, k_max + 1):
        sol = solve_flows(problem, k)
        out.append(sol)
        if sol.status == "optimal" and sol.empty_flows > 0:
            break
    return out


def max_single_flow_gain(problem: FlowProblem) -> float:
    """``max over source-to-sink paths of rho * sum w_ij`` (longest path in the DAG). The paper asks for ``rho`` to
    keep it below 1 (Section III-E): otherwise one robot's path is worth more than the robot, an extra robot on the
    same path always lowers the cost (60a) and the iteration over K never finds an empty flow."""
    succ: dict[int, list[tuple[int, float]]] = {}
    indeg = np.zeros(problem.n, int)
    for i, j, w in problem.edges:
        succ.setdefault(i, []).append((j, w))
        indeg[j] += 1
    order, stack = [], [k for k in range(problem.n) if indeg[k] == 0]
    while stack:
        k = stack.pop()
        order.append(k)
        for j, _ in succ.get(k, []):
            indeg[j] -= 1
            if indeg[j] == 0:
                stack.append(j)
    if len(order) != problem.n:
        raise ValueError("the checkpoint graph has a cycle; flows need a DAG.")
    best = np.full(problem.n, -np.inf)
    best[list(problem.starts)] = 0.0
    for k in order:
        if not np.isfinite(best[k]):
            continue
        for j, w in succ.get(k, []):
            best[j] = max(best[j], best[k] + w)
    return problem.rho * float(max(best[e] for e in problem.ends))
