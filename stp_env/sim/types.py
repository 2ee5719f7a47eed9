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

from stp_env import catalog
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

SPAWN_MODES = catalog.SPAWN_MODES


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
    kbar_reached: jax.Array


def _pytree(cls, meta=()):
    fields = [f.name for f in dataclasses.fields(cls)]
    return jax.tree_util.register_dataclass(cls, data_fields=[f for f in fields if f not in meta],
                                            meta_fields=list(meta))


@dataclasses.dataclass(frozen=True)
class EpisodeParams:
    """When and where an episode runs, and what it pays (``params.episode``)."""

    dt: jax.Array                 # () [s] step length (zero-order hold)
    t_start: jax.Array            # () [s] episode start time (plan time axis)
    t_end: jax.Array              # () [s] the episode is truncated here
    domain_lo: jax.Array          # (2,) [m]
    domain_hi: jax.Array          # (2,) [m]
    collision_radius: jax.Array   # () R_c [m]
    reward_weights: RewardWeights  # by name, see stp_env.sim.config.RewardConfig
    # --- static
    safety_filter: bool = True    # override a vehicle's action with u^A from its avoid-start time (eq. 38)
    n_nearest: int = 4            # vehicles listed in each observation
    control_substeps: int = 1     # inner control steps per step (period dt / control_substeps)


@dataclasses.dataclass(frozen=True)
class VehicleParams:
    """The vehicles: their plant, bounds and plans (``params.vehicles``; ``N`` vehicles, ``K`` plan samples)."""

    bounds: jax.Array             # (5,) v_min, v_max [m/s], omega_max [rad/s], wind [m/s], heading dist. [rad/s]
    #                               (the HJ model's bounds, read by the names of stp_env.sim.bounds: b[V_MAX]...;
    #                               the vehicle model maps actions with them)
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
    # --- static
    n: int                        # vehicles simulated
    model: Any = dataclasses.field(default_factory=Dubins)  # the plant, a stp_env.sim.vehicle_models.VehicleModel
    # --- optional: part of a fleet (stp_env.sim.fleet.select)
    ids: Any = None               # (N,) int32 index of each simulated vehicle in the fleet, or None (all of it)
    outside_waiting: Any = None   # () bool: a vehicle left out waits to take off (the fleet is never all done)
    fleet_size: int | None = None  # (static) the whole fleet's vehicle count


@dataclasses.dataclass(frozen=True)
class IntruderParams:
    """The intruder of the game and the bound it tests (``params.intruder``; Assumption 1)."""

    bounds: jax.Array             # (5,) as VehicleParams.bounds, for the intruder (it flies Dubins)
    t_iat: jax.Array              # () [s]
    appear_window: jax.Array      # (2,) [s] the intruder appears at t_ ~ U[lo, hi] (lo == hi: fixed)
    spawn_radius: jax.Array       # () [m] "outside" spawns lie within this distance of a flying vehicle
    spawn_boundary_probability: jax.Array  # () the episode's spawn is "boundary" with this probability, else "outside"
    kbar: jax.Array               # () int, the bound under test
    d_sense: jax.Array            # () [m] sensing range (>= d^A)


@dataclasses.dataclass(frozen=True)
class TableParams:
    """Every grid table the step interpolates, with the numbers derived from them (``params.tables``; ``S`` avoid
    slices)."""

    sdf: jax.Array                # sdf_grid.shape [m] signed distance to buildings (negative inside)
    avoid_taus: jax.Array         # (S,) [s] ascending
    avoid_values: jax.Array       # (S, *avoid_grid.shape) V^A(tau_k, t_IAT) [m], periodic axes padded (tables.py)
    detection_range: jax.Array    # () d^A [m] (eq. 16)
    avoid_margin: jax.Array       # () [m] avoid start when V^A <= margin (one inner step of the value's fastest fall,
    #                               the table's closed-loop error and rounding: stp_env.sim.margins)
    avoid_fall_rate: jax.Array    # () [m/s] the fastest fall of the interpolated V^A near its zero level: the check
    #                               can fire as low as avoid_margin - control_dt * avoid_fall_rate
    tracking_table: jax.Array     # (*tracking_grid.shape, 4) the gradient of W = -V of the tracking-error game (3)
    #                               and V itself [m], padded (one block read gives kappa and the value)
    tracking_bound: jax.Array     # () r_e [m]
    tracking_free_level: jax.Array  # () [m] a tube-keeping filter lets a vehicle on its plan leave kappa only
    #                               while V(e) <= this level (V(0) less one inner step of V's fastest rise under
    #                               any control: stp_env.sim.margins.tube_free_level)
    # --- static
    sdf_grid: Grid
    avoid_grid: Grid
    tracking_grid: Grid
    avoid_dynamics: RelativeDubins     # eq. (44) with the roles of eq. (14)
    tracking_dynamics: RelativeDubins  # SPP eqs. (24)-(25)
    # --- optional: the relative buffer region of the buffer game (stp_env.assembly.with_buffer)
    buffer_values: Any = None     # buffer_grid.shape V^B(0, t_BRD) of the plan's k̄ [m] (eqs. 46-47), or None
    buffer_grid: Grid | None = None
    # --- optional: the tables a plug-in registers (stp_env.requirements.register_table), loaded for the policies
    #     that read them; read by name with stp_env.sim.tables.extra_table
    extra: tuple = ()             # Table, one per name, sorted by name


@dataclasses.dataclass(frozen=True)
class Table:
    """A grid table beyond the built-in ones (``params.tables.extra``): what a plug-in policy reads by ``name``
    (:func:`stp_env.sim.tables.extra_table`, :func:`stp_env.sim.tables.table_value`). The name and the grid are
    static: a table of another shape or grid is another compiled program."""

    values: jax.Array             # grid.shape
    # --- static
    name: str
    grid: Grid


@dataclasses.dataclass(frozen=True)
class WindParams:
    """The wind (``params.wind``); its bound is ``vehicles.bounds[WIND]``."""

    model: Any = "uniform"        # a stp_env.sim.winds.WindModel (or a registered name: its default parameters)


EpisodeParams = _pytree(EpisodeParams, meta=("safety_filter", "n_nearest", "control_substeps"))
VehicleParams = _pytree(VehicleParams, meta=("n", "model", "fleet_size"))
IntruderParams = _pytree(IntruderParams)
TableParams = _pytree(TableParams, meta=("sdf_grid", "avoid_grid", "tracking_grid", "avoid_dynamics",
                                         "tracking_dynamics", "buffer_grid"))
Table = _pytree(Table, meta=("name", "grid"))
WindParams = _pytree(WindParams, meta=("model",))

GROUPS = {"episode": EpisodeParams, "vehicles": VehicleParams, "intruder": IntruderParams, "tables": TableParams,
          "wind": WindParams}

@dataclasses.dataclass(frozen=True)
class EnvParams:
    """Constants of an environment, in five groups (see :func:`stp_env.assembly.make_params`, which fills them from
    a scenario, a plan and the reachability artifacts):

    * ``episode`` (:class:`EpisodeParams`): step length, time window, domain, ``R_c``, rewards, the inner control
      loop (``control_substeps``: the vehicles' low-level controllers — the tracker ``kappa``, ``u^A``, any vehicle
      policy passed to :func:`stp_env.sim.core.step` — and the motion run this many times per step), the safety
      filter switch and the observation size;
    * ``vehicles`` (:class:`VehicleParams`): the plant, its bounds and the plans; the optional fleet fields are set
      by :func:`stp_env.sim.fleet.select` (the simulation of the part of a fleet that can fly in the episode's
      window: per-agent random draws are made for the whole fleet and the simulated agents' rows taken, so part of
      a fleet sees the same random numbers as all of it);
    * ``intruder`` (:class:`IntruderParams`): its bounds, ``t_IAT``, spawn and appearance, and the k̄ under test;
    * ``tables`` (:class:`TableParams`): the signed distance to the buildings, ``V^A``, the tracking game's
      gradient and ``V^B`` (optional: only the buffer game's policies read it, loaded by
      :func:`stp_env.assembly.with_buffer`), with the numbers derived from them (``d^A``, the avoid margin, ``r_e``),
      and the tables plug-ins add (``extra``, by name; :mod:`stp_env.requirements` loads every table a run's
      policies read);
    * ``wind`` (:class:`WindParams`): the wind model.

    Static fields (sizes, grids, models, switches) are metadata: changing them recompiles. Change fields with
    :meth:`replace`: ``params.replace(episode={"t_end": t}, vehicles=new_vehicles)``.
    """

    episode: EpisodeParams
    vehicles: VehicleParams
    intruder: IntruderParams
    tables: TableParams
    wind: WindParams

    def replace(self, **groups) -> EnvParams:
        """A copy with groups changed: each value is a whole group or a mapping of that group's fields to new
        values."""
        changes = {}
        for name, value in groups.items():
            if name not in GROUPS:
                raise TypeError(f"EnvParams has no group {name!r} (groups: {', '.join(GROUPS)})")
            if isinstance(value, dict):
                value = dataclasses.replace(getattr(self, name), **value)
            elif not isinstance(value, GROUPS[name]):
                raise TypeError(f"EnvParams.{name} must be a {GROUPS[name].__name__} or a dict of its fields, "
                                f"not {type(value).__name__}")
            changes[name] = value
        return dataclasses.replace(self, **changes)


EnvParams = _pytree(EnvParams)


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
    #                               vehicle is certified (EnvParams.vehicles.certified)
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
    avoid_action: jax.Array       # (N, action_dim) u^A (eq. 15) against the intruder (action); 0 when absent, for
    #                               a vehicle not flying, and for one outside the avoid table's box that is not
    #                               avoiding (no one applies it there; sim.core.avoid_read_needed)
    track_action: jax.Array       # (N, action_dim) kappa (SPP eq. 26) of each vehicle for its nominal trajectory
    tracking_error: jax.Array     # (N,) [m] distance to the nominal position (body-frame error ||e_p||)
    tracking_value: jax.Array     # (N,) [m] V of the tracking game at the error (inf outside its table)
    max_tracking_error: jax.Array  # (N,) [m] largest ||e_p|| at an inner step while flying its plan (nominal
    #                               mode, never forced); the robust-tracking guarantee bounds it by r_e
    tracked: jax.Array            # (N,) bool: applied kappa at every inner step while flying its plan, except
    #                               where its tracking value was at most tables.tracking_free_level
    tracking_violation: jax.Array  # (N,) bool: tracked, and max_tracking_error exceeded r_e


EnvState = _pytree(EnvState)

# EnvState fields with one row per simulated vehicle (axis 0 unbatched); the others are global or, ``wind``, the
# whole fleet's (stp_env.sim.fleet_expand.expand relies on this list; tests/test_fleet.py checks it against the
# shapes).
VEHICLE_FIELDS = ("x", "status", "mode", "avoid_start", "complied", "assumption_ok", "used_filter", "min_separation",
                  "arrival_time", "collision_time", "collided_with_intruder", "guarantee_violation",
                  "intruder_distance", "avoid_value", "avoid_action", "track_action", "tracking_error",
                  "tracking_value", "max_tracking_error", "tracked", "tracking_violation")


def replace(obj: Any, **changes) -> Any:
    return dataclasses.replace(obj, **changes)


def n_forced(state: EnvState) -> jax.Array:
    """``|N^RP|`` (eq. 39): vehicles forced to avoid the intruder so far."""
    return jnp.sum(jnp.isfinite(state.avoid_start))
