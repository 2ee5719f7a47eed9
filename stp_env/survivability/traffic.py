"""Intruder traffic: random Bezier curves in (x, y, t) (survivability paper, Section III-B) and their cells.

Each intruder flies a Bezier curve of degree ``k``: its first control point (where it enters) is uniform in the
operating area and the other ``k`` are uniform in the disk of radius ``reach_km`` around it (the convention of this
project's random-Bezier intruder, :func:`stp_env.policies.intruders.bezier_intruder`). Its time is linear in the
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

The above is the ``local`` model (``TrafficConfig(model="local")``, the default). ``model="paper"`` follows the
survivability paper's Section III-B instead (:func:`sample_traffic`): "Given k random control points
{(x_i^B, y_i^B, t_i^B) | x_i^B in [X_l, X_u], y_i^B in [Y_l, Y_u], t_i^B in (t_0, t_fu), for all i = 0, ..., k}"
-- every control point uniform over the whole area, the entry and exit times (those of the 0-th and k-th control
points, "adjusting the 0-th and k-th control points, one can specify the entrance and exit location of the
intruder as well as its flight duration") uniform in the mission window ``(t_0, t_fu)`` (``t_fu`` = the upper end
of the RTA), time still linear in the curve parameter between them; a share of the intruders hovers, "a Bezier
curve with degree number 1 - a straight line that occupies a fixed location for a time interval"; and a partially
known intruder's realisation may use the whole tube: "the intruder may fly a trajectory that deviates at most r
from the planned trajectory" (:func:`tube_offsets`). The paper bounds no intruder speed; ``max_speed`` conditions its
draw on one (:func:`_sample_paper`), and :func:`traffic_statistics` says what each reading puts in the air.
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
    hovering: np.ndarray | None = None   # (N,) bool: degree-1 hovering intruders (paper model); None: none

    @property
    def n(self) -> int:
        return int(self.t_in.shape[0])


def bernstein(degree: int, s) -> np.ndarray:
    """``(..., degree + 1)`` Bernstein basis at parameters ``s``."""
    s = np.asarray(s, np.float64)
    u = 1.0 - s
    sp, up = [np.ones_like(s)], [np.ones_like(s)]
    for _ in range(degree):
        sp.append(sp[-1] * s)
        up.append(up[-1] * u)
    return np.stack([math.comb(degree, i) * sp[i] * up[degree - i] for i in range(degree + 1)], -1)


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


def tube_peak(degree: int) -> float:
    """``max_s`` of the summed interior Bernstein weights ``1 - (1 - s)^k - s^k``, reached at ``s = 1/2``:
    ``1 - 2^(1 - k)`` (0 for degree 1, 0.5 for 2, 0.75 for 3)."""
    return 0.0 if degree < 2 else 1.0 - 2.0 ** (1 - degree)


def tube_offsets(rng: np.random.Generator, n: int, degree: int, radius: float) -> np.ndarray:
    """``(n, degree - 1, 2)`` displacements of the interior control points of ``n`` partially known intruders'
    realisations in the ``paper`` model: one offset ``d`` per intruder, uniform in the disk of ``radius``, added to
    every interior control point scaled by ``1 / tube_peak(degree)``. The path then deviates from the nominal one by
    ``d (1 - (1 - s)^k - s^k) / tube_peak(k)``: zero at both ends (it "start[s] at cell c(x_0^B, y_0^B, t_0^B) and
    end[s] at cell c(x_k^B, y_k^B, t_k^B)", Section III-B), at most ``|d| <= r`` everywhere (inside ``V(l^B, r)``)
    and exactly ``d`` at mid-flight, so the realisations cover the whole tube of radius ``r``: "the intruder may fly
    a trajectory that deviates at most r from the planned trajectory". (The ``local`` model's independent offsets
    per control point reach at most ``0.75 r`` for cubic curves and about 2 km of 5 on average.)"""
    if degree < 2:
        return np.zeros((n, 0, 2))
    d = disk_offsets(rng, (n,), radius) / tube_peak(degree)
    return np.repeat(d[:, None, :], degree - 1, axis=1)


def sample_traffic(seed, mission: MissionConfig, config: TrafficConfig) -> Traffic:
    """A traffic instance of ``config`` in ``mission``'s area, from ``seed`` (an int, a sequence of ints or a
    ``numpy.random.SeedSequence``).

    Every random quantity of each intruder class has its own stream, so the first ``n`` intruders of a class do not
    depend on how many are drawn: instance ``i`` of scenario ``(N_p, N_u)`` contains the intruders of instance
    ``i`` of every smaller scenario (common random numbers across scenarios)."""
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    if config.model == "paper":
        return _sample_paper(seq, mission, config)
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


def _sample_paper(seq: np.random.SeedSequence, mission: MissionConfig, config: TrafficConfig) -> Traffic:
    """The survivability paper's traffic (Section III-B; see the module docstring): for each intruder, ``k + 1``
    control points uniform in ``[0, area]^2``; entry and exit times the smaller and larger of two uniforms in
    ``(t_0, t_fu) = (0, rta_min[1])``; with probability ``config.hover_fraction`` a hovering intruder instead, a
    degree-1 curve whose two control points share one uniform location (stored degree-elevated: all ``k + 1``
    control points equal); a partially known intruder's actual path from :func:`tube_offsets`. The streams are
    per class and per quantity, as in the ``local`` model, so a larger scenario keeps a smaller one's intruders.

    ``config.max_speed``: that draw conditioned on the nominal curve's mean speed ``L / D`` being at most
    ``max_speed`` (``L`` its length, ``D`` its duration), exactly and with no loop over intruders: the draw is
    uniform over (control points, sorted time pair), so the condition keeps a curve of length ``L`` with the
    probability that the two times are at least ``d = L / max_speed`` apart, ``((t_fu - d) / t_fu)^2`` (0 when
    ``d >= t_fu``); a rejected curve is replaced by the next of :data:`SPEED_CANDIDATES` more curves of its own
    stream; and given the curve, the times are uniform on the part of the triangle ``0 < t_in < t_out < t_fu``
    with ``t_out - t_in >= d``, which is the whole triangle scaled by ``c = (t_fu - d) / t_fu`` and shifted:
    ``t_in = c t_min``, ``D = d + c (t_max - t_min)``. Hovering intruders (``L = 0``) are unchanged; without
    ``max_speed`` nothing is drawn beyond the unbounded model's streams, so its instances stay bit for bit."""
    k = config.degree
    t_fu = mission.rta_min[1]
    parts = []
    for cls, (n, child) in enumerate(zip((config.n_partial, config.n_unknown), seq.spawn(2))):
        *streams, speed_seq = child.spawn(5)
        ctrl_rng, hover_rng, time_rng, actual_rng = (np.random.default_rng(s) for s in streams)
        nominal = ctrl_rng.uniform(0.0, mission.area_km, size=(n, k + 1, 2))
        hovering = hover_rng.uniform(size=n) < config.hover_fraction
        t = time_rng.uniform(0.0, t_fu, size=(n, 2))
        t_in = t.min(axis=1)
        gap = t.max(axis=1) - t_in
        if config.max_speed is not None:
            bounded, min_duration = _speed_bounded(speed_seq, nominal, config.max_speed, t_fu, mission.area_km)
            nominal = np.where(hovering[:, None, None], nominal, bounded)        # a hovering intruder stays put
            min_duration = np.where(hovering, 0.0, min_duration)
            scale = (t_fu - min_duration) / t_fu
            t_in, gap = scale * t_in, min_duration + scale * gap
        nominal[hovering] = nominal[hovering, :1]
        duration = np.maximum(gap, 1e-6)
        actual = nominal.copy()
        if cls == 0 and k >= 2:
            actual[:, 1:k] += tube_offsets(actual_rng, n, k, config.uncertainty_km)
        parts.append((nominal, actual, t_in, duration, hovering))
    nominal, actual, t_in, duration, hovering = (np.concatenate([a[i] for a in parts]) for i in range(5))
    return Traffic(nominal, actual, t_in, duration, config.n_partial, hovering)


SPEED_CANDIDATES = 256
"""Curves drawn per intruder for ``TrafficConfig.max_speed`` beyond its first (:func:`_speed_bounded`)."""


def _speed_bounded(seq: np.random.SeedSequence, nominal: np.ndarray, max_speed: float, t_fu: float, area_km: float):
    """``(nominal, d)``: each intruder's curve conditioned on fitting in ``(0, t_fu)`` at ``max_speed`` [m/s], and
    the shortest duration ``d`` [min] of it (see :func:`_sample_paper`). Curve ``i`` is the first of
    ``nominal[i]``, then ``SPEED_CANDIDATES`` more uniform curves, that an acceptance uniform keeps (all drawn in
    blocks, one stream each, whose first rows do not depend on the number of intruders). If none is kept (on the
    paper's area at 40 m/s a curve is kept with probability 0.22, so about 1e-28), the shortest one is used."""
    n, m = nominal.shape[0], SPEED_CANDIDATES
    curve_rng, accept_rng = (np.random.default_rng(s) for s in seq.spawn(2))
    extra = curve_rng.uniform(0.0, area_km, size=(n, m, *nominal.shape[1:]))
    accept = accept_rng.uniform(size=(n, m + 1))
    out = nominal.copy()
    d_out = np.full(n, np.inf)
    todo = np.arange(n)
    for j in range(m + 1):
        if not todo.size:
            break
        cand = nominal[todo] if j == 0 else extra[todo, j - 1]
        d = curve_length(cand) / (max_speed * KM_PER_MIN_PER_MS)
        shorter = d < d_out[todo]                     # the fallback: the shortest candidate so far
        out[todo[shorter]], d_out[todo[shorter]] = cand[shorter], d[shorter]
        keep = accept[todo, j] < np.clip((t_fu - d) / t_fu, 0.0, 1.0) ** 2
        out[todo[keep]], d_out[todo[keep]] = cand[keep], d[keep]
        todo = todo[~keep]
    return out, np.minimum(d_out, t_fu)


def airborne_fraction(traffic: Traffic, mission: MissionConfig) -> float:
    """The mean share of ``traffic``'s intruders in flight at a minute of the mission: the fraction of (intruder,
    minute) pairs, over the ``n_minutes`` minutes from departure to the endurance, in which the intruder is flying
    at the middle of the minute (about 0.1 in the ``local`` model, about ``(t_fu / 3) / endurance`` = 0.31 in the
    ``paper`` model on the paper's mission)."""
    if traffic.n == 0:
        return 0.0
    who, _, _ = present_samples(traffic.t_in, traffic.duration, mission, 1)
    return float(len(who) / (traffic.n * mission.n_minutes))


def traffic_statistics(traffic: Traffic, mission: MissionConfig, samples_per_min: int) -> dict:
    """What one reading of the traffic model puts in the air: over the intruders that move (hovering ones left
    out), the mean length [km] and duration [min] of the nominal path and the percentiles (50, 90, 99) of its mean
    speed [m/s]; over all intruders, :func:`airborne_fraction` and the mean number of (x, y, minute) cells of the
    whole area that an intruder's actual path blocks during the mission (Assumption II.1, as rasterised here at
    ``samples_per_min``), the volume of space-time it takes from the ownship."""
    moving = np.ones(traffic.n, bool) if traffic.hovering is None else ~traffic.hovering
    length = curve_length(traffic.nominal[moving])
    speed = length / traffic.duration[moving] / KM_PER_MIN_PER_MS
    who, minute, c = actual_cells(traffic, mission, samples_per_min)
    n = mission.n_cells
    cells = np.unique(((who * mission.n_minutes + minute) * n + c[:, 0]) * n + c[:, 1])
    return {"moving": int(moving.sum()), "length_km": float(length.mean()),
            "duration_min": float(traffic.duration[moving].mean()),
            "speed_ms_p50_p90_p99": [float(v) for v in np.percentile(speed, [50, 90, 99])],
            "airborne_fraction": airborne_fraction(traffic, mission),
            "cells_per_intruder": len(cells) / max(traffic.n, 1)}


def sample_times(mission: MissionConfig, samples_per_min: int) -> tuple[np.ndarray, np.ndarray]:
    """The rasterisation instants [min] and the time cell of each: ``samples_per_min`` per cell, mid-interval."""
    n_min = mission.n_minutes
    q = (np.arange(samples_per_min) + 0.5) / samples_per_min
    minute = np.repeat(np.arange(n_min), samples_per_min)
    return (minute + np.tile(q, n_min)) * mission.cell_min, minute


def present_samples(t_in, duration, mission: MissionConfig, samples_per_min: int):
    """The (intruder, instant) pairs at which each curve is flying: intruder index, instant index into
    :func:`sample_times` and the curve parameter ``s`` in ``[0, 1]``."""
    times, _ = sample_times(mission, samples_per_min)
    step = mission.cell_min / samples_per_min
    first = np.clip(np.ceil((t_in - times[0]) / step - 1e-9), 0, len(times)).astype(np.int64)
    last = np.clip(np.floor((t_in + duration - times[0]) / step + 1e-9), -1, len(times) - 1).astype(np.int64)
    count = np.maximum(last - first + 1, 0)
    who = np.repeat(np.arange(len(t_in)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    t = first[who] + offset
    s = np.clip((times[t] - t_in[who]) / duration[who], 0.0, 1.0)
    return who, t, s


def curve_points(ctrl, who, s) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(P, 2)`` on curves ``ctrl[who]`` at parameters ``s``, and the basis ``(P, k + 1)``."""
    basis = bernstein(ctrl.shape[1] - 1, s)
    pts = np.zeros((len(s), 2))
    for i in range(ctrl.shape[1]):
        pts += basis[:, i, None] * ctrl[who, i]
    return pts, basis


def occupancy(traffic: Traffic, mission: MissionConfig, samples_per_min: int, cell_id: np.ndarray,
              n_cells: int) -> np.ndarray:
    """``(n_cells, N)`` bool: which intruder's *actual* path occupies each tracked cell (``cell_id``: dense
    ``(minute, x, y) -> id``, ``-1`` = not tracked)."""
    who, minute, c = actual_cells(traffic, mission, samples_per_min)
    ids = cell_id[minute, c[:, 0], c[:, 1]]
    occ = np.zeros((n_cells + 1, traffic.n), bool)
    occ[np.where(ids >= 0, ids, n_cells), who] = True
    return occ[:n_cells]


def actual_cells(traffic: Traffic, mission: MissionConfig, samples_per_min: int):
    """The cells the intruders' *actual* paths are in at the rasterisation instants, inside the area: intruder
    index, time cell (minute since departure) and ``(P, 2)`` cell indices (x, y)."""
    who, t, s = present_samples(traffic.t_in, traffic.duration, mission, samples_per_min)
    pts, _ = curve_points(traffic.actual, who, s)
    _, minute = sample_times(mission, samples_per_min)
    c = np.floor(pts / mission.cell_km).astype(np.int64)
    n = mission.n_cells
    inside = (c[:, 0] >= 0) & (c[:, 0] < n) & (c[:, 1] >= 0) & (c[:, 1] < n)
    return who[inside], minute[t[inside]], c[inside]
