"""Reads of the reachability tables held in :class:`~stp_env.sim.types.EnvParams` (jittable, one state at a
time; vmap for many).

* :func:`avoid_value`: ``V^A(tau, t_IAT)(x_rel)`` (intruder paper eqs. 13-14), ``+inf``-like outside its grid.
* :func:`avoidance_control`: ``u^A`` (eq. 15), the vehicle's maximising control of the avoid game.
* :func:`pursuit_input`: the intruder's minimising control and the worst combined wind of the same game.
* :func:`tracking_control`: the robust tracker ``kappa`` (SPP eq. 26) and its worst-case wind.
* :func:`buffer_value`, :func:`buffer_hop` and the other buffer-game reads: ``V^B`` (eqs. 46-47), when loaded.
* :func:`extra_table`, :func:`table_value`: a table a plug-in registered (:mod:`stp_env.requirements`), by name.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj

FAR = 1.0e6  # value reported outside the avoid-region grid [m]

# ------------------------------------------------------------------------------------------------ block reads
BLOCK = 4
"""Nodes per axis of the block an avoid-table read takes around a state: the state's cell and one node on each
side, enough for the value and its one-cell central differences (the reads of :func:`avoid_value_and_gradient`)."""
PERIODIC_PAD = (1, 2)
"""Nodes wrapped before and after every periodic axis of a block-read table (:func:`pad_periodic`), so that a
block never needs to wrap: ``dynamic_slice`` cannot."""


def pad_periodic(values, grid, lead: int = 0) -> np.ndarray:
    """``values`` (``lead`` leading axes, then ``grid.shape``) with every periodic axis of ``grid`` wrapped by
    :data:`PERIODIC_PAD` nodes: the layout :func:`avoid_value_and_gradient` reads
    (``EnvParams.tables.avoid_values``)."""
    v = np.asarray(values)
    if v.shape[lead:] != tuple(grid.shape):
        raise ValueError(f"values of shape {v.shape} do not match the grid {tuple(grid.shape)} after {lead} "
                         f"leading axes.")
    if any(n < BLOCK for n in grid.shape):
        raise ValueError(f"block reads need at least {BLOCK} nodes per axis; the grid has {tuple(grid.shape)}.")
    before, after = PERIODIC_PAD
    for d in grid.periodic:
        ax = lead + d
        n = v.shape[ax]
        v = np.concatenate([np.take(v, range(n - before, n), axis=ax), v, np.take(v, range(after), axis=ax)],
                           axis=ax)
    return v


def _cell(grid, d: int, pos):
    """The cell of axis ``d`` holding fractional index ``pos``: its lower node ``i0`` (unpadded) and the position
    the weights are taken at. Periodic axes: ``pos`` in ``[0, n]``, ``i0 <= n - 1`` (the last cell wraps);
    non-periodic ones clamp as :func:`stp_env.hj.interpolation.interpolate` does (into ``[0, n - 1]``,
    ``i0 <= n - 2``)."""
    n = grid.shape[d]
    if d in grid.periodic:
        return jnp.minimum(jnp.floor(pos), n - 1).astype(jnp.int32), pos
    p = jnp.clip(pos, 0.0, n - 1.0)
    return jnp.minimum(jnp.floor(p).astype(jnp.int32), n - 2), p


def _block_axis(grid, d: int, pos):
    """Axis ``d`` of a block read at fractional index ``pos`` (``grid.fractional_index``, periodic axes in
    ``[0, n]``): the block's first node in the padded table, and the ``BLOCK`` weights of the multilinear
    interpolation at ``pos - 1``, ``pos`` and ``pos + 1`` (one cell back, the state, one cell on). Non-periodic axes
    clamp as :func:`stp_env.hj.interpolation.interpolate` does (into ``[0, n - 1]``, the last cell ``n - 2``);
    periodic ones wrap through the padding."""
    n = grid.shape[d]
    node = jnp.arange(BLOCK)
    i0, centre = _cell(grid, d, pos)
    if d in grid.periodic:
        base = i0 - 1                      # the block's first node, unpadded (may be -1: the wrapped one)
        start = base + PERIODIC_PAD[0]     # ... in the padded table: in [0, n - 1]
        points = (pos - 1.0, pos, pos + 1.0)
    else:
        base = jnp.clip(i0 - 1, 0, n - BLOCK)
        start = base
        points = (jnp.clip(pos - 1.0, 0.0, n - 1.0), centre, jnp.clip(pos + 1.0, 0.0, n - 1.0))
    weights = []
    for q in points:
        lower = jnp.clip(jnp.floor(q).astype(jnp.int32) - base, 0, BLOCK - 2)
        w1 = jnp.clip(q - (base + lower).astype(q.dtype), 0.0, 1.0)
        weights.append(jnp.where(node == lower, 1.0 - w1, 0.0) + jnp.where(node == lower + 1, w1, 0.0))
    return start, weights


def _indices(*starts):
    """Start indices of a ``dynamic_slice``, all int32 (with x64 enabled, literals and ``searchsorted`` are int64)."""
    return tuple(jnp.asarray(i, jnp.int32) for i in starts)


def _contract(block, weights):
    """``sum_abc block[a, b, c] w0[a] w1[b] w2[c]`` for a 3-D block."""
    return jnp.einsum("abc,a,b,c->", block, *weights)


def avoid_value_and_gradient(grid, taus, padded, tau, x_rel):
    """``V^A(tau, t_IAT)`` and its spatial gradient at ``x_rel`` (3,) from one ``2 x 4 x 4 x 4`` block of the
    table ``padded`` (:func:`pad_periodic` of the slices at ascending ``taus``, one leading time axis): linear in
    ``tau``, multilinear in the state, the gradient by one-cell central differences. The same function as
    :func:`stp_env.reach.avoid.avoid_table_value` and the gradient of
    :func:`stp_env.reach.avoid.avoid_table_input` up to rounding (``tests/test_block_reads.py`` compares them),
    read with one block gather instead of 112 scalar ones: a smaller program, faster to compile and to run."""
    if grid.ndim != 3:
        raise ValueError(f"avoid tables are 3-D; got a {grid.ndim}-D grid.")
    k = jnp.clip(jnp.searchsorted(taus, tau, side="right") - 1, 0, taus.shape[0] - 2)
    span = taus[k + 1] - taus[k]
    w = jnp.clip(jnp.where(span > 0, (tau - taus[k]) / span, 0.0), 0.0, 1.0)
    pos = grid.fractional_index(x_rel)
    axes = [_block_axis(grid, d, pos[d]) for d in range(3)]
    block = jax.lax.dynamic_slice(padded, _indices(k, *(a[0] for a in axes)), (2, BLOCK, BLOCK, BLOCK))
    block = (1.0 - w) * block[0] + w * block[1]
    centre = [a[1][1] for a in axes]
    value = _contract(block, centre)
    spacing = np.asarray(grid.spacing)
    grad = []
    for d in range(3):
        up = [axes[e][1][2] if e == d else centre[e] for e in range(3)]
        down = [axes[e][1][0] if e == d else centre[e] for e in range(3)]
        grad.append((_contract(block, up) - _contract(block, down)) / (2.0 * spacing[d]))
    return value, jnp.stack(grad)


def _cell_axis(grid, d: int, pos):
    """Axis ``d`` of a one-cell read at fractional index ``pos``: the cell's first node in the padded table and the
    two multilinear weights (clamped or wrapped as :func:`_block_axis`)."""
    i0, p = _cell(grid, d, pos)
    w1 = p - i0.astype(p.dtype)
    start = i0 + PERIODIC_PAD[0] if d in grid.periodic else i0
    return start, jnp.stack([1.0 - w1, w1])


def pad_components(fields, grid) -> np.ndarray:
    """Arrays on ``grid`` (one per component, e.g. a gradient field) stacked on a trailing axis, periodic axes
    padded (:func:`pad_periodic`): the layout :func:`interpolate_components` reads
    (``EnvParams.tables.tracking_table``)."""
    return np.stack([pad_periodic(f, grid) for f in fields], axis=-1)


def interpolate_components(grid, padded, state):
    """Multilinear interpolation at ``state`` of every component of ``padded`` (:func:`pad_components`), ``(K,)``:
    :func:`stp_env.hj.interpolation.interpolate_gradient` of the unstacked fields up to rounding
    (``tests/test_block_reads.py``), read as one ``2 x ... x 2 x K`` block."""
    pos = grid.fractional_index(state)
    axes = [_cell_axis(grid, d, pos[d]) for d in range(grid.ndim)]
    k = padded.shape[-1]
    block = jax.lax.dynamic_slice(padded, _indices(*(a[0] for a in axes), 0), (2,) * grid.ndim + (k,))
    for a in axes:  # contract the leading axis with its weights, one axis at a time
        block = jnp.tensordot(a[1], block, axes=1)
    return block


# Every table read is its own jitted function (grids and dynamics static), called from the simulator's traced
# programs: inlined, a read would be traced again at every call site (the step reads the tables at reset, at each
# inner control step and at the step's end, for every policy that reads them) and re-batched by every enclosing
# ``vmap`` and ``scan``; as a nested jitted call it is traced once per shape and batched once per batching pattern
# (measured when the block reads landed; the figures are in git history).
_avoid_read = jax.jit(avoid_value_and_gradient, static_argnums=(0,))
interpolate = jax.jit(hj.interpolation.interpolate, static_argnums=(0, 3))
_tracking_read = jax.jit(interpolate_components, static_argnums=(0,))


def _inside(grid, x):
    lo, hi = jnp.asarray(grid.lo[:2]), jnp.asarray(grid.hi[:2])
    return jnp.all((x[:2] >= lo) & (x[:2] <= hi))


def inside_avoid_box(params, x_rel):
    """Whether the relative position of ``x_rel`` (3,) lies in the avoid table's box (bounds included): where
    :func:`avoid_value` is read rather than ``FAR``."""
    return _inside(params.tables.avoid_grid, x_rel)


def avoid_value(params, tau, x_rel):
    """``V^A(tau, t_IAT)`` at the intruder's relative state ``x_rel`` (3,); ``FAR`` outside the grid
    (:func:`inside_avoid_box`)."""
    grid = params.tables.avoid_grid
    v, _ = _avoid_read(grid, params.tables.avoid_taus, params.tables.avoid_values, tau, x_rel)
    return jnp.where(inside_avoid_box(params, x_rel), v, FAR)


def _avoid_input_of(params, player, tau, x_rel):
    """One player's optimal input of eq. (14) from the block-read gradient (as
    :func:`stp_env.reach.avoid.avoid_table_input`)."""
    _, p = _avoid_read(params.tables.avoid_grid, params.tables.avoid_taus, params.tables.avoid_values, tau, x_rel)
    dyn = params.tables.avoid_dynamics
    optimum = dyn.optimal_control if player == "vehicle" else dyn.optimal_disturbance
    return jnp.stack(optimum((x_rel[0], x_rel[1], x_rel[2]), (p[0], p[1], p[2])))


def avoidance_control(params, tau, x_rel):
    """``u^A`` (eq. 15): ``(v_i, omega_i)`` maximising ``dV^A/dt`` at ``x_rel``."""
    return _avoid_input_of(params, "vehicle", tau, x_rel)


def pursuit_input(params, tau, x_rel):
    """The minimising player of eq. (14): ``(v_I, omega_I, w_x, w_y)``, the intruder's control and the worst
    combined wind ``R(-theta_i)(d_I - d_i)`` in the vehicle's body frame."""
    return _avoid_input_of(params, "intruder", tau, x_rel)


RECOVERY_GAIN = 2.0  # [1/s] turn rate per radian of bearing error when the error has left the tracking table


def tracking_control(params, error):
    """:func:`tracking_control_and_value` without the value."""
    u, d, _ = tracking_control_and_value(params, error)
    return u, d


def tracking_control_and_value(params, error):
    """The robust tracker ``kappa(e)`` (SPP eq. 26) at the tracking error ``e`` (3,): ``(v, omega)``, and the worst
    wind of the same game (in the vehicle's body frame, as it enters the error dynamics: the vehicle's own wind
    in the world frame is ``-R(theta) d``).

    ``kappa`` is bang-bang: each input at the bound picked by the sign of its switching function ``p . B_i(e)``
    (``p`` the interpolated gradient of ``W = -V``). It keeps the error inside ``{V <= V(e_0)}`` only if it is
    re-evaluated often enough: the core runs it at the inner control rate (``EnvConfig.control_dt``), not at the
    decision rate, because held for 0.1 s it chatters out of the invariant set (see ``docs/numerics.md``). Outside
    the table (the guarantee already broken) the vehicle heads for its reference at full speed, so that it
    recovers instead of flying off with a gradient read at the table's edge.

    The third output is the tracking value ``V(e)`` [m] (the same block read: ``params.tables.tracking_table``
    holds the gradient and the value), ``inf`` outside the table."""
    dyn = params.tables.tracking_dynamics
    grid = params.tables.tracking_grid
    lo, hi = jnp.asarray(grid.lo), jnp.asarray(grid.hi)
    e = jnp.clip(error, lo, hi)
    p = _tracking_read(grid, params.tables.tracking_table, e)
    pp = tuple(p[i] for i in range(3))
    ee = tuple(e[i] for i in range(3))
    u = jnp.stack(dyn.optimal_control(ee, pp))
    d = jnp.stack(dyn.optimal_disturbance(ee, pp))
    inside = jnp.all((error[:2] >= lo[:2]) & (error[:2] <= hi[:2]))
    box = dyn.control_space.blocks[0]
    bearing = jnp.arctan2(error[1], error[0])
    recover = jnp.stack([jnp.asarray(box.hi[0], u.dtype),
                         jnp.clip(RECOVERY_GAIN * bearing, box.lo[1], box.hi[1]).astype(u.dtype)])
    return jnp.where(inside, u, recover), d[2:4], jnp.where(inside, p[3], jnp.inf)


# ------------------------------------------------------------------------------------------------ plug-in tables
def extra_table(params, name: str):
    """The table ``name`` of ``params.tables.extra`` (a :class:`~stp_env.sim.types.Table`: ``values`` on
    ``grid``), which :func:`stp_env.requirements.with_required_tables` loads for a policy whose record lists it
    (its builder registered with :func:`stp_env.requirements.register_table`). Looked up when the policy is traced
    (the names are static): a missing table is a ``ValueError`` then, never a wrong number."""
    for table in params.tables.extra:
        if table.name == name:
            return table
    loaded = ", ".join(t.name for t in params.tables.extra) or "none"
    raise ValueError(f"table {name!r} is not in the params (loaded: {loaded}): list it in the policy's record "
                     "(Intruder(policy, tables=(...))) so that stp_env.requirements.with_required_tables loads it.")


def table_value(params, name: str, x, fill_value: float | None = None):
    """Table ``name`` (:func:`extra_table`) at ``x`` (its grid's dimension): multilinear, clamped to the grid as
    :func:`stp_env.hj.interpolation.interpolate`, or ``fill_value`` outside the grid when one is given. Jittable
    and differentiable in ``x`` (``jax.grad`` gives the gradient of the multilinear interpolant)."""
    table = extra_table(params, name)
    return interpolate(table.grid, table.values, jnp.asarray(x), fill_value)


# ------------------------------------------------------------------------------------------------ buffer game
def _require_buffer(params):
    if params.tables.buffer_values is None or params.tables.buffer_grid is None:
        raise ValueError("this policy plays the buffer game and needs V^B in the params: the record of a policy "
                         "that reads it lists the table 'buffer' (Intruder(policy, tables=('buffer',))), and "
                         "stp_env.requirements.with_required_tables loads it (stp_env.assembly.with_buffer).")


def buffer_game(params):
    """The dynamics of the buffer game (intruder paper eqs. 46-47): eq. (44) with *every* player minimising (the
    vehicle, the intruder and both winds bring the intruder toward the vehicle's avoid region)."""
    return params.tables.avoid_dynamics.with_modes(control_mode="min", disturbance_mode="min")


def buffer_value(params, x_rel):
    """``V^B(0, t_BRD)`` at the intruder's relative state ``x_rel`` (3,); ``FAR`` outside its grid."""
    _require_buffer(params)
    grid = params.tables.buffer_grid
    v = interpolate(grid, params.tables.buffer_values, x_rel)
    return jnp.where(_inside(grid, x_rel), v, FAR)


def buffer_gradient(params, x_rel):
    """Spatial gradient of :func:`buffer_value` by one-cell central differences, ``(3,)`` (zero outside the grid)."""
    _require_buffer(params)
    grid = params.tables.buffer_grid
    steps = jnp.asarray(np.eye(3) * np.asarray(grid.spacing)[:, None], x_rel.dtype)
    g = jnp.stack([(interpolate(grid, params.tables.buffer_values, x_rel + steps[i])
                    - interpolate(grid, params.tables.buffer_values, x_rel - steps[i]))
                   / (2 * steps[i, i]) for i in range(3)])
    return jnp.where(_inside(grid, x_rel), g, 0.0)


def buffer_hop(params, x_rel, vehicle_heading):
    """The buffer game's hop toward a vehicle (intruder paper eqs. 46-47) from the intruder's relative state
    ``x_rel`` (3,): the world heading of steepest descent of ``V^B`` (``-grad_p V^B`` turned by the vehicle's
    heading) and whether it holds (``V^B <= 0`` and a non-zero gradient; elsewhere the hop flies straight at the
    vehicle). The scripted ``optimal-max-k`` intruder and the learned intruders' ``"game"`` observation read it."""
    g = buffer_gradient(params, x_rel)
    heading = vehicle_heading + jnp.arctan2(-g[1], -g[0])
    inside = (buffer_value(params, x_rel) <= 0.0) & (jnp.hypot(g[0], g[1]) > 1e-3)
    return heading, inside


def buffer_descent(params, x_rel):
    """One gradient read of ``V^B`` at ``x_rel`` for the worst vehicle: ``(v, angle, |grad_p V^B|)``, the game's
    speed (the minimiser of :func:`worst_control`) and the heading, in the vehicle's body frame, along which the
    *vehicle* moving lowers ``V^B`` fastest: the direction of ``+grad_p V^B`` (the relative position changes by minus
    the vehicle's velocity; the intruder's heading is the opposite one, ``-grad_p V^B``)."""
    g = buffer_gradient(params, x_rel)
    v = buffer_game(params).optimal_control(tuple(x_rel), tuple(g))[0]
    return v, jnp.arctan2(g[1], g[0]), jnp.hypot(g[0], g[1])


def worst_control(params, x_rel):
    """The vehicle's minimising control of the buffer game at ``x_rel``: ``(v_i, omega_i)`` bringing the intruder
    into its avoid region fastest (the vehicle behaviour ``V^B`` assumes)."""
    p = buffer_gradient(params, x_rel)
    return jnp.stack(buffer_game(params).optimal_control(tuple(x_rel), tuple(p)))


def buffer_pursuit(params, x_rel):
    """The intruder's minimising input of the buffer game at ``x_rel``: ``(v_I, omega_I, w_x, w_y)`` (its control
    and the combined wind, as in :func:`pursuit_input`)."""
    p = buffer_gradient(params, x_rel)
    return jnp.stack(buffer_game(params).optimal_disturbance(tuple(x_rel), tuple(p)))
