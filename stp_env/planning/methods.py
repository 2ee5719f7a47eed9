"""Sequential trajectory planning with the centralized and the least-restrictive induced obstacles.

SPP paper Section IV-A (centralized control, eqs. 11-19) and Section IV-B (least-restrictive control, eqs.
20-23). Vehicles plan in priority order with the *full* control set ``U`` and the worst-case disturbance:

1. Vehicle ``j``'s BRS ``V_j(t)`` is the backward reach-avoid tube of its target under the time-varying obstacle
   ``G_j(t)`` of the higher-priority vehicles (double-obstacle VI, eqs. 7, 11-12), solved back from ``t_STA_j``
   minus an arrival margin of two cells' crossing at ``v_max`` and stopped once the start is inside;
   ``t_LDT`` is read from its time-to-reach; the nominal trajectory follows the planning controller of
   :func:`stp_env.planning.single.planning_control` (eq. 13).
2. The obstacle ``j`` induces for lower-priority vehicles is computed from a forward reachable set ``W_j(t)``
   started at ``x_j0`` at ``t_LDT_j`` (footnote 2: a ball of 1.5 cells around it, :func:`initial_ball`) and kept
   until ``t_STA_j``:

   * ``"centralized"``: ``W_j`` under the enforced feedback ``u_j^*(t, x)`` of eq. (13) -- exactly the planning
     controller, evaluated on the whole grid from the stored slices of ``V_j`` (:class:`SliceFeedback`), so the
     vehicle that flies this controller is the vehicle whose FRS was computed -- with every disturbance covered
     (eqs. 14-17; :class:`stp_env.hj.FeedbackDynamics`); ``P_j(t)`` is its projection on the position plane
     (eq. 19), taken of ``W_j ∩ V_j`` (equal to ``W_j`` in exact arithmetic, see :func:`induced_frs`). The true
     ``W_j`` is thinner than a heading cell; :func:`heading_floor` keeps the numerical set from vanishing.
   * ``"least_restrictive"``: ``W_j`` under every control and disturbance (eqs. 21-22), intersected with the BRS:
     ``P_j(t)`` is the projection of ``V_j(t) ∩ W_j(t)`` (eq. 23). Any controller that keeps the vehicle inside
     its BRS (eq. 20) keeps it inside ``P_j``.

   The obstacle is ``O_i^j(t) = {p : dist(p, P_j(t)) <= R_c}`` (eqs. 18, 23), stored as a table of lower bounds of
   ``dist(p, P_j(t_k)) - R_c`` on the position plane at FRS slice times ``t_k`` (:func:`projected_obstacle_table`:
   exact Euclidean distance to the nodes of ``P_j`` on a 4x finer grid, minus that grid's cell diagonal so that
   the sub-cell extent of the set is covered); between two slices the union of both is used
   (:func:`tabulated_obstacles`). It is present while ``j`` is in the air, ``[t_LDT_j, t_STA_j]``; before, the
   vehicle waits on the ground (as in :mod:`stp_env.planning.obstacles`).

Every higher-priority vehicle's tables have one shape and the feedback tables are traced, so one scenario compiles
each solver loop once.

Measured on the four-vehicle example (81 x 81 x 40, WENO5 + RK2, ``R_c = 0.1``; examples/four_vehicle_methods.py):
t_LDT centralized ``[-1.28, -2.17, -2.56, -2.96]``, least-restrictive ``[-1.28, -2.20, -2.65, -3.31]`` (paper:
``[-1.35, -1.37, -1.94, -2.04]`` and ``[-1.35, -1.97, -2.66, -3.39]``, R_c not stated). Q2 departs much earlier
than in the paper under both methods: Q1 flies head-on toward it, and the latest feasible plan found by the BRS
passes Q1's start position just before Q1 departs (about -1.3 s), not Q1's in-flight obstacle.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage
from tqdm.auto import tqdm

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.hj.derivatives import central_gradient
from stp_env.planning.plan import Plan, VehiclePlan
from stp_env.planning.single import InfeasiblePlanError, initial_ball, plan_single_with_slices, saturated_control

METHODS = ("centralized", "least_restrictive")
NO_OBSTACLE = 1e6
"""Obstacle value where a vehicle induces none (far above any distance on a planning grid)."""
FINE = 4
"""Refinement of the position plane on which distances to ``P_j`` are measured."""


# --------------------------------------------------------------------------------------------- controllers
@dataclasses.dataclass(frozen=True)
class SliceFeedback:
    """The enforced feedback ``u^*(t, x)`` of eq. (13) on the whole grid, for :class:`stp_env.hj.FeedbackDynamics`.

    ``params``: ``slice_times`` (ascending, ``(K,)``) and ``stack`` (``(K, *grid.shape)``), the BRS slices. At time
    ``t`` the value is blended linearly between the two bracketing slices, differentiated by central differences
    and turned into the control by :func:`saturated_control`: at grid nodes this is what
    :func:`stp_env.planning.single.planning_control` computes for a single state.
    """

    grid: hj.Grid
    dynamics: DubinsWind

    def __call__(self, t, x, params):
        times, stack = params["slice_times"], params["stack"]
        k = jnp.clip(jnp.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
        span = times[k + 1] - times[k]
        w = jnp.clip(jnp.where(span > 0, (t - times[k]) / span, 0.0), 0.0, 1.0)
        lo = jax.lax.dynamic_index_in_dim(stack, k, keepdims=False)
        hi = jax.lax.dynamic_index_in_dim(stack, k + 1, keepdims=False)
        p = central_gradient((1.0 - w) * lo + w * hi, self.grid.spacing, self.grid.is_periodic)
        return saturated_control(self.dynamics, x, p)


# --------------------------------------------------------------------------------------------- obstacles
class EmptyReachableSetError(ValueError):
    """A reachable set vanished on the grid (too thin for its cells)."""


def _linear_upsample_matrix(n: int, m: int) -> np.ndarray:
    """``((n - 1) m + 1, n)`` matrix of linear interpolation onto an ``m`` times finer grid (same end nodes)."""
    fine = np.arange((n - 1) * m + 1) / m
    i0 = np.minimum(np.floor(fine).astype(int), n - 2)
    w = fine - i0
    a = np.zeros((fine.size, n))
    a[np.arange(fine.size), i0] = 1.0 - w
    a[np.arange(fine.size), i0 + 1] = w
    return a


def projected_obstacle_table(grid: hj.Grid, sets, collision_radius: float, fine: int = FINE) -> np.ndarray:
    """Lower bounds of ``dist(p, P(t_k)) - R_c`` on the position nodes (eqs. 18-19, 23).

    Args:
        grid: the ``(p_x, p_y, theta)`` grid.
        sets: ``(K, *grid.shape)`` values whose sub-zero level sets are the possible states at ``K`` times.
        collision_radius: ``R_c``.
        fine: refinement of the plane on which the distance is measured.

    ``P(t_k)`` is the projection ``{p : min_theta sets_k(p, theta) <= 0}``, bilinear between nodes. It is
    sampled on a ``fine`` times finer plane; any point of it lies within one fine cell diagonal of a fine node in
    it, so the exact Euclidean distance to those nodes minus that diagonal is a lower bound of the distance to
    ``P``: the obstacle errs on the large side. Returns ``(K, nx, ny)`` (``{<= 0}`` forbidden).

    Raises:
        EmptyReachableSetError: if ``P(t_k)`` has no node at some ``k`` (the set vanished: refine the grid).
    """
    proj = np.asarray(jnp.min(jnp.asarray(sets), axis=-1), np.float64)
    ax = _linear_upsample_matrix(grid.shape[0], fine)
    ay = _linear_upsample_matrix(grid.shape[1], fine)
    hx, hy = grid.spacing[0] / fine, grid.spacing[1] / fine
    diag = math.hypot(hx, hy)
    out = np.empty(proj.shape, np.float32)
    for k, plane in enumerate(proj):
        inside = (ax @ plane @ ay.T) <= 0
        if not inside.any():
            raise EmptyReachableSetError(f"the projected reachable set is empty at slice {k}: the set smeared away on "
                                         "this grid (docs/numerics.md: keep a few cells across it).")
        dist = ndimage.distance_transform_edt(~inside, sampling=(hx, hy))
        out[k] = dist[::fine, ::fine] - diag - collision_radius
    return out


def tabulated_obstacles(t, params):
    """``g(t, p) = min_j g_j(t, p)`` over the active higher-priority vehicles (position plane, ``(nx, ny)``).

    ``params``: ``times`` ``(J, K)`` (ascending per vehicle), ``tables`` ``(J, K, nx, ny)`` from
    :func:`projected_obstacle_table`, ``start`` and ``end`` ``(J,)`` (the vehicle is in the air, and the obstacle
    present, for ``start <= t <= end``), optional ``static`` ``(nx, ny)``. Between two slices both are used (their
    union), so a moving set is not thinned by blending.
    """
    def one(times, tables, start, end):
        k = jnp.clip(jnp.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
        g = jnp.minimum(jax.lax.dynamic_index_in_dim(tables, k, keepdims=False),
                        jax.lax.dynamic_index_in_dim(tables, k + 1, keepdims=False))
        return jnp.where((t >= start) & (t <= end), g, NO_OBSTACLE)

    g = jnp.min(jax.vmap(one)(params["times"], params["tables"], params["start"], params["end"]), axis=0)
    if "static" in params:
        g = jnp.minimum(g, params["static"])
    return g


def _pack_tables(grid: hj.Grid, induced: list, n_slots: int, n_times: int, static) -> dict:
    """Pads the induced obstacles ``(times (K_j,), tables (K_j, nx, ny), start, end)`` to ``n_slots`` vehicles and
    ``n_times`` slices (padding slices: later times, no obstacle), so that every vehicle passes one shape."""
    nx, ny = grid.shape[:2]
    times = np.tile(np.arange(n_times, dtype=np.float64), (n_slots, 1))
    tables = np.full((n_slots, n_times, nx, ny), NO_OBSTACLE, np.float32)
    start, end = np.full(n_slots, np.inf), np.full(n_slots, -np.inf)
    for j, (ts, tab, s, e) in enumerate(induced):
        k = len(ts)
        times[j, :k] = ts
        times[j, k:] = ts[-1] + np.arange(1, n_times - k + 1)
        tables[j, :k] = tab
        start[j], end[j] = s, e
    out = {"times": jnp.asarray(times, jnp.float32), "tables": jnp.asarray(tables),
           "start": jnp.asarray(start, jnp.float32), "end": jnp.asarray(end, jnp.float32)}
    if static is not None:
        out["static"] = jnp.asarray(static, jnp.float32)
    return out


# --------------------------------------------------------------------------------------------- reachable sets
@dataclasses.dataclass(frozen=True)
class VehicleReach:
    """What one vehicle's planning computed, beside its :class:`stp_env.planning.single.SinglePlan`.

    Attributes:
        slice_times: ascending times of the BRS slices [s], ``(K,)``.
        brs: ``V_j(t)`` at ``slice_times``, ``(K, *grid.shape)`` (the planning controller's table).
        obstacle_times: FRS slice times ``[t_LDT, t_STA]`` [s] (empty for the lowest-priority vehicle).
        obstacle: its induced obstacle ``dist(p, P_j) - R_c`` at ``obstacle_times``, ``(K_f, nx, ny)``.
        obstacle_method: the method that made ``obstacle``: the plan's, or ``"least_restrictive"`` where the
            centralized FRS vanished on the grid (a superset, so still safe; a warning says so).
        seconds: wall time of this vehicle's planning (BRS, trajectory and induced obstacle) [s].
    """

    slice_times: np.ndarray
    brs: jnp.ndarray
    obstacle_times: np.ndarray
    obstacle: np.ndarray
    seconds: float
    obstacle_method: str = ""


@dataclasses.dataclass(frozen=True)
class MethodPlan:
    """A :class:`Plan` made with the centralized or least-restrictive method, with each vehicle's sets."""

    plan: Plan
    method: str
    reach: tuple[VehicleReach, ...]

    def seconds_per_vehicle(self) -> np.ndarray:
        return np.asarray([r.seconds for r in self.reach])


HEADING_FLOOR_CELLS = 1
"""Half-width [heading cells] below which the centralized FRS may not thin in heading (:func:`heading_floor`)."""


def heading_floor(grid: hj.Grid, values, cells: int = HEADING_FLOOR_CELLS):
    """``min(W, W_floor)``: a superset of ``{W <= 0}`` at least ``2 cells + 1`` heading nodes thick.

    ``W_floor(p, theta) = m(p) + (dx / dtheta) max(0, |theta - theta_hat(p)| - cells dtheta)`` with ``m(p) = min_theta
    W(p, theta)`` attained at ``theta_hat(p)``: every position column keeps its minimum over a band of headings
    around its minimiser. Why: the enforced turn-rate feedback contracts the heading with a gain of about
    ``omega_max / 0.1 rad`` against a heading disturbance of 0.2 rad/s, so the true FRS is a sheet about 0.04 rad
    thick, a quarter of a heading cell on the four-vehicle grid; without the floor the numerical set loses it
    within a second (measured: empty after 0.6-0.9 s). Applied after every FRS slice; only enlarges the set, so
    the obstacle stays conservative (it grows at most like an extra heading spread of ``cells`` cells)."""
    m = jnp.min(values, axis=2, keepdims=True)
    th = jnp.asarray(grid.coordinate_vector(2), values.dtype)
    th_hat = th[jnp.argmin(values, axis=2)][..., None]
    dth = jnp.abs(wrap_angle(th[None, None, :] - th_hat))
    slope = min(grid.spacing[:2]) / grid.spacing[2]
    floor = m + slope * jnp.maximum(0.0, dth - cells * grid.spacing[2])
    return jnp.minimum(values, floor)


def induced_frs(grid: hj.Grid, vehicle: DubinsWind, method: str, start, t_ldt: float, sta: float,
                slice_times, brs, frs_dt: float, settings: hj.SolverSettings):
    """The possible states of a vehicle that departs ``start`` at ``t_ldt`` (eqs. 15-17 or 21-23).

    Returns ``(times, sets)``: ascending times in ``[t_ldt, sta]`` and values whose sub-zero level sets are
    ``V(t) ∩ W(t)`` (``V`` grown by one cell: the BRS holds the flown vehicle only up to the grid), with ``W``
    the FRS under the enforced feedback (``"centralized"``, eqs. 14-17) or under every control
    (``"least_restrictive"``, eqs. 21-22). For the centralized method the set is ``V ∩ W_all ∩ W`` with
    ``W_all`` the FRS of every control: both intersections are exact in theory (the feedback is one of all
    controls, ``W ⊆ W_all``; under the optimal feedback of eq. 13 and any disturbance the vehicle stays in
    ``V(t)``, by dynamic programming, ``W ⊆ V``), so eq. (19) is unchanged; on the grid they trim what the
    initial ball and the heading floor add, and make the centralized obstacle a subset of the least-restrictive
    one, as eqs. (19) and (23) imply.
    """
    n = max(2, math.ceil((sta - t_ldt) / frs_dt - 1e-9) + 1)
    times = np.linspace(t_ldt, sta, n)
    init = initial_ball(grid, start)
    tables = {"slice_times": jnp.asarray(slice_times, jnp.float32), "stack": brs}
    # {V <= one cell}: flown under the worst case, the planning controller keeps the vehicle on the numerical BRS
    # only up to the grid (measured on 61 x 61 x 30: up to 1.2 cells outside it; see tests/test_planning_methods.py).
    slack = max(grid.spacing[:2])
    v_at = jax.vmap(lambda t: hj.interpolation.interpolate_in_time(tables["slice_times"], brs, t))(
        jnp.asarray(times, jnp.float32)) - slack
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}.")
    every_control = vehicle.with_modes(control_mode="max", disturbance_mode="max")
    w_all = hj.solve(settings, every_control, grid, times, init, progress=False).values  # eqs. 21-22
    if method == "centralized":
        dyn = hj.FeedbackDynamics(base=vehicle, feedback=SliceFeedback(grid, vehicle), disturbance_mode="max")
        values = [init]
        for k in range(n - 1):
            w = hj.solve(settings, dyn, grid, times[k:k + 2], values[0], initial_values=values[-1],
                         dynamics_params=tables, progress=False).values[-1]
            values.append(heading_floor(grid, w, HEADING_FLOOR_CELLS))
        return times, jnp.maximum(jnp.maximum(jnp.stack(values), w_all), v_at)
    return times, jnp.maximum(w_all, v_at)


def _plan_vehicle(grid, vehicle, start, target, radius, sta, horizon, settings, slice_dt, time_step, obstacle):
    """:func:`stp_env.planning.single.plan_single_with_slices` (zero wind, early stop) with the BRS slices padded
    to the whole horizon: the unsolved early part repeats the earliest solved slice (never read: the vehicle
    departs at ``t_LDT``, later), so that every vehicle's feedback table has one shape and the FRS solver loop
    compiles once per scenario."""
    obstacle_fn = None if obstacle is None else tabulated_obstacles
    single, solved_times, stack = plan_single_with_slices(
        grid, vehicle, start, target, radius, sta, horizon, obstacle_fn=obstacle_fn, obstacle_params=obstacle,
        settings=settings, slice_dt=slice_dt, time_step=time_step, wind_mode="zero")
    n_slices = max(2, math.ceil(horizon / slice_dt) + 1)
    slice_times = (sta - np.linspace(0.0, horizon, n_slices))[::-1].copy()
    assert np.allclose(slice_times[n_slices - len(solved_times):], solved_times)
    stack = jnp.concatenate([jnp.broadcast_to(stack[:1], (n_slices - stack.shape[0], *grid.shape)), stack])
    return single, slice_times, stack


def plan_methods(grid: hj.Grid, vehicle: DubinsWind, method: str, collision_radius: float, starts: Sequence,
                 targets: Sequence, target_radius: float | Sequence[float], stas: Sequence[float],
                 priorities: Sequence[int] | None = None, *, horizon: float, static_obstacle=None,
                 settings: hj.SolverSettings | None = None, time_step: float = 0.01, slice_dt: float | None = None,
                 frs_dt: float | None = None, arrival_margin: float | None = None,
                 progress: bool = True) -> MethodPlan:
    """Plans every vehicle with the centralized (SPP Section IV-A) or least-restrictive (IV-B) method.

    Args:
        grid: planning grid ``(p_x, p_y, theta)``, heading periodic.
        vehicle: dynamics with the full control set and the disturbance bounds (control ``"min"``, disturbance
            ``"max"``, eq. 12).
        method: ``"centralized"`` or ``"least_restrictive"``.
        collision_radius: ``R_c`` [m].
        starts, targets, target_radius, stas: per vehicle ``(p_x, p_y, theta)``, target centre, radius, STA.
        priorities: ``0`` = highest (default: input order).
        horizon: planning horizon before each STA [s].
        static_obstacle: optional ``g`` on the position plane (``{g <= 0}`` forbidden) for every vehicle.
        time_step: nominal trajectory sample period [s].
        slice_dt: spacing of the stored BRS slices (default ``horizon / 160``).
        frs_dt: spacing of the induced-obstacle slices (default ``slice_dt``).
        arrival_margin: each vehicle plans to arrive this much before its STA [s] (default: two cells at
            ``v_max``; one cell at ``v_min`` for the four-vehicle bounds, as robust tracking uses with ``U^p``,
            but finite when ``v_min = 0``): the BRS is exact only up to the grid, and
            flown under worst-case wind the planning controller arrives up to about a cell's crossing late
            (measured on 61 x 61 x 30: 0.025 s late without a margin). The obstacles stay until the STA itself.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}.")
    n = len(starts)
    radii = np.broadcast_to(np.asarray(target_radius, np.float64), (n,))
    priorities = list(range(n)) if priorities is None else list(priorities)
    if sorted(priorities) != list(range(n)):
        raise ValueError(f"priorities must be a permutation of 0..{n - 1}; got {priorities}.")
    settings = settings or hj.SolverSettings.with_accuracy("high")
    slice_dt = slice_dt or horizon / 160
    frs_dt = frs_dt or slice_dt
    if arrival_margin is None:
        arrival_margin = 2.0 * max(grid.spacing[:2]) / vehicle.v_max
    n_frs = math.ceil(horizon / frs_dt) + 2
    order = sorted(range(n), key=lambda i: priorities[i])
    induced: list = []
    plans: dict[int, VehiclePlan] = {}
    reach: dict[int, VehicleReach] = {}
    for rank, i in enumerate(tqdm(order, desc=f"STP planning ({method})", unit="vehicle", disable=not progress)):
        t0 = time.perf_counter()
        obstacle = None
        if induced or static_obstacle is not None:
            obstacle = _pack_tables(grid, induced, max(n - 1, 1), n_frs, static_obstacle)
        try:
            single, slice_times, stack = _plan_vehicle(grid, vehicle, np.asarray(starts[i], np.float64), targets[i],
                                                       float(radii[i]), float(stas[i]) - arrival_margin, horizon,
                                                       settings, slice_dt, time_step, obstacle)
        except InfeasiblePlanError as err:
            raise InfeasiblePlanError(f"vehicle {i} (priority {rank}): no feasible departure for its STA "
                                      f"{float(stas[i])} s: {err}", err.latest_departure) from err
        single = dataclasses.replace(single, sta=float(stas[i]))
        ob_times, ob_table = np.zeros(0), np.zeros((0, *grid.shape[:2]), np.float32)
        if rank < n - 1:
            ob_times, sets = induced_frs(grid, vehicle, method, starts[i], single.t_ldt, float(stas[i]),
                                         slice_times, stack, frs_dt, settings)
            obstacle_method = method
            try:
                ob_table = projected_obstacle_table(grid, sets, collision_radius)
            except EmptyReachableSetError as err:
                if method != "centralized":
                    raise
                # The least-restrictive set contains the centralized one (eqs. 19, 23): a safe, larger obstacle.
                warnings.warn(f"vehicle {i}: the centralized FRS vanished on this grid ({err}); its induced "
                              "obstacle is the least-restrictive one instead.", stacklevel=2)
                obstacle_method = "least_restrictive"
                ob_times, sets = induced_frs(grid, vehicle, obstacle_method, starts[i], single.t_ldt,
                                             float(stas[i]), slice_times, stack, frs_dt, settings)
                ob_table = projected_obstacle_table(grid, sets, collision_radius)
            induced.append((ob_times, ob_table, single.t_ldt, float(stas[i])))
        jax.block_until_ready(stack)
        seconds = time.perf_counter() - t0
        plans[i] = VehiclePlan(index=i, priority=rank, plan=single, obstacle_lags=np.zeros(1),
                               obstacle_radii=np.asarray([collision_radius]))
        reach[i] = VehicleReach(slice_times=slice_times, brs=stack, obstacle_times=ob_times, obstacle=ob_table,
                                seconds=seconds, obstacle_method=obstacle_method if rank < n - 1 else "")
    plan = Plan(vehicles=tuple(plans[i] for i in range(n)), tracking_bound=0.0,
                collision_radius=float(collision_radius), kbar=None)
    return MethodPlan(plan=plan, method=method, reach=tuple(reach[i] for i in range(n)))
