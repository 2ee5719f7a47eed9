"""Feasible-trajectory counts over the dense network (every cell, heading and speed of every window).

One backward sweep: ``N_k(s) = 1`` at a terminal state of window ``k``, else the sum over the primitives of
``F_k(s, a) N_{k+1}(s')`` (see :mod:`stp_env.survivability.dp`). The sums over the 25 primitives are separable in
(heading change, speed change), so a window costs a handful of passes over the ``85 x 85 x 24 x 9`` states. Used
to find the states a mission can use (:mod:`stp_env.survivability.graph`), for maps of the counts per cell, and as
a check of the compact-graph programs.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.survivability.network import Network

NEG = -jnp.inf


@dataclasses.dataclass(frozen=True, eq=False)
class Solver:
    """Jitted DP sweeps over a :class:`Network` (built once per network by :func:`solver`)."""

    net: Network
    ix: jax.Array          # (X, 1, H, V) padded-grid x index of each state's successor under (h, v)
    iy: jax.Array          # (1, Y, H, V)
    move_of: jax.Array     # (H, V)
    pad: int
    goal_cell: jax.Array   # (X, Y) bool
    alt_cell: jax.Array    # (X, Y) bool
    goal_h: jax.Array      # (H,) bool
    alt_h: jax.Array       # (H,) bool

    def terminal(self, k, kind: str) -> jax.Array:
        """``(X, Y, H, V)`` bool: terminal states at window ``k`` (``kind``: ``goal``, ``alt`` or ``all``)."""
        net = self.net
        v0 = jnp.arange(net.n_speeds) == 0
        g0, g1 = net.goal_windows
        goal = (self.goal_cell[:, :, None, None] & self.goal_h[None, None, :, None] & v0
                & (k >= g0) & (k <= g1))
        alt = self.alt_cell[:, :, None, None] & self.alt_h[None, None, :, None] & v0 & (k >= 1) & (k <= net.n_windows)
        return {"goal": goal, "alt": alt, "all": goal | alt}[kind]

    # ---- one backward step ------------------------------------------------------------------------------------
    def successor_values(self, table_next, fill=0.0):
        """``(X, Y, H, V)``: ``table_next`` at the successor of each (cell, new heading, new speed)."""
        p = self.pad
        padded = jnp.pad(table_next, ((p, p), (p, p), (0, 0), (0, 0)), constant_values=fill)
        h = jnp.arange(self.net.n_headings)[None, None, :, None]
        v = jnp.arange(self.net.n_speeds)[None, None, None, :]
        return padded[self.ix, self.iy, h, v]

    def per_new_state(self, seg_table):
        """``(X, Y, M)`` segment table -> ``(X, Y, H, V)`` by the (new heading, new speed) of each move."""
        return seg_table[:, :, self.move_of]

    def over_actions(self, g, op: str):
        """Combine ``g[x, y, h', v']`` over the primitives reaching ``(h', v')`` from each ``(h, v)``: ``op`` is
        ``sum`` or ``max`` (empty: 0 or -inf)."""
        half = (self.net.mission.n_increments - 1) // 2
        fill = 0.0 if op == "sum" else NEG
        comb = jnp.add if op == "sum" else jnp.maximum
        gv = jnp.pad(g, ((0, 0), (0, 0), (0, 0), (half, half)), constant_values=fill)
        nv = self.net.n_speeds
        acc = gv[..., 0:nv]
        for dv in range(1, 2 * half + 1):
            acc = comb(acc, gv[..., dv:dv + nv])
        out = acc
        for dh in sorted({int(d) for d in self.net.primitives[:, 0]}):
            if dh:
                out = comb(out, jnp.roll(acc, -dh, axis=2))
        return out


@functools.lru_cache(maxsize=4)
def solver(net: Network) -> Solver:
    H, V, n = net.n_headings, net.n_speeds, net.n
    pad = net.max_reach
    xs = np.arange(n)
    ix = xs[:, None, None, None] + pad + net.disp[None, None, :, :, 0]
    iy = xs[None, :, None, None] + pad + net.disp[None, None, :, :, 1]
    goal_cell = np.zeros((n, n), bool)
    goal_cell[net.goal] = True
    alt_cell = np.zeros((n, n), bool)
    for c in net.alternates:
        alt_cell[c] = True
    del H, V
    return Solver(net=net, ix=jnp.asarray(ix, jnp.int32), iy=jnp.asarray(iy, jnp.int32),
                  move_of=jnp.asarray(net.move_of), pad=pad, goal_cell=jnp.asarray(goal_cell),
                  alt_cell=jnp.asarray(alt_cell), goal_h=jnp.asarray(net.goal_heading_mask),
                  alt_h=jnp.asarray(net.alt_heading_mask))


def counts(net: Network, feasible, kind: str = "all"):
    """``(K + 1, X, Y, H, V)`` numbers of feasible trajectories to the terminal states of ``kind`` (``goal``,
    ``alt`` or ``all``), given ``feasible`` ``(K, X, Y, M)`` bool segment feasibility."""
    return _counts(solver(net), jnp.asarray(feasible), kind)


@functools.partial(jax.jit, static_argnums=(0, 2))
def _counts(sv: Solver, feasible, kind):
    K = sv.net.n_windows

    def step(nxt, k):
        term = sv.terminal(k, kind)
        g = sv.per_new_state(feasible[k]) * sv.successor_values(nxt)
        cur = jnp.where(term, 1.0, sv.over_actions(g, "sum"))
        return cur, cur

    last = sv.terminal(K, kind).astype(jnp.float32)
    _, out = jax.lax.scan(step, last, jnp.arange(K - 1, -1, -1))
    return jnp.concatenate([out[::-1], last[None]], 0)


def free_feasibility(net: Network) -> np.ndarray:
    """``(K, X, Y, M)`` bool: segment feasibility with no traffic (both ends inside the area)."""
    n = net.n
    x = np.arange(n)
    ex = x[:, None, None] + net.moves[None, None, :, 0]
    ey = x[None, :, None] + net.moves[None, None, :, 1]
    inside = (ex >= 0) & (ex < n) & (ey >= 0) & (ey < n)
    return np.broadcast_to(inside, (net.n_windows, *inside.shape)).copy()


def feasibility_from_blocked(net: Network, blocked) -> np.ndarray:
    """``(K, X, Y, M)`` bool: segment feasibility given ``blocked`` ``(n_minutes, X, Y)`` bool cells (both ends
    inside the area; cells outside the area are never blocked)."""
    blocked = np.asarray(blocked, bool)
    n = net.n
    out = free_feasibility(net)
    pad = net.max_reach + int(np.abs(net.offsets[..., :2]).max()) + 1
    bp = np.pad(blocked, ((0, 0), (pad, pad), (pad, pad)))
    x = np.arange(n)
    for k in range(net.n_windows):
        t0 = net.window_start_minute(k)
        for m in range(net.n_moves):
            hit = np.zeros((n, n), bool)
            for ox, oy, j in net.offsets[m][net.offset_valid[m]]:
                t = t0 + j
                if t < blocked.shape[0]:
                    hit |= bp[t, pad + ox + x[:, None], pad + oy + x[None, :]]
            out[k, :, :, m] &= ~hit
    return out
