"""Level-set solver for Hamilton-Jacobi reachability.

Sign conventions (stated once, used everywhere)
-----------------------------------------------
* Sets are sub-zero level sets: target ``L = {l <= 0}``, obstacle ``G(t) = {g(t, .) <= 0}``, reachable set
  ``{V(t, .) <= 0}`` (intruder paper eq. 5; SPP paper eq. 9).
* The PDE is always ``D_t V + H(x, D_x V) = 0`` with ``H = opt_u opt_d p . f`` and the players' roles
  (``"min"``/``"max"``) carried by the dynamics (:mod:`stp_env.hj.dynamics`).
* ``times`` is the list of times at which values are wanted; ``times[0]`` is where the boundary condition holds.
  Decreasing times solve a **backward** problem (``V(times[0]) = l``, a BRS/BRT); increasing times solve a
  **forward** problem (``W(times[0]) = l``, an FRS).
* ``tube=True`` computes the set of states that reach the target at *some* time within the horizon (a tube):
  ``V <- min(V, l)`` after every step (or the ``"freeze"`` variant, see :class:`SolverSettings`). ``tube=False``
  gives the set at exactly the horizon.
* ``obstacle`` adds the double-obstacle variational inequality of the intruder paper eq. (3) / SPP paper
  eq. (7): ``V <- max(V, -g(t))`` after every step, and ``V(times[0]) = max(l, -g(times[0]))``. The same
  constraint applied to a forward problem gives the states reachable while staying out of ``G`` (eq. 4).

Numerics: Lax-Friedrichs numerical Hamiltonian
``H^(x, p-, p+) = H(x, (p- + p+)/2) - sum_i alpha_i(x) (p+_i - p-_i) / 2`` with the dynamics' partial bounds
``alpha``; upwind derivatives from :mod:`stp_env.hj.derivatives`; TVD Runge-Kutta of order 1-3 with a fixed
CFL-limited step (the bound is computed once: dynamics are time-invariant, or, for closed-loop
:class:`~stp_env.hj.FeedbackDynamics`, bounded over all inputs by their open-loop bounds; such time-varying
dynamics receive the stage time and the traced ``dynamics_params``). Each time interval between
requested times runs as device loops of ``steps_per_chunk`` steps; values never leave the device inside a loop.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.hj.derivatives import one_sided_derivatives
from stp_env.hj.dynamics import ControlAffineDynamics
from stp_env.hj.grid import Grid
from stp_env.hj.settings import SolverSettings

ObstacleFn = Callable[[Any, Any], jnp.ndarray]


def static_obstacle(t, g):
    """Obstacle function for a time-invariant obstacle array ``g`` (``obstacle_fn`` default)."""
    del t
    return g


@dataclasses.dataclass(frozen=True)
class ReachResult:
    """Output of :func:`solve`.

    Attributes:
        values: value functions at the requested ``times``, shape ``(len(times), *grid.shape)``.
        times: the requested times.
        n_steps: number of time steps taken (each of ``integrator`` order stages).
        dt: the CFL-limited time step used (the last step of each interval may be shorter).
        time_to_reach: if requested, ``|t - times[0]|`` at which each node first entered ``{V <= 0}``
            (linearly interpolated within a step; ``inf`` if never).
    """

    values: jnp.ndarray
    times: np.ndarray
    n_steps: int
    dt: float
    time_to_reach: jnp.ndarray | None = None


# ------------------------------------------------------------------------------------------- kernels
def _broadcast(grid: Grid, coords):
    """Grid states from *traced* coordinate vectors: with compile-time constant coordinates XLA would
    constant-fold functions of the state over the whole grid (seconds of compilation on millions of nodes)."""
    out = []
    for i, c in enumerate(coords):
        shape = [1] * grid.ndim
        shape[i] = grid.shape[i]
        out.append(jnp.reshape(c, shape))
    return tuple(out)


def _coords(grid: Grid, dtype):
    return tuple(jnp.asarray(c, dtype) for c in grid.coordinate_vectors())


def _rate(settings: SolverSettings, dynamics: ControlAffineDynamics, grid: Grid, direction: float,
          global_alpha, coords, values, t=None, dyn_params=None):
    """``dV/ds`` in solver time ``s`` (``s = t`` forward, ``s = -t`` backward); ``t`` and ``dyn_params`` reach
    time-varying dynamics (:meth:`ControlAffineDynamics.hamiltonian_at`), time-invariant ones ignore them."""
    states = _broadcast(grid, coords)
    lefts, rights = [], []
    for axis in range(grid.ndim):
        left, right = one_sided_derivatives(values, axis, grid.spacing[axis], grid.is_periodic[axis],
                                            settings.scheme, settings.boundary, settings.weno_eps)
        lefts.append(left)
        rights.append(right)
    p_mean = tuple(0.5 * (a + b) for a, b in zip(lefts, rights))
    ham = dynamics.hamiltonian_at(t, states, p_mean, dyn_params)
    if settings.dissipation == "local":
        alpha = dynamics.partial_bounds_at(t, states, dyn_params)
    else:
        alpha = tuple(global_alpha[i] for i in range(grid.ndim))
    diss = sum(a * (r - l) for a, l, r in zip(alpha, lefts, rights)) * 0.5
    # Solver-time PDE: V_s + (direction * H) = 0, Lax-Friedrichs flux.
    rate = diss - direction * ham
    return jnp.broadcast_to(rate, values.shape)


def _rk_step(settings, dynamics, grid, direction, global_alpha, coords, values, dt_abs, t=None, dyn_params=None,
             freeze=False):
    """One TVD Runge-Kutta step from time ``t``; the stages are evaluated at ``t``, ``t + h`` and (RK3)
    ``t + h/2`` (``h = direction * dt_abs``), which only time-varying dynamics read. ``freeze``: the monotone
    ("freeze") tube, every stage rate clipped to ``<= 0``."""
    def rate(v, c):
        tc = None if t is None else t + direction * c * dt_abs
        r = _rate(settings, dynamics, grid, direction, global_alpha, coords, v, tc, dyn_params)
        return jnp.minimum(r, 0.0) if freeze else r
    v1 = values + dt_abs * rate(values, 0.0)
    if settings.integrator == "euler":
        return v1
    v2 = v1 + dt_abs * rate(v1, 1.0)
    if settings.integrator == "rk2":
        return 0.5 * (values + v2)
    v_half = 0.75 * values + 0.25 * v2
    v3 = v_half + dt_abs * rate(v_half, 0.5)
    return values / 3.0 + (2.0 / 3.0) * v3


@functools.partial(jax.jit, static_argnames=("settings", "dynamics", "grid", "direction", "tube",
                                             "obstacle_fn", "track_ttr"))
def _advance(values, target, ttr, global_alpha, coords, t_start, dt, n_steps, last_dt, elapsed0, obstacle_params,
             dyn_params=None, *, settings, dynamics, grid, direction, tube, obstacle_fn, track_ttr):
    """``n_steps`` steps from time ``t_start``: all of (signed) size ``direction * dt`` but the last, of size
    ``direction * last_dt`` (the remainder that lands exactly on a requested time; ``last_dt = dt`` if none)."""
    freeze = tube and settings.tube_mode == "freeze"

    def body(i, carry):
        v, ttr = carry
        h = jnp.where(i == n_steps - 1, last_dt, dt)
        t_old = t_start + direction * i * dt
        v_new = _rk_step(settings, dynamics, grid, direction, global_alpha, coords, v, h, t_old, dyn_params, freeze)
        t_new = t_start + direction * (i * dt + h)
        if tube and not freeze:
            v_new = jnp.minimum(v_new, target)
        if obstacle_fn is not None:
            v_new = jnp.maximum(v_new, -obstacle_fn(t_new, obstacle_params))
        if track_ttr:
            e_old = elapsed0 + i * dt
            frac = jnp.where(v > 0, v / jnp.maximum(v - v_new, 1e-30), 0.0)
            crossing = e_old + jnp.clip(frac, 0.0, 1.0) * h
            ttr = jnp.where(jnp.isinf(ttr) & (v_new <= 0), crossing, ttr)
        return v_new, ttr

    return jax.lax.fori_loop(0, n_steps, body, (values, ttr))


@functools.partial(jax.jit, static_argnames=("dynamics", "grid"))
def _partial_bounds_max(coords, *, dynamics, grid):
    states = _broadcast(grid, coords)
    alpha = dynamics.partial_bounds(states)
    maxes = jnp.stack([jnp.max(jnp.broadcast_to(jnp.abs(a), grid.shape)) for a in alpha])
    cfl_denominator = jnp.max(jnp.broadcast_to(
        sum(jnp.abs(a) / dx for a, dx in zip(alpha, grid.spacing)), grid.shape))
    return maxes, cfl_denominator


def cfl_time_step(settings: SolverSettings, dynamics: ControlAffineDynamics, grid: Grid,
                  dtype=jnp.float32) -> tuple[float, np.ndarray]:
    """The CFL-limited time step and the per-dimension maximum dissipation coefficients.

    ``dt = cfl / max_x sum_i alpha_i(x) / dx_i``, the same rule as ``hj_reachability``; with global dissipation
    the bound uses the per-dimension maxima (``sum_i max_x alpha_i / dx_i``), which is what that scheme needs.
    """
    maxes, denom_local = _partial_bounds_max(_coords(grid, dtype), dynamics=dynamics, grid=grid)
    maxes = np.asarray(maxes, dtype=np.float64)
    if settings.dissipation == "global":
        denom = float(np.sum(maxes / np.asarray(grid.spacing)))
    else:
        denom = float(denom_local)
    if not denom > 0:
        return math.inf, maxes
    return settings.cfl / denom, maxes


# ------------------------------------------------------------------------------------------- API
def _check_inputs(grid: Grid, dynamics, target, times) -> np.ndarray:
    if not isinstance(grid, Grid):
        raise TypeError(f"grid must be a stp_env.hj.Grid; got {type(grid).__name__}.")
    if not isinstance(dynamics, ControlAffineDynamics):
        raise TypeError(f"dynamics must be a ControlAffineDynamics; got {type(dynamics).__name__}.")
    if dynamics.state_dim != grid.ndim:
        raise ValueError(f"dynamics has {dynamics.state_dim} states but the grid has {grid.ndim} dimensions.")
    grid.check_values(target, "target")
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1 or times.size < 2:
        raise ValueError(f"times must be a 1-D sequence of at least 2 times; got shape {times.shape}.")
    if not np.all(np.isfinite(times)):
        raise ValueError(f"times must be finite; got {times}.")
    steps = np.diff(times)
    if not (np.all(steps < 0) or np.all(steps > 0)):
        raise ValueError("times must be strictly decreasing (backward problem) or strictly increasing "
                         f"(forward problem); got {times}.")
    return times


def solve(settings: SolverSettings, dynamics: ControlAffineDynamics, grid: Grid, times: Sequence[float],
          target, *, tube: bool = False, obstacle=None, obstacle_fn: ObstacleFn | None = None,
          initial_values=None, time_to_reach: bool = False, progress: bool = True,
          dtype=jnp.float32, dynamics_params=None) -> ReachResult:
    """Solves a reachability problem and returns the value functions at ``times`` only.

    Args:
        settings: numerical settings (:meth:`SolverSettings.with_accuracy` for presets).
        dynamics: control- and disturbance-affine dynamics, with the players' roles.
        grid: the state grid.
        times: requested times; ``times[0]`` carries the boundary condition (see the module docstring).
        target: ``l(x)`` on the grid (target set ``{l <= 0}``).
        initial_values: values at ``times[0]`` if not ``target`` (to continue an earlier solve).
        tube: reach at *some* time within the horizon (BRT/FRT) instead of exactly at the horizon.
        obstacle: obstacle data: an array ``g(x)`` on the grid (``{g <= 0}`` is forbidden) when ``obstacle_fn``
            is ``None``, else any pytree of arrays passed to ``obstacle_fn``.
        obstacle_fn: jittable ``(t, obstacle) -> g(t, x)`` for time-varying obstacles (hashable: a module-level
            function, so that repeated solves reuse the compiled loop).
        time_to_reach: also return the first time each node enters ``{V <= 0}``.
        dynamics_params: pytree of arrays passed, traced, to time-varying dynamics at every Runge-Kutta stage
            (``dynamics.hamiltonian_at(t, x, p, dynamics_params)``; for :class:`~stp_env.hj.FeedbackDynamics`
            the tables of its feedback law). Time-invariant dynamics ignore it.
        progress: show a tqdm progress bar (in simulated seconds).
        dtype: ``jnp.float32`` (default) or ``jnp.float64`` (needs ``jax_enable_x64``).
    """
    if not isinstance(settings, SolverSettings):
        raise TypeError(f"settings must be a SolverSettings; got {type(settings).__name__}.")
    times = _check_inputs(grid, dynamics, target, times)
    if jnp.dtype(dtype) not in (jnp.dtype(jnp.float32), jnp.dtype(jnp.float64)):
        raise ValueError(f"dtype must be float32 or float64; got {dtype}.")
    if jnp.dtype(dtype) == jnp.dtype(jnp.float64) and not jax.config.jax_enable_x64:
        raise ValueError("dtype=float64 needs jax.config.update('jax_enable_x64', True) before any JAX work.")
    direction = -1.0 if times[1] < times[0] else 1.0

    target = jnp.asarray(target, dtype)
    if obstacle is not None and obstacle_fn is None:
        grid.check_values(obstacle, "obstacle")
        obstacle = jnp.asarray(obstacle, dtype)
        obstacle_fn = static_obstacle
    elif obstacle_fn is not None:
        probe = jax.eval_shape(lambda o: obstacle_fn(jnp.asarray(times[0], dtype), o), obstacle)
        if tuple(probe.shape) != grid.shape:
            raise ValueError(f"obstacle_fn returns shape {tuple(probe.shape)}, but the grid has shape "
                             f"{grid.shape}.")
        obstacle = jax.tree.map(lambda a: jnp.asarray(a), obstacle)

    if dynamics_params is not None:
        dynamics_params = jax.tree.map(lambda a: jnp.asarray(a), dynamics_params)
    dt_max, alpha_max = cfl_time_step(settings, dynamics, grid, dtype)
    global_alpha = jnp.asarray(alpha_max, dtype)

    if initial_values is None:
        values = target
    else:
        grid.check_values(initial_values, "initial_values")
        values = jnp.asarray(initial_values, dtype)
    if obstacle_fn is not None:
        values = jnp.maximum(values, -obstacle_fn(jnp.asarray(times[0], dtype), obstacle))
    ttr = None
    if time_to_reach:
        ttr = jnp.where(values <= 0, 0.0, jnp.inf).astype(dtype)
    ttr_carry = ttr if ttr is not None else jnp.zeros((), dtype)

    outputs = [values]
    n_steps_total = 0
    coords = _coords(grid, dtype)
    bar = _progress_bar(abs(times[-1] - times[0]), progress)
    try:
        t = float(times[0])
        for t_next in times[1:]:
            span = abs(float(t_next) - t)
            if math.isinf(dt_max):
                n_full, rem = 1, 0.0
                step = span
            else:
                n_full = math.floor(span / dt_max * (1 + 1e-12))
                rem = span - n_full * dt_max
                step = dt_max
                if rem <= 1e-9 * max(span, 1.0):
                    rem = 0.0
            # Chunks of full steps; the remainder step (if any) rides in the last chunk: one dispatch per chunk.
            plan = []
            done = 0
            while done < n_full:
                n = min(settings.steps_per_chunk, n_full - done)
                plan.append([n, step, done * step, step])
                done += n
            if rem > 0:
                if plan and plan[-1][0] < settings.steps_per_chunk:
                    plan[-1][0] += 1
                    plan[-1][3] = rem
                else:
                    plan.append([1, step, n_full * step, rem])
            for n, h, offset, last in plan:
                elapsed = abs(t - times[0]) + offset
                values, ttr_carry = _advance(
                    values, target, ttr_carry, global_alpha, coords,
                    jnp.asarray(t + direction * offset, dtype), jnp.asarray(h, dtype),
                    jnp.asarray(n, jnp.int32), jnp.asarray(last, dtype), jnp.asarray(elapsed, dtype), obstacle,
                    dynamics_params, settings=settings, dynamics=dynamics, grid=grid, direction=direction, tube=tube,
                    obstacle_fn=obstacle_fn, track_ttr=time_to_reach)
                n_steps_total += n
                if bar is not None:
                    values.block_until_ready()
                    bar.update((n - 1) * h + last)
            t = float(t_next)
            outputs.append(values)
    finally:
        if bar is not None:
            bar.close()

    return ReachResult(values=jnp.stack(outputs), times=times, n_steps=n_steps_total,
                       dt=float(dt_max), time_to_reach=ttr_carry if time_to_reach else None)


@dataclasses.dataclass(frozen=True)
class ConvergedResult:
    """Output of :func:`solve_until_converged`.

    Attributes:
        values: the final value function.
        converged: whether the last check interval changed every compared quantity by at most ``tol + rtol *
            scale``; never on an empty comparison set.
        horizon: the (absolute) horizon at which the loop stopped.
        n_steps: time steps taken.
        changes: the residual after each check interval: the largest change of the compared values and of the
            watched quantities (``inf`` when the comparison set was empty).
        compared: how many grid nodes each check compared (``band`` or ``region``; the whole grid otherwise).
        watched: the watched quantities after each check (``watch``), one tuple per check.
    """

    values: jnp.ndarray
    converged: bool
    horizon: float
    n_steps: int
    changes: tuple[float, ...]
    compared: tuple[int, ...] = ()
    watched: tuple[tuple[float, ...], ...] = ()
    check_interval: float = 1.0

    @property
    def rate(self) -> float:
        """The residual rate of change at the end, ``changes[-1] / check_interval`` (per unit of time)."""
        return self.changes[-1] / self.check_interval if self.changes else math.inf


def solve_until_converged(settings: SolverSettings, dynamics: ControlAffineDynamics, grid: Grid, target, *,
                          tube: bool = True, obstacle=None, check_interval: float = 1.0,
                          max_horizon: float = 100.0, tol: float = 1e-3, rtol: float = 0.0,
                          band: float | None = None, region: Callable[[Any, Any], Any] | None = None,
                          watch: Callable[[Any], Any] | None = None, warn: bool = True,
                          progress: bool = True, dtype=jnp.float32) -> ConvergedResult:
    """Backward solve until the value function stops changing: infinite-horizon sets such as the robust
    controlled-invariant set of tracking-error dynamics (SPP paper eqs. 24-26).

    After every ``check_interval`` of simulated time the loop compares the new values with the old ones and stops
    when the residual is at most ``tol + rtol * scale`` (``scale``: the largest watched quantity in absolute value
    when ``watch`` is given, else the largest ``|V|`` compared). The residual is the largest of

    * ``max |V_new - V_old|`` over the compared nodes: those with ``|V| <= band`` (old or new) when ``band`` is
      given (the sets near the zero level, not the far field), those where ``region(old, new)`` is true when
      ``region`` is given, else the whole grid;
    * ``max |watch(V_new) - watch(V_old)|`` when ``watch`` is given: the quantities a user consumes (a value at a
      point, the smallest level, ...), a jittable ``values -> array``.

    A check whose comparison set is empty compares nothing and cannot pass: its residual is ``inf`` (a band that
    every node's value has left would otherwise report convergence on the first check). At ``max_horizon`` the
    loop stops with ``converged=False`` and, unless ``warn=False``, a :class:`RuntimeWarning` that gives the last
    residual and its rate per unit time (``ConvergedResult.rate``, the creep a user should know of).
    """
    if not (check_interval > 0 and max_horizon >= check_interval and tol >= 0 and rtol >= 0 and tol + rtol > 0):
        raise ValueError("Need check_interval > 0, max_horizon >= check_interval, tol >= 0, rtol >= 0 and tol + rtol "
                         f"> 0; got {check_interval}, {max_horizon}, {tol}, {rtol}.")
    if band is not None and region is not None:
        raise ValueError("Give band or region, not both.")
    if band is not None:
        if not band > 0:
            raise ValueError(f"band must be > 0; got {band}.")

        def region(old, new):
            return (jnp.abs(new) <= band) | (jnp.abs(old) <= band)

    values = jnp.asarray(target, dtype)
    horizon, n_steps, changes, compared, watched = 0.0, 0, [], [], []
    converged = False
    n_checks = math.ceil(max_horizon / check_interval - 1e-9)
    previous_watch = None if watch is None else np.asarray(watch(values), np.float64).ravel()
    bar = _progress_bar(max_horizon, progress)
    try:
        for _ in range(n_checks):
            # Autonomous dynamics and a static obstacle: each interval continues the previous one exactly.
            res = solve(settings, dynamics, grid, [0.0, -check_interval], target, initial_values=values,
                        tube=tube, obstacle=obstacle, progress=False, dtype=dtype)
            new = res.values[-1]
            change, count, scale = _residual(values, new, region)
            if watch is not None:
                current = np.asarray(watch(new), np.float64).ravel()
                change = max(change, float(np.max(np.abs(current - previous_watch), initial=0.0)))
                scale = float(np.max(np.abs(current), initial=0.0))
                previous_watch = current
                watched.append(tuple(float(c) for c in current))
            changes.append(change)
            compared.append(count)
            values = new
            horizon += check_interval
            n_steps += res.n_steps
            if bar is not None:
                bar.update(check_interval)
            if change <= tol + rtol * scale:
                converged = True
                break
    finally:
        if bar is not None:
            bar.close()
    if not converged and warn:
        import warnings

        rate = changes[-1] / check_interval
        warnings.warn(f"solve_until_converged: not converged after {horizon:g} of simulated time; the last check "
                      f"changed the compared values by {changes[-1]:.4g} (tol {tol:g}; rate {rate:.4g} per unit "
                      "time).", RuntimeWarning, stacklevel=2)
    return ConvergedResult(values=values, converged=converged, horizon=horizon, n_steps=n_steps,
                           changes=tuple(changes), compared=tuple(compared), watched=tuple(watched),
                           check_interval=float(check_interval))


def _residual(old, new, region) -> tuple[float, int, float]:
    """``(max |new - old|``, nodes compared, ``max |new|``) over ``region(old, new)`` (whole grid if ``None``);
    ``(inf, 0, 0)`` if the region is empty."""
    diff = jnp.abs(new - old)
    if region is None:
        return float(jnp.max(diff)), int(diff.size), float(jnp.max(jnp.abs(new)))
    mask = region(old, new)
    count = int(jnp.sum(mask))
    if count == 0:
        return math.inf, 0, 0.0
    return (float(jnp.max(jnp.where(mask, diff, 0.0))), count,
            float(jnp.max(jnp.where(mask, jnp.abs(new), 0.0))))


def _progress_bar(total: float, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=float(total), unit="sim s", desc="HJ solve", leave=False,
                bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} sim s [{elapsed}<{remaining}]")
