"""The whole fleet back from part of it (:mod:`stp_env.sim.fleet`): the vehicles left out of a simulation, put back
with the state the full simulation gives them (their reset state, with the controllers' outputs refreshed at the
final time, as every step's lifecycle does). Above the core, whose reset and controllers it runs; ``fleet`` is
below it (the core draws its random numbers for the whole fleet with it)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.sim import core
from stp_env.sim.fleet import select
from stp_env.sim.types import VEHICLE_FIELDS, EnvParams, EnvState, replace


def parked_state(params: EnvParams, ids) -> EnvState:
    """The reset state of the fleet's vehicles ``ids`` (of ``params``, the whole fleet), which the episode never
    changes when they are outside the airspace throughout (their rows only; the global fields are unused)."""
    return core.reset(jax.random.key(0), select(params, ids))


def expand(state: EnvState, params: EnvParams, ids, parked: EnvState | None) -> EnvState:
    """The whole fleet's state (one episode) from ``state``, of the fleet's vehicles ``ids`` (numpy, as given to
    :func:`~stp_env.sim.fleet.select`), and the ``parked`` rows of the others (:func:`parked_state`; ``None`` when
    none is left out). The parked rows get the controllers' outputs at ``state``'s time and intruder, as the full
    simulation's lifecycle computes them for vehicles on the ground."""
    n = params.vehicles.n
    ids = np.asarray(ids)
    rest = np.setdiff1d(np.arange(n), ids)
    if rest.size == 0:
        return state
    if parked is None:
        raise ValueError("the vehicles left out need their parked state.")
    now = replace(parked, t=state.t, intruder_x=state.intruder_x, intruder_status=state.intruder_status,
                  t_appear=state.t_appear)
    now = core.refresh_controllers(now, select(params, rest))
    rows = {}
    for name in VEHICLE_FIELDS:
        a, b = getattr(state, name), getattr(now, name)
        full = jnp.zeros((n, *a.shape[1:]), a.dtype)
        rows[name] = full.at[jnp.asarray(ids)].set(a).at[jnp.asarray(rest)].set(b.astype(a.dtype))
    return replace(state, **rows)


def expand_trajectory(traj: dict, params: EnvParams, ids, parked: EnvState) -> dict:
    """A recorded trajectory (:func:`stp_env.sim.rollout`, batched ``(B, T, ...)``) of the vehicles ``ids`` as the
    whole fleet's: the others keep their parked pose, status and mode, and get zero rewards (the core rewards
    only flying vehicles)."""
    n = params.vehicles.n
    ids = np.asarray(ids)
    rest = np.setdiff1d(np.arange(n), ids)
    out = dict(traj)
    for name in ("x", "status", "mode"):
        a = traj[name]
        full = jnp.broadcast_to(getattr(parked, name).astype(a.dtype), (*a.shape[:2], rest.size, *a.shape[3:]))
        out[name] = jnp.zeros((*a.shape[:2], n, *a.shape[3:]), a.dtype).at[:, :, ids].set(a).at[:, :, rest].set(
            full)
    r = traj["rewards"]
    out["rewards"] = jnp.zeros((*r.shape[:2], n + 1), r.dtype).at[:, :, np.append(ids, n)].set(r)
    return out
