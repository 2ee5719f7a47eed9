"""Values, gradients and optimal inputs at arbitrary states: multilinear, periodic-aware, jittable, vmappable.

Single states are arrays of shape ``(ndim,)``; use ``jax.vmap`` for batches. Grids are static (hashable), so
pass them through ``functools.partial`` or as static arguments when jitting.

Out-of-domain states (non-periodic dimensions): ``fill_value=None`` clamps to the nearest boundary node (the
value there is what a set that does not touch the boundary reports far away); a number is returned instead
when given (for example ``jnp.inf`` or ``jnp.nan``).
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np

from stp_env.hj.derivatives import central_gradient
from stp_env.hj.grid import Grid


def _corners(grid: Grid, state):
    """Indices and weights of the ``2^ndim`` nodes around ``state``."""
    state = jnp.asarray(state)
    pos = grid.fractional_index(state)
    shape = np.asarray(grid.shape)
    periodic = np.asarray(grid.is_periodic)
    # Non-periodic: clamp into [0, n-1]; the upper corner is then at most n-1.
    pos = jnp.where(periodic, pos, jnp.clip(pos, 0.0, shape - 1.0))
    i0 = jnp.floor(pos).astype(jnp.int32)
    i0 = jnp.where(periodic, i0, jnp.minimum(i0, shape - 2))
    w1 = pos - i0
    i1 = jnp.where(periodic, jnp.mod(i0 + 1, shape), i0 + 1)
    i0 = jnp.where(periodic, jnp.mod(i0, shape), i0)
    return i0, i1, w1


def _multilinear(grid: Grid, state, read):
    """``sum_corners weight * read(corner index)`` over the ``2^ndim`` nodes around ``state``."""
    i0, i1, w1 = _corners(grid, state)
    w0 = 1.0 - w1
    out = 0.0
    for corner in itertools.product((0, 1), repeat=grid.ndim):
        idx = tuple(jnp.where(c, i1[d], i0[d]) for d, c in enumerate(corner))
        w = 1.0
        for d, c in enumerate(corner):
            w = w * (w1[d] if c else w0[d])
        out = out + w * read(idx)
    return out


def interpolate(grid: Grid, values, state, fill_value=None):
    """Multilinear interpolation of ``values`` (``grid.shape``, or ``grid.shape + (k,)`` for vector fields)
    at ``state`` (shape ``(ndim,)``)."""
    out = _multilinear(grid, state, lambda idx: values[idx])
    if fill_value is not None:
        out = jnp.where(grid.contains(state), out, fill_value)
    return out


def gradient_field(grid: Grid, values) -> tuple:
    """Central-difference spatial gradient of ``values`` at every node (one array per dimension), to be
    stored beside a value function and interpolated by controllers."""
    grid.check_values(values)
    return central_gradient(jnp.asarray(values), grid.spacing, grid.is_periodic)


def interpolate_gradient(grid: Grid, gradients: tuple, state):
    """Gradient at ``state`` from a :func:`gradient_field`; returns shape ``(ndim,)``."""
    return jnp.stack([interpolate(grid, g, state) for g in gradients])


def value_and_gradient(grid: Grid, values, gradients: tuple, state, fill_value=None):
    return interpolate(grid, values, state, fill_value), interpolate_gradient(grid, gradients, state)


def optimal_control(grid: Grid, dynamics, gradients: tuple, state):
    """Closed-form optimal control ``arg opt_u p . f`` at ``state`` from the interpolated gradient."""
    p = interpolate_gradient(grid, gradients, state)
    x = tuple(jnp.asarray(state)[i] for i in range(grid.ndim))
    return jnp.stack(dynamics.optimal_control(x, tuple(p[i] for i in range(grid.ndim))))


def optimal_disturbance(grid: Grid, dynamics, gradients: tuple, state):
    """Closed-form optimal disturbance at ``state`` from the interpolated gradient."""
    p = interpolate_gradient(grid, gradients, state)
    x = tuple(jnp.asarray(state)[i] for i in range(grid.ndim))
    d = dynamics.optimal_disturbance(x, tuple(p[i] for i in range(grid.ndim)))
    return jnp.stack(d) if d else jnp.zeros((0,), jnp.asarray(state).dtype)


def interpolate_in_time(times, values_stack, t):
    """Linear interpolation in time between value slices ``values_stack[k]`` at ``times[k]`` (monotone, either
    direction); clamps outside the range. Returns an array of ``values_stack.shape[1:]``."""
    times = jnp.asarray(times)
    ascending = times[-1] >= times[0]
    ts = jnp.where(ascending, times, -times)
    tq = jnp.where(ascending, t, -t)
    tq = jnp.clip(tq, ts[0], ts[-1])
    k = jnp.clip(jnp.searchsorted(ts, tq, side="right") - 1, 0, times.shape[0] - 2)
    span = ts[k + 1] - ts[k]
    w = jnp.where(span > 0, (tq - ts[k]) / span, 0.0)
    return (1.0 - w) * values_stack[k] + w * values_stack[k + 1]


def interpolate_slices(grid: Grid, slice_times, stack, t, state):
    """``V(t, state)`` from value slices ``stack[k]`` at *ascending* ``slice_times``: linear in time, multilinear
    in space, clamped outside the time range. Only the ``2 * 2^ndim`` nodes around ``(t, state)`` are read, by
    scalar gathers into the whole stack (indexing ``stack[k]`` with a traced ``k`` would copy a whole slice, and
    under ``vmap`` one slice per batch element)."""
    k = jnp.clip(jnp.searchsorted(slice_times, t, side="right") - 1, 0, slice_times.shape[0] - 2)
    span = slice_times[k + 1] - slice_times[k]
    w = jnp.clip(jnp.where(span > 0, (t - slice_times[k]) / span, 0.0), 0.0, 1.0)
    return _multilinear(grid, state, lambda idx: (1.0 - w) * stack[(k, *idx)] + w * stack[(k + 1, *idx)])


def gradient_slices(grid: Grid, slice_times, stack, t, state):
    """Spatial gradient of :func:`interpolate_slices` by one-cell central differences (the nodes' central
    differences where ``state`` is a node); shape ``(ndim,)``."""
    steps = np.eye(grid.ndim) * np.asarray(grid.spacing)[:, None]
    return jnp.stack([(interpolate_slices(grid, slice_times, stack, t, state + h)
                       - interpolate_slices(grid, slice_times, stack, t, state - h)) / (2 * h[i])
                      for i, h in enumerate(steps)])


def time_to_reach_at(grid: Grid, time_to_reach, state):
    """Time-to-reach at ``state``: multilinear where all surrounding nodes (of non-zero weight) are finite, else
    ``inf`` (the state is not reached within the horizon for certain)."""
    i0, i1, w1 = _corners(grid, state)
    w0 = 1.0 - w1
    out, finite = 0.0, True
    for corner in itertools.product((0, 1), repeat=grid.ndim):
        idx = tuple(jnp.where(c, i1[d], i0[d]) for d, c in enumerate(corner))
        w = 1.0
        for d, c in enumerate(corner):
            w = w * (w1[d] if c else w0[d])
        node = time_to_reach[idx]
        finite = finite & (jnp.isfinite(node) | (w == 0))  # a corner with zero weight does not matter
        out = out + w * jnp.where(jnp.isfinite(node), node, 0.0)
    return jnp.where(finite & grid.contains(state), out, jnp.inf)


def latest_departure_time(grid: Grid, time_to_reach, state, arrival_time: float):
    """Latest departure time ``t_LDT = t_STA - TTR(x0)`` (intruder paper Section III-B: ``arg sup_t {x0 in
    V(t, t_STA)}``) from the time-to-reach of a backward tube solved from ``t_STA``; ``-inf`` if ``x0`` cannot
    reach the target within the horizon."""
    ttr = time_to_reach_at(grid, time_to_reach, state)
    return jnp.where(jnp.isfinite(ttr), arrival_time - ttr, -jnp.inf)
