"""The wind-model interface and what the models share (the disk radii, sampling, heading disturbances)."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from stp_env.sim.bounds import HEADING_DISTURBANCE, WIND
from stp_env.sim.fleet import agent_rows, fleet_size
from stp_env.sim.physics import disk_sample


def radii(params, n: int | None = None):
    """Each agent's wind bound ``(n + 1,)`` [m/s] (``n``: the simulated vehicles by default): ``d_r`` for the
    vehicles, then ``d_I`` for the intruder."""
    n = params.vehicles.n if n is None else n
    return jnp.concatenate([jnp.full((n,), params.vehicles.bounds[WIND]), params.intruder.bounds[WIND:WIND + 1]])


def fleet_radii(params):
    """:func:`radii` of the whole fleet ``(F + 1,)`` (the wind state's rows; :mod:`stp_env.sim.fleet`)."""
    return radii(params, fleet_size(params))


def heading_bounds(params):
    """Each agent's heading-rate disturbance bound ``(N + 1,)`` [rad/s]."""
    n = params.vehicles.n
    return jnp.concatenate([jnp.full((n,), params.vehicles.bounds[HEADING_DISTURBANCE]),
                            params.intruder.bounds[HEADING_DISTURBANCE:HEADING_DISTURBANCE + 1]])


def uniform_in_fleet_disks(key, params):
    """A wind uniformly in each disk of the whole fleet's agents ``(F + 1, 2)``."""
    return disk_sample(jax.random.uniform(key, (fleet_size(params) + 1, 2)), fleet_radii(params))


def uniform_in_disks(key, params):
    """A wind uniformly in each simulated agent's disk ``(N + 1, 2)`` (drawn for the whole fleet)."""
    return agent_rows(params, uniform_in_fleet_disks(key, params))


@dataclasses.dataclass(frozen=True)
class WindModel(abc.ABC):
    """A wind model: a frozen (hashable) dataclass whose fields are its parameters, checked in
    ``__post_init__``. Subclasses set :attr:`name` and :attr:`help` and implement :meth:`draw` (abstract: a
    subclass without it fails at instantiation with a ``TypeError``), and override :meth:`initial` if the wind
    persists across steps, :meth:`inner` if it depends on the state within a step. All methods are pure and
    jittable.

    The wind state has a row per agent of the whole fleet ``(F + 1, 2)``; the winds and heading disturbances a
    model returns may have a row per simulated agent ``(N + 1, ...)`` or per agent of the whole fleet (shaped like
    the wind state: :mod:`stp_env.sim.wind` then takes the simulated agents' rows). ``F = N`` unless part of a
    fleet is simulated (:mod:`stp_env.sim.fleet`): random draws are then made for the whole fleet and the rows
    taken (:func:`stp_env.sim.fleet.agent_rows`), so that part of a fleet sees the same winds."""

    name: ClassVar[str] = ""
    help: ClassVar[str] = ""
    order: ClassVar[int] = 100  # position in listings (the papers' model first)

    def initial(self, key, params):
        """The wind state at reset ``(F + 1, 2)`` (:attr:`~stp_env.sim.types.EnvState.wind`); zeros here."""
        del key
        return jnp.zeros((fleet_size(params) + 1, 2))

    @abc.abstractmethod
    def draw(self, key, state, params):
        """``(winds (N + 1, 2), new wind state (F + 1, 2))`` for the step starting at ``state``."""
        raise NotImplementedError

    def sample(self, key, state, params):
        """``(winds (N + 1, 2), heading disturbances (N + 1,), new wind state (F + 1, 2))`` for this step: the
        winds are held over its inner steps unless :meth:`inner` replaces them; the heading disturbances are
        uniform in their bounds."""
        k1, k2 = jax.random.split(key)
        hd = (2 * agent_rows(params, jax.random.uniform(k2, (fleet_size(params) + 1,))) - 1) * heading_bounds(params)
        winds, new = self.draw(k1, state, params)
        return winds, hd, new

    state_dependent: ClassVar[bool] = False
    """True when :meth:`inner` computes the winds from the state at every inner step."""

    def inner(self, state, params, held):
        """The winds ``(N + 1, 2)`` at an inner step's state; ``held`` (this step's draw) here."""
        del state, params
        return held


@dataclasses.dataclass(frozen=True)
class StateFeedbackWind(WindModel):
    """A wind that is a function of the state, computed afresh at every inner step by :meth:`inner` (which
    subclasses implement): nothing is drawn or held, and there is no random heading disturbance."""

    state_dependent: ClassVar[bool] = True

    def draw(self, key, state, params):
        """Zeros (held winds unused: :meth:`inner` computes the winds at every inner step); the state unchanged."""
        del key
        return jnp.zeros((params.vehicles.n + 1, 2)), state.wind

    def sample(self, key, state, params):
        """No random heading disturbance either: the wind is all :meth:`inner`'s."""
        winds, new = self.draw(key, state, params)
        return winds, jnp.zeros((params.vehicles.n + 1,)), new

    @abc.abstractmethod
    def inner(self, state, params, held):
        """The winds ``(N + 1, 2)`` at an inner step's state (``held`` is unused)."""
        raise NotImplementedError
