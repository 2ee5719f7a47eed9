"""Hypothesis strategies shared by the grid and interpolation tests."""

from __future__ import annotations

from hypothesis import strategies as st

from stp_env import hj


@st.composite
def grids(draw, max_dim: int = 3, max_n: int = 12, periodic: bool = True):
    """Random grids: 1..max_dim dimensions, 2..max_n points each, bounds in [-10, 30], some dims periodic."""
    ndim = draw(st.integers(1, max_dim))
    lo, hi, shape, per = [], [], [], []
    for i in range(ndim):
        a = draw(st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False))
        extent = draw(st.floats(0.5, 20.0, allow_nan=False, allow_infinity=False))
        lo.append(a)
        hi.append(a + extent)
        shape.append(draw(st.integers(2, max_n)))
        if periodic and draw(st.booleans()):
            per.append(i)
    return hj.Grid.from_bounds(lo, hi, shape, periodic=tuple(per))
