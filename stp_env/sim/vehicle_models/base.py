"""The plant interface of the simulator's vehicles."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar


@dataclasses.dataclass(frozen=True)
class VehicleModel(abc.ABC):
    """A vehicle plant: a frozen (hashable) dataclass, its fields its parameters. Every method is pure and
    jittable and broadcasts over leading axes. ``bounds`` is the bounds row of
    :class:`~stp_env.sim.types.EnvParams` (``vehicles.bounds``: ``v_min, v_max`` [m/s], ``omega_max`` [rad/s],
    wind [m/s], heading-rate disturbance [rad/s]; arrays, so they change without recompiling).

    The state's first two entries are the position [m] (the events and the domain checks read them). Every
    method is abstract: a subclass that misses one fails at instantiation (``TypeError`` naming it)."""

    name: ClassVar[str] = ""
    state_dim: ClassVar[int] = 3
    action_dim: ClassVar[int] = 2

    @abc.abstractmethod
    def action_to_control(self, action, bounds):
        """The control the plant applies for an action in ``[-1, 1]^action_dim`` (clipped)."""
        raise NotImplementedError

    @abc.abstractmethod
    def step(self, x, control, wind, heading_disturbance, dt):
        """The state after ``dt`` with ``control``, ``wind`` ``(..., 2)`` [m/s] and the heading-rate disturbance
        held (the plant may ignore what it has no use for)."""
        raise NotImplementedError

    @abc.abstractmethod
    def pose(self, x):
        """``(x, y, heading)`` ``(..., 3)``: what sensing (relative states, value tables), observations and the
        renderer read."""
        raise NotImplementedError

    @abc.abstractmethod
    def from_pose(self, pose):
        """The state at a plan's pose ``(..., 3)`` (take-off onto the nominal trajectory, and reset)."""
        raise NotImplementedError

    @abc.abstractmethod
    def command_to_action(self, x, v, omega, bounds):
        """The action that makes the plant at ``x`` follow a speed ``v`` [m/s] and turn rate ``omega`` [rad/s]:
        the command of the papers' controllers (the tracker ``kappa``, ``u^A``, the after-avoidance fallback),
        which are written for the HJ model's Dubins inputs. ``(..., action_dim)``."""
        raise NotImplementedError
