"""How fast the avoid value can fall: the bound behind the simulator's sampled-data avoid margin.

A vehicle starts avoiding when its sampled ``V^A(t - t_, t_IAT)(x_rel) <= margin`` (intruder paper eqs. 17-18).
Checked every ``control_dt`` seconds, the value must not be able to fall from above the margin to below zero
between two checks, so ``margin >= control_dt * max(-dV/dt)``, the largest rate at which the value the simulator
reads (the multilinear interpolant of the table, linear in ``tau``) can fall along any relative trajectory near
the set's boundary. That rate is not a closing speed: the relative state lives in the vehicle's frame (intruder
paper eq. 9), so the vehicle's own turn rotates the relative position, and the relative heading changes at up to
``omega_V + omega_I``, which moves the value too.

:func:`avoid_value_fall_rate` bounds it cell by cell. In a cell of the table (two ``tau`` slices, two nodes per
state axis) the interpolant's partial derivative along an axis is a convex combination of the forward differences
on the cell's edges along that axis, so the gradient lies in the box spanned by their minima and maxima, and the
time derivative in ``[min, max]`` of the ``tau`` differences. The fall rate for a gradient ``p`` at relative state
``(x, y, theta)`` is the relative dynamics' Hamiltonian with every input against the value,

    v_V max(p1, 0) + v_I max(0, -(p1 cos theta + p2 sin theta)) + omega_V |p1 y - p2 x - p3|
        + omega_I |p3| + (d_V + d_I) |(p1, p2)|,

convex in ``p`` and in ``(x, y)``, so its maximum over the cell is at a vertex of the gradient box and a corner
of the cell; the heading enters through ``cos``/``sin`` over an interval of width ``h_theta``, bounded by its
endpoints plus ``|(p1, p2)| (1 - cos(h_theta / 2))``. Only cells that can hold values within ``band`` of zero count:
detection happens there.
"""

from __future__ import annotations

import itertools

import numpy as np

FALL_RATE_BAND = 25.0
"""[m] cells holding a value within this distance of zero count in the avoid table's fall-rate bound: detection
reads values up to ``margin + control_dt * rate`` (about 5 m at the default 0.02 s inner step)."""


def _pool_max(a: np.ndarray, axes) -> np.ndarray:
    for ax in axes:
        n = a.shape[ax]
        a = np.maximum(np.take(a, range(n - 1), axis=ax), np.take(a, range(1, n), axis=ax))
    return a


def _pool_min(a: np.ndarray, axes) -> np.ndarray:
    for ax in axes:
        n = a.shape[ax]
        a = np.minimum(np.take(a, range(n - 1), axis=ax), np.take(a, range(1, n), axis=ax))
    return a


def avoid_value_fall_rate(values: np.ndarray, taus: np.ndarray, grid, vehicle, intruder, band: float) -> float:
    """Largest rate [m/s] at which the interpolated ``V^A`` can fall near its zero level (cells holding a value
    within ``band`` of zero), under any vehicle and intruder input and wind (see the module docstring).

    Args:
        values: ``(n_slices, nx, ny, ntheta)`` table ``V^A(tau_k, t_IAT)`` on ``grid`` (theta periodic, last axis).
        taus: ``(n_slices,)`` ascending.
        grid: the table's :class:`stp_env.hj.Grid`.
        vehicle, intruder: :class:`stp_env.dynamics.DubinsWind` (``v_max``, ``omega_max``, ``wind``).
        band: [m].
    """
    v = np.asarray(values, np.float64)
    if v.ndim != 4 or v.shape[1:] != tuple(grid.shape):
        raise ValueError(f"values must have shape (n_slices, *{tuple(grid.shape)}); got {v.shape}.")
    if tuple(grid.periodic) != (2,):
        raise ValueError("the avoid table's grid must be periodic in its third (heading) axis only.")
    taus = np.asarray(taus, np.float64)
    v = np.concatenate([v, v[..., :1]], axis=3)  # close the heading period: cells wrap around
    xs, ys, ths = (np.asarray(c, np.float64) for c in grid.coordinate_vectors())
    ths = np.append(ths, ths[0] + grid.period[2])
    hx, hy, hth = (float(h) for h in grid.spacing)

    # cells near the zero level: some node within band of zero, or a sign change across the cell
    all_axes = (0, 1, 2, 3)
    cell_lo, cell_hi = _pool_min(v, all_axes), _pool_max(v, all_axes)
    cells = np.nonzero((cell_lo <= band) & (cell_hi >= -band))
    if cells[0].size == 0:
        raise ValueError(f"no cell of the avoid table holds a value within {band} m of zero: the set is empty or "
                         "the band is too narrow, and a rate bound from it would be vacuous.")

    def edge_range(diff, axis):
        others = tuple(a for a in all_axes if a != axis)
        return _pool_min(diff, others)[cells], _pool_max(diff, others)[cells]

    dt_lo, _ = edge_range(np.diff(v, axis=0) / np.diff(taus)[:, None, None, None], 0)
    p_ranges = [edge_range(np.diff(v, axis=a) / h, a) for a, h in ((1, hx), (2, hy), (3, hth))]
    _, i, j, k = cells
    x_c = (xs[i], xs[i + 1])
    y_c = (ys[j], ys[j + 1])
    th_c = (ths[k], ths[k + 1])
    vv, vi = vehicle.v_max, intruder.v_max
    wv, wi = vehicle.omega_max, intruder.omega_max
    dd = vehicle.wind + intruder.wind
    heading_slack = 1.0 - np.cos(hth / 2.0)

    worst = np.zeros_like(dt_lo)
    for p1, p2, p3 in itertools.product(*p_ranges):
        norm = np.hypot(p1, p2)
        along = np.maximum(*(np.maximum(0.0, -(p1 * np.cos(th) + p2 * np.sin(th))) for th in th_c))
        turn = np.max([np.abs(p1 * y - p2 * x - p3) for x in x_c for y in y_c], axis=0)
        rate = (vv * np.maximum(p1, 0.0) + vi * (along + norm * heading_slack) + wv * turn + wi * np.abs(p3)
                + dd * norm)
        worst = np.maximum(worst, rate)
    worst = worst + np.maximum(0.0, -dt_lo)
    return float(worst.max())
