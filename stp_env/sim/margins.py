"""Sampled-data margins of the simulator's inner control loop.

A vehicle starts avoiding when its sampled ``V^A(t - t_, t_IAT)(x_rel) <= margin`` (intruder paper eqs. 17-18),
checked every ``control_dt`` seconds. Two things must hold for the avoidance guarantee to survive the sampling and
the grid:

1. the value must not be able to fall from above the margin to below the level the avoidance needs between two
   checks: ``control_dt`` times the largest rate at which the interpolated value can fall near its zero level
   (:func:`stp_env.reach.fall_rate.avoid_value_fall_rate`, stored with the avoid region);
2. from the lowest level at which the check can fire, ``u^A`` must keep the intruder out of ``R_c`` in closed loop.
   On the grid it does not from the zero level itself (the game's own optimal pursuit gets up to about half a metre
   inside at 6 m/s wind), so the avoidance must start ``table_error`` below the margin's floor
   (:attr:`stp_env.reach.avoid.AvoidRegion.table_error`, certified in closed loop when the table is computed).

The margin is the sum of both, plus an allowance for float32 rounding.
"""

from __future__ import annotations

import math

ROUNDING_ALLOWANCE = 0.01
"""[m] added to the avoid margin for float32 rounding: positions of a few kilometres are resolved to about
1e-4 m, and an intruder that plays the game optimally from the margin ends on ``R_c`` exactly, where rounding
decides. One centimetre is a hundred times that resolution, and far below the grid's spacing."""


def default_avoid_margin(control_dt: float, fall_rate: float, table_error: float = 0.0) -> float:
    """``control_dt * fall_rate + table_error + ROUNDING_ALLOWANCE`` [m]: the value cannot step from above the
    margin to below ``table_error`` between two checks of the inner loop, and from ``table_error`` up ``u^A`` keeps
    the intruder out of ``R_c`` in closed loop."""
    return control_dt * fall_rate + table_error + ROUNDING_ALLOWANCE


def tube_free_level(value, gradient, states, control_lo, control_hi, control_dt: float, level: float) -> float:
    """The tracking value below which a tube-keeping filter may let a vehicle on its plan fly another control than
    the tracker ``kappa`` for one inner step [m] (``-inf`` when no such level exists).

    The error dynamics (SPP eqs. 24-25, body frame) depend on the vehicle's control ``(v, omega)`` through
    ``-v + omega e_y`` (``e_x``), ``-omega e_x`` (``e_y``) and ``-omega`` (``e_theta``); over the control box another
    control changes them by at most ``dv + domega |e_y|``, ``domega |e_x|`` and ``domega``, so it raises ``V`` at
    most ``|V_x| (dv + domega |e_y|) + |V_y| domega |e_x| + |V_theta| domega`` faster than ``kappa`` (under which
    ``V`` does not rise). One inner step of the largest such rate over the sub-level set ``{V <= level}`` is taken off
    ``level``: from ``V <= free level`` any control ends the step with ``V <= level`` (to first order in the step),
    from where ``kappa`` keeps the error within the tube. ``value`` ``(...)``: ``V`` on the grid; ``gradient``
    ``(3, ...)``: its gradient; ``states`` ``(3, ...)``: the grid's error states."""
    import numpy as np

    value = np.asarray(value, np.float64)
    g = np.abs(np.asarray(gradient, np.float64))
    e = np.abs(np.asarray(states, np.float64))
    dv = float(control_hi[0] - control_lo[0])
    dom = float(control_hi[1] - control_lo[1])
    rate = g[0] * (dv + dom * e[1]) + g[1] * dom * e[0] + g[2] * dom
    inside = value <= level
    if not np.any(inside):
        return -math.inf
    return float(level - control_dt * np.max(rate[inside]))
