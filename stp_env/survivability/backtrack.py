"""The survivability paper's backtracking algorithm (Section III-A, Algorithms 1-2), literally: lists of states.

Starting from the terminal states, every unvisited state of window ``t`` is expanded backward with every primitive
(``ExpandPrune``); a generated state is kept if the segment joining it to its ancestor is feasible (Assumption II.2)
and it is forward reachable from the origin (inequality 4), and it becomes one unvisited state of window ``t - 1``.
Each kept state stands for one feasible trajectory from it to a terminal state, so the number of feasible
trajectories of a cell is the number of states generated in it. A generated state that is itself terminal is not
kept (a trajectory ends at its first terminal state, as in :mod:`stp_env.survivability.dp`).

The lists grow like the number of trajectories, so this is for small networks: it is the independent check of the
dynamic programs (same counts, state by state).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from stp_env.survivability.network import Network


def segment_free(net: Network, x: int, y: int, k: int, move: int, blocked: set) -> bool:
    """Assumption II.2: every (cell, minute) the segment occupies is inside the area and not in ``blocked``
    (a set of ``(x, y, minute)``); the segment's end must be inside the area."""
    dx, dy = net.moves[move]
    if not (0 <= x + dx < net.n and 0 <= y + dy < net.n):
        return False
    for cx, cy, t in net.segment_cells(x, y, k, move):
        if (int(cx), int(cy), int(t)) in blocked:
            return False
    return True


def terminal_states(net: Network, k: int, kind: str) -> list[tuple[int, int, int, int]]:
    out = []
    if kind in ("goal", "all") and net.goal_windows[0] <= k <= net.goal_windows[1]:
        out += [(*net.goal, h, 0) for h in np.flatnonzero(net.goal_heading_mask)]
    if kind in ("alt", "all") and 1 <= k <= net.n_windows:
        for c in net.alternates:
            out += [(*c, h, 0) for h in np.flatnonzero(net.alt_heading_mask)]
    return [tuple(int(v) for v in s) for s in out]


def backtrack_counts(net: Network, blocked=frozenset(), kind: str = "goal", limit: int = 2_000_000):
    """Run Algorithms 1-2. Returns ``(state_counts, cell_counts)``: ``Counter`` keyed by ``(k, x, y, h, v)`` and by
    ``(k, x, y)`` of the trajectories from each state/cell to a terminal state of ``kind``. Raises
    ``ValueError`` if more than ``limit`` states are generated (the network is too large for this method)."""
    K = net.n_windows
    speed_km = net.mission.v_max * net.mission.window_min * 60.0 / 1000.0 / net.mission.cell_km  # cells/window
    ox, oy = net.origin
    terminal = {k: set(terminal_states(net, k, kind)) for k in range(K + 1)}
    unvisited = {k: list(terminal[k]) for k in range(K + 1)}
    states = Counter()
    for k in range(K + 1):
        for s in unvisited[k]:
            states[(k, *s)] += 1
    generated = 0
    for t in range(K, 0, -1):
        for s in unvisited[t]:
            x, y, h, v = s
            for dh, dv in net.primitives:
                hp, vp = (h - int(dh)) % net.n_headings, v - int(dv)
                if not 0 <= vp < net.n_speeds:
                    continue
                dx, dy = net.disp[h, v]
                xp, yp = x - int(dx), y - int(dy)
                if not (0 <= xp < net.n and 0 <= yp < net.n):
                    continue
                prev = (xp, yp, hp, vp)
                if prev in terminal[t - 1]:
                    continue
                # Inequality 4: the new state must be forward reachable from the origin by window t - 1.
                if math.hypot(xp - ox, yp - oy) > speed_km * (t - 1) + 1e-9:
                    continue
                if not segment_free(net, xp, yp, t - 1, int(net.move_of[h, v]), blocked):
                    continue
                unvisited[t - 1].append(prev)
                states[(t - 1, *prev)] += 1
                generated += 1
                if generated > limit:
                    raise ValueError(f"backtracking generated more than {limit} states; use the DP instead.")
    cells = Counter()
    for (k, x, y, _h, _v), c in states.items():
        cells[(k, x, y)] += c
    return states, cells
