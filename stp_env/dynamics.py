"""Vehicle dynamics of the papers, as control- and disturbance-affine systems for the HJ solver.

* :class:`DubinsWind`: a Dubins vehicle in wind, intruder paper eq. (43); with ``heading_disturbance > 0`` it is
  the SPP paper's eq. (28). State ``(p_x, p_y, theta)`` [m, m, rad]; control ``(v, omega)`` in
  ``[v_min, v_max] x [-omega_max, omega_max]`` [m/s, rad/s]; disturbance: wind ``(d_x, d_y)`` with
  ``||d|| <= wind`` [m/s] (and ``|d_theta| <= heading_disturbance`` [rad/s]).
* :class:`RelativeDubins`: the state of an *other* Dubins vehicle (intruder, or a tracking reference) relative
  to a vehicle ``i``, in ``i``'s body frame, intruder paper eq. (44):

      d/dt p_x = -v_i + omega_i p_y + v_o cos(theta) + w_x
      d/dt p_y =      - omega_i p_x + v_o sin(theta) + w_y
      d/dt theta = omega_o - omega_i  (+ heading disturbances)

  With heading-rate disturbances ``d_theta,i`` and ``d_theta,o`` (SPP eq. 28), vehicle ``i``'s frame turns at
  ``omega_i + d_theta,i``: its own disturbance enters like ``omega_i`` (column ``(p_y, -p_x, -1)``), the other's
  like ``omega_o`` (column ``(0, 0, 1)``).

  (eq. 44 prints ``v_i sin`` in the second line; the derivation, ``d/dt R(-theta_i)(p_o - p_i)``, gives
  ``v_o sin``, as in Air3D.) The control is vehicle ``i``'s ``(v_i, omega_i)``; the disturbance collects the other
  vehicle's ``(v_o, omega_o)`` and the wind: both winds rotated into ``i``'s frame add up to a disk of radius
  ``wind_i + wind_o``. With the default roles (``control_mode="max"``, ``disturbance_mode="min"``) the vehicle
  avoids and the other vehicle and the winds pursue: the avoid region of eqs. (13)-(14).
* :func:`tracking_error_dynamics`: robust trajectory tracking (SPP paper Section IV-C, eqs. 24-26): the error
  between the tracking vehicle (full controls, wind) and a virtual reference that moves with the reduced
  planning controls ``U^p`` and no wind, in the vehicle's body frame. Same form as :class:`RelativeDubins`.
* :class:`SingleIntegrator`: ``dx/dt = u``, ``||u|| <= speed``: closed-form test problems.

All optimal controls and disturbances come in closed form from :class:`stp_env.hj.ControlAffineDynamics`.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from stp_env.hj.dynamics import ControlAffineDynamics
from stp_env.hj.sets import Ball, Box, ProductSet


def _check_bounds(name: str, lo: float, hi: float, allow_negative: bool = False) -> None:
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{name} bounds must be finite; got [{lo}, {hi}].")
    if lo > hi:
        raise ValueError(f"{name} lower bound {lo} exceeds upper bound {hi}.")
    if not allow_negative and lo < 0:
        raise ValueError(f"{name} must be >= 0; got lower bound {lo}.")


def _check_nonneg(name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0; got {value}.")


class _DubinsControl:
    """The state and control of a Dubins vehicle ``(p_x, p_y, theta)``, ``(v, omega)`` in
    ``[v_min, v_max] x [-omega_max, omega_max]``, shared by the absolute and the relative models."""

    @property
    def state_dim(self) -> int:
        return 3

    @property
    def control_space(self) -> ProductSet:
        return ProductSet((Box((self.v_min, -self.omega_max), (self.v_max, self.omega_max)),))


@dataclasses.dataclass(frozen=True, kw_only=True)
class DubinsWind(_DubinsControl, ControlAffineDynamics):
    """Dubins vehicle under bounded wind (intruder paper eq. 43; SPP paper eq. 28).

    Default roles: the control minimises (reaching a target), the wind maximises (hinders it).
    """

    v_min: float = 0.0
    v_max: float = 25.0
    omega_max: float = 2.0
    wind: float = 6.0
    heading_disturbance: float = 0.0
    control_mode: str = "min"
    disturbance_mode: str = "max"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_bounds("speed", self.v_min, self.v_max)
        _check_nonneg("omega_max", self.omega_max)
        _check_nonneg("wind", self.wind)
        _check_nonneg("heading_disturbance", self.heading_disturbance)

    @property
    def disturbance_space(self) -> ProductSet:
        blocks: list = [Ball((0.0, 0.0), self.wind)]
        if self.heading_disturbance > 0:
            blocks.append(Box((-self.heading_disturbance,), (self.heading_disturbance,)))
        return ProductSet(tuple(blocks))

    def open_loop(self, x):
        return (0.0, 0.0, 0.0)

    def control_jacobian(self, x):
        c, s = jnp.cos(x[2]), jnp.sin(x[2])
        return ((c, 0.0), (s, 0.0), (0.0, 1.0))

    def disturbance_jacobian(self, x):
        if self.heading_disturbance > 0:
            return ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return ((1.0, 0.0), (0.0, 1.0), (0.0, 0.0))


@dataclasses.dataclass(frozen=True, kw_only=True)
class RelativeDubins(_DubinsControl, ControlAffineDynamics):
    """Relative dynamics of another Dubins vehicle in vehicle ``i``'s body frame (intruder paper eq. 44).

    Attributes:
        v_min, v_max, omega_max: vehicle ``i``'s control bounds (the control of this system).
        other_v_min, other_v_max, other_omega_max: the other vehicle's bounds (part of the disturbance).
        wind: combined wind bound ``d_r,i + d_r,o`` [m/s].
        own_heading_disturbance: vehicle ``i``'s heading-rate disturbance bound [rad/s].
        other_heading_disturbance: the other vehicle's heading-rate disturbance bound [rad/s].
    """

    v_min: float = 0.0
    v_max: float = 25.0
    omega_max: float = 2.0
    other_v_min: float = 0.0
    other_v_max: float = 25.0
    other_omega_max: float = 2.0
    wind: float = 12.0
    own_heading_disturbance: float = 0.0
    other_heading_disturbance: float = 0.0
    control_mode: str = "max"
    disturbance_mode: str = "min"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_bounds("vehicle speed", self.v_min, self.v_max)
        _check_bounds("other speed", self.other_v_min, self.other_v_max)
        _check_nonneg("omega_max", self.omega_max)
        _check_nonneg("other_omega_max", self.other_omega_max)
        _check_nonneg("wind", self.wind)
        _check_nonneg("own_heading_disturbance", self.own_heading_disturbance)
        _check_nonneg("other_heading_disturbance", self.other_heading_disturbance)

    @property
    def disturbance_space(self) -> ProductSet:
        blocks: list = [Box((self.other_v_min, -self.other_omega_max), (self.other_v_max, self.other_omega_max))]
        if self.wind > 0:
            blocks.append(Ball((0.0, 0.0), self.wind))
        for bound in (self.own_heading_disturbance, self.other_heading_disturbance):
            if bound > 0:
                blocks.append(Box((-bound,), (bound,)))
        return ProductSet(tuple(blocks))

    def open_loop(self, x):
        return (0.0, 0.0, 0.0)

    def control_jacobian(self, x):
        return ((-1.0, x[1]), (0.0, -x[0]), (0.0, -1.0))

    def disturbance_jacobian(self, x):
        c, s = jnp.cos(x[2]), jnp.sin(x[2])
        rows = [[c, 0.0], [s, 0.0], [0.0, 1.0]]
        if self.wind > 0:
            rows[0] += [1.0, 0.0]
            rows[1] += [0.0, 1.0]
            rows[2] += [0.0, 0.0]
        if self.own_heading_disturbance > 0:  # vehicle i's frame turns with it
            rows[0] += [x[1]]
            rows[1] += [-x[0]]
            rows[2] += [-1.0]
        if self.other_heading_disturbance > 0:
            rows[0] += [0.0]
            rows[1] += [0.0]
            rows[2] += [1.0]
        return tuple(tuple(r) for r in rows)


def tracking_error_dynamics(vehicle: DubinsWind, planning_v: tuple[float, float],
                            planning_omega_max: float) -> RelativeDubins:
    """Tracking-error dynamics of robust trajectory tracking (SPP paper eqs. 24-25).

    The state is the virtual reference relative to the tracking vehicle, in the vehicle's body frame. The
    vehicle uses its full control set ``U`` and keeps the error small (``"max"`` of the value of the error-bound
    violation set); the reference moves with the planning set ``U^p = planning_v x [-planning_omega_max,
    planning_omega_max]`` and, with the wind, tries to grow the error (``"min"``).
    """
    v_lo, v_hi = planning_v
    if not (vehicle.v_min <= v_lo <= v_hi <= vehicle.v_max and 0 <= planning_omega_max <= vehicle.omega_max):
        raise ValueError(
            f"The planning control set U^p = [{v_lo}, {v_hi}] x |omega| <= {planning_omega_max} must lie inside "
            f"U = [{vehicle.v_min}, {vehicle.v_max}] x |omega| <= {vehicle.omega_max}."
        )
    return RelativeDubins(
        v_min=vehicle.v_min, v_max=vehicle.v_max, omega_max=vehicle.omega_max,
        other_v_min=v_lo, other_v_max=v_hi, other_omega_max=planning_omega_max,
        wind=vehicle.wind, own_heading_disturbance=vehicle.heading_disturbance,
        control_mode="max", disturbance_mode="min",
    )


@dataclasses.dataclass(frozen=True, kw_only=True)
class SingleIntegrator(ControlAffineDynamics):
    """``dx/dt = u`` with ``||u||_2 <= speed`` (plus an optional constant drift) in ``dim`` dimensions."""

    dim: int = 2
    speed: float = 1.0
    drift: tuple[float, ...] = ()
    control_mode: str = "min"
    disturbance_mode: str = "max"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_nonneg("speed", self.speed)
        if self.dim < 1:
            raise ValueError(f"dim must be >= 1; got {self.dim}.")
        if self.drift and len(self.drift) != self.dim:
            raise ValueError(f"drift must have {self.dim} components; got {len(self.drift)}.")

    @property
    def state_dim(self) -> int:
        return self.dim

    @property
    def control_space(self) -> ProductSet:
        return ProductSet((Ball((0.0,) * self.dim, self.speed),))

    @property
    def disturbance_space(self) -> ProductSet:
        return ProductSet(())

    def open_loop(self, x):
        return tuple(float(v) for v in self.drift) if self.drift else (0.0,) * self.dim

    def control_jacobian(self, x):
        return tuple(tuple(1.0 if i == j else 0.0 for j in range(self.dim)) for i in range(self.dim))

    def disturbance_jacobian(self, x):
        return tuple(() for _ in range(self.dim))
