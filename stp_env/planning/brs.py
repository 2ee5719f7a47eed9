"""The planning BRS of one vehicle in one compiled program: a heading-split scheme and an on-device early stop.

The planning problem (intruder paper eqs. 35-36, SPP paper eqs. 7-12) is a backward reach-avoid tube of a Dubins
vehicle whose Hamiltonian separates into a position part and a heading part,

    H(x, p) = min_v max_d (v (p_x cos th + p_y sin th) + d . (p_x, p_y)) + min_|w| <= w_max  w p_th,

because the control set is a box and the wind acts on the position only. :func:`stp_env.hj.solve` advances both
parts together with Lax-Friedrichs fluxes, whose CFL step is set by the heading axis: on the city grid (15 degree
cells, ``w_max = 1.2 rad/s``) ``w_max / dth = 4.6 /s`` against ``sum v / dx = 0.55 /s`` for the position. Here
the two parts are split (Lie splitting, first order in the step like the splitting error of a sampled control):

* position: the solver's own ENO/WENO derivatives, local Lax-Friedrichs dissipation and TVD Runge-Kutta
  stages on the two position axes only (:func:`stp_env.hj.derivatives.one_sided_derivatives`), at the CFL step
  of the position axes alone;
* heading: the exact solution of ``V_s + min_w w V_th = 0`` over a step ``h`` (solver time ``s = -t``), a
  minimum of ``V`` over the heading window ``[th - w_max h, th + w_max h]`` of the piecewise-linear interpolant
  (dynamic programming for a pure turn: ``V(t - h, th) = min_|d| <= w_max h V(t, th + d)``). It is monotone and
  unconditionally stable, so it does not limit the step.

The step is also capped so that one step turns at most :data:`MAX_TURN_PER_STEP` (a sampled turn of that size
moves the vehicle less than a tenth of a cell sideways on the planning grids). Measured on the city, the plans
agree with :func:`stp_env.hj.solve`'s within the grid's resolution (BENCHMARKS.md, "City planning").

The time loop is one ``lax.while_loop`` over the stored slices (each a ``fori_loop`` over solver steps) that
stops on the device once the start state has a finite time-to-reach (and the solve has passed ``depart_at``);
every slice is written into a buffer of the whole horizon, so every vehicle of a scenario runs the same compiled
program (same shapes) with one dispatch and one host synchronisation.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.hj.derivatives import one_sided_derivatives
from stp_env.planning.model import PlanningModel, as_planning_model

MAX_TURN_PER_STEP = 0.5
"""Largest heading window [rad] of one split step (``w_max * h``); with it the city's step is 0.42 s (7.6 s of
turn at 1.2 rad/s would be 1.4 s)."""


def check_split_dynamics(model) -> PlanningModel:
    """``model`` as a planning model (:func:`stp_env.planning.model.as_planning_model`: a ``DubinsWind`` or anything
    with the members of :class:`stp_env.planning.model.PlanningModel`), checked for the split: it is exact only for
    dynamics whose controller minimises and whose heading turns at the control's rate alone
    (:attr:`~stp_env.planning.model.PlanningModel.heading_split`; for ``DubinsWind``: no heading disturbance)."""
    model = as_planning_model(model)
    dynamics = model.dynamics
    if dynamics.control_mode != "min" or not model.heading_split:
        detail = (f"heading_disturbance={dynamics.heading_disturbance}" if hasattr(dynamics, "heading_disturbance")
                  else f"heading_split={model.heading_split}")
        raise ValueError("the heading-split BRS needs control_mode='min' and no heading disturbance; got "
                         f"control_mode={dynamics.control_mode!r}, {detail}.")
    return model


def split_time_step(settings: hj.SolverSettings, model: PlanningModel, grid: hj.Grid) -> float:
    """The CFL step of the position axes (``cfl / max_x sum_{i in (x, y)} alpha_i(x) / dx_i``), capped so that a
    step turns at most :data:`MAX_TURN_PER_STEP` (``model``: a planning model or a ``DubinsWind``)."""
    model = as_planning_model(model)
    states = grid.broadcast_states()
    alpha = model.dynamics.partial_bounds(states)
    denom = float(jnp.max(jnp.broadcast_to(jnp.abs(alpha[0]) / grid.spacing[0] + jnp.abs(alpha[1]) / grid.spacing[1],
                                           grid.shape)))
    dt = settings.cfl / denom if denom > 0 else math.inf
    if model.omega_max > 0:
        dt = min(dt, MAX_TURN_PER_STEP / model.omega_max)
    if not math.isfinite(dt):
        raise ValueError("the dynamics neither move nor turn: no time step.")
    return dt


def heading_min_filter(values, width: float):
    """``min_{|d| <= width} V(th + d)`` along the (periodic) last axis, ``V`` linear between nodes; ``width`` in
    cells (a Python number: the window is part of the compiled program)."""
    m = math.floor(width)
    frac = width - m
    rolled = {0: values}
    for k in range(1, m + 2):
        rolled[k], rolled[-k] = jnp.roll(values, k, axis=-1), jnp.roll(values, -k, axis=-1)
    out = values
    for k in range(1, m + 1):
        out = jnp.minimum(out, jnp.minimum(rolled[k], rolled[-k]))
    if frac > 0:
        for sign in (1, -1):
            out = jnp.minimum(out, (1.0 - frac) * rolled[sign * m] + frac * rolled[sign * (m + 1)])
    return out


def _position_rate(settings, model, grid, states, values):
    """``dV/ds`` of the position part (backward, solver time ``s = -t``), local Lax-Friedrichs."""
    lefts, rights = [], []
    for axis in (0, 1):
        left, right = one_sided_derivatives(values, axis, grid.spacing[axis], grid.is_periodic[axis],
                                            settings.scheme, settings.boundary, settings.weno_eps)
        lefts.append(left)
        rights.append(right)
    zero = jnp.zeros((), values.dtype)
    p_mean = (0.5 * (lefts[0] + rights[0]), 0.5 * (lefts[1] + rights[1]), zero)
    ham = model.dynamics.hamiltonian(states, p_mean)
    alpha = model.dynamics.partial_bounds(states)
    diss = 0.5 * (alpha[0] * (rights[0] - lefts[0]) + alpha[1] * (rights[1] - lefts[1]))
    return jnp.broadcast_to(diss + ham, values.shape)


def _split_step(settings, model, grid, states, values, h: float, flag):
    """One Lie step of size ``h`` backward: Runge-Kutta on the position part, then the heading window.

    The heading window runs inside a conditional on ``flag`` (a traced ``True``): the conditional's operand, the
    Runge-Kutta result, is then written once. Without it XLA fuses the whole Runge-Kutta step into each of the
    window's shifted reads (measured on the city grid: 41 ms instead of 8 ms of CPU per step);
    ``optimization_barrier`` does not prevent that fusion, and a conditional around the Runge-Kutta step itself
    makes it 4x slower inside the time loop."""
    def rate(v):
        return _position_rate(settings, model, grid, states, v)

    v1 = values + h * rate(values)
    if settings.integrator == "euler":
        v = v1
    else:
        v2 = v1 + h * rate(v1)
        if settings.integrator == "rk2":
            v = 0.5 * (values + v2)
        else:
            v3 = 0.75 * values + 0.25 * v2
            v3 = v3 + h * rate(v3)
            v = values / 3.0 + (2.0 / 3.0) * v3
    if model.omega_max > 0:
        width = model.omega_max * h / grid.spacing[2]
        v = jax.lax.cond(flag, lambda v: heading_min_filter(v, width), lambda v: v, v)
    return v


@functools.partial(jax.jit, static_argnames=("settings", "model", "grid", "obstacle_fn", "h", "per_slice"))
def _solve(target, x0, times, stop_time, obstacle_params, flag, *, settings, model, grid, obstacle_fn, h, per_slice):
    """The tube over the decreasing, evenly spaced slice ``times`` (``(n,)``), ``per_slice`` steps of ``h``
    between two slices (``flag``: a traced ``True``, see :func:`_split_step`), stopped after the first slice ``k``
    at which ``x0`` has a finite time-to-reach and ``times[k] <= stop_time``. Returns ``(stack, k, ttr, n_steps)``:
    ``stack[n - 1 - j]`` the values at ``times[j]`` (ascending time) for ``j <= k``; the earlier entries repeat
    the values at ``times[k]``."""
    states = tuple(jnp.asarray(s, target.dtype) for s in grid.broadcast_states())
    n = times.shape[0]

    def obstacle(t, v):
        if obstacle_fn is None:
            return v
        # The plane is computed once behind a conditional (see _split_step): fused into the broadcast over the
        # headings it was recomputed for each of them (measured: 14 ms of CPU per step on the city, instead of 2).
        g = jax.lax.cond(flag, lambda p: obstacle_fn(t, p), lambda p: jnp.zeros(grid.shape[:2], v.dtype),
                         obstacle_params)
        return jnp.maximum(v, -g[:, :, None])

    values = obstacle(times[0], target)
    ttr = jnp.where(values <= 0, 0.0, jnp.inf).astype(target.dtype)
    stack = jnp.broadcast_to(values, (n, *values.shape))

    def reached(values, ttr, k):
        # Every node around x0 has entered the tube, and x0 is inside it at this slice: where obstacles sweep over
        # the start (a shared origin), a node's first entry can lie later than another's, and the time-to-reach
        # interpolated between them is then a time at which x0 is in none of the slices' tubes (see
        # :func:`stp_env.planning.single.departure_in_tube`); the solve goes on until a slice has x0 inside.
        at = hj.interpolation.time_to_reach_at(grid, ttr, x0)
        inside = hj.interpolation.interpolate(grid, values, x0) <= 0
        return jnp.isfinite(at) & inside & (times[k] <= stop_time)

    def cond(carry):
        k, values, ttr, _, _ = carry
        return (k < n - 1) & ~reached(values, ttr, k)

    def body(carry):
        k, values, ttr, stack, steps = carry
        elapsed0 = times[0] - times[k]

        def step(i, c):
            v, ttr = c
            t_new = times[k] - (i + 1) * h
            v_new = _split_step(settings, model, grid, states, v, h, flag)
            v_new = obstacle(t_new, jnp.minimum(v_new, target))
            frac = jnp.where(v > 0, v / jnp.maximum(v - v_new, 1e-30), 0.0)
            crossing = elapsed0 + i * h + jnp.clip(frac, 0.0, 1.0) * h
            ttr = jnp.where(jnp.isinf(ttr) & (v_new <= 0), crossing, ttr)
            return v_new, ttr

        values, ttr = jax.lax.fori_loop(0, per_slice, step, (values, ttr))
        stack = jax.lax.dynamic_update_index_in_dim(stack, values, n - 2 - k, 0)
        return k + 1, values, ttr, stack, steps + per_slice

    k, values, ttr, stack, steps = jax.lax.while_loop(
        cond, body, (jnp.int32(0), values, ttr, stack, jnp.int32(0)))
    idx = jnp.arange(n).reshape((n,) + (1,) * values.ndim)
    stack = jnp.where(idx < n - 1 - k, values[None], stack)
    return stack, k, ttr, steps


def solve_until_departure(settings: hj.SolverSettings, model: PlanningModel, grid: hj.Grid, times, target, x0,
                          obstacle_fn=None, obstacle_params=None, depart_at: float | None = None):
    """The planning tube (reach ``{target <= 0}``, avoid ``{obstacle_fn(t) <= 0}``, tube mode
    ``"min_with_target"``) over the decreasing, evenly spaced slice ``times``, heading-split, stopped at the first
    slice by which every node around ``x0`` has entered the tube and at which ``x0`` lies inside it (and which is
    no later than ``depart_at``).

    ``obstacle_fn`` is a position-plane ``(t, params) -> g`` of shape ``grid.shape[:2]``, broadcast over the heading.
    Returns ``(time_to_reach, n_solved, n_steps, stack)``: the time-to-reach measured from ``times[0]``, how many
    slices were solved (``times[:n_solved]``), the solver steps, and the values at every slice in *ascending* time
    (``stack[-n_solved:]`` are the solved ones; the earlier entries repeat the earliest solved slice, so every
    vehicle has one shape). ``model``: a planning model or a ``DubinsWind`` (:func:`check_split_dynamics`).
    """
    model = check_split_dynamics(model)
    if not grid.is_periodic[2] or grid.ndim != 3:
        raise ValueError("the heading-split BRS needs a 3-D grid (p_x, p_y, theta) with a periodic heading.")
    times = np.asarray(times, np.float64)
    if times.ndim != 1 or times.size < 2 or not np.all(np.diff(times) < 0):
        raise ValueError("times must be at least 2 strictly decreasing times (a backward problem).")
    spans = -np.diff(times)
    if np.ptp(spans) > 1e-9 * spans.max():
        raise ValueError("the heading-split BRS needs evenly spaced slice times.")
    # Every step the same size (the heading window is compiled in): the largest that divides a slice interval.
    span = float(spans.mean())
    per_slice = max(1, math.ceil(span / split_time_step(settings, model, grid) - 1e-9))
    h = span / per_slice
    stop = math.inf if depart_at is None else float(depart_at)
    f32 = jnp.float32
    stack, k, ttr, steps = _solve(jnp.asarray(target, f32), jnp.asarray(x0, f32), jnp.asarray(times, f32),
                                  f32(stop), obstacle_params, jnp.bool_(True), settings=settings, model=model,
                                  grid=grid, obstacle_fn=obstacle_fn, h=h, per_slice=per_slice)
    return ttr, int(k) + 1, int(steps), stack
