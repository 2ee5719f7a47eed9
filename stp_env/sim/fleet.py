"""Simulating part of a fleet: only the vehicles that can fly in an episode's window, with the whole fleet's
random numbers.

An evaluation episode covers a window of a plan (town: 73-93 s of a 7-vehicle plan; the dense scenarios: 26-53 s of a
20-vehicle plan, ``stp_env.assembly.busiest_window``). Vehicles that arrived before the window starts, or depart
after it ends, stay outside the airspace for the whole episode: the core neither moves them nor lets them collide,
their avoid values are ``FAR``, spawns and observations consider flying vehicles only. Simulating only the others
(3 of 7 on town, 4 of 20 on the crossing) gives the same episode at a fraction of the cost: the pair distances
grow with the square of the count, the table reads linearly.

"The same episode" needs the same random numbers. Per-agent draws (winds, heading disturbances, the vehicle the
intruder spawns next to) have one row per agent, so part of a fleet draws for the whole fleet and takes its rows
(:func:`agent_rows`, :func:`random_vehicle`), and the wind state stays the whole fleet's. The vehicles left out are
put back by :func:`stp_env.sim.fleet_expand.expand` with the state the full simulation gives them: their reset
state, with the controllers' outputs (``u^A``, ``kappa``, the tracking error) refreshed at the final time as every
step's lifecycle does.

* :func:`airborne`: the vehicles that can fly in ``[t_start, t_end]`` (host side, from the plan).
* :func:`select`: ``EnvParams`` of those vehicles (``vehicles.ids``, ``vehicles.fleet_size`` set).
* :func:`stp_env.sim.fleet_expand.expand`: a state of the selected vehicles as the whole fleet's state (in a module
  above the core, whose reset and controllers it runs; this one is below it).

``tests/test_fleet.py`` compares evaluations against the whole fleet's (statuses, modes, forced sets, avoid starts
and flags equal; states up to rounding) and shows that leaving out a vehicle that flies is caught. Part of a fleet
is another compiled program of the same arithmetic: a last-bit difference can flip a bang-bang control at a tie
and part two trajectories by up to 200 m (more than 1 m in 2-6 episodes of 1,000), as another batch size does
(``docs/numerics.md``, "Two compiled programs of the same episode").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.sim.types import EnvParams

# EnvParams.vehicles fields with one entry per vehicle (axis 0); select() slices them.
PARAM_VEHICLE_FIELDS = ("departure", "sta", "nominal_arrival", "starts", "targets", "target_radii", "nominal_t0",
                        "nominal_states", "nominal_controls", "nominal_len", "certified")


def fleet_size(params: EnvParams) -> int:
    """The whole fleet's vehicle count (``vehicles.n`` unless part of a fleet is simulated)."""
    return params.vehicles.n if params.vehicles.fleet_size is None else params.vehicles.fleet_size


def agent_rows(params: EnvParams, draws):
    """The simulated agents' rows ``(N + 1, ...)`` of a per-agent array of the whole fleet ``(F + 1, ...)``
    (vehicles, then the intruder)."""
    if params.vehicles.ids is None:
        return draws
    ids = jnp.asarray(params.vehicles.ids, jnp.int32)
    return draws[jnp.concatenate([ids, jnp.full((1,), fleet_size(params), jnp.int32)])]


def random_vehicle(key, mask, params: EnvParams):
    """A simulated vehicle drawn uniformly among those in ``mask`` ``(N,)`` (any vehicle if none is), as the whole
    fleet would draw it: ``(index, any)``."""
    if params.vehicles.ids is None:
        logits = jnp.where(mask, 0.0, -jnp.inf)
        return jax.random.categorical(key, jnp.where(jnp.any(mask), logits, 0.0)), jnp.any(mask)
    ids = jnp.asarray(params.vehicles.ids, jnp.int32)
    full = jnp.zeros((fleet_size(params),), bool).at[ids].set(mask)
    logits = jnp.where(full, 0.0, -jnp.inf)
    j_full = jax.random.categorical(key, jnp.where(jnp.any(full), logits, 0.0))
    # j_full is a simulated vehicle whenever any is in mask; otherwise the caller ignores the index
    return jnp.argmax(ids == j_full), jnp.any(mask)


def airborne(params: EnvParams) -> np.ndarray:
    """Indices (ascending) of the vehicles that can fly in ``[t_start, t_end]``: not arrived at the start (by their
    nominal arrival and state at ``t_start``, as :func:`stp_env.sim.core.reset` decides) and departing no later than
    one step after ``t_end``. The others never leave ``WAITING`` or ``ARRIVED`` in an episode."""
    if params.vehicles.ids is not None:
        raise ValueError("these params already simulate part of a fleet.")
    t1, dt = float(params.episode.t_end), float(params.episode.dt)
    # within 1 mm of the target's edge counts as not arrived: simulating a vehicle that is done is harmless
    arrived = np.asarray(jax.jit(arrived_at_start)(params, 1e-3))
    return np.flatnonzero(~arrived & (np.asarray(params.vehicles.departure, np.float64) <= t1 + dt))


def select(params: EnvParams, ids) -> EnvParams:
    """``params`` for the vehicles ``ids`` (ascending, distinct) of the whole fleet. Only exact when every vehicle
    left out stays outside the airspace for the whole episode (:func:`airborne`)."""
    if params.vehicles.ids is not None:
        raise ValueError("these params already simulate part of a fleet.")
    ids = np.asarray(ids)
    n = params.vehicles.n
    if ids.ndim != 1 or ids.size == 0 or not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(f"ids must be a non-empty 1-d array of vehicle indices; got {ids!r}.")
    if np.any(np.diff(ids) <= 0) or ids[0] < 0 or ids[-1] >= n:
        raise ValueError(f"ids must be ascending, distinct and in [0, {n}); got {ids.tolist()}.")
    sliced = {f: getattr(params.vehicles, f)[jnp.asarray(ids)] for f in PARAM_VEHICLE_FIELDS}
    rest = np.setdiff1d(np.arange(n), ids)
    waiting = ~arrived_at_start(params)[jnp.asarray(rest)] if rest.size else jnp.zeros((0,), bool)
    return params.replace(vehicles=dict(n=int(ids.size), ids=jnp.asarray(ids, jnp.int32),
                                        outside_waiting=jnp.any(waiting),
                                        fleet_size=n, **sliced))


def arrived_at_start(params: EnvParams, slack=0.0):
    """``(N,)`` bool: out of the airspace at ``t_start`` because it arrived: departed, and either its nominal
    trajectory reached the target by then (``nominal_arrival <= t_start``) or its nominal position is at least
    ``slack`` [m] inside the target disk (``slack = 0``: what :func:`stp_env.sim.core.reset` decides). Jittable.

    The arrival time decides, not only the position: a vehicle leaves the airspace when it reaches its target, and
    the planner's trajectory after that instant is not a flight. The city planner's trajectories fly on through the
    target disk (by up to 1 km in the shipped city plans), and judged by position alone those vehicles would be
    back in the air at the episode's start, on top of each other at the trajectories' last samples."""
    from stp_env.sim.reference import nominal_reference

    x_nom, _ = nominal_reference(params, params.episode.t_start)
    departed = params.vehicles.departure <= params.episode.t_start
    landed = params.vehicles.nominal_arrival <= params.episode.t_start
    inside = jnp.hypot(*(x_nom[:, :2] - params.vehicles.targets).T) <= params.vehicles.target_radii - slack
    return departed & (landed | inside)
