"""Planning one vehicle: the reach-avoid BRS from its target under time-varying obstacles, its latest departure
time, and the nominal trajectory.

Intruder paper Section III-B (eqs. 9-11) and Section IV-D (eqs. 35-37); SPP paper eqs. (7)-(13). The BRS
``V(t, t_STA)`` is the backward reach-avoid *tube* of the target ``L`` with the obstacle ``G(t)`` (double-obstacle
VI, eq. 3), the vehicle's control minimising and the disturbance maximising (eq. 36). The latest departure time
is ``t_LDT = sup {t : x0 in V(t, t_STA)}`` (end of Section III-B), read from the time-to-reach of the tube. The
nominal trajectory follows ``u(t, x) = arg min_u max_d grad V(t, x) . f`` (eqs. 11, 37) from ``x0`` at ``t_LDT``.

Obstacles are given as a jittable function of ``(t, params)`` returning ``g`` on the *position plane* (shape
``grid.shape[:2]``; ``{g <= 0}`` is forbidden); it is broadcast over the heading, so moving disks around other
vehicles' nominal trajectories cost one 2-D evaluation per time step.
"""

from __future__ import annotations

import functools
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.planning.model import (  # noqa: F401  (TURN_DEADBAND, saturated_control: re-exported, their old place)
    TURN_DEADBAND,
    PlanningModel,
    as_planning_model,
    saturated_control,
)
from stp_env.planning.plan import InfeasiblePlanError, SinglePlan

SOLVERS = ("hj", "split")


def planning_control(grid: hj.Grid, dynamics: PlanningModel | DubinsWind, slice_times, stack, t, x):
    """Optimal control and disturbance (eqs. 11, 37) at ``(t, x)`` from the BRS slices (jittable): the
    gradient is a one-cell central difference of the interpolated value; the control is the planning model's
    (:meth:`stp_env.planning.model.PlanningModel.control`; for a ``DubinsWind``, :func:`saturated_control`), the
    disturbance its solver dynamics' optimal one (a zero wind ``(2,)`` for dynamics without disturbance).

    The turn rate is bang-bang in theory; on a grid its switching function ``dV/dtheta`` is noise around zero on
    a straight optimal path, and a literal sign makes the vehicle chatter and arrive late. It is therefore
    saturated-linear: full turn once turning changes ``V`` at least ``TURN_DEADBAND`` times as fast as the best
    translation does, proportional below."""
    model = as_planning_model(dynamics)
    p = hj.interpolation.gradient_slices(grid, slice_times, stack, t, x)
    xs, ps = (x[0], x[1], x[2]), (p[0], p[1], p[2])
    d = model.dynamics.optimal_disturbance(xs, ps)
    return jnp.stack(model.control(xs, ps)), jnp.stack(d) if d else jnp.zeros(2, x.dtype)


MAX_TURN_PER_SAMPLE = 0.3
"""Largest heading change [rad] over one trajectory sample (``time_step * omega_max``, checked by
:func:`plan_single_with_slices`): the planning controller is held over a sample, and a bang-bang turn held much
longer overshoots every sample and never settles onto the target (measured on ``bay-area`` with 1 s samples at
1.2 rad/s: no arrival)."""


EXTRACTION_MARGIN_CELLS = 0.25
"""The goal-directed control of :func:`_rollout` is used only where it keeps ``V(t + dt, x) <= -margin`` with this
margin in cells of the finest position axis (values are distances in position units)."""


EXTRACTIONS = ("goal", "tube")
"""The nominal-trajectory controllers of :func:`_rollout`: ``"goal"`` the least-restrictive one (a goal-directed
control filtered by the tube), ``"tube"`` the control of eqs. (11), (37) on the current slice alone."""


class TubeExcursionWarning(UserWarning):
    """A nominal trajectory left its reach-avoid tube by more than :data:`TUBE_TOLERANCE_CELLS`: it may enter an
    obstacle (:func:`stp_env.planning.stp.plan_rtt` then plans the vehicle again with the unsplit solver)."""


TUBE_TOLERANCE_CELLS = 1.0
"""A nominal trajectory whose tube value ``V(t, x(t))`` exceeds this many cells (of the finest position axis) before
its arrival or the STA has left the reach-avoid tube: it may enter an obstacle (:func:`plan_single_with_slices`
keeps the better extraction and warns). The numerical tube is optimistic by about a cell, so a trajectory that
keeps to it can fall up to about a cell behind its zero level near the STA (the problem's ``arrival_margin``
absorbs that; measured on ``tiny-intruder``: 43 m with 50 m cells, 2 s before the aimed arrival)."""


@functools.partial(jax.jit, static_argnames=("grid", "model", "n_steps", "wind_mode", "extraction"))
def _rollout(key, x0, t0, dt, slice_times, stack, time_to_reach, *, grid, model, n_steps, wind_mode,
             extraction="goal"):
    """The nominal trajectory: a control evaluated at every sample and held over it, with the planning model's
    exact motion (:meth:`stp_env.planning.model.PlanningModel.step`; Dubins: :func:`stp_env.kinematics.dubins_step`)
    under a wind held over the sample. With ``wind_mode="zero"`` (robust
    trajectory tracking) the samples and controls therefore *are* a trajectory of the planning dynamics at every
    instant: the simulator reconstructs the reference between samples exactly
    (:func:`stp_env.sim.reference.nominal_reference`). Returns the states at the samples and the controls held
    from them.

    The control is least-restrictive (a safety filter on a goal-directed control). The reach-avoid tube
    ``V(t, .)`` (eq. 36, target kept, ``min`` with ``l``) is flat wherever the vehicle still has time to spare: it
    equals the depth of the target, whatever the route, so its gradient carries no direction there, and the
    controller of eqs. (11), (37) alone wanders. (Measured on the intruder-aware city at k̄ = 2, where the
    departures spaced 67.5 s apart leave a vehicle up to 1,600 s of slack: it wandered until a moving obstacle
    swept the plateau away and ended 2.3 km from its target after the STA.) The goal-directed control is that of
    eqs. (11), (37) on the *latest* slice that still contains the state, ``t' = t_STA - TTR(x)`` (``TTR`` the
    tube's time-to-reach, so ``x`` lies on the zero level of ``V(t', .)`` and the gradient points to the fastest
    arrival); it is used when the next sample stays inside the tube of its own time, ``V(t + dt, x') <= -margin``
    (:data:`EXTRACTION_MARGIN_CELLS`), and otherwise the control of ``V(t, .)`` itself, which keeps the state in
    the tube in exact arithmetic (numerically it need not: :func:`plan_single_with_slices` checks the values).
    Without slack ``t' = t`` and the two coincide. With ``extraction="tube"`` the control of ``V(t, .)`` is used
    throughout (the papers' extraction).

    Returns ``(states, controls, values)`` at the samples; ``values`` is the tube value ``V(t, x(t))`` (positive:
    the trajectory has left the tube)."""
    margin = EXTRACTION_MARGIN_CELLS * float(min(grid.spacing[:2]))
    sta = slice_times[-1]

    def wind(key, d_opt):
        if wind_mode == "zero" or model.wind == 0:
            return jnp.zeros(2)
        if wind_mode == "worst":
            return d_opt[:2]
        ang = jax.random.uniform(key, (), minval=-jnp.pi, maxval=jnp.pi)
        r = model.wind * jnp.sqrt(jax.random.uniform(jax.random.fold_in(key, 1)))
        return r * jnp.array([jnp.cos(ang), jnp.sin(ang)])

    def step(carry, k):
        x, key = carry
        key, sub = jax.random.split(key)
        t = t0 + k * dt
        u_safe, d_safe = planning_control(grid, model, slice_times, stack, t, x)
        x_safe = model.step(x, u_safe, wind(sub, d_safe), dt)
        value = hj.interpolation.interpolate_slices(grid, slice_times, stack, t, x)
        if extraction == "tube":
            return (x_safe, key), (x, u_safe, value)
        ttr = hj.interpolation.time_to_reach_at(grid, time_to_reach, x)
        t_goal = jnp.clip(jnp.where(jnp.isfinite(ttr), sta - ttr, t), t, sta)
        u_goal, d_goal = planning_control(grid, model, slice_times, stack, t_goal, x)
        x_goal = model.step(x, u_goal, wind(sub, d_goal), dt)
        ok = hj.interpolation.interpolate_slices(grid, slice_times, stack, t + dt, x_goal) <= -margin
        return (jnp.where(ok, x_goal, x_safe), key), (x, jnp.where(ok, u_goal, u_safe), value)

    (_, _), (xs, us, vs) = jax.lax.scan(step, (x0, key), jnp.arange(n_steps))
    return xs, us, vs


def plan_single(grid: hj.Grid, dynamics: PlanningModel | DubinsWind, start, target_center, target_radius: float,
                sta: float, horizon: float, **kwargs) -> SinglePlan:
    """Plans one vehicle (intruder paper eqs. 35-37); the arguments are those of :func:`plan_single_with_slices`,
    which also returns the BRS slices the trajectory controller used."""
    return plan_single_with_slices(grid, dynamics, start, target_center, target_radius, sta, horizon, **kwargs)[0]


def plan_single_with_slices(grid: hj.Grid, dynamics: PlanningModel | DubinsWind, start, target_center,
                            target_radius: float, sta: float, horizon: float, *, obstacle_fn=None, obstacle_params=None,
                            settings: hj.SolverSettings | None = None, slice_dt: float | None = None,
                            time_step: float = 0.05, wind_mode: str = "zero", seed: int = 0,
                            depart_at: float | None = None, progress: bool = False,
                            early_stop: bool = True, solver: str = "hj") -> tuple[SinglePlan, np.ndarray, jnp.ndarray]:
    """Plans one vehicle (intruder paper eqs. 35-37) and returns ``(plan, slice_times, stack)``: the plan, and the
    BRS slices ``V(t)`` in ascending time (``(K,)`` and ``(K, *grid.shape)``; with ``early_stop`` only the solved
    ones, from about ``t_LDT`` to the STA), which the induced obstacles of the centralized and least-restrictive
    methods are computed from (:mod:`stp_env.planning.methods`).

    Args:
        grid: ``(p_x, p_y, theta)`` grid, heading periodic.
        dynamics: the planning model (:class:`stp_env.planning.model.PlanningModel`), or a ``DubinsWind`` (planned
            as :class:`stp_env.planning.model.DubinsPlanning`); for robust trajectory tracking the reduced control
            set ``U^p`` and no wind; roles: control ``"min"``, disturbance ``"max"``.
        start: initial state ``(p_x, p_y, theta)``.
        target_center, target_radius: the target disk ``L`` [m].
        sta: scheduled time of arrival [s].
        horizon: how far before ``sta`` to look for a departure [s].
        obstacle_fn: jittable ``(t, params) -> g`` on the position plane, shape ``grid.shape[:2]``.
        obstacle_params: pytree of arrays passed to ``obstacle_fn``.
        settings: solver settings (default: ``high`` accuracy).
        slice_dt: spacing of the stored value slices used by the trajectory controller (default: ``time_step``).
        time_step: trajectory sample period [s].
        wind_mode: wind while extracting the trajectory: ``"zero"``, ``"random"`` or ``"worst"``.
        seed: key of the random wind.
        depart_at: start the trajectory at this time instead of ``t_LDT`` (a vehicle already in the air, as after
            replanning); it must not be later than ``t_LDT``.
        early_stop: stop the backward solve at the first stored slice by which the start state has entered the
            tube and at which it lies inside (and, with ``depart_at``, that is no later than it): ``t_LDT`` is then
            known (the time-to-reach of a node never changes once finite; :func:`departure_in_tube` checks it
            against the slices) and the slices from there to the STA are all the trajectory needs.
            ``False`` solves the whole horizon (same values, same ``t_LDT``; only for comparisons).
        solver: ``"hj"`` (:func:`stp_env.hj.solve`, all axes together, early stop checked in segments) or
            ``"split"`` (:mod:`stp_env.planning.brs`: the heading split, one compiled loop that stops on the
            device; always stops early).

    Raises:
        InfeasiblePlanError: if ``start`` cannot reach the target by ``sta`` within ``horizon``.
    """
    model = as_planning_model(dynamics)
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}; got {solver!r}.")
    if grid.ndim != model.dynamics.state_dim:
        raise ValueError(f"the planning grid has {grid.ndim} dimensions and the planning model "
                         f"{model.dynamics.state_dim} states; the planner plans (p_x, p_y, theta).")
    if wind_mode not in ("zero", "random", "worst"):
        raise ValueError(f"wind_mode must be 'zero', 'random' or 'worst'; got {wind_mode!r}.")
    if not (horizon > 0 and time_step > 0):
        raise ValueError(f"horizon and time_step must be positive; got {horizon}, {time_step}.")
    if time_step * model.omega_max > MAX_TURN_PER_SAMPLE + 1e-9:
        raise ValueError(f"time_step ({time_step} s) turns up to {time_step * model.omega_max:.2f} rad per sample "
                         f"at omega_max = {model.omega_max} rad/s; at most {MAX_TURN_PER_SAMPLE} rad is allowed "
                         "(the planning controller is held over a sample).")
    start = np.asarray(start, np.float64)
    if not bool(grid.contains(jnp.asarray(start))):
        raise ValueError(f"start {tuple(start)} lies outside the planning grid {grid.lo}..{grid.hi}.")
    settings = settings or hj.SolverSettings.with_accuracy("high")
    slice_dt = slice_dt or time_step
    n_slices = max(2, math.ceil(horizon / slice_dt) + 1)
    times = sta - np.linspace(0.0, horizon, n_slices)  # decreasing: backward from the STA
    target = hj.shapes.cylinder(grid, (0, 1), target_center, target_radius)
    full_fn = None
    if obstacle_fn is not None:
        full_fn = full_grid_obstacle(obstacle_fn, grid.shape[2])
    x0 = jnp.asarray(start, jnp.float32)
    stack_all = None
    if solver == "split":
        from stp_env.planning.brs import solve_until_departure

        ttr, n_solved, n_steps, stack_all = solve_until_departure(settings, model, grid, times, target, x0,
                                                                  obstacle_fn, obstacle_params, depart_at)
        res = hj.ReachResult(values=stack_all[len(times) - n_solved:], times=times[:n_solved], n_steps=n_steps,
                             dt=math.nan, time_to_reach=ttr)  # values in ascending time
        times = times[:n_solved]
    elif early_stop:
        res, times = _solve_until_departure(settings, model.dynamics, grid, times, target, x0, full_fn, obstacle_params,
                                            depart_at, progress)
    else:
        res = hj.solve(settings, model.dynamics, grid, times, target, tube=True, obstacle=obstacle_params,
                       obstacle_fn=full_fn, time_to_reach=True, progress=progress)
    t_ldt = float(sta - _time_to_reach_at(res.time_to_reach, x0, grid=grid))  # -inf if not reached
    if not math.isfinite(t_ldt):
        raise InfeasiblePlanError(
            f"start {tuple(np.round(start, 3))} cannot reach the target {tuple(target_center)} (radius "
            f"{target_radius}) by t_STA = {sta} s within a {horizon} s horizon; increase the horizon or move the "
            "STA later.")
    tolerance = TUBE_TOLERANCE_CELLS * float(min(grid.spacing[:2]))
    if depart_at is None:  # the start must lie in the tube at its departure (see departure_in_tube)
        if stack_all is not None:  # the whole horizon's buffer (one shape: one compiled read), its solved end
            at_start = np.asarray(_values_along(stack_all, x0, grid=grid), np.float64)[-len(times):]
        else:
            at_start = np.asarray(_values_along(res.values[::-1], x0, grid=grid), np.float64)  # ascending time
        checked = departure_in_tube(np.asarray(times[::-1], np.float64), at_start, t_ldt, tolerance)
        if not math.isfinite(checked):
            raise InfeasiblePlanError(
                f"start {tuple(np.round(start, 3))}: the time-to-reach gives a departure at {t_ldt:.3f} s, but the "
                f"start lies outside the tube there (value {float(np.interp(t_ldt, times[::-1], at_start)):.3g}) and "
                "in no slice before it; increase the horizon or move the STA later.")
        t_ldt = checked
    t_start = t_ldt
    if depart_at is not None:
        if depart_at > t_ldt + 1e-6:
            raise InfeasiblePlanError(f"departing at {depart_at} s is later than the latest departure time "
                                      f"{t_ldt:.3f} s for an arrival by {sta} s.", latest_departure=t_ldt)
        t_start = float(depart_at)
    # Trajectory from t_start with the controller of the stored slices (ascending time for interpolation).
    if stack_all is None:
        stack = res.values[::-1]
        slice_times = jnp.asarray(times[::-1].copy(), jnp.float32)
        rollout_stack = stack
    else:  # every slice of the horizon (one shape for every vehicle: one compiled rollout)
        stack = res.values
        slice_times = jnp.asarray((sta - np.linspace(0.0, horizon, n_slices))[::-1].copy(), jnp.float32)
        rollout_stack = stack_all
    # Simulate a little past the STA so that a late arrival is measured, not hidden. The scan always runs for the
    # whole horizon (one compiled rollout per horizon and time step, shared by every vehicle of a scenario).
    n_steps = max(1, math.ceil(1.1 * (sta - t_start) / time_step) + 1)
    n_scan = max(n_steps, math.ceil(1.1 * horizon / time_step) + 1)
    sample_times = t_start + time_step * np.arange(n_steps)
    best = None
    for extraction in EXTRACTIONS:
        xs, us, vs = _rollout(jax.random.key(seed), jnp.asarray(start, jnp.float32), jnp.float32(t_start),
                              jnp.float32(time_step), slice_times, rollout_stack, res.time_to_reach, grid=grid,
                              model=model, n_steps=n_scan, wind_mode=wind_mode, extraction=extraction)
        xs, us = np.asarray(xs, np.float64)[:n_steps], np.asarray(us, np.float64)[:n_steps]
        dist = np.hypot(xs[:, 0] - target_center[0], xs[:, 1] - target_center[1])
        inside = np.nonzero(dist <= target_radius)[0]
        arrival = float(sample_times[int(inside[0])]) if inside.size else math.inf
        # How far the trajectory leaves the tube before it arrives or the STA (the departure sample lies on the
        # zero level; a late arrival is the caller's to handle).
        end = min(int(inside[0]) + 1 if inside.size else n_steps, int(np.searchsorted(sample_times, sta, "right")))
        excursion = float(np.asarray(vs, np.float64)[1:end].max(initial=-math.inf))
        # In the tube: the earliest arrival; out of it: an arrival first, then the smaller excursion.
        left = excursion > tolerance
        score = (left, (not math.isfinite(arrival), excursion) if left else (arrival, excursion))
        if best is None or score < best[0]:
            best = (score, extraction, xs, us, arrival, excursion)
    _, extraction, xs, us, arrival, excursion = best
    if excursion > tolerance:
        warnings.warn(f"the nominal trajectory from {tuple(round(float(c), 3) for c in start)} leaves the "
                      f"reach-avoid tube by {excursion:.3g} (more than a cell, {tolerance:.3g}) with either "
                      "extraction; it may enter an obstacle.", TubeExcursionWarning, stacklevel=3)
    # The samples go on past the arrival (into the target, with the same controller) until the STA: a tracking
    # vehicle that trails its reference by up to the error bound still has a moving reference to follow.
    plan = SinglePlan(t_ldt=t_start, sta=float(sta), times=sample_times, states=xs, controls=us,
                      arrival_time=arrival, n_steps=res.n_steps)
    if wind_mode == "zero" or model.wind == 0:  # each stored control must carry its sample to the next one
        from stp_env.planning.verify import reconcile_controls

        plan, _ = reconcile_controls(plan, time_step, model.speed_bounds, model.omega_max, model=model)
    return plan, times[::-1].copy(), stack


@functools.partial(jax.jit, static_argnames=("grid",))
def _value_at(values, x, *, grid):
    """:func:`hj.interpolation.interpolate`, compiled."""
    return hj.interpolation.interpolate(grid, values, x)


@functools.partial(jax.jit, static_argnames=("grid",))
def _values_along(stack, x, *, grid):
    """The values of every slice of ``stack`` at ``x``."""
    return jax.vmap(lambda v: hj.interpolation.interpolate(grid, v, x))(stack)


def departure_in_tube(slice_times, values_at_start, t_ldt: float, tolerance: float) -> float:
    """The latest departure ``t_LDT`` (SPP Section IV, intruder paper Section III-B: the latest time at which the
    start lies in the tube), checked against the tube's slices: ``t_ldt`` itself when the start's value there
    (linear between the slices ``slice_times``, ascending, with the start's values ``values_at_start``) is at most
    ``tolerance``; otherwise the latest slice time before ``t_ldt`` at which the start is inside (value ``<= 0``).

    ``t_ldt`` comes from the time-to-reach interpolated between the grid nodes around the start, each the node's
    *first* entry into the tube going backward. Where no obstacle sweeps over the start, a node stays inside once
    it has entered, and the interpolated time is one at which the start is inside too. Where one does (the
    origin that higher-priority vehicles have just left, whose disks move off it), the nodes around the start can
    enter at times tens of seconds apart, with the disk over the start in between: measured on the bay area,
    vehicle 68 (priority 111, departing a city 111 others share) got -582.2 s from the time-to-reach, where the
    start's value is +92 to +115 m for 85 s on either side; the slice at -639.0 s, value -63.8 m, is the latest
    at which it is inside. Departing at the interpolated time, the vehicle started 170 m inside the disk of a
    vehicle that had left 0.03 s before it.

    Returns ``t_ldt`` or the earlier slice time; ``-inf`` when no slice before ``t_ldt`` has the start inside."""
    ts = np.asarray(slice_times, np.float64)
    vs = np.asarray(values_at_start, np.float64)
    if ts.shape != vs.shape or ts.ndim != 1 or ts.size < 1 or np.any(np.diff(ts) <= 0):
        raise ValueError("departure_in_tube needs ascending slice times and one value per slice.")
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be a finite number >= 0; got {tolerance}.")
    if not math.isfinite(t_ldt):
        return t_ldt
    if float(np.interp(t_ldt, ts, vs)) <= tolerance:
        return float(t_ldt)
    inside = np.flatnonzero((ts <= t_ldt) & (vs <= 0))
    return float(ts[inside[-1]]) if inside.size else -math.inf


@functools.partial(jax.jit, static_argnames=("grid",))
def _time_to_reach_at(ttr, x, *, grid):
    """:func:`hj.interpolation.time_to_reach_at`, compiled (eagerly it dispatches dozens of small ops)."""
    return hj.interpolation.time_to_reach_at(grid, ttr, x)


EARLY_STOP_SEGMENTS = 20
"""With ``early_stop``, the backward solve checks the start state about this many times over the horizon."""


def _solve_until_departure(settings, dynamics, grid, times, target, x0, obstacle_fn, obstacle_params, depart_at,
                           progress):
    """The tube of :func:`hj.solve` over the decreasing slice ``times``, in segments of consecutive slices, stopped
    after the first segment at whose end the start ``x0`` has a finite time-to-reach and lies inside the tube (and
    the solve has passed ``depart_at``, if given). Each segment continues from the previous one's last values (the
    solver re-applies the obstacle at a segment's first time: idempotent, ``max(V, -g)`` already holds), so the
    values are those of a single solve; the time-to-reach of a segment is shifted by its start's elapsed time and
    kept where earlier segments had set it (a node's time-to-reach is its *first* entry). Returns ``(result,
    times_solved)``."""
    n = len(times)
    per = max(1, math.ceil((n - 1) / EARLY_STOP_SEGMENTS))
    stacks, ttr, n_steps, dt, lo = [], None, 0, 0.0, 0
    while lo < n - 1:
        hi = min(lo + per, n - 1)
        seg = hj.solve(settings, dynamics, grid, times[lo:hi + 1], target, tube=True, obstacle=obstacle_params,
                       obstacle_fn=obstacle_fn, initial_values=None if lo == 0 else stacks[-1][-1],
                       time_to_reach=True, progress=progress)
        offset = jnp.float32(abs(times[lo] - times[0]))
        shifted = seg.time_to_reach + offset
        ttr = shifted if ttr is None else jnp.where(jnp.isfinite(ttr), ttr, shifted)
        stacks.append(seg.values if lo == 0 else seg.values[1:])
        n_steps, dt, lo = n_steps + seg.n_steps, seg.dt, hi
        reached = bool(jnp.isfinite(_time_to_reach_at(ttr, x0, grid=grid)))
        # ... and x0 inside the tube at the segment's end (see :func:`departure_in_tube`).
        reached = reached and float(_value_at(stacks[-1][-1], x0, grid=grid)) <= 0
        if reached and (depart_at is None or times[hi] <= depart_at):
            break
    solved = times[:lo + 1]
    return hj.ReachResult(values=jnp.concatenate(stacks), times=solved, n_steps=n_steps, dt=dt,
                          time_to_reach=ttr), solved


@functools.lru_cache(maxsize=64)
def full_grid_obstacle(obstacle_fn, n_theta: int):
    """``obstacle_fn`` on the position plane, broadcast over ``n_theta`` headings (cached so that repeated plans
    with the same function reuse the compiled solver loop)."""

    def full(t, params):
        g2 = obstacle_fn(t, params)
        return jnp.broadcast_to(g2[:, :, None], (*g2.shape, n_theta))

    return full


def initial_ball(grid: hj.Grid, state, cells: float = 1.5):
    """``l(x) <= 0`` on a ball of ``cells`` cells (position and heading, max-norm in cell units) around
    ``state``, the small initial set of SPP footnote 2, in position units.

    The ball is kept small because at departure it is the whole obstacle (grown by ``R_c``) that the lower-priority
    vehicles must avoid: on the four-vehicle example, 3 cells (0.075) make Q1's parked start block Q2's straight
    path, so Q2 must pass it before Q1 leaves, under either method. The centralized FRS does not vanish from
    this small ball thanks to :func:`stp_env.planning.methods.heading_floor`."""
    x = grid.broadcast_states()
    sp = grid.spacing
    dth = jnp.abs(wrap_angle(x[2] - state[2]))
    val = jnp.maximum(jnp.sqrt(((x[0] - state[0]) / sp[0]) ** 2 + ((x[1] - state[1]) / sp[1]) ** 2), dth / sp[2])
    return jnp.broadcast_to((val - cells) * min(sp[:2]), grid.shape)
