"""Which agents do what now, read from the core's state: the predicates the step, the observations and the
rewards share (:mod:`stp_env.sim.core`, :mod:`stp_env.sim.observations`, :mod:`stp_env.sim.rewards`)."""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.sim.types import ARRIVED, FLYING, NOMINAL, PRESENT, EnvParams, EnvState


def poses(params: EnvParams, state: EnvState):
    """Every vehicle's pose ``(x, y, heading)`` ``(N, 3)`` from its state (the vehicle model's
    :meth:`~stp_env.sim.vehicle_models.VehicleModel.pose`): what sensing, the value tables and the observations
    read."""
    return params.vehicles.model.pose(state.x)


def flying(state: EnvState):
    return state.status == FLYING


def intruder_present(state: EnvState):
    return state.intruder_status == PRESENT


def on_plan(state: EnvState):
    """Vehicles the robust-tracking guarantee covers now: flying their plan (nominal mode, never forced)."""
    return flying(state) & (state.mode == NOMINAL) & ~jnp.isfinite(state.avoid_start)


def done_vehicles(state: EnvState):
    return state.status >= ARRIVED
