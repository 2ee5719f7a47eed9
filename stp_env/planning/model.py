"""What the planner needs from the dynamics it plans with: :class:`PlanningModel`, and :class:`DubinsPlanning`,
the papers' Dubins vehicle as one.

The sequential planner (:mod:`stp_env.planning.stp`) and the single-vehicle planner (:mod:`stp_env.planning.single`)
use the dynamics in four places:

* the BRS solvers integrate :attr:`PlanningModel.dynamics`, a solver dynamics object
  (:class:`stp_env.hj.ControlAffineDynamics`) over the planning grid ``(p_x, p_y, theta)``; the heading-split solver
  (:mod:`stp_env.planning.brs`) also needs its heading to turn at the control's rate alone, bounded by
  :attr:`PlanningModel.omega_max` (:attr:`PlanningModel.heading_split`);
* the nominal trajectory is a rollout that evaluates :meth:`PlanningModel.control` on the BRS gradient at every
  sample and moves the sample with :meth:`PlanningModel.step` (jittable, float32);
* the stored controls are checked and repaired against the same motion in float64 NumPy
  (:meth:`PlanningModel.step64`, :meth:`PlanningModel.control_between`,
  :func:`stp_env.planning.verify.reconcile_controls`);
* the plan stores states ``(p_x, p_y, theta)`` and controls ``(v, omega)`` (:class:`stp_env.planning.plan.SinglePlan`),
  checked against the planning set ``U^p`` = :attr:`PlanningModel.speed_bounds` ``x [-omega_max, omega_max]``; the
  top planning speed also sizes the folding of the moving disks and the default arrival margin.

A second planning model is one new module with a class that has these members; the planner takes it wherever it
takes a :class:`stp_env.dynamics.DubinsWind` (which it wraps in :class:`DubinsPlanning`).
``tests/test_planning_problem.py`` plans a vehicle drifting in a steady current with a model defined in the test.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol, runtime_checkable

import jax.numpy as jnp
import numpy as np

from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.hj.dynamics import ControlAffineDynamics
from stp_env.kinematics import dubins_step

PLANNING_MODEL_MEMBERS = ("dynamics", "speed_bounds", "omega_max", "wind", "heading_split", "control", "step",
                          "step64", "control_between")
"""The members of :class:`PlanningModel`, in the order :func:`as_planning_model` names the missing ones."""


@runtime_checkable
class PlanningModel(Protocol):
    """The dynamics a vehicle is planned with (the reduced control set ``U^p``; for robust trajectory tracking no
    disturbance). States are ``(p_x, p_y, theta)`` [m, m, rad] with the heading periodic, controls ``(v, omega)``."""

    @property
    def dynamics(self) -> ControlAffineDynamics:
        """The solver dynamics the BRS is computed with (3 states; the control minimises, roles as in
        :class:`stp_env.dynamics.DubinsWind`)."""

    @property
    def speed_bounds(self) -> tuple[float, float]:
        """``(v_min, v_max)`` of ``U^p`` [m/s]."""

    @property
    def omega_max(self) -> float:
        """The largest turn rate of ``U^p`` [rad/s]."""

    @property
    def wind(self) -> float:
        """Radius [m/s] of the position disturbance a rollout may draw (``wind_mode="random"``); 0 for planning."""

    @property
    def heading_split(self) -> bool:
        """Whether the Hamiltonian separates into a position part and ``min_|w| <= omega_max w p_theta`` (the
        heading turns at the control's rate alone), as the heading-split BRS (:mod:`stp_env.planning.brs`) needs."""

    def control(self, x, p) -> tuple:
        """The planning controller ``(v, omega)`` for state(s) ``x`` and value gradient(s) ``p`` (tuples of arrays,
        structure-of-arrays; jittable)."""

    def step(self, x, u, wind, dt):
        """The state after ``dt`` with the control ``u`` (``(2,)``) and the position disturbance ``wind`` (``(2,)``)
        held (``x``: ``(3,)``; jittable)."""

    def step64(self, states, controls, dt) -> np.ndarray:
        """:meth:`step` without disturbance in float64 NumPy, for many samples: ``states`` ``(n, 3)``, ``controls``
        ``(n, 2)``; an independent evaluation that the stored samples are checked against."""

    def control_between(self, x0, x1, dt) -> tuple[float, float]:
        """The control ``(v, omega)`` (not clipped to ``U^p``) whose :meth:`step64` carries ``x0`` to ``x1`` over
        ``dt`` (float64 NumPy), or the closest the model can say."""


TURN_DEADBAND = 0.05
"""The turn rate of :func:`saturated_control` is full once turning changes ``V`` at least this many times as fast as
the best translation does."""


def saturated_control(dynamics: ControlAffineDynamics, x, p) -> tuple:
    """``(v, omega)`` of the planning controller for state(s) ``x`` and value gradient(s) ``p``
    (structure-of-arrays, so one state or whole grids): ``arg min_u max_d p . f`` (eqs. 11, 37; SPP eq. 13) with
    the turn rate saturated-linear (:func:`stp_env.planning.single.planning_control`). ``dynamics``: a
    ``DubinsWind``, or solver dynamics with the same controls ``(v, omega)`` and attributes ``v_max``, ``omega_max``.
    """
    v, omega = dynamics.optimal_control(x, p)
    if dynamics.omega_max > 0:
        scale = TURN_DEADBAND * jnp.hypot(p[0], p[1]) * dynamics.v_max / dynamics.omega_max + 1e-12
        sign = -1.0 if dynamics.control_mode == "min" else 1.0
        omega = sign * dynamics.omega_max * jnp.clip(p[2] / scale, -1.0, 1.0)
    return v, omega


def missing_members(obj) -> list[str]:
    """The members of :class:`PlanningModel` that ``obj`` lacks (``[]``: it has them all)."""
    return [name for name in PLANNING_MODEL_MEMBERS if not hasattr(obj, name)]


def as_planning_model(obj) -> PlanningModel:
    """``obj`` as a :class:`PlanningModel`: a :class:`stp_env.dynamics.DubinsWind` wrapped in :class:`DubinsPlanning`,
    anything with the protocol's members itself. Raises :class:`TypeError` naming the missing members, and
    :class:`ValueError` if its solver dynamics is not one of 3 states and 2 controls."""
    if isinstance(obj, DubinsWind):
        return DubinsPlanning(obj)
    missing = missing_members(obj)
    if missing:
        raise TypeError(f"{type(obj).__name__} is not a planning model: it lacks {', '.join(missing)} (the members "
                        "of stp_env.planning.model.PlanningModel).")
    dyn = obj.dynamics
    if not isinstance(dyn, ControlAffineDynamics):
        raise TypeError(f"{type(obj).__name__}.dynamics must be a stp_env.hj.ControlAffineDynamics (the BRS solvers "
                        f"integrate it); got {type(dyn).__name__}.")
    if dyn.state_dim != 3 or dyn.control_space.dim != 2:
        raise ValueError(f"{type(obj).__name__}.dynamics has {dyn.state_dim} states and {dyn.control_space.dim} "
                         "controls; the planner plans states (p_x, p_y, theta) with controls (v, omega).")
    return obj


def dubins_step64(states, v, omega, dt):
    """:func:`stp_env.kinematics.dubins_step` without wind, in float64 NumPy: ``states`` ``(n, 3)``, ``v`` and
    ``omega`` ``(n,)``."""
    half = 0.5 * omega * dt
    chord = v * dt * np.sinc(half / np.pi)
    mid = states[:, 2] + half
    return np.stack([states[:, 0] + chord * np.cos(mid), states[:, 1] + chord * np.sin(mid),
                     states[:, 2] + omega * dt], axis=1)


def dubins_control_between(x0, x1, dt) -> tuple[float, float]:
    """The Dubins control ``(v, omega)`` whose exact step (no wind) carries ``x0`` to ``x1`` over ``dt``: the turn
    rate from the heading change, the speed from the chord."""
    omega = wrap_angle(float(x1[2] - x0[2])) / dt
    chord = math.hypot(x1[0] - x0[0], x1[1] - x0[1])
    v = chord / (dt * float(np.sinc(0.5 * omega * dt / np.pi)))
    return v, omega


@dataclasses.dataclass(frozen=True)
class DubinsPlanning:
    """The papers' planning model: a :class:`stp_env.dynamics.DubinsWind` (``U^p``, for robust trajectory tracking
    no wind) with exact Dubins motion (:func:`stp_env.kinematics.dubins_step`) and the saturated planning controller
    (:func:`saturated_control`)."""

    dynamics: DubinsWind

    def __post_init__(self) -> None:
        if not isinstance(self.dynamics, DubinsWind):
            raise TypeError(f"DubinsPlanning wraps a DubinsWind; got {type(self.dynamics).__name__}.")

    @property
    def speed_bounds(self) -> tuple[float, float]:
        return (self.dynamics.v_min, self.dynamics.v_max)

    @property
    def omega_max(self) -> float:
        return self.dynamics.omega_max

    @property
    def wind(self) -> float:
        return self.dynamics.wind

    @property
    def heading_split(self) -> bool:
        return not self.dynamics.heading_disturbance > 0

    def control(self, x, p) -> tuple:
        return saturated_control(self.dynamics, x, p)

    def step(self, x, u, wind, dt):
        return dubins_step(x, u[0], u[1], wind, dt)

    def step64(self, states, controls, dt) -> np.ndarray:
        return dubins_step64(states, controls[:, 0], controls[:, 1], dt)

    def control_between(self, x0, x1, dt) -> tuple[float, float]:
        return dubins_control_between(x0, x1, dt)
