"""Intruder traffic: random Bezier curves in (x, y, t) (survivability paper, Section III-B) and their cells.

Each intruder flies a Bezier curve of degree ``k``: its first control point (where it enters) is uniform in the
operating area and the other ``k`` are uniform in the disk of radius ``reach_km`` around it (the convention of this
project's random-Bezier intruder, :func:`stp_env.baselines.intruders.bezier_intruder`). Its time is linear in the
curve parameter (the control points' times are equally spaced), so it flies the
curve in ``D = L / v`` minutes, ``L`` the curve's length and ``v`` a mean speed uniform in ``speed_range``. Its
entry time is uniform in ``[-D, T]`` (``T`` = the endurance), so that the traffic is stationary over the mission:
about ``N D / (T + D)`` intruders are in the air at any minute, and some are already flying at departure.

A **partially known** intruder's nominal curve and uncertainty radius ``r`` are known to the ownship; its actual
curve has the same end points and times and its interior control points displaced by independent offsets uniform
in the disk of radius ``r``. A point of a Bezier curve is a convex combination of its control points, so the
actual path stays within ``r`` of the nominal one at all times (inside the tube ``V(l^B, r)``) and starts and ends
where the nominal one does, as the paper's uncertainty model requires. An **unknown** intruder's curve is drawn the
same way and is never shown to the ownship until a conflict reveals it.

A curve blocks the cell it is in at each of ``samples_per_min`` instants per minute (Assumption II.1); the
separation radius is applied on the ownship's side (:mod:`stp_env.survivability.network`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from stp_env.survivability.config import MissionConfig, TrafficConfig

KM_PER_MIN_PER_MS = 0.06   # 1 m/s = 0.06 km/min


class Traffic(NamedTuple):
    """One traffic instance (numpy). Intruders ``0 .. n_partial - 1`` are partially known, the rest unknown."""

    nominal: np.ndarray    # (N, k + 1, 2) control points [km], what the ownship knows of a partially known one
    actual: np.ndarray     # (N, k + 1, 2) control points of the path actually flown
    t_in: np.ndarray       # (N,) entry time [min since departure]
    duration: np.ndarray   # (N,) [min]
    n_partial: int

    @property
    def n(self) -> int:
        return int(self.t_in.shape[0])


def bernstein(degree: int, s) -> np.ndarray:
    """``(..., degree + 1)`` Bernstein basis at parameters ``s`` (works for numpy and JAX arrays)."""
    i = np.arange(degree + 1)
    binom = np.array([math.comb(degree, j) for j in i], np.float64)
    s = s[..., None]
    return binom * s ** i * (1.0 - s) ** (degree - i)


def curve_length(ctrl: np.ndarray, n: int = 129) -> np.ndarray:
    """Polyline length of Bezier curves ``(..., k + 1, 2)`` at ``n`` parameter values."""
    basis = bernstein(ctrl.shape[-2] - 1, np.linspace(0.0, 1.0, n))        # (n, k + 1)
    pts = np.einsum("sk,...kd->...sd", basis, ctrl)
    return np.linalg.norm(np.diff(pts, axis=-2), axis=-1).sum(-1)


def disk_offsets(rng: np.random.Generator, shape, radius: float) -> np.ndarray:
    """``shape + (2,)`` points uniform in the disk of ``radius`` (one draw of ``shape + (2,)`` uniforms, so that
    a prefix of the first axis does not depend on its length)."""
    u = rng.uniform(size=(*shape, 2))
    r = radius * np.sqrt(u[..., 0])
    a = 2.0 * np.pi * u[..., 1]
    return np.stack([r * np.cos(a), r * np.sin(a)], -1)


def sample_traffic(seed, mission: MissionConfig, config: TrafficConfig) -> Traffic:
    """A traffic instance of ``config`` in ``mission``'s area, from ``seed`` (an int, a sequence of ints or a
    ``numpy.random.SeedSequence``).

    Every random quantity of each intruder class has its own stream, so the first ``n`` intruders of a class do not
    depend on how many are drawn: instance ``i`` of scenario ``(N_p, N_u)`` contains the intruders of instance
    ``i`` of every smaller scenario (common random numbers across scenarios)."""
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    k = config.degree
    parts = []
    for cls, (n, child) in enumerate(zip((config.n_partial, config.n_unknown), seq.spawn(2))):
        entry_rng, ctrl_rng, speed_rng, time_rng, actual_rng = (np.random.default_rng(s) for s in child.spawn(5))
        entry = entry_rng.uniform(0.0, mission.area_km, size=(n, 1, 2))
        nominal = np.concatenate([entry, entry + disk_offsets(ctrl_rng, (n, k), config.reach_km)], axis=1)
        speed = speed_rng.uniform(*config.speed_range, size=n)
        duration = np.maximum(curve_length(nominal), 1e-6) / (speed * KM_PER_MIN_PER_MS)
        t_in = -duration + time_rng.uniform(size=n) * (mission.endurance_min + duration)
        actual = nominal.copy()
        if cls == 0 and k >= 2:
            actual[:, 1:k] += disk_offsets(actual_rng, (n, k - 1), config.uncertainty_km)
        parts.append((nominal, actual, t_in, duration))
    nominal, actual, t_in, duration = (np.concatenate([a[i] for a in parts]) for i in range(4))
    return Traffic(nominal, actual, t_in, duration, config.n_partial)


def sample_times(mission: MissionConfig, samples_per_min: int) -> tuple[np.ndarray, np.ndarray]:
    """The rasterisation instants [min] and the time cell of each: ``samples_per_min`` per cell, mid-interval."""
    n_min = mission.n_minutes
    q = (np.arange(samples_per_min) + 0.5) / samples_per_min
    minute = np.repeat(np.arange(n_min), samples_per_min)
    return (minute + np.tile(q, n_min)) * mission.cell_min, minute


def occupied_cells(ctrl, t_in, duration, mission: MissionConfig, samples_per_min: int, cell_id: np.ndarray):
    """For each curve, the ids (``cell_id``: dense ``(minute, x, y) -> id``, ``-1`` = not tracked) of the cells it
    occupies: an ``(N, n_samples)`` int array, ``-1`` where the intruder is absent or the cell not tracked."""
    times, minute = sample_times(mission, samples_per_min)
    s = (times[None, :] - t_in[:, None]) / duration[:, None]               # (N, T)
    present = (s >= 0.0) & (s <= 1.0)
    basis = bernstein(ctrl.shape[1] - 1, np.clip(s, 0.0, 1.0))             # (N, T, k + 1)
    pts = np.einsum("ntk,nkd->ntd", basis, ctrl)
    c = np.floor(pts / mission.cell_km).astype(np.int64)
    n = mission.n_cells
    inside = present & (c[..., 0] >= 0) & (c[..., 0] < n) & (c[..., 1] >= 0) & (c[..., 1] < n)
    ids = cell_id[np.broadcast_to(minute, s.shape), np.clip(c[..., 0], 0, n - 1), np.clip(c[..., 1], 0, n - 1)]
    return np.where(inside, ids, -1)


def occupancy(traffic: Traffic, mission: MissionConfig, samples_per_min: int, cell_id: np.ndarray,
              n_cells: int) -> np.ndarray:
    """``(n_cells, N)`` bool: which intruder's *actual* path occupies each tracked cell."""
    ids = occupied_cells(traffic.actual, traffic.t_in, traffic.duration, mission, samples_per_min, cell_id)
    occ = np.zeros((n_cells + 1, traffic.n), bool)
    rows = np.where(ids >= 0, ids, n_cells)
    occ[rows, np.broadcast_to(np.arange(traffic.n)[:, None], rows.shape)] = True
    return occ[:n_cells]
