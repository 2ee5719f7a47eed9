"""Feasible-trajectory counts and the policies' trajectory values by dynamic programming over the mission graph.

The survivability paper counts the feasible trajectories of every cell by backtracking from the terminal states
(Section III-A, Algorithms 1-2): each backward-generated state is one feasible trajectory to a terminal state. On
the lattice of :mod:`stp_env.survivability.network` two backward paths that reach the same state merge, so the same
count is a sum over the primitives, one backward sweep for all states at once:

    N_k(s) = 1                                         if s is a terminal state at window k
    N_k(s) = sum_a F(s, a) N_{k+1}(s'(s, a))           otherwise,

with ``F(s, a) = 1`` when the segment of primitive ``a`` is feasible (no known blocked cell). Terminal states are
absorbing (a trajectory ends where it lands). :mod:`stp_env.survivability.backtrack` runs the paper's algorithm
literally (lists of states) as the independent check.

The same sweep gives what the policies of Section IV-B need, with ``p(s, a)`` the robustness of a segment:

* ``W_k(s)``, the sum over the trajectories ``l`` from ``s`` of their robustness ``P_l`` (eq. 1 with
  ``alpha = 1``): ``W = sum_a F p W'``. The average trajectory robustness of ``pi_Avg(R)`` is ``W / N``.
* ``R_k(s)``, the survivability of ``s``, the probability that at least one trajectory from ``s`` stays feasible:
  ``R = 1 - prod_a (1 - F p R')``. This is eq. 3 over the *tree* of trajectories from ``s``, in which a segment
  shared by many trajectories enters once. Eq. 3 over the list of trajectories multiplies a shared segment's risk
  once per trajectory (its independence assumption fails for trajectories that share segments) and saturates at 1
  on this network, where the origin has 10^8 trajectories; in the tree form, branches that merge again later are
  still treated as independent.
* ``J_k(s)``, the best future term of the policy's receding-horizon objective (eq. 5) over the trajectories from
  ``s`` that end in the current terminal set ``Omega``: ``J = max_a [r(s, a) + v_{k+1}(s') + J_{k+1}(s')]``,
  ``J = 0`` at a terminal state of ``Omega`` and ``-inf`` where ``Omega`` is out of reach, with ``(r, v) = (p, 0)``
  for ``pi_R``, ``(0, N)`` for ``pi_Nf``, ``(0, R)`` for ``pi_S`` and ``(0, W / N)`` for ``pi_Avg(R)``.

``N``, ``W``, ``R`` and the values ``v`` count trajectories to *any* landing site (the set ``c.L`` of Section
IV-B); ``Omega`` (the goal only, then the goal and the alternative sites once the goal is out of reach) restricts
which trajectory the policy may pick (constraint 10). That is ``nf_count="landing"`` (the default). With
``nf_count="goal"`` ``pi_Nf``'s value is the paper's ``c.N_f`` instead: Algorithm 1 initialises the count to 1 at
"any valid terminal state ... in Omega(t_0)" and "the total number of feasible trajectories in a cell equals the
number of promising states in that cell", so ``v(s)`` is the sum, over every graph state ``s''`` of the same window
in the same (x, y) cell as ``s``, of ``N^Omega(s'')``, the trajectories from ``s''`` to the current terminal set
``Omega`` (``n_goal`` while ``Omega`` is the goal, ``n_all`` once it includes the alternative sites). The cell
sum is a segment sum over precomputed cell ids per window, in the same sweep. All functions are pure and jittable,
on the compact graph of :mod:`stp_env.survivability.graph` (a few milliseconds per sweep), and ``vmap`` over
instances.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.survivability.config import NF_COUNTS, POLICIES
from stp_env.survivability.graph import Graph

NEG = -jnp.inf
OMEGAS = ("goal", "all")


class Tables(NamedTuple):
    """DP tables over the graph's states, each ``(S,)`` float32."""

    n_goal: jax.Array     # trajectories to the goal only (alternative sites are not terminal)
    n_all: jax.Array      # trajectories to any landing site (c.N_f)
    value: jax.Array      # the policy's state value v: N (pi_Nf), R (pi_S), W / N (pi_Avg(R)), 0 (pi_R)
    future: jax.Array     # J: best future term over trajectories ending in Omega (-inf: Omega out of reach)


class _Meta(NamedTuple):
    """Static shape information of a graph (hashable: a static argument of the jitted sweeps)."""

    n_windows: int
    window_start: tuple
    n_cell_groups: tuple     # per window: distinct (x, y) cells of its states


BUCKET_WIDTHS = (4, 8, 16)
"""Widths of the successor tables a window's states are grouped by (plus the window's largest number of
successors): see :func:`_buckets`."""
BUCKET_MIN_STATES = 1024
"""Windows with fewer states keep one group (the compilation grows with the groups; small windows gain little)."""


@functools.lru_cache(maxsize=4)
def _consts(graph: Graph):
    """``(meta, arrays)``: the graph's per-window tables as device arrays, passed to the sweeps as arguments (as
    constants, XLA would spend seconds folding them at every compilation). ``succ[k]``: ``(n_k, A)`` local index
    of the successor in window ``k + 1`` (sentinel ``n_{k+1}``); ``seg[k]``: segment id (sentinel ``n_seg``);
    ``cell_group[k]``: ``(n_k,)`` id of the state's (x, y) cell among the window's cells; ``buckets[k]`` and
    ``order[k]``: the same successors packed by :func:`_buckets`."""
    ws = graph.window_start
    K = graph.net.n_windows
    succ, seg, tg, ta, groups, n_groups, buckets, order = [], [], [], [], [], [], [], []
    for k in range(K + 1):
        sl = slice(ws[k], ws[k + 1])
        tg.append(jnp.asarray(graph.term_goal[sl]))
        ta.append(jnp.asarray(graph.term_alt[sl]))
        grp, n_grp = cell_groups(graph, k)
        groups.append(jnp.asarray(grp, jnp.int32))
        n_groups.append(n_grp)
        if k < K:
            s = graph.succ[sl]
            n_next = ws[k + 2] - ws[k + 1]
            local = np.where(s >= 0, s - ws[k + 1], n_next)
            segs = np.where(s >= 0, graph.seg[sl], graph.n_segments)
            succ.append(jnp.asarray(local, jnp.int32))
            seg.append(jnp.asarray(segs, jnp.int32))
            parts, inv = _buckets(s >= 0, local, segs, BUCKET_WIDTHS if len(s) >= BUCKET_MIN_STATES else ())
            buckets.append(tuple((jnp.asarray(rows, jnp.int32), jnp.asarray(a, jnp.int32), jnp.asarray(b, jnp.int32))
                                 for rows, a, b in parts))
            order.append(jnp.asarray(inv, jnp.int32))
    arrays = {"succ": tuple(succ), "seg": tuple(seg), "term_goal": tuple(tg), "term_alt": tuple(ta),
              "cell_group": tuple(groups), "buckets": tuple(buckets), "order": tuple(order)}
    return _Meta(K, tuple(int(v) for v in ws), tuple(n_groups)), arrays


def _buckets(valid, succ, seg, bucket_widths=BUCKET_WIDTHS):
    """A window's successor tables packed for the sweep: most states have far fewer successors than primitives
    (7 of 25 on average on the Bay-Area mission), so each state's valid primitives are moved to the left, in
    their order, and the states are grouped by how many they have, each group padded only to its width
    (``bucket_widths``, then the largest). Returns ``[(rows, succ, seg)]``, one per non-empty group (``rows``:
    the group's states, local indices; ``succ``, ``seg``: ``(len(rows), width)`` with the tables' sentinels), and
    ``inv``: the position of each state in the groups' concatenation.

    The sweep gives the same bits as on the full tables: a dropped entry is a primitive with no successor, which
    adds ``+0.0`` to a sum taken left to right (:func:`_total`; ``x + 0.0 == x`` for every ``x`` but ``-0.0``,
    and no term of these sums is ``-0.0``: counts, products of non-negative numbers, logarithms of numbers in
    ``(0, 1]``), ``-inf`` to a maximum and no bit to an OR; the entries kept are added in the same order."""
    n = len(valid)
    deg = valid.sum(axis=1)
    # Stable sort of each row: valid entries first, in their order.
    pos = np.argsort(~valid, axis=1, kind="stable")
    succ = np.take_along_axis(succ, pos, axis=1)
    seg = np.take_along_axis(seg, pos, axis=1)
    top = int(deg.max()) if n else 0
    widths = sorted({min(w, top) for w in bucket_widths} | {top})
    parts, lo = [], -1
    for w in widths:
        rows = np.flatnonzero((deg > lo) & (deg <= w))
        lo = w
        if rows.size or (w == widths[-1] and not parts):          # an empty window keeps one empty group
            parts.append((rows, succ[rows, :max(w, 1)], seg[rows, :max(w, 1)]))
    inv = np.empty(n, np.int64)
    inv[np.concatenate([r for r, _, _ in parts])] = np.arange(n)
    return parts, inv


def cell_groups(graph: Graph, k: int) -> tuple[np.ndarray, int]:
    """``(n_k,)`` id of each state of window ``k`` among the distinct (x, y) cells of the window's states, and
    the number of those cells (the grouping of the paper's per-cell count ``c.N_f``)."""
    xy = graph.states[graph.window_start[k]:graph.window_start[k + 1], :2].astype(np.int64)
    _, inv = np.unique(xy[:, 0] * graph.net.n + xy[:, 1], return_inverse=True)
    return inv.reshape(-1), int(inv.max()) + 1 if len(inv) else 0


def cell_sums(graph: Graph, x) -> np.ndarray:
    """(numpy) ``(S,)``: for each state, the sum of ``x`` over the states of its window and (x, y) cell (the
    paper's per-cell count ``c.N_f`` when ``x`` counts trajectories per state)."""
    x = np.asarray(x)
    out = np.zeros_like(x)
    for k in range(graph.net.n_windows + 1):
        sl = slice(graph.window_start[k], graph.window_start[k + 1])
        grp, n_grp = cell_groups(graph, k)
        out[sl] = np.bincount(grp, weights=x[sl], minlength=n_grp)[grp]
    return out


def _pad(x, fill):
    return jnp.concatenate([x, jnp.full((1,), fill, x.dtype)])


def counts(graph: Graph, feasible, kind: str = "all") -> jax.Array:
    """``(S,)`` feasible-trajectory counts to the terminal states of ``kind`` (``goal``, ``alt`` or ``all``),
    given ``feasible`` ``(n_seg,)`` bool."""
    if kind not in ("goal", "alt", "all"):
        raise ValueError(f"kind must be 'goal', 'alt' or 'all'; got {kind!r}.")
    meta, arrays = _consts(graph)
    return _counts(meta, arrays, jnp.asarray(feasible, bool), kind)


@functools.partial(jax.jit, static_argnums=(0, 3))
def _counts(meta: _Meta, c, feasible, kind):
    f_all = _pad(feasible, False)
    K = meta.n_windows

    def term(k):
        tg, ta = c["term_goal"][k], c["term_alt"][k]
        return {"goal": tg, "alt": ta, "all": tg | ta}[kind]

    nxt = term(K).astype(jnp.float32)
    out = [nxt]
    for k in range(K - 1, -1, -1):
        f = f_all[c["seg"][k]]
        cur = jnp.where(term(k), 1.0, jnp.sum(jnp.where(f, _pad(nxt, 0.0)[c["succ"][k]], 0.0), axis=1))
        out.append(cur)
        nxt = cur
    return jnp.concatenate(out[::-1])


def tables(graph: Graph, feasible, robustness, policy: str, omega: str, start: int = 0,
           blocked_bits=None, nf_count: str = "landing") -> Tables:
    """The DP tables of ``policy`` (``R``, ``Nf``, ``S`` or ``AvgR``) for terminal set ``omega`` (``goal`` or
    ``all``), given ``feasible`` ``(n_seg,)`` bool and ``robustness`` ``(n_seg,)`` segment robustness ``p``.
    Windows before ``start`` are not computed (their entries are 0, and ``-inf`` for ``future``).
    ``blocked_bits``: ``(n_seg, W)`` uint32 bit sets of the Monte Carlo realisations blocking each segment; given,
    ``pi_S``'s survivability ``R`` is the fraction of those ``32 W`` realisations in which some trajectory stays
    feasible (exact up to Monte Carlo error); ``None``: the tree recursion ``R = 1 - prod_a (1 - F p R')``.
    ``nf_count``: ``pi_Nf``'s value, ``landing`` (trajectories from the state to any landing site) or ``goal``
    (the paper's per-cell ``c.N_f`` to ``Omega``, see the module docstring)."""
    return tables_many(graph, feasible, robustness, (policy,), omega, start, blocked_bits, nf_count)[policy]


def tables_many(graph: Graph, feasible, robustness, policies, omega: str, start: int = 0,
                blocked_bits=None, nf_count: str = "landing") -> dict[str, Tables]:
    """:func:`tables` of several policies in one sweep (the counts and values they share are computed once)."""
    policies = tuple(policies)
    for policy in policies:
        if policy not in POLICIES:
            raise ValueError(f"unknown policy {policy!r}; allowed: {', '.join(POLICIES)}.")
    if omega not in OMEGAS:
        raise ValueError(f"omega must be 'goal' or 'all'; got {omega!r}.")
    if nf_count not in NF_COUNTS:
        raise ValueError(f"nf_count must be one of {', '.join(NF_COUNTS)}; got {nf_count!r}.")
    if not 0 <= start <= graph.net.n_windows:
        raise ValueError(f"start must be a window in [0, {graph.net.n_windows}]; got {start}.")
    meta, arrays = _consts(graph)
    exact = blocked_bits is not None and "S" in policies
    bits = jnp.asarray(blocked_bits if exact else np.zeros((1, 1), np.uint32), jnp.uint32)
    out = tables_jit(meta, arrays, jnp.asarray(feasible, bool), jnp.asarray(robustness, jnp.float32),
                     jnp.int32(start), bits, policies, omega, exact, nf_count)
    return dict(zip(policies, out))


@functools.partial(jax.jit, static_argnums=(0, 6, 7, 8, 9))
def tables_jit(meta: _Meta, c, feasible, robustness, start, bits, policies, omega, exact, nf_count="landing"):
    """The sweep; windows before ``start`` (a traced integer: one compiled program for every start) are skipped
    by ``lax.cond``."""
    K = meta.n_windows
    f_all = _pad(feasible, False)
    p_all = _pad(robustness, 0.0)
    need_w, need_r = "AvgR" in policies, "S" in policies
    ones = jnp.uint32(0xFFFFFFFF)
    n_words = bits.shape[1]
    # Free realisations of each segment (the padding segment is never free).
    free_bits = jnp.concatenate([~bits, jnp.zeros((1, n_words), jnp.uint32)]) if exact else None

    def value(policy, n_all, w, r, k, n_om):
        if policy == "Nf":
            if nf_count == "goal":
                grp = c["cell_group"][k]
                return jax.ops.segment_sum(n_om, grp, num_segments=meta.n_cell_groups[k])[grp]
            return n_all
        if policy == "S":
            return r
        if policy == "AvgR":
            return jnp.where(n_all > 0, w / jnp.maximum(n_all, 1.0), 0.0)
        return jnp.zeros_like(n_all)

    def step(k, carry):
        n_goal1, n_all1, w1, r1, vs1, js1, reach1 = carry
        tg_k, ta_k = c["term_goal"][k], c["term_goal"][k] | c["term_alt"][k]
        order = c["order"][k]
        padded = {"n_goal": _pad(n_goal1, 0.0), "n_all": _pad(n_all1, 0.0), "w": _pad(w1, 0.0)}
        if need_r and exact:
            padded["reach"] = jnp.concatenate([reach1, jnp.zeros((1, n_words), jnp.uint32)])
        elif need_r:
            padded["r"] = _pad(r1, 0.0)

        def assemble(parts):
            return jnp.concatenate(parts)[order]

        # The counts, W and R of every group of states (see _buckets), then the window's values.
        groups = []
        for rows, succ, seg in c["buckets"][k]:
            f, p = f_all[seg], p_all[seg]
            tg, ta = tg_k[rows], ta_k[rows]
            g = {"f": f, "p": p, "succ": succ, "tg": tg, "ta": ta}
            g["n_goal"] = jnp.where(tg, 1.0, _total(jnp.where(f, padded["n_goal"][succ], 0.0)))
            g["n_all"] = jnp.where(ta, 1.0, _total(jnp.where(f, padded["n_all"][succ], 0.0)))
            if need_w:
                g["w"] = jnp.where(ta, 1.0, _total(jnp.where(f, p * padded["w"][succ], 0.0)))
            if need_r and exact:
                # Realisations in which some trajectory from the state stays free: OR over the primitives of
                # (segment free AND continuation free).
                both = jnp.where(f[..., None], free_bits[seg] & padded["reach"][succ], jnp.uint32(0))
                reach = jax.lax.reduce(both, np.uint32(0), jax.lax.bitwise_or, (1,))
                g["reach"] = jnp.where(ta[:, None], ones, reach)
            elif need_r:
                log_fail = _total(jnp.where(f, jnp.log(jnp.maximum(1.0 - p * padded["r"][succ], 1e-30)), 0.0))
                g["r"] = jnp.where(ta, 1.0, -jnp.expm1(log_fail))
            groups.append(g)
        n_goal = assemble([g["n_goal"] for g in groups])
        n_all = assemble([g["n_all"] for g in groups])
        w = assemble([g["w"] for g in groups]) if need_w else jnp.zeros_like(n_all)
        reach = words(n_all.shape[0])
        r = jnp.zeros_like(n_all)
        if need_r and exact:
            reach = assemble([g["reach"] for g in groups])
            r = jnp.sum(jax.lax.population_count(reach), axis=1).astype(jnp.float32) / (32.0 * n_words)
        elif need_r:
            r = assemble([g["r"] for g in groups])
        n_om = n_goal if omega == "goal" else n_all
        vs, js = {}, {}
        for q in policies:
            vs[q] = value(q, n_all, w, r, k, n_om)
            v1, j1 = _pad(vs1[q], 0.0), _pad(js1[q], NEG)
            parts = []
            for g in groups:
                f, succ = g["f"], g["succ"]
                reward = g["p"] if q == "R" else 0.0
                cand = jnp.where(f, reward + v1[succ] + j1[succ], NEG)
                n_om_g = g["n_goal"] if omega == "goal" else g["n_all"]
                t_om = g["tg"] if omega == "goal" else g["ta"]
                parts.append(jnp.where(n_om_g > 0, jnp.where(t_om, 0.0, jnp.max(cand, axis=1)), NEG))
            js[q] = assemble(parts)
        return n_goal, n_all, w, r, vs, js, reach

    def words(n, ta=None):
        if not exact:
            return jnp.zeros((n, 1), jnp.uint32)
        if ta is None:
            return jnp.zeros((n, n_words), jnp.uint32)
        return jnp.broadcast_to(jnp.where(ta[:, None], ones, jnp.uint32(0)), (n, n_words))

    def skip(k):
        n = meta.window_start[k + 1] - meta.window_start[k]
        zero, neg = jnp.zeros(n, jnp.float32), jnp.full(n, NEG, jnp.float32)
        return zero, zero, zero, zero, {q: zero for q in policies}, {q: neg for q in policies}, words(n)

    tg, ta = c["term_goal"][K], c["term_goal"][K] | c["term_alt"][K]
    n_goal, n_all = tg.astype(jnp.float32), ta.astype(jnp.float32)
    n_om = n_goal if omega == "goal" else n_all
    carry = (n_goal, n_all, n_all, n_all, {q: value(q, n_all, n_all, n_all, K, n_om) for q in policies},
             {q: jnp.where(tg if omega == "goal" else ta, 0.0, NEG) for q in policies}, words(len(n_all), ta))
    outs = [carry]
    for k in range(K - 1, -1, -1):
        carry = jax.lax.cond(k >= start, functools.partial(step, k), lambda _, k=k: skip(k), carry)
        outs.append(carry)
    outs = outs[::-1]

    def cat(i, q=None):
        return jnp.concatenate([o[i] if q is None else o[i][q] for o in outs])

    return tuple(Tables(cat(0), cat(1), cat(4, q), cat(5, q)) for q in policies)


def _total(x):
    """Sum over the primitives (axis 1), left to right: a fixed order of float32 additions, the same on jax and numpy
    arrays, so that :func:`cone_tables` (numpy) repeats the compiled sweep bit for bit (``jnp.sum``'s order is
    XLA's choice)."""
    acc = x[:, 0]
    for a in range(1, x.shape[1]):
        acc = acc + x[:, a]
    return acc


def scores(policy: str, beta: float, tables: Tables, succ, first_robustness):
    """(numpy) The receding-horizon objective (eq. 5) of each primitive, given the successors ``succ`` ``(A,)`` (global
    state indices; invalid entries are masked by the caller) and the first segments' robustness ``(A,)``:

    * ``pi_R``: ``p(s, a) + beta J(s')`` (``J`` sums the robustness of the later segments),
    * ``pi_Nf``: ``N(s') + beta J(s')`` (``J`` sums ``N`` over the later waypoints),
    * ``pi_S``: ``p(s, a) + beta (R(s') + J(s'))``,
    * ``pi_Avg(R)``: ``p(s, a) + beta (W(s') / N(s') + J(s'))``.
    """
    s = np.maximum(succ, 0)
    fut, val = tables.future[s], tables.value[s]
    if policy == "R":
        return first_robustness + beta * fut
    if policy == "Nf":
        return val + beta * fut
    return first_robustness + beta * (val + fut)


def cone(graph: Graph, root: int, limit: int | None = None) -> list[np.ndarray] | None:
    """The states reachable from state ``root``, window by window: ``layers[j]`` (sorted global indices) at window
    ``window_of(root) + j``. A mission at ``root`` only ever visits these, and their DP entries depend only on
    each other. ``limit``: ``None`` as soon as the layers found so far hold more than this many states (the
    caller then sweeps every state instead; the windows are visited in order, so a large cone is abandoned after
    its first large layer)."""
    layers = [np.array([root], np.int64)]
    total = 1
    ws = graph.window_start
    for k in range(graph.window_of(root) + 1, graph.net.n_windows + 1):
        nxt = graph.succ[layers[-1]].ravel()
        mark = np.zeros(ws[k + 1] - ws[k], bool)
        mark[nxt[nxt >= 0] - ws[k]] = True
        layers.append(np.flatnonzero(mark) + ws[k])
        total += len(layers[-1])
        if limit is not None and total > limit:
            return None
    return layers


def cone_applies(policy: str, blocked_bits, nf_count: str) -> bool:
    """Whether :func:`cone_tables` can give ``policy``'s tables (see its ``None`` cases)."""
    return not ((policy == "S" and blocked_bits is None) or (policy == "Nf" and nf_count == "goal"))


def cone_tables(graph: Graph, feasible, robustness, policy: str, omega: str, root: int,
                blocked_bits=None, layers=None, nf_count: str = "landing") -> Tables | None:
    """(numpy) :func:`tables` on the states reachable from ``root`` only (:func:`cone`), equal to it there
    entry for entry (the same float32 operations in the same order: sums run over the primitives left to right in
    both, see :func:`_total`); other entries are 0 (``-inf`` for ``future``). A mission deciding at ``root`` and
    after it reads no other entry. From the third window on the cone holds a few percent of the remaining states
    (:mod:`stp_env.survivability.mission` uses it there). ``None`` when it does not apply: ``pi_S`` without
    ``blocked_bits`` (its tree recursion's logarithms are not reproduced bit for bit in numpy), and ``pi_Nf`` with
    ``nf_count="goal"`` (a cell's count sums states outside the cone). ``layers``: :func:`cone` of ``root``, if
    already computed."""
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; allowed: {', '.join(POLICIES)}.")
    if omega not in OMEGAS:
        raise ValueError(f"omega must be 'goal' or 'all'; got {omega!r}.")
    if nf_count not in NF_COUNTS:
        raise ValueError(f"nf_count must be one of {', '.join(NF_COUNTS)}; got {nf_count!r}.")
    if not cone_applies(policy, blocked_bits, nf_count):
        return None
    feasible = np.asarray(feasible, bool)
    robustness = np.asarray(robustness, np.float32)
    layers = cone(graph, root) if layers is None else layers
    S = graph.n_states
    out = Tables(np.zeros(S, np.float32), np.zeros(S, np.float32), np.zeros(S, np.float32),
                 np.full(S, -np.inf, np.float32))
    f32 = np.float32
    n_words = 0 if blocked_bits is None else blocked_bits.shape[1]
    nxt = None
    for layer in layers[::-1]:
        tg = graph.term_goal[layer]
        ta = tg | graph.term_alt[layer]
        t_om = tg if omega == "goal" else ta
        if nxt is None:                                                     # the last window: terminal values
            n_goal, n_all = tg.astype(f32), ta.astype(f32)
            w = n_all
            reach = np.where(ta[:, None], np.uint32(0xFFFFFFFF), np.uint32(0)) * np.ones((1, n_words), np.uint32)
            r = n_all
            fut = np.where(t_om, f32(0.0), f32(-np.inf))
        else:
            n_goal1, n_all1, w1, reach1, v1, j1, nlayer = nxt
            succ = graph.succ[layer]
            ok = succ >= 0
            pos = np.where(ok, np.searchsorted(nlayer, np.where(ok, succ, 0)), len(nlayer))   # pad row last
            seg = graph.seg[layer]
            f = ok & feasible[np.where(ok, seg, 0)]
            p = np.where(ok, robustness[np.where(ok, seg, 0)], f32(0.0))

            def at(x, fill=0.0, pos=pos):
                return np.concatenate([x, np.array([fill], f32)])[pos]

            zero = f32(0.0)
            n_goal = np.where(tg, f32(1.0), _total(np.where(f, at(n_goal1), zero)))
            n_all = np.where(ta, f32(1.0), _total(np.where(f, at(n_all1), zero)))
            w = np.where(ta, f32(1.0), _total(np.where(f, p * at(w1), zero))) if policy == "AvgR" else None
            r = reach = None
            if policy == "S":
                free = ~blocked_bits[np.where(ok, seg, 0)]                                  # (n, A, W)
                cont = np.concatenate([reach1, np.zeros((1, n_words), np.uint32)])[pos]
                both = np.where(f[..., None], free & cont, np.uint32(0))
                reach = np.bitwise_or.reduce(both, axis=1)
                reach = np.where(ta[:, None], np.uint32(0xFFFFFFFF), reach)
                r = (np.bitwise_count(reach).astype(np.int32).sum(axis=1).astype(f32) / f32(32.0 * n_words))
            n_om = n_goal if omega == "goal" else n_all
            reward = p if policy == "R" else zero
            cand = np.where(f, reward + at(v1) + at(j1, -np.inf), f32(-np.inf))
            fut = np.where(n_om > 0, np.where(t_om, zero, cand.max(axis=1)), f32(-np.inf))
        if policy == "Nf":
            v = n_all
        elif policy == "S":
            v = r
        elif policy == "AvgR":
            v = np.where(n_all > 0, w / np.maximum(n_all, f32(1.0)), f32(0.0))
        else:
            v = np.zeros_like(n_all)
        out.n_goal[layer], out.n_all[layer], out.value[layer], out.future[layer] = n_goal, n_all, v, fut
        nxt = (n_goal, n_all, w, reach, v, fut, layer)
    return out
