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

ROUNDING_ALLOWANCE = 0.01
"""[m] added to the avoid margin for float32 rounding: positions of a few kilometres are resolved to about
1e-4 m, and an intruder that plays the game optimally from the margin ends on ``R_c`` exactly, where rounding
decides. One centimetre is a hundred times that resolution, and far below the grid's spacing."""


def default_avoid_margin(control_dt: float, fall_rate: float, table_error: float = 0.0) -> float:
    """``control_dt * fall_rate + table_error + ROUNDING_ALLOWANCE`` [m]: the value cannot step from above the
    margin to below ``table_error`` between two checks of the inner loop, and from ``table_error`` up ``u^A`` keeps
    the intruder out of ``R_c`` in closed loop."""
    return control_dt * fall_rate + table_error + ROUNDING_ALLOWANCE
