"""The SPP paper's four-vehicle example (Section V, eqs. 28-30)."""

from __future__ import annotations

import math

from stp_env.dynamics import DubinsWind
from stp_env.scenarios.config import Scenario, VehicleSpec
from stp_env.scenarios.registry import register


@register("four-vehicle")
def four_vehicle() -> Scenario:
    """The SPP paper's four-vehicle example (Section V).

    * Dynamics eq. (28): ``v in [0.5, 1]``, ``|omega| <= 1``, wind ``d_r = 0.1``, heading disturbance ``0.2``.
    * Initial states eq. (29): ``(-0.5, 0, 0)``, ``(0.5, 0, pi)``, ``(-0.6, 0.6, 7 pi/4)``, ``(0.6, 0.6, 5 pi/4)``
      (headings stored wrapped to ``[-pi, pi)``: ``-pi``, ``-pi/4``, ``-3 pi/4`` for vehicles 1-3).
    * Targets eq. (30): centres ``(0.7, 0.2)``, ``(-0.7, 0.2)``, ``(0.7, -0.7)``, ``(-0.7, -0.7)``, ``r = 0.1``.
    * ``t_i^STA = 0`` for all (as in the paper); priorities ``Q_1 > Q_2 > Q_3 > Q_4`` (0..3 in that order).
    * Our choices (the paper does not state them): ``R_c = 0.1``; domain ``[-1, 1]^2``; planning set for robust
      trajectory tracking ``U^p = [0.6, 0.7] x |omega| <= 0.2``: the tracking-error bound must stay well below the
      target radius 0.1, and the heading disturbance of 0.2 rad/s makes it grow fast with the reference's turn
      rate (measured on 41^3 error grids of half-width 0.15-0.2 with the converged stopping rule: 0.031 for
      ``omega <= 0.1``, 0.051 for 0.2, 0.074 for 0.3, 0.117 for 0.4, above 0.17 for ``[0.7, 0.8] x 0.5``; a
      reference slower than ``v_min`` plus the wind is overtaken in a tail wind and has no small bound); grid
      81 x 81 x 40 (spacing 0.025: five cells across the target, see ``docs/numerics.md``); trajectory samples
      every 0.01 (paper time units).
    * Default method ``"centralized"`` (Section V-A); ``method="least_restrictive"`` or ``"rtt"`` give V-B and V-C.
    * No intruder (``kbar=None``); ``t_iat`` is left at its default and unused.
    """
    starts = ((-0.5, 0.0, 0.0), (0.5, 0.0, math.pi), (-0.6, 0.6, 7 * math.pi / 4), (0.6, 0.6, 5 * math.pi / 4))
    targets = ((0.7, 0.2), (-0.7, 0.2), (0.7, -0.7), (-0.7, -0.7))
    vehicles = tuple(VehicleSpec(start=s, target=c, target_radius=0.1, sta=0.0, priority=k)
                     for k, (s, c) in enumerate(zip(starts, targets)))
    return Scenario(
        name="four-vehicle",
        domain_lo=(-1.0, -1.0),
        domain_hi=(1.0, 1.0),
        vehicle=DubinsWind(v_min=0.5, v_max=1.0, omega_max=1.0, wind=0.1, heading_disturbance=0.2),
        planning_v=(0.6, 0.7),
        planning_omega_max=0.2,
        collision_radius=0.1,
        vehicles=vehicles,
        method="centralized",
        grid_points=(81, 81, 40),
        time_step=0.01,
        seed=0,
        description="SPP paper Section V four-vehicle example, eqs. (28)-(30); R_c = 0.1 and U^p = [0.6, 0.7] x 0.2 "
                    "are our choices.",
    )
