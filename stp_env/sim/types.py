"""State and parameters of the pure simulation core (arrays only, so that ``reset`` and ``step`` jit and vmap).

``EnvParams`` holds everything a step needs (bounds, plans, value tables); ``EnvState`` what changes every step.
Both are pytrees (``jax.tree_util.register_dataclass``). Static sizes (vehicle count, grids, wind model) are
metadata fields: they are part of the compiled program, so changing them recompiles; every array field can change
without recompiling, and ``EnvState`` fields can be batched with ``vmap``.

Frames and units: SI (m, s, rad), world frame for absolute states, headings wrapped to ``[-pi, pi)``. Relative
states are in the vehicle's body frame (intruder paper eq. 44).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from stp_env.dynamics import RelativeDubins
from stp_env.hj.grid import Grid
from stp_env.sim.vehicle_models import Dubins

# Vehicle statuses (EnvState.status).
WAITING, FLYING, ARRIVED, COLLIDED, OUT_OF_BOUNDS = 0, 1, 2, 3, 4
STATUS_NAMES = ("waiting", "flying", "arrived", "collided", "out_of_bounds")
# Vehicle control modes (EnvState.mode): following the plan, avoiding the intruder (u^A, eq. 15), after avoidance
# (eq. 40: heading for the target with the fallback controller).
NOMINAL, AVOIDING, AFTER_AVOIDANCE = 0, 1, 2
MODE_NAMES = ("nominal", "avoiding", "after_avoidance")
# Intruder lifecycle (EnvState.intruder_status), Assumption 1.
PENDING, PRESENT, GONE = 0, 1, 2
INTRUDER_STATUS_NAMES = ("pending", "present", "gone")

SPAWN_MODES = ("outside", "boundary", "mixed")


class RewardWeights(NamedTuple):
    """The reward weights of :class:`stp_env.sim.config.RewardConfig` as arrays ``()``, read by name in the core
    (a NamedTuple: a pytree, so they change without recompiling)."""

    progress: jax.Array
    arrival: jax.Array
    late_arrival: jax.Array
    collision: jax.Array
    forced: jax.Array
    intruder_collision: jax.Array
    shaping: jax.Array


def _pytree(cls, meta=()):
    fields = [f.name for f in dataclasses.fields(cls)]
    return jax.tree_util.register_dataclass(cls, data_fields=[f for f in fields if f not in meta],
                                            meta_fields=list(meta))


@dataclasses.dataclass(frozen=True)
class EnvParams:
    """Constants of an environment (see :func:`stp_env.assembly.make_params`, which fills them from a scenario,
    a plan and the reachability artifacts). ``N`` vehicles, ``K`` plan samples, ``S`` avoid-region slices.

    Static (metadata, hashable):
        n_vehicles, avoid_grid, tracking_grid, sdf_grid: sizes and grids.
        avoid_dynamics: eq. (44) with the roles of eq. (14); tracking_dynamics: SPP eqs. (24)-(25).
        wind_model: a :class:`stp_env.sim.winds.WindModel` (or a registered name: its default parameters).
        vehicle_model: the vehicles' plant, a :class:`stp_env.sim.vehicle_models.VehicleModel` (the intruder flies
            Dubins).
        control_substeps: the vehicles' low-level controllers (the tracker ``kappa``, ``u^A``, any vehicle policy
            passed to :func:`stp_env.sim.core.step`) and the motion run this many times per step, at the inner
            control period ``dt / control_substeps``.
        safety_filter: override a vehicle's action with ``u^A`` from its avoid-start time (eq. 38).
        n_nearest: vehicles listed in each observation.
        buffer_grid: grid of ``buffer_values`` (``None`` when no buffer table is loaded).

    Optional (``None`` unless loaded with :func:`stp_env.assembly.with_buffer`; only the policies of the buffer
    game read it: the ``worst`` vehicles and the ``optimal-max-k`` intruder):
        buffer_values: ``V^B(0, t_BRD)`` of the plan's k̄ (intruder paper eqs. 46-47) on ``buffer_grid``.

    Optional (``None`` unless made by :func:`stp_env.sim.fleet.select`: the simulation of part of a fleet, the
    vehicles that can fly in the episode's window):
        vehicle_ids: ``(N,)`` int32, each simulated vehicle's index in the whole fleet (ascending).
        outside_waiting: ``()`` bool, whether a vehicle left out is still waiting to take off: the whole fleet is
            then never all done, so the episode does not end before ``t_end`` (:func:`stp_env.sim.core.episode_over`).
        fleet_size: (static) the whole fleet's vehicle count. Per-agent random draws are made for the whole fleet
            and the simulated agents' rows taken (:func:`stp_env.sim.fleet.agent_rows`), and the wind state
            (``EnvState.wind``) is the whole fleet's, so part of a fleet sees the same random numbers as all of it.
    """

    # --- time
    dt: jax.Array                 # () [s] step length (zero-order hold)
    t_start: jax.Array            # () [s] episode start time (plan time axis)
    t_end: jax.Array              # () [s] the episode is truncated here
    # --- domain and bounds
    domain_lo: jax.Array          # (2,) [m]
    domain_hi: jax.Array          # (2,) [m]
    vehicle_bounds: jax.Array     # (5,) v_min, v_max [m/s], omega_max [rad/s], wind [m/s], heading dist. [rad/s]
    #                               (the HJ model's bounds, read by the names of stp_env.sim.bounds: b[V_MAX]...;
    #                               the vehicle model maps actions with them)
    intruder_bounds: jax.Array    # (5,) the same for the intruder
    collision_radius: jax.Array   # () R_c [m]
    # --- plans (per vehicle)
    departure: jax.Array          # (N,) [s] departure time (t_LDT)
    sta: jax.Array                # (N,) [s]
    nominal_arrival: jax.Array    # (N,) [s] arrival time of each plan (inf if none)
    starts: jax.Array             # (N, 3) [m, m, rad] state on the ground
    targets: jax.Array            # (N, 2) [m]
    target_radii: jax.Array       # (N,) [m]
    nominal_t0: jax.Array         # (N,) [s] time of the first plan sample
    nominal_dt: jax.Array         # () [s] plan sample period
    nominal_states: jax.Array     # (N, K, 3) [m, m, rad], padded with the last sample
    nominal_controls: jax.Array   # (N, K, 2) [m/s, rad/s]
    nominal_len: jax.Array        # (N,) samples used
    certified: jax.Array          # (N,) bool: the guarantees' assumptions hold for this vehicle: its plan is a
    #                               flight of U^p and the simulator's inner period and margin are certified (false
    #                               only with EnvConfig.allow_uncertified); its violations are assumption failures
    planning_v_max: jax.Array     # () [m/s] fastest planning speed (fallback controller)
    # --- static obstacles
    sdf: jax.Array                # sdf_grid.shape [m] signed distance to buildings (negative inside)
    # --- reachability tables
    avoid_taus: jax.Array         # (S,) [s] ascending
    avoid_values: jax.Array       # (S, *avoid_grid.shape) V^A(tau_k, t_IAT) [m], periodic axes padded (tables.py)
    detection_range: jax.Array    # () d^A [m] (eq. 16)
    tracking_grads: jax.Array     # (*tracking_grid.shape, 3) gradient of W = -V of the tracking-error game, padded
    tracking_bound: jax.Array     # () r_e [m]
    # --- intruder
    t_iat: jax.Array              # () [s]
    appear_window: jax.Array      # (2,) [s] the intruder appears at t_ ~ U[lo, hi] (lo == hi: fixed)
    spawn_radius: jax.Array       # () [m] "outside" spawns lie within this distance of a flying vehicle
    spawn_boundary_probability: jax.Array  # () the episode's spawn is "boundary" with this probability, else "outside"
    avoid_margin: jax.Array       # () [m] avoid start when V^A <= margin (one inner step of the value's fastest fall,
    #                               the table's closed-loop error and rounding: stp_env.sim.margins)
    avoid_fall_rate: jax.Array    # () [m/s] the fastest fall of the interpolated V^A near its zero level: the check
    #                               can fire as low as avoid_margin - control_dt * avoid_fall_rate
    kbar: jax.Array               # () int, the bound under test
    d_sense: jax.Array            # () [m] sensing range (>= d^A)
    # --- rewards
    reward_weights: RewardWeights  # by name, see stp_env.sim.config.RewardConfig
    # --- static
    n_vehicles: int
    avoid_grid: Grid
    tracking_grid: Grid
    sdf_grid: Grid
    avoid_dynamics: RelativeDubins
    tracking_dynamics: RelativeDubins
    wind_model: Any = "uniform"
    vehicle_model: Any = dataclasses.field(default_factory=Dubins)
    safety_filter: bool = True
    n_nearest: int = 4
    control_substeps: int = 1
    # --- optional: the relative buffer region of the buffer game
    buffer_values: Any = None     # buffer_grid.shape V^B(0, t_BRD) [m], or None
    buffer_grid: Grid | None = None
    # --- optional: part of a fleet (stp_env.sim.fleet)
    vehicle_ids: Any = None       # (N,) int32 index of each simulated vehicle in the fleet, or None (all of it)
    outside_waiting: Any = None   # () bool: a vehicle left out waits to take off (the fleet is never all done)
    fleet_size: int | None = None


EnvParams = _pytree(EnvParams, meta=("n_vehicles", "avoid_grid", "tracking_grid", "sdf_grid", "avoid_dynamics",
                                     "tracking_dynamics", "wind_model", "vehicle_model",
                                     "safety_filter", "n_nearest", "control_substeps", "buffer_grid",
                                     "fleet_size"))


@dataclasses.dataclass(frozen=True)
class EnvState:
    """Everything that changes during an episode (``N`` vehicles)."""

    t: jax.Array                  # () [s]
    step_count: jax.Array         # () int
    x: jax.Array                  # (N, state_dim) of the vehicle model; Dubins: [m, m, rad]
    status: jax.Array             # (N,) int, WAITING / FLYING / ARRIVED / COLLIDED / OUT_OF_BOUNDS
    mode: jax.Array               # (N,) int, NOMINAL / AVOIDING / AFTER_AVOIDANCE
    avoid_start: jax.Array        # (N,) [s] t_i of eqs. 17-18 (inf: never)
    complied: jax.Array           # (N,) bool: applied u^A at every step since t_i
    assumption_ok: jax.Array      # (N,) bool: the intruder appeared outside this vehicle's avoid region, and the
    #                               vehicle is certified (EnvParams.certified)
    used_filter: jax.Array        # (N,) bool: the safety filter replaced this step's action
    min_separation: jax.Array     # (N,) [m] smallest distance to another vehicle or the intruder so far
    arrival_time: jax.Array       # (N,) [s] (inf: not arrived)
    collision_time: jax.Array     # (N,) [s] (inf: none)
    collided_with_intruder: jax.Array  # (N,) bool
    guarantee_violation: jax.Array     # (N,) bool
    wind: jax.Array               # (F + 1, 2) [m/s] wind state per agent of the whole fleet (F = N unless part of
    #                               a fleet is simulated; constant and gust models), the intruder last
    intruder_x: jax.Array         # (3,) [m, m, rad]
    intruder_status: jax.Array    # () int, PENDING / PRESENT / GONE
    t_appear: jax.Array           # () [s] t_
    intruder_key: jax.Array       # key: randomness of scripted intruders for this episode
    intruder_memory: jax.Array    # (4,) spawn state (x, y, theta) and 0, drawn at reset (scripted intruders read it)
    intruder_distance: jax.Array  # (N,) [m] distance to the intruder (inf when absent)
    avoid_value: jax.Array        # (N,) [m] V^A(t - t_, t_IAT) of each flying vehicle (FAR when absent)
    avoid_action: jax.Array       # (N, action_dim) u^A (eq. 15) of each vehicle against the intruder (action)
    track_action: jax.Array       # (N, action_dim) kappa (SPP eq. 26) of each vehicle for its nominal trajectory
    tracking_error: jax.Array     # (N,) [m] distance to the nominal position (body-frame error ||e_p||)
    max_tracking_error: jax.Array  # (N,) [m] largest ||e_p|| at an inner step while flying its plan (nominal
    #                               mode, never forced); the robust-tracking guarantee bounds it by r_e
    tracked: jax.Array            # (N,) bool: applied kappa at every inner step while flying its plan
    tracking_violation: jax.Array  # (N,) bool: tracked, and max_tracking_error exceeded r_e


EnvState = _pytree(EnvState)

# EnvState fields with one row per simulated vehicle (axis 0 unbatched); the others are global or, ``wind``, the
# whole fleet's (stp_env.sim.fleet_expand.expand relies on this list; tests/test_fleet.py checks it against the
# shapes).
VEHICLE_FIELDS = ("x", "status", "mode", "avoid_start", "complied", "assumption_ok", "used_filter", "min_separation",
                  "arrival_time", "collision_time", "collided_with_intruder", "guarantee_violation",
                  "intruder_distance", "avoid_value", "avoid_action", "track_action", "tracking_error",
                  "max_tracking_error", "tracked", "tracking_violation")


def replace(obj: Any, **changes) -> Any:
    return dataclasses.replace(obj, **changes)


def n_forced(state: EnvState) -> jax.Array:
    """``|N^RP|`` (eq. 39): vehicles forced to avoid the intruder so far."""
    return jnp.sum(jnp.isfinite(state.avoid_start))
