"""Sampled-data margins of the simulator's inner control loop.

A vehicle starts avoiding when its sampled ``V^A(t - t_, t_IAT)(x_rel) <= margin`` (intruder paper eqs. 17-18),
checked every ``control_dt`` seconds. The value must not be able to fall from above the margin to below zero
between two checks, so the margin is ``control_dt`` times the largest rate at which the interpolated value can
fall near its zero level (:func:`stp_env.reach.fall_rate.avoid_value_fall_rate`, stored with the avoid region),
plus an allowance for rounding.
"""

from __future__ import annotations

ROUNDING_ALLOWANCE = 0.01
"""[m] added to the avoid margin for float32 rounding: positions of a few kilometres are resolved to about
1e-4 m, and an intruder that plays the game optimally from the margin ends on ``R_c`` exactly, where rounding
decides. One centimetre is a hundred times that resolution, and far below the grid's spacing."""


def default_avoid_margin(control_dt: float, fall_rate: float) -> float:
    """``control_dt * fall_rate + ROUNDING_ALLOWANCE`` [m]: the value cannot step from above the margin to below
    zero between two checks of the inner loop."""
    return control_dt * fall_rate + ROUNDING_ALLOWANCE
