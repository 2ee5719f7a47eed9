"""What the papers' scenarios share: the vehicle of the intruder and BEACLS papers, the BEACLS planning set, and
the checks of the factories' common arguments. Scenario modules (:mod:`stp_env.scenarios.catalog`) import these."""

from __future__ import annotations

import math

import numpy as np

from stp_env.arguments import MAX_SPEED, check_real
from stp_env.dynamics import DubinsWind
from stp_env.scenarios.config import Scenario

BEACLS_PLANNING_V = (11.0, 13.0)
BEACLS_PLANNING_OMEGA_MAX = 1.2


def check_factory_args(*, n_vehicles: int | None = None, sta_spacing: float | None = None,
                        seed: int | None = None) -> None:
    if n_vehicles is not None and (isinstance(n_vehicles, bool) or not isinstance(n_vehicles, (int, np.integer))
                                   or n_vehicles < 1):
        raise ValueError(f"n_vehicles must be an integer >= 1; got {n_vehicles!r}.")
    if sta_spacing is not None and (isinstance(sta_spacing, bool) or not isinstance(sta_spacing, (int, float))
                                    or not math.isfinite(sta_spacing) or sta_spacing < 0):
        raise ValueError(f"sta_spacing must be a finite number of seconds >= 0 (the papers use 0, 5 or 10); "
                         f"got {sta_spacing!r}.")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed must be an integer >= 0; got {seed!r}.")


def check_kbar(scenario: str, kbar, allowed, note: str = "") -> int:
    """``kbar`` as an ``int`` if it is one of the scenario's ``allowed`` bounds; ``ValueError`` naming the scenario
    otherwise (a ``bool`` is not an integer here)."""
    if isinstance(kbar, bool) or not isinstance(kbar, (int, np.integer)) or int(kbar) not in allowed:
        raise ValueError(f"{scenario}: kbar must be one of {tuple(allowed)}{note}; got {kbar!r}.")
    return int(kbar)


def heading(frm, to) -> float:
    return math.atan2(to[1] - frm[1], to[0] - frm[0])


def paper_vehicle(wind: float) -> DubinsWind:
    """Vehicle bounds of the intruder and BEACLS papers (eq. 43 / 23): ``v in [0, 25] m/s``, ``|omega| <= 2 rad/s``;
    ``wind`` a number in ``[0, MAX_SPEED]`` m/s (:data:`stp_env.arguments.MAX_SPEED`; never a string or a boolean).
    """
    return DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=check_real(wind, "wind [m/s]", 0.0, MAX_SPEED))


def paper_fields(wind: float) -> dict:
    """Fields shared by the papers' UAV scenarios: vehicle bounds (intruder paper eq. 43 bounds), the BEACLS
    planning set ``U^p`` and ``R_c = 100 m``."""
    return {"vehicle": paper_vehicle(wind), "planning_v": BEACLS_PLANNING_V,
            "planning_omega_max": BEACLS_PLANNING_OMEGA_MAX, "collision_radius": 100.0}


def dense_scenario(name: str, *, domain, vehicles, kbar: int, wind: float, grid_points: tuple[int, int, int],
                   seed: int, description: str):
    """A dense scenario of straight routes (``corridor``, ``crossing``, ``pinwheel``): the papers' vehicle and
    planning set (:func:`paper_fields`), ``t_IAT = 10 s``, plan samples every 0.25 s, and the method ``"straight"``
    (straight flights checked against the intruder-aware planner's disks,
    :func:`stp_env.planning.verify.straight_plan`); ``domain = (lo, hi)``."""
    return Scenario(name=name, domain_lo=domain[0], domain_hi=domain[1], **paper_fields(wind), vehicles=vehicles,
                    method="straight", kbar=int(kbar), t_iat=10.0, grid_points=grid_points, time_step=0.25, seed=seed,
                    description=description)
