"""The winds of a step, from the environment's wind model (:mod:`stp_env.sim.winds`: one module per model,
registered by name; ``EnvParams.wind_model`` is a model or a registered name).

Every agent has its own wind in the disk of its bound (``d_r`` for vehicles, ``d_I`` for the intruder; intruder
paper eq. 43), and a heading-rate disturbance in ``[-d_theta, d_theta]`` where the vehicle model has one (SPP
eq. 28). The reachability tables and the tracking bound are certified for those bounds only, so the winds and
disturbances a model returns pass through :func:`within_bounds` on their way to the motion: a plug-in model cannot
push them past what the guarantees assume.
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.sim import winds
from stp_env.sim.fleet import agent_rows, fleet_size
from stp_env.sim.types import EnvParams, EnvState
from stp_env.sim.winds.base import heading_bounds, radii
from stp_env.sim.winds.worst import worst_winds

BOUND_TOLERANCE = 1e-5
"""Relative slack of :func:`within_bounds`: a wind on its disk's boundary, computed in float32 (``"worst"``,
``"tailwind"``), is left as it is, bit for bit."""


def within_bounds(params: EnvParams, wind, heading=None):
    """``wind`` ``(N + 1, 2)`` with every vector longer than its agent's bound (:func:`~stp_env.sim.winds.base.radii`,
    beyond :data:`BOUND_TOLERANCE`) scaled back onto it, and ``heading`` ``(N + 1,)`` clipped to its bounds."""
    r = radii(params)
    norm = jnp.linalg.norm(wind, axis=-1)
    scale = jnp.where(norm > r * (1 + BOUND_TOLERANCE), r / jnp.maximum(norm, 1e-30), 1.0)
    wind = wind * scale[:, None].astype(wind.dtype)
    if heading is None:
        return wind
    hb = heading_bounds(params)
    return wind, jnp.clip(heading, -hb, hb)


def model(params: EnvParams) -> winds.WindModel:
    """The environment's wind model (a registered name is made with its default parameters)."""
    return winds.make(params.wind.model)


def initial_wind(key, params: EnvParams):
    """Wind state at reset ``(F + 1, 2)``: a row per agent of the whole fleet (``F = N`` unless part of a fleet is
    simulated, :mod:`stp_env.sim.fleet`); ``ValueError`` for a model that gives another shape."""
    wind = model(params).initial(key, params)
    expected = (fleet_size(params) + 1, 2)
    if tuple(wind.shape) != expected:
        raise ValueError(f"wind model {model(params).name!r}: initial() must return the wind state of the whole "
                         f"fleet, shape {expected}; got {tuple(wind.shape)} (size it with "
                         "stp_env.sim.fleet.fleet_size(params), not params.vehicles.n).")
    return wind


def _simulated(params: EnvParams, per_agent):
    """A model's per-agent output for the simulated agents ``(N + 1, ...)``: a model may return it for the whole
    fleet ``(F + 1, ...)`` (shaped like the wind state), whose rows are then taken (:mod:`stp_env.sim.fleet`)."""
    n, f = params.vehicles.n, fleet_size(params)
    if f != n and per_agent.shape[0] == f + 1:
        return agent_rows(params, per_agent)
    return per_agent


def sample(key, state: EnvState, params: EnvParams):
    """``(winds (N + 1, 2), heading disturbances (N + 1,), new wind state (F + 1, 2))`` for this step (held over
    its inner steps unless the model is state-dependent: see :func:`inner`)."""
    winds_now, heading, new = model(params).sample(key, state, params)
    winds_now, heading = within_bounds(params, _simulated(params, winds_now), _simulated(params, heading))
    return winds_now, heading, new


def inner(state: EnvState, params: EnvParams, held):
    """The winds at an inner step's state: ``held`` (this step's :func:`sample`) unless the model recomputes them
    from the state (``"worst"``)."""
    return within_bounds(params, _simulated(params, model(params).inner(state, params, held)))


def worst(state: EnvState, params: EnvParams):
    """The ``"worst"`` model's winds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    return worst_winds(state, params)
