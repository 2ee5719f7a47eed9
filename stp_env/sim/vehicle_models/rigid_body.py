"""The vehicles as pymunk rigid bodies (the optional ``pymunk`` extra): the simulator's plant moved into a 2-D
physics engine, to measure how much model mismatch the papers' guarantees survive.

Two plants, both :class:`~stp_env.sim.vehicle_models.base.VehicleModel` subclasses, so that everything built on
the core (the PettingZoo adapter, ``stp-env evaluate``, rollouts, the falsifier's cross-entropy search) runs them
unchanged:

* :class:`PymunkKinematic`: state ``(x, y, theta)``; each inner control step is ``substeps`` pymunk steps of a
  kinematic body whose velocity is set before every one of them to the exact zero-order-hold displacement rate of
  the papers' Dubins model (intruder paper eq. 43): the chord ``v h sinc(omega h / 2)`` along the mean heading,
  plus the wind, and whose angular velocity is ``omega`` plus the heading-rate disturbance. pymunk's position
  update then lands on the exact Dubins state, which validates the engine's integration against
  :func:`stp_env.sim.physics.dubins_step` (and the other way round).
* :class:`PymunkRigidBody` (:class:`RigidBodyConfig`): a dynamic body with mass and moment of inertia, driven by
  first-order actuators. The commanded speed ``v_c`` and turn rate ``omega_c`` (the action, as for Dubins) go
  through first-order lags (time constants ``speed_time_constant``, ``turn_time_constant``) to the actuators'
  set points ``v_a``, ``omega_a``. Thrust ``c_lin v_a`` along the heading and linear drag ``-c_lin (v - kappa_w
  d)`` on the velocity relative to the air (``d`` the wind, ``kappa_w`` = ``wind_coupling``: the wind acts as an
  aerodynamic force) give the force ``F = c_lin (v_a e_theta - v + kappa_w d)``; the yaw torque is ``tau =
  c_ang (omega_a + d_theta - omega)``. The velocity relaxes to ``v_a e_theta + kappa_w d`` with time constant
  ``m / c_lin`` and the turn rate to ``omega_a + d_theta`` with ``I / c_ang``; as all four time constants go to
  zero (and ``kappa_w = 1``) the plant becomes the papers' Dubins model. State ``(x, y, theta, v_x, v_y,
  omega, v_a, omega_a, started)``: the velocity and the actuators' states live in the JAX state, so the pymunk
  step is a pure function of its inputs (a body set from the state, stepped, read back) and the batched core
  carries it. ``started`` is 0 after :meth:`~PymunkRigidBody.from_pose` (take-off): the first step starts the
  vehicle at its commanded speed and turn rate (as Dubins does), with the wind.

The step runs on the host through :func:`jax.pure_callback` (``vmap_method="expand_dims"``: a batch of episodes
is one callback with every vehicle of every episode a body of one space; the bodies do not interact). It has no
derivative: the falsifier's gradient search needs the JAX plant; its cross-entropy search runs on this one. pymunk
integrates with semi-implicit Euler; the dynamic plant takes pymunk steps of at most ``max_substep`` seconds, which
:class:`RigidBodyConfig` checks is well below every body time constant (stable, monotone relaxation).
"""

from __future__ import annotations

import atexit
import dataclasses
import math
import threading

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.angles import wrap_angle
from stp_env.sim.vehicle_models.dubins import Dubins

__all__ = ["PymunkKinematic", "PymunkRigidBody", "RigidBodyConfig", "require_pymunk"]


def require_pymunk():
    """The ``pymunk`` module, or ``ImportError`` saying how to install it."""
    try:
        import pymunk
    except ImportError:  # pragma: no cover - the extra is installed in CI
        raise ImportError("the pymunk backend needs pymunk: pip install 'stp-env[pymunk]'.") from None
    return pymunk


# ------------------------------------------------------------------------------------------------ host side
class _Bodies:
    """pymunk Spaces by body count and type, reused across calls (every call sets every body's whole state before
    stepping, so the result depends on the inputs only). Callbacks may run on XLA's threads: a lock serialises
    them (and the spaces live in the main module state, never freed on a worker thread)."""

    def __init__(self):
        self.spaces = {}
        self.lock = threading.Lock()
        atexit.register(self.spaces.clear)  # free the spaces while pymunk is still importable

    def get(self, count: int, kind: str, mass: float = 1.0, moment: float = 1.0):
        key = (count, kind, mass, moment)
        if key not in self.spaces:
            pymunk = require_pymunk()
            space = pymunk.Space()
            space.gravity = (0.0, 0.0)
            space.damping = 1.0
            if kind == "kinematic":
                bodies = [pymunk.Body(body_type=pymunk.Body.KINEMATIC) for _ in range(count)]
            else:
                bodies = [pymunk.Body(mass, moment) for _ in range(count)]
            space.add(*bodies)
            self.spaces[key] = (space, bodies)
        return self.spaces[key]


_BODIES = _Bodies()


def _broadcast(x, *others):
    """``x`` ``(..., D)`` and the per-vehicle inputs broadcast to one leading shape, flattened to ``(B, ...)``."""
    lead = np.broadcast_shapes(x.shape[:-1], *(o.shape[:o.ndim - tail] for o, tail in others))
    flat = [np.broadcast_to(x, (*lead, x.shape[-1])).reshape(-1, x.shape[-1]).astype(np.float64)]
    for o, tail in others:
        shape = (*lead, *o.shape[o.ndim - tail:]) if tail else lead
        flat.append(np.broadcast_to(o, shape).reshape(-1, *o.shape[o.ndim - tail:]).astype(np.float64))
    return lead, flat


def _groups(dt):
    """Index groups of equal step length (one ``Space.step`` length each; a single group unless params are
    batched with different ``dt``)."""
    values = np.unique(dt)
    return [(float(v), np.nonzero(dt == v)[0]) for v in values]


def _kinematic_host(x, v, omega, wind, head, dt, substeps):
    lead, (x, v, omega, wind, head, dt) = _broadcast(
        np.asarray(x), (np.asarray(v), 0), (np.asarray(omega), 0), (np.asarray(wind), 1), (np.asarray(head), 0),
        (np.asarray(dt), 0))
    out = x.copy()
    turn = omega + head
    for h_total, idx in _groups(dt):
        h = h_total / substeps
        space, bodies = _BODIES.get(len(idx), "kinematic")
        for b, i in zip(bodies, idx):
            b.position = (x[i, 0], x[i, 1])
            b.angle = x[i, 2]
            b.angular_velocity = turn[i]
        for _ in range(substeps):
            for b, i in zip(bodies, idx):
                half = 0.5 * turn[i] * h
                rate = v[i] * np.sinc(half / np.pi)  # chord / h
                mid = b.angle + half
                b.velocity = (rate * math.cos(mid) + wind[i, 0], rate * math.sin(mid) + wind[i, 1])
            space.step(h)
        for b, i in zip(bodies, idx):
            out[i, 0], out[i, 1] = b.position
            out[i, 2] = b.angle
    return out.reshape(*lead, 3)


def _lag_mean(h: float, tau: float) -> float:
    """The weight of the initial offset in the mean of a first-order lag over ``h``: ``tau / h (1 - exp(-h / tau))``
    (0 without lag)."""
    return tau / h * -math.expm1(-h / tau) if tau > 0 else 0.0


def _dynamic_host(x, v_c, omega_c, wind, head, dt, cfg: RigidBodyConfig):
    lead, (x, v_c, omega_c, wind, head, dt) = _broadcast(
        np.asarray(x), (np.asarray(v_c), 0), (np.asarray(omega_c), 0), (np.asarray(wind), 1),
        (np.asarray(head), 0), (np.asarray(dt), 0))
    out = x.copy()
    wind = cfg.wind_coupling * wind
    start = x[:, 8] < 0.5
    # Take-off: at the commanded speed and turn rate, with the wind (as the Dubins plant).
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    x[start, 3] = v_c[start] * c[start] + wind[start, 0]
    x[start, 4] = v_c[start] * s[start] + wind[start, 1]
    x[start, 5] = omega_c[start] + head[start]
    x[start, 6], x[start, 7] = v_c[start], omega_c[start]
    for h_total, idx in _groups(dt):
        n_sub = max(1, math.ceil(h_total / cfg.max_substep - 1e-9))
        h = h_total / n_sub
        keep_v = math.exp(-h / cfg.speed_time_constant) if cfg.speed_time_constant > 0 else 0.0
        keep_w = math.exp(-h / cfg.turn_time_constant) if cfg.turn_time_constant > 0 else 0.0
        space, bodies = _BODIES.get(len(idx), "dynamic", cfg.mass, cfg.moment)
        v_a, w_a = x[idx, 6].copy(), x[idx, 7].copy()
        for b, i in zip(bodies, idx):
            b.position = (x[i, 0], x[i, 1])
            b.angle = x[i, 2]
            b.velocity = (x[i, 3], x[i, 4])
            b.angular_velocity = x[i, 5]
        # The drag relaxes the velocity to its target with time constant m / c_lin (yaw: I / c_ang). pymunk's
        # semi-implicit Euler step with the force m (target - v) (1 - exp(-h c / m)) / h lands on the exact
        # relaxation over h for a held target, and the target uses the actuator's mean over the substep.
        gain_v = cfg.mass * -math.expm1(-h / cfg.velocity_time_constant) / h
        gain_w = cfg.moment * -math.expm1(-h / cfg.yaw_time_constant) / h
        mean_v = _lag_mean(h, cfg.speed_time_constant)
        mean_w = _lag_mean(h, cfg.turn_time_constant)
        for _ in range(n_sub):
            va_mean = v_c[idx] + (v_a - v_c[idx]) * mean_v     # the exact first-order lag's mean over h ...
            wa_mean = omega_c[idx] + (w_a - omega_c[idx]) * mean_w
            v_a = v_c[idx] + (v_a - v_c[idx]) * keep_v         # ... and its value at the end of h
            w_a = omega_c[idx] + (w_a - omega_c[idx]) * keep_w
            for k, (b, i) in enumerate(zip(bodies, idx)):
                vx, vy = b.velocity
                th = b.angle
                b.force = (gain_v * (va_mean[k] * math.cos(th) - vx + wind[i, 0]),
                           gain_v * (va_mean[k] * math.sin(th) - vy + wind[i, 1]))
                b.torque = gain_w * (wa_mean[k] + head[i] - b.angular_velocity)
            space.step(h)
        for k, (b, i) in enumerate(zip(bodies, idx)):
            out[i, 0], out[i, 1] = b.position
            out[i, 2] = b.angle
            out[i, 3], out[i, 4] = b.velocity
            out[i, 5] = b.angular_velocity
            out[i, 6], out[i, 7], out[i, 8] = v_a[k], w_a[k], 1.0
    out[:, 2] = np.mod(out[:, 2] + np.pi, 2 * np.pi) - np.pi
    return out.reshape(*lead, x.shape[-1])


def _host_step(fn, x, control, wind, heading_disturbance, dt):
    """``fn(x, v, omega, wind, heading_disturbance, dt)`` on the host (every input broadcast per vehicle): a pure
    function of its inputs, batched by one call per vmap."""
    v, omega = control
    dt = jnp.broadcast_to(jnp.asarray(dt, x.dtype), jnp.shape(v))
    args = (v, omega, wind, heading_disturbance, dt)
    dtype = np.dtype(x.dtype)

    def host(*a):
        with _BODIES.lock:
            return np.ascontiguousarray(fn(*a), dtype)

    return jax.pure_callback(host, jax.ShapeDtypeStruct(x.shape, x.dtype), x, *args, vmap_method="expand_dims")


# ------------------------------------------------------------------------------------------------ models
@dataclasses.dataclass(frozen=True)
class PymunkKinematic(Dubins):
    """The papers' Dubins vehicle as a pymunk kinematic body (see the module docstring): the same state, actions
    and controller mapping as :class:`~stp_env.sim.vehicle_models.Dubins` (inherited); the motion is pymunk's.

    Attributes:
        substeps: pymunk steps per inner control step (each sets the body's velocity; any number gives the exact
            zero-order-hold motion).
    """

    substeps: int = 1
    name = "pymunk-kinematic"

    def __post_init__(self) -> None:
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1; got {self.substeps!r}.")
        require_pymunk()

    def step(self, x, control, wind, heading_disturbance, dt):
        new = _host_step(lambda *a: _kinematic_host(*a, self.substeps), x, control, wind, heading_disturbance, dt)
        return new.at[..., 2].set(wrap_angle(new[..., 2]))


def _check(name: str, value, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"RigidBodyConfig.{name} must be a finite number; got {value!r}.")
    if value < 0 or (positive and value == 0):
        raise ValueError(f"RigidBodyConfig.{name} must be {'> 0' if positive else '>= 0'}; got {value!r}.")
    return float(value)


@dataclasses.dataclass(frozen=True, kw_only=True)
class RigidBodyConfig:
    """Physical parameters of :class:`PymunkRigidBody` (SI units). The defaults describe a small multirotor-class
    vehicle (illustrative values, not identified from a real airframe): velocity and yaw-rate body time constants
    ``m / c_lin = I / c_ang = 0.05 s`` and actuator lags of 0.1 s.

    Attributes:
        mass: ``m`` [kg] (default 1.0).
        moment: moment of inertia about the vertical axis ``I`` [kg m^2] (default 0.01).
        linear_drag: ``c_lin`` [N s/m], drag per unit air-relative velocity; thrust is ``c_lin v_a`` (default 20).
        angular_drag: ``c_ang`` [N m s/rad], yaw damping and yaw-rate controller gain (default 0.2).
        speed_time_constant: first-order lag of the speed actuator [s] (default 0.1; 0: none).
        turn_time_constant: first-order lag of the turn-rate actuator [s] (default 0.1; 0: none).
        wind_coupling: ``kappa_w``: the drag acts on the velocity relative to ``kappa_w`` times the wind (default
            1: the wind is moving air; 0: the vehicle ignores it).
        max_substep: longest pymunk step [s] (default 0.005); must be at most a quarter of ``m / c_lin`` and of
            ``I / c_ang`` (semi-implicit Euler on the drag: stable and monotone).
    """

    mass: float = 1.0
    moment: float = 0.01
    linear_drag: float = 20.0
    angular_drag: float = 0.2
    speed_time_constant: float = 0.1
    turn_time_constant: float = 0.1
    wind_coupling: float = 1.0
    max_substep: float = 0.005

    def __post_init__(self) -> None:
        for name in ("mass", "moment", "linear_drag", "angular_drag", "max_substep"):
            object.__setattr__(self, name, _check(name, getattr(self, name), positive=True))
        for name in ("speed_time_constant", "turn_time_constant", "wind_coupling"):
            object.__setattr__(self, name, _check(name, getattr(self, name)))
        for label, tau in (("mass / linear_drag", self.mass / self.linear_drag),
                           ("moment / angular_drag", self.moment / self.angular_drag)):
            if self.max_substep > 0.25 * tau:
                raise ValueError(f"RigidBodyConfig.max_substep ({self.max_substep} s) must be at most a quarter of "
                                 f"{label} ({tau:.4g} s): pymunk's semi-implicit Euler step would overshoot the "
                                 "drag's relaxation.")

    @property
    def velocity_time_constant(self) -> float:
        """``m / c_lin`` [s]."""
        return self.mass / self.linear_drag

    @property
    def yaw_time_constant(self) -> float:
        """``I / c_ang`` [s]."""
        return self.moment / self.angular_drag


@dataclasses.dataclass(frozen=True)
class PymunkRigidBody(Dubins):
    """A dynamic pymunk body with mass, inertia, drag, actuator lags and wind as an aerodynamic force (see the
    module docstring and :class:`RigidBodyConfig`). Actions as for Dubins: ``[-1, 1]^2`` to the commanded
    ``(v_c, omega_c)``; the papers' controllers command through the same mapping (inherited from
    :class:`~stp_env.sim.vehicle_models.Dubins`); the state and the motion are the body's."""

    config: RigidBodyConfig = dataclasses.field(default_factory=RigidBodyConfig)
    name = "pymunk-rigid-body"
    state_dim = 9

    def __post_init__(self) -> None:
        if not isinstance(self.config, RigidBodyConfig):
            raise ValueError(f"config must be a RigidBodyConfig; got {type(self.config).__name__}.")
        require_pymunk()

    def step(self, x, control, wind, heading_disturbance, dt):
        return _host_step(lambda *a: _dynamic_host(*a, self.config), x, control, wind, heading_disturbance, dt)

    def pose(self, x):
        return x[..., :3]

    def from_pose(self, pose):
        zeros = jnp.zeros((*pose.shape[:-1], self.state_dim - 3), pose.dtype)
        return jnp.concatenate([pose, zeros], axis=-1)

