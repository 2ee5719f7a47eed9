"""Feasible-trajectory counts over the dense network (every cell, heading and speed of every window).

One backward sweep: ``N_k(s) = 1`` at a terminal state of window ``k``, else the sum over the primitives of
``F_k(s, a) N_{k+1}(s')`` (see :mod:`stp_env.survivability.dp`). The sums over the 25 primitives are separable in
(heading change, speed change), so a window costs a handful of passes over the ``85 x 85 x 24 x 9`` states. Used
to find the states a mission can use (:mod:`stp_env.survivability.graph`), for maps of the counts per cell, and as
a check of the compact-graph programs.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.survivability.network import Network

NEG = -jnp.inf


class _Static(NamedTuple):
    """Hashable shape information (a static argument: networks of the same shapes share compiled sweeps)."""

    n_headings: int
    n_speeds: int
    n_windows: int
    half: int              # speed-change steps each way
    dh: tuple              # the distinct heading changes
    goal_windows: tuple
    pad: int


class _Arrays(NamedTuple):
    ix: jax.Array          # (X, 1, H, V) padded-grid x index of each state's successor under (h, v)
    iy: jax.Array          # (1, Y, H, V)
    move_of: jax.Array     # (H, V)
    goal_cell: jax.Array   # (X, Y) bool
    alt_cell: jax.Array    # (X, Y) bool
    goal_h: jax.Array      # (H,) bool
    alt_h: jax.Array       # (H,) bool


def terminal(st: _Static, a: _Arrays, k, kind: str) -> jax.Array:
    """``(X, Y, H, V)`` bool: terminal states at window ``k`` (``kind``: ``goal``, ``alt`` or ``all``)."""
    v0 = jnp.arange(st.n_speeds) == 0
    g0, g1 = st.goal_windows
    goal = a.goal_cell[:, :, None, None] & a.goal_h[None, None, :, None] & v0 & (k >= g0) & (k <= g1)
    alt = a.alt_cell[:, :, None, None] & a.alt_h[None, None, :, None] & v0 & (k >= 1) & (k <= st.n_windows)
    return {"goal": goal, "alt": alt, "all": goal | alt}[kind]


def successor_values(st: _Static, a: _Arrays, table_next, fill=0.0):
    """``(X, Y, H, V)``: ``table_next`` at the successor of each (cell, new heading, new speed)."""
    p = st.pad
    padded = jnp.pad(table_next, ((p, p), (p, p), (0, 0), (0, 0)), constant_values=fill)
    h = jnp.arange(st.n_headings)[None, None, :, None]
    v = jnp.arange(st.n_speeds)[None, None, None, :]
    return padded[a.ix, a.iy, h, v]


def over_actions(st: _Static, g, op: str):
    """Combine ``g[x, y, h', v']`` over the primitives reaching ``(h', v')`` from each ``(h, v)``: ``op`` is
    ``sum`` or ``max`` (empty: 0 or -inf). Separable in (heading change, speed change)."""
    half = st.half
    fill = 0.0 if op == "sum" else NEG
    comb = jnp.add if op == "sum" else jnp.maximum
    gv = jnp.pad(g, ((0, 0), (0, 0), (0, 0), (half, half)), constant_values=fill)
    nv = st.n_speeds
    acc = gv[..., 0:nv]
    for dv in range(1, 2 * half + 1):
        acc = comb(acc, gv[..., dv:dv + nv])
    out = acc
    for dh in st.dh:
        if dh:
            out = comb(out, jnp.roll(acc, -dh, axis=2))
    return out


@functools.lru_cache(maxsize=8)
def solver(net: Network) -> tuple[_Static, _Arrays]:
    n, pad = net.n, net.max_reach
    xs = np.arange(n)
    ix = xs[:, None, None, None] + pad + net.disp[None, None, :, :, 0]
    iy = xs[None, :, None, None] + pad + net.disp[None, None, :, :, 1]
    goal_cell = np.zeros((n, n), bool)
    goal_cell[net.goal] = True
    alt_cell = np.zeros((n, n), bool)
    for c in net.alternates:
        alt_cell[c] = True
    st = _Static(net.n_headings, net.n_speeds, net.n_windows, (net.mission.n_increments - 1) // 2,
                 tuple(sorted({int(d) for d in net.primitives[:, 0]})), tuple(net.goal_windows), pad)
    arrays = _Arrays(jnp.asarray(ix, jnp.int32), jnp.asarray(iy, jnp.int32), jnp.asarray(net.move_of),
                     jnp.asarray(goal_cell), jnp.asarray(alt_cell), jnp.asarray(net.goal_heading_mask),
                     jnp.asarray(net.alt_heading_mask))
    return st, arrays


def counts(net: Network, feasible, kind: str = "all"):
    """``(K + 1, X, Y, H, V)`` numbers of feasible trajectories to the terminal states of ``kind`` (``goal``,
    ``alt`` or ``all``), given ``feasible`` ``(K, X, Y, M)`` bool segment feasibility."""
    if kind not in ("goal", "alt", "all"):
        raise ValueError(f"kind must be 'goal', 'alt' or 'all'; got {kind!r}.")
    st, arrays = solver(net)
    return _counts(st, arrays, jnp.asarray(feasible), kind)


@functools.partial(jax.jit, static_argnums=(0, 3))
def _counts(st: _Static, a: _Arrays, feasible, kind):
    K = st.n_windows

    def step(nxt, k):
        term = terminal(st, a, k, kind)
        g = feasible[k][:, :, a.move_of] * successor_values(st, a, nxt)
        cur = jnp.where(term, 1.0, over_actions(st, g, "sum"))
        return cur, cur

    last = terminal(st, a, K, kind).astype(jnp.float32)
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
