"""Obstacles that keep two vehicles apart while they avoid the intruder, and the static-obstacle augmentation.

Intruder paper eqs. (24)-(31) (Case 1: the higher-priority vehicle ``Q_j`` is forced first) and (49)-(57)
(Case 2: the lower-priority ``Q_i`` first), and eqs. (32)-(33) for static obstacles.

Two forms are provided.

**Lag profiles** (what the planner uses). Every one of these obstacles, for the lower-priority vehicle ``Q_i`` at
time ``t``, is contained in a union of disks centred on the higher-priority vehicle's *nominal* positions
``p_j(t + lambda)`` with radii ``rho(lambda)`` over a window of lags ``lambda``:

    g(t, x) = min_lambda ||p - p_j(t + lambda)|| - rho(lambda)      (obstacle = {g <= 0}),

a signed-distance table the planner evaluates from the nominal trajectory. The radii follow from three facts,
with ``vbar = v_max + d_r`` the largest ground speed and ``r_M`` the base obstacle's radius (tracking bubble):
the positions reachable from a disk in ``Delta`` seconds under any control and wind lie within ``vbar * Delta``
more (forward reachable sets (24)-(25), (27)); the states from which a disk can be reached within ``Delta`` under
some control (the BRSs (29), (50), (55) with Hamiltonians (30), (51), (56), both players minimising) lie within
``vbar * Delta`` more; and the danger zone adds ``R_c``.

* Case 1A, eqs. (26)-(27): ``rho(lambda) = r_M + R_c + vbar * (-lambda)``, ``lambda in [-t_IAT, 0]``.
* Case 1B, eqs. (28)-(31): ``K^B1(s) = W^O(s - t_IAT, s)`` reached by ``Q_i`` within ``s - t in [0, t_IAT - t_BRD]``:
  ``rho(lambda) = r_M + R_c + vbar * min(2 (t_IAT - t_BRD) - lambda, 2 t_IAT + lambda)``, ``lambda in [-t_IAT,
  t_IAT - t_BRD]``.
* Case 2A, eqs. (49)-(52): ``K^A2(s) = M~_j(s)`` reached within ``s - t in [0, t_IAT]``:
  ``rho(lambda) = r_M + R_c + vbar * lambda``, ``lambda in [0, t_IAT]``.
* Case 2B, eqs. (53)-(57): ``K^B2(s) = W^O(s - t_IAT + t_BRD, s)`` reached within ``s - t in [t_BRD, t_IAT]``:
  ``rho(lambda) = r_M + R_c + vbar * (2 (t_IAT - t_BRD) + lambda)``, ``lambda in [2 t_BRD - t_IAT, t_BRD]``.

The lower-priority vehicle's own tracking bubble (Remark 1) is added by the planner, not here.

**Grid sets.** :func:`static_obstacle_augmentation` computes ``V^S`` (32)-(33) on a grid with the solver, and
:func:`disk_frs` the forward reachable set of a base-obstacle disk (24)-(25), so that the radii above can be
compared against the sets they bound (tests, and :func:`frs_radius_ratio`).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.reach.buffer import brd_time, position_radius


@dataclasses.dataclass(frozen=True)
class LagProfile:
    """Radii ``radii[k]`` [m] around the higher-priority vehicle's nominal position at ``t + lags[k]`` [s]."""

    name: str
    lags: np.ndarray
    radii: np.ndarray

    def signed_distance(self, positions_at_lags, p):
        """``min_k ||p - positions_at_lags[k]|| - radii[k]`` (jittable); ``positions_at_lags`` has shape
        ``(len(lags), 2)``, ``p`` shape ``(..., 2)``."""
        d = jnp.linalg.norm(p[..., None, :] - positions_at_lags, axis=-1) - jnp.asarray(self.radii)
        return jnp.min(d, axis=-1)


def intruder_obstacle_profiles(vehicle: DubinsWind, tracking_bound: float, collision_radius: float, t_iat: float,
                               kbar: int, n_lags: int = 41) -> dict[str, LagProfile]:
    """The four obstacle profiles of eqs. (26)-(31) and (49)-(57) for one ``k̄`` (see the module docstring)."""
    if tracking_bound < 0 or collision_radius <= 0:
        raise ValueError(f"Need tracking_bound >= 0 and collision_radius > 0; got {tracking_bound}, "
                         f"{collision_radius}.")
    t_brd = brd_time(t_iat, kbar)
    vbar = vehicle.v_max + vehicle.wind
    base = tracking_bound + collision_radius

    def profile(name, lo, hi, radius_fn):
        lags = np.linspace(lo, hi, n_lags)
        return LagProfile(name, lags, np.asarray([radius_fn(lam) for lam in lags]))

    return {
        "case1A": profile("case1A", -t_iat, 0.0, lambda lam: base + vbar * (-lam)),
        "case1B": profile("case1B", -t_iat, t_iat - t_brd,
                          lambda lam: base + vbar * min(2 * (t_iat - t_brd) - lam, 2 * t_iat + lam)),
        "case2A": profile("case2A", 0.0, t_iat, lambda lam: base + vbar * lam),
        "case2B": profile("case2B", 2 * t_brd - t_iat, t_brd,
                          lambda lam: base + vbar * (2 * (t_iat - t_brd) + lam)),
    }


def static_inflation_radius(vehicle: DubinsWind, collision_radius: float, t_iat: float) -> float:
    """Conservative ``V^S`` (32): static obstacles grown by ``R_c + vbar * t_IAT``."""
    return collision_radius + (vehicle.v_max + vehicle.wind) * t_iat


def static_obstacle_augmentation(grid: hj.Grid, obstacle_sdf, vehicle: DubinsWind, collision_radius: float,
                                 t_iat: float, accuracy: str = "high", progress: bool = False):
    """``V^S(t, t + t_IAT)`` (eqs. 32-33) on a ``(p_x, p_y, theta)`` grid: the states from which the vehicle,
    under *some* control and wind (both minimise), reaches a static obstacle grown by ``R_c`` within ``t_IAT``.

    ``obstacle_sdf`` is a signed distance to the static obstacles on the grid (negative inside). Returns the
    value function (``V^S = {V <= 0}``)."""
    grid.check_values(obstacle_sdf, "obstacle_sdf")
    target = jnp.asarray(obstacle_sdf, jnp.float32) - collision_radius
    dyn = vehicle.with_modes(control_mode="min", disturbance_mode="min")
    res = hj.solve(hj.SolverSettings.with_accuracy(accuracy), dyn, grid, [0.0, -t_iat], target, tube=True,
                   progress=progress)
    return res.values[-1]


def disk_frs(grid: hj.Grid, vehicle: DubinsWind, radius: float, duration: float, heading: float | None = None,
             accuracy: str = "high", progress: bool = False):
    """Forward reachable set (eqs. 24-25) after ``duration`` of the base obstacle ``M`` = disk of ``radius``
    around the origin (all headings, or within one cell of ``heading``), under any control and wind (both
    maximise in the forward problem)."""
    x = grid.broadcast_states()
    init = jnp.sqrt(x[0] ** 2 + x[1] ** 2) - radius
    if heading is not None:
        dth = jnp.abs(wrap_angle(x[2] - heading))
        init = jnp.maximum(init, dth - grid.spacing[2])
    init = jnp.broadcast_to(init, grid.shape)
    dyn = vehicle.with_modes(control_mode="max", disturbance_mode="max")
    res = hj.solve(hj.SolverSettings.with_accuracy(accuracy), dyn, grid, [0.0, duration], init, progress=progress)
    return res.values[-1]


def frs_radius_ratio(grid: hj.Grid, frs_values, radius_bound: float) -> float:
    """``radius_bound`` over the position radius of an FRS grid set (>= 1 when the bound is conservative)."""
    r = position_radius(grid, np.asarray(frs_values))
    return radius_bound / r if r > 0 else math.inf
