"""The wind-model interface and what the models share (the disk radii, sampling, heading disturbances)."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from stp_env.sim.bounds import HEADING_DISTURBANCE, WIND
from stp_env.sim.physics import disk_sample


def radii(params):
    """Each agent's wind bound ``(N + 1,)`` [m/s]: ``d_r`` for the vehicles, then ``d_I`` for the intruder."""
    n = params.n_vehicles
    return jnp.concatenate([jnp.full((n,), params.vehicle_bounds[WIND]), params.intruder_bounds[WIND:WIND + 1]])


def heading_bounds(params):
    """Each agent's heading-rate disturbance bound ``(N + 1,)`` [rad/s]."""
    n = params.n_vehicles
    return jnp.concatenate([jnp.full((n,), params.vehicle_bounds[HEADING_DISTURBANCE]),
                            params.intruder_bounds[HEADING_DISTURBANCE:HEADING_DISTURBANCE + 1]])


def uniform_in_disks(key, params):
    """A wind uniformly in each agent's disk ``(N + 1, 2)``."""
    return disk_sample(jax.random.uniform(key, (params.n_vehicles + 1, 2)), radii(params))


@dataclasses.dataclass(frozen=True)
class WindModel(abc.ABC):
    """A wind model: a frozen (hashable) dataclass whose fields are its parameters, checked in
    ``__post_init__``. Subclasses set :attr:`name` and :attr:`help` and implement :meth:`draw` (abstract: a
    subclass without it fails at instantiation with a ``TypeError``), and override :meth:`initial` if the wind
    persists across steps, :meth:`inner` if it depends on the state within a step. All methods are pure and
    jittable."""

    name: ClassVar[str] = ""
    help: ClassVar[str] = ""
    order: ClassVar[int] = 100  # position in listings (the papers' model first)

    def initial(self, key, params):
        """The wind state at reset ``(N + 1, 2)`` (:attr:`~stp_env.sim.types.EnvState.wind`); zeros here."""
        del key
        return jnp.zeros((params.n_vehicles + 1, 2))

    @abc.abstractmethod
    def draw(self, key, state, params):
        """``(winds (N + 1, 2), new wind state (N + 1, 2))`` for the step starting at ``state``."""
        raise NotImplementedError

    def sample(self, key, state, params):
        """``(winds (N + 1, 2), heading disturbances (N + 1,), new wind state (N + 1, 2))`` for this step: the
        winds are held over its inner steps unless :meth:`inner` replaces them; the heading disturbances are
        uniform in their bounds."""
        k1, k2 = jax.random.split(key)
        hd = (2 * jax.random.uniform(k2, (params.n_vehicles + 1,)) - 1) * heading_bounds(params)
        winds, new = self.draw(k1, state, params)
        return winds, hd, new

    state_dependent: ClassVar[bool] = False
    """True when :meth:`inner` computes the winds from the state at every inner step."""

    def inner(self, state, params, held):
        """The winds ``(N + 1, 2)`` at an inner step's state; ``held`` (this step's draw) here."""
        del state, params
        return held
