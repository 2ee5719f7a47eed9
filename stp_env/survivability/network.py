"""The discrete space-time network of the survivability paper (Section II, Fig. 2), as static numpy tables.

A **state** at decision window ``k`` (``k = 0`` is the start of cruise) is ``(x, y, h, v)``: the cell the ownship
is in (cell centres, ``cell_km`` apart), its heading index ``h`` (``heading_step`` degrees per index, 0 = east,
counter-clockwise) and its speed index ``v`` (``speed_step`` m/s per index), both those of the window just flown.
A **primitive** ``a = (dh, dv)`` (``n_increments`` x ``n_increments`` of them, paper: 25) applied at decision ``k``
sets the heading and speed of window ``k`` (held constant, Section II); the ownship then moves by
``v' window (cos h', sin h')``, rounded to whole cells (halves away from zero; positions stay on cell centres:
the network's choice of cell rasterisation). The straight line between the two cell centres, over the window's
``minutes_per_window`` time cells, is the **segment** (Assumption II.2); it is identified by its start cell, its
window and its **move** ``m`` (the distinct displacements, :attr:`Network.moves`). A segment *occupies* every
(cell, minute) whose square lies closer than ``separation_km`` to the part of the line flown in that minute (the
cells it crosses when the separation is 0); an intruder in any of them blocks it.

A trajectory starts at the origin cell with speed 0 and ``departure_heading``, and ends at a **terminal state**: the
goal cell with speed 0 and a goal heading, at a window whose landing falls inside the RTA; or an alternative site's
cell with speed 0 and an alternative-site heading, at any window up to the endurance (Definition II.1).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from stp_env.survivability.config import MissionConfig


@dataclasses.dataclass(frozen=True, eq=False)
class Network:
    """Static tables of a mission's network (see the module docstring). Arrays are numpy, read-only."""

    mission: MissionConfig
    n: int                      # cells per side
    n_headings: int
    n_speeds: int
    n_windows: int              # cruise windows K; decisions at k = 0 .. K - 1, states at k = 0 .. K
    minutes_per_window: int
    primitives: np.ndarray      # (A, 2) int: (dh, dv) in index steps
    disp: np.ndarray            # (H, V, 2) int: cells moved in a window flown at heading h, speed v
    move_of: np.ndarray         # (H, V) int: move index of (h, v)
    moves: np.ndarray           # (M, 2) int: the distinct displacements
    offsets: np.ndarray         # (M, O, 3) int: (dx, dy, minute) of the cells a move occupies, padded
    offset_valid: np.ndarray    # (M, O) bool
    origin: tuple[int, int]
    origin_heading: int
    goal: tuple[int, int]
    alternates: tuple[tuple[int, int], ...]
    goal_heading_mask: np.ndarray   # (H,) bool
    alt_heading_mask: np.ndarray    # (H,) bool
    goal_windows: tuple[int, int]   # first and last window at which an arrival at the goal meets the RTA
    site_km: dict

    @property
    def n_moves(self) -> int:
        return int(self.moves.shape[0])

    @property
    def n_actions(self) -> int:
        return int(self.primitives.shape[0])

    @property
    def max_reach(self) -> int:
        return int(np.abs(self.moves).max())

    def state_shape(self) -> tuple[int, int, int, int]:
        return (self.n, self.n, self.n_headings, self.n_speeds)

    def successor(self, state, action: int):
        """``(x, y, h, v)`` after primitive ``action``, or ``None`` if the speed leaves its range (host helper)."""
        x, y, h, v = (int(s) for s in state)
        dh, dv = self.primitives[action]
        v2 = v + int(dv)
        if not 0 <= v2 < self.n_speeds:
            return None
        h2 = (h + int(dh)) % self.n_headings
        dx, dy = self.disp[h2, v2]
        return (x + int(dx), y + int(dy), h2, v2)

    def segment_cells(self, x: int, y: int, k: int, move: int) -> np.ndarray:
        """The (x, y, minute) cells a segment occupies (absolute minute of departure time; host helper)."""
        off = self.offsets[move][self.offset_valid[move]]
        t0 = self.window_start_minute(k)
        return np.stack([x + off[:, 0], y + off[:, 1], t0 + off[:, 2]], axis=1)

    def window_start_minute(self, k: int) -> int:
        """Minute (since departure) at which cruise window ``k`` starts."""
        m = self.mission
        return round((m.takeoff_min + k * m.window_min) / m.cell_min)

    def is_goal_terminal(self, state, k: int) -> bool:
        x, y, h, v = (int(s) for s in state)
        return ((x, y) == self.goal and v == 0 and bool(self.goal_heading_mask[h])
                and self.goal_windows[0] <= k <= self.goal_windows[1])

    def is_alt_terminal(self, state, k: int) -> bool:
        x, y, h, v = (int(s) for s in state)
        return (x, y) in self.alternates and v == 0 and bool(self.alt_heading_mask[h]) and 1 <= k <= self.n_windows

    def origin_state(self) -> tuple[int, int, int, int]:
        return (*self.origin, self.origin_heading, 0)


def segment_box_distance(a, b, lo) -> np.ndarray:
    """Distance between the segment ``[a, b]`` (2-vectors) and each unit square ``[lo, lo + 1]`` (``lo``:
    ``(..., 2)``); 0 when they touch."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    lo = np.asarray(lo, float)
    hi = lo + 1.0
    d = b - a
    # Liang-Barsky clipping, per square: the parameter interval [t0, t1] of the segment inside the square.
    t0 = np.zeros(lo.shape[:-1])
    t1 = np.ones(lo.shape[:-1])
    hit = np.ones(lo.shape[:-1], bool)
    for i in range(2):
        if abs(d[i]) < 1e-12:
            hit &= (a[i] >= lo[..., i]) & (a[i] <= hi[..., i])
        else:
            ta, tb = (lo[..., i] - a[i]) / d[i], (hi[..., i] - a[i]) / d[i]
            t0 = np.maximum(t0, np.minimum(ta, tb))
            t1 = np.minimum(t1, np.maximum(ta, tb))
    hit &= t0 <= t1

    def point_box(p):
        return np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=-1)

    den = float(d @ d)

    def point_segment(p):
        t = np.zeros(p.shape[:-1]) if den == 0.0 else np.clip(((p - a) @ d) / den, 0.0, 1.0)
        return np.linalg.norm(a + t[..., None] * d - p, axis=-1)

    corners = [lo, np.stack([hi[..., 0], lo[..., 1]], -1), hi, np.stack([lo[..., 0], hi[..., 1]], -1)]
    dist = np.minimum(point_box(a), point_box(b))
    for c in corners:
        dist = np.minimum(dist, point_segment(c))
    return np.where(hit, 0.0, dist)


def segment_offsets(disp: tuple[int, int], minutes: int, separation: float) -> np.ndarray:
    """(dx, dy, minute) of the cells a segment from the centre of cell (0, 0) to the centre of cell ``disp``
    occupies over ``minutes`` time cells (each minute the part of the line flown in it), with the separation
    radius in cells. Sorted, unique."""
    start = np.array([0.5, 0.5])
    d = np.asarray(disp, float)
    reach = math.ceil(separation) + 1
    out = []
    for j in range(minutes):
        a, b = start + d * j / minutes, start + d * (j + 1) / minutes
        xs = np.arange(math.floor(min(a[0], b[0])) - reach, math.floor(max(a[0], b[0])) + reach + 1)
        ys = np.arange(math.floor(min(a[1], b[1])) - reach, math.floor(max(a[1], b[1])) + reach + 1)
        lo = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
        dist = segment_box_distance(a, b, lo)
        keep = (dist <= 1e-9) if separation <= 0 else (dist < separation - 1e-9)
        out.extend((int(cx), int(cy), j) for cx, cy in lo[keep])
    return np.array(sorted(set(out)), dtype=np.int32).reshape(-1, 3)


def _heading_index(deg: float, step: float, n: int) -> int:
    return round((deg % 360.0) / step) % n


@functools.lru_cache(maxsize=8)
def build_network(mission: MissionConfig | None = None) -> Network:
    """The network of ``mission`` (default: the paper's Bay-Area mission). Cached per config."""
    m = MissionConfig() if mission is None else mission
    H, V, n, W = m.n_headings, m.n_speeds, m.n_cells, m.minutes_per_window
    half = (m.n_increments - 1) // 2
    steps = np.arange(m.n_increments) - half
    # Two heading changes equal modulo 360 deg are one primitive (they lead to the same state).
    dhs = sorted({int(dh) % H for dh in steps}, key=lambda d: (d if d <= H // 2 else d - H))
    dhs = [d if d <= H // 2 else d - H for d in dhs]
    primitives = np.array([(dh, dv) for dh in dhs for dv in steps], dtype=np.int32)
    heads = np.radians(np.arange(H) * m.heading_step)
    speeds = np.arange(V) * m.speed_step
    dist_cells = speeds * m.window_min * 60.0 / 1000.0 / m.cell_km          # (V,)
    exact = dist_cells[None, :, None] * np.stack([np.cos(heads), np.sin(heads)], -1)[:, None, :]
    disp = (np.sign(exact) * np.floor(np.abs(exact) + 0.5)).astype(np.int32)  # half away from 0, (H, V, 2)
    moves, move_of = np.unique(disp.reshape(-1, 2), axis=0, return_inverse=True)
    move_of = move_of.reshape(H, V).astype(np.int32)
    sep = m.separation_km / m.cell_km
    offs = [segment_offsets(tuple(mv), W, sep) for mv in moves]
    o_max = max(len(o) for o in offs)
    offsets = np.zeros((len(moves), o_max, 3), np.int32)
    valid = np.zeros((len(moves), o_max), bool)
    for i, o in enumerate(offs):
        offsets[i, :len(o)] = o
        valid[i, :len(o)] = True

    pos = m.site_positions_km()
    cell = {name: (int(p[0] // m.cell_km), int(p[1] // m.cell_km)) for name, p in pos.items()}
    goal_mask = np.zeros(H, bool)
    goal_mask[[_heading_index(h, m.heading_step, H) for h in m.goal_headings]] = True
    alt_mask = np.zeros(H, bool)
    alt_mask[[_heading_index(h, m.heading_step, H) for h in m.alternate_headings]] = True
    for arr in (primitives, disp, move_of, moves, offsets, valid, goal_mask, alt_mask):
        arr.setflags(write=False)
    return Network(
        mission=m, n=n, n_headings=H, n_speeds=V, n_windows=m.max_windows, minutes_per_window=W,
        primitives=primitives, disp=disp, move_of=move_of, moves=moves.astype(np.int32), offsets=offsets,
        offset_valid=valid, origin=cell[m.origin.name],
        origin_heading=_heading_index(m.departure_heading, m.heading_step, H), goal=cell[m.goal.name],
        alternates=tuple(cell[s.name] for s in m.alternates), goal_heading_mask=goal_mask,
        alt_heading_mask=alt_mask, goal_windows=(m.first_goal_window, m.last_goal_window), site_km=pos)
