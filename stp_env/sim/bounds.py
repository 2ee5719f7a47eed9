"""The bounds row of an agent (:class:`~stp_env.sim.types.EnvParams` ``vehicles.bounds`` and ``intruder.bounds``):
the HJ model's bounds as one ``(5,)`` array, so that they change without recompiling, read by name through the
column indices below (plain ``int`` constants: indexing with them is the same program as with the literals).
"""

from __future__ import annotations

V_MIN, V_MAX, OMEGA_MAX, WIND, HEADING_DISTURBANCE = range(5)
"""Columns: speed bounds ``v_min, v_max`` [m/s], turn-rate bound ``omega_max`` [rad/s], wind bound (the radius of
the wind disk, ``d_r`` or ``d_I``) [m/s] and heading-rate disturbance bound [rad/s]."""

COLUMNS = ("v_min", "v_max", "omega_max", "wind", "heading_disturbance")
"""The names of the columns, in order: the fields of :class:`stp_env.dynamics.DubinsWind` the row is made of."""


def bounds_row(dynamics) -> list[float]:
    """The row of a :class:`stp_env.dynamics.DubinsWind` (its fields named in :data:`COLUMNS`, in order)."""
    return [getattr(dynamics, name) for name in COLUMNS]
