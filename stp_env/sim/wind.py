"""The winds of a step, from the environment's wind model (:mod:`stp_env.sim.winds`: one module per model,
registered by name; ``EnvParams.wind_model`` is a model or a registered name).

Every agent has its own wind in the disk of its bound (``d_r`` for vehicles, ``d_I`` for the intruder; intruder
paper eq. 43), and a heading-rate disturbance in ``[-d_theta, d_theta]`` where the vehicle model has one (SPP
eq. 28).
"""

from __future__ import annotations

from stp_env.sim import winds
from stp_env.sim.types import EnvParams, EnvState
from stp_env.sim.winds.worst import worst_winds


def model(params: EnvParams) -> winds.WindModel:
    """The environment's wind model (a registered name is made with its default parameters)."""
    return winds.make(params.wind_model)


def initial_wind(key, params: EnvParams):
    """Wind state at reset ``(N + 1, 2)``."""
    return model(params).initial(key, params)


def sample(key, state: EnvState, params: EnvParams):
    """``(winds (N + 1, 2), heading disturbances (N + 1,), new wind state (N + 1, 2))`` for this step (held over
    its inner steps unless the model is state-dependent: see :func:`inner`)."""
    return model(params).sample(key, state, params)


def inner(state: EnvState, params: EnvParams, held):
    """The winds at an inner step's state: ``held`` (this step's :func:`sample`) unless the model recomputes them
    from the state (``"worst"``)."""
    return model(params).inner(state, params, held)


def worst(state: EnvState, params: EnvParams):
    """The ``"worst"`` model's winds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    return worst_winds(state, params)
