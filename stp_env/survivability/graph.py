"""The part of the network a mission can use, as a compact graph: states reachable from the origin that can still
reach some landing site with no traffic at all, their transitions and the segments and cells behind them.

Traffic only removes segments, so every state and segment a mission can ever use is in this graph. On the paper's
Bay-Area mission it has about 53 thousand states (of 1.6 million per window in the dense network), 378 thousand
transitions, 44 thousand distinct segments and their cells, which makes the dynamic programs of
:mod:`stp_env.survivability.dp` a few milliseconds each.

Indexing: states are numbered window by window (``window_start[k] <= g < window_start[k + 1]``); ``succ[g, a]`` is
the global index of the successor under primitive ``a`` (``-1``: the speed leaves its range, the end leaves the
area or the successor cannot reach any site); ``seg[g, a]`` the segment id (``-1`` likewise). ``cells`` lists every
(x, y, minute) a segment occupies; ``seg_cells[s]`` holds segment ``s``'s cell ids (``-1`` padding) and
``cell_id`` maps a dense ``(minute, x, y)`` to a cell id (``-1``: no segment uses it).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from stp_env.survivability import dense
from stp_env.survivability.network import Network, build_network


@dataclasses.dataclass(frozen=True, eq=False)
class Graph:
    net: Network
    window_start: np.ndarray   # (K + 2,) int: states of window k are window_start[k] .. window_start[k + 1] - 1
    states: np.ndarray         # (S, 4) int: (x, y, h, v)
    succ: np.ndarray           # (S, A) int
    seg: np.ndarray            # (S, A) int
    term_goal: np.ndarray      # (S,) bool
    term_alt: np.ndarray       # (S,) bool
    segments: np.ndarray       # (n_seg, 4) int: (window, x, y, move)
    seg_cells: np.ndarray      # (n_seg, O) int
    cells: np.ndarray          # (n_cells, 3) int: (x, y, minute)
    cell_id: np.ndarray        # (n_minutes, X, Y) int

    @property
    def n_states(self) -> int:
        return int(self.states.shape[0])

    @property
    def n_segments(self) -> int:
        return int(self.segments.shape[0])

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @property
    def origin(self) -> int:
        return 0

    def window_of(self, g: int) -> int:
        return int(np.searchsorted(self.window_start, g, side="right") - 1)

    def index(self, k: int, state) -> int:
        """Global index of ``state = (x, y, h, v)`` at window ``k`` (``-1`` if not in the graph)."""
        lo, hi = self.window_start[k], self.window_start[k + 1]
        hit = np.nonzero((self.states[lo:hi] == np.asarray(state)).all(axis=1))[0]
        return int(lo + hit[0]) if hit.size else -1


@functools.lru_cache(maxsize=4)
def build_graph(net: Network | None = None) -> Graph:
    """The compact graph of ``net`` (default: the paper's mission). Cached per network."""
    net = build_network() if net is None else net
    K, n, A = net.n_windows, net.n, net.n_actions
    free = dense.free_feasibility(net)
    alive = np.asarray(dense.counts(net, free, "all")) > 0            # (K + 1, X, Y, H, V): can reach a site
    if not alive[0][net.origin_state()]:
        raise ValueError("the mission is infeasible with no traffic: no trajectory from the origin reaches any site.")
    layers = [np.array([net.origin_state()], np.int64)]
    trans = []
    for k in range(K):
        cur = layers[-1]
        x, y, h, v = cur.T
        dh, dv = net.primitives[:, 0], net.primitives[:, 1]
        h2 = (h[:, None] + dh[None]) % net.n_headings                # (n_k, A)
        v2 = v[:, None] + dv[None]
        ok = (v2 >= 0) & (v2 < net.n_speeds)
        v2c = np.clip(v2, 0, net.n_speeds - 1)
        d = net.disp[h2, v2c]
        x2, y2 = x[:, None] + d[..., 0], y[:, None] + d[..., 1]
        ok &= (x2 >= 0) & (x2 < n) & (y2 >= 0) & (y2 < n)
        x2c, y2c = np.clip(x2, 0, n - 1), np.clip(y2, 0, n - 1)
        ok &= alive[k + 1][x2c, y2c, h2, v2c]
        key = ((x2c * n + y2c) * net.n_headings + h2) * net.n_speeds + v2c
        uniq, inv = np.unique(np.where(ok, key, -1), return_inverse=True)
        inv = inv.reshape(ok.shape)
        has_dead = uniq[0] == -1
        nxt_keys = uniq[1:] if has_dead else uniq
        local = np.where(ok, inv - (1 if has_dead else 0), -1)
        hv = nxt_keys % (net.n_headings * net.n_speeds)
        xy = nxt_keys // (net.n_headings * net.n_speeds)
        layers.append(np.stack([xy // n, xy % n, hv // net.n_speeds, hv % net.n_speeds], 1))
        move = net.move_of[h2, v2c]
        trans.append((local, ok, x[:, None].repeat(A, 1), y[:, None].repeat(A, 1), move))
    sizes = np.array([len(s) for s in layers])
    start = np.concatenate([[0], np.cumsum(sizes)])
    states = np.concatenate(layers).astype(np.int32)
    S = len(states)
    succ = -np.ones((S, A), np.int32)
    seg_key = -np.ones((S, A), np.int64)
    M = net.n_moves
    for k, (local, ok, sx, sy, move) in enumerate(trans):
        sl = slice(start[k], start[k + 1])
        succ[sl] = np.where(ok, local + start[k + 1], -1)
        seg_key[sl] = np.where(ok, ((k * n + sx) * n + sy) * M + move, -1)
    keys, seg = np.unique(seg_key, return_inverse=True)
    seg = seg.reshape(S, A)
    if keys[0] == -1:
        keys, seg = keys[1:], seg - 1
    seg = np.where(succ >= 0, seg, -1).astype(np.int32)
    segments = np.stack([keys // (n * n * M), (keys // (n * M)) % n, (keys // M) % n, keys % M], 1).astype(np.int32)

    # Cells of every segment.
    off = net.offsets[segments[:, 3]]                                # (n_seg, O, 3)
    valid = net.offset_valid[segments[:, 3]]
    t0 = np.array([net.window_start_minute(k) for k in range(K)])[segments[:, 0]]
    cx = segments[:, 1, None] + off[..., 0]
    cy = segments[:, 2, None] + off[..., 1]
    ct = t0[:, None] + off[..., 2]
    inside = valid & (cx >= 0) & (cx < n) & (cy >= 0) & (cy < n)    # cells off the area are never blocked
    n_min = net.mission.n_minutes
    flat = np.where(inside, (ct * n + cx) * n + cy, -1)
    cell_keys, inv = np.unique(flat, return_inverse=True)
    inv = inv.reshape(flat.shape)
    if cell_keys[0] == -1:
        cell_keys, inv = cell_keys[1:], inv - 1
    seg_cells = np.where(inside, inv, -1).astype(np.int32)
    cells = np.stack([(cell_keys // n) % n, cell_keys % n, cell_keys // (n * n)], 1).astype(np.int32)
    cell_id = -np.ones((n_min, n, n), np.int32)
    cell_id[cells[:, 2], cells[:, 0], cells[:, 1]] = np.arange(len(cells), dtype=np.int32)

    g0, g1 = net.goal_windows
    win = np.repeat(np.arange(K + 1), sizes)
    at_goal = (states[:, 0] == net.goal[0]) & (states[:, 1] == net.goal[1])
    term_goal = at_goal & (states[:, 3] == 0) & net.goal_heading_mask[states[:, 2]] & (win >= g0) & (win <= g1)
    at_alt = np.zeros(S, bool)
    for c in net.alternates:
        at_alt |= (states[:, 0] == c[0]) & (states[:, 1] == c[1])
    term_alt = at_alt & (states[:, 3] == 0) & net.alt_heading_mask[states[:, 2]] & (win >= 1)
    arrays = (start, states, succ, seg, term_goal, term_alt, segments, seg_cells, cells, cell_id)
    for arr in arrays:
        arr.setflags(write=False)
    return Graph(net, *arrays)


def feasible_from_blocked(graph: Graph, blocked) -> np.ndarray:
    """``(n_seg,)`` bool segment feasibility given ``blocked`` ``(n_minutes, X, Y)`` bool cells."""
    blocked = np.asarray(blocked, bool)
    cell_blocked = np.append(blocked[graph.cells[:, 2], graph.cells[:, 0], graph.cells[:, 1]], False)
    return ~cell_blocked[graph.seg_cells].any(axis=1)


@functools.lru_cache(maxsize=4)
def _cell_segments(graph: Graph) -> tuple[np.ndarray, np.ndarray]:
    """``(indptr, segs)``: the segments through each cell (``segs[indptr[c]:indptr[c + 1]]``, sorted)."""
    seg, slot = np.nonzero(graph.seg_cells >= 0)
    cell = graph.seg_cells[seg, slot]
    order = np.argsort(cell, kind="stable")
    indptr = np.zeros(graph.n_cells + 1, np.int64)
    np.cumsum(np.bincount(cell, minlength=graph.n_cells), out=indptr[1:])
    return indptr, seg[order]


def segments_through(graph: Graph, cells) -> np.ndarray:
    """The segments (with repeats) through any of ``cells`` (cell ids)."""
    indptr, segs = _cell_segments(graph)
    cells = np.asarray(cells, np.int64)
    lo, n = indptr[cells], indptr[cells + 1] - indptr[cells]
    if not n.sum():
        return np.zeros(0, np.int64)
    start = np.repeat(lo - np.cumsum(n) + n, n)
    return segs[start + np.arange(n.sum())]
