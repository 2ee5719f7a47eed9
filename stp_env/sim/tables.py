"""Reads of the reachability tables held in :class:`~stp_env.sim.types.EnvParams` (jittable, one state at a
time; vmap for many).

* :func:`avoid_value`: ``V^A(tau, t_IAT)(x_rel)`` (intruder paper eqs. 13-14), ``+inf``-like outside its grid.
* :func:`avoidance_control`: ``u^A`` (eq. 15), the vehicle's maximising control of the avoid game.
* :func:`pursuit_input`: the intruder's minimising control and the worst combined wind of the same game.
* :func:`tracking_control`: the robust tracker ``kappa`` (SPP eq. 26) and its worst-case wind.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.reach.avoid import avoid_table_input, avoid_table_value
from stp_env.sim.physics import relative_state

FAR = 1.0e6  # value reported outside the avoid-region grid [m]


def _inside(grid, x):
    lo, hi = jnp.asarray(grid.lo[:2]), jnp.asarray(grid.hi[:2])
    return jnp.all((x[:2] >= lo) & (x[:2] <= hi))


def avoid_value(params, tau, x_rel):
    """``V^A(tau, t_IAT)`` at the intruder's relative state ``x_rel`` (3,); ``FAR`` outside the grid."""
    grid = params.avoid_grid
    v = avoid_table_value(grid, params.avoid_taus, params.avoid_values, tau, x_rel)
    return jnp.where(_inside(grid, x_rel), v, FAR)


def _avoid_input(params, player, tau, x_rel):
    return avoid_table_input(params.avoid_dynamics, params.avoid_grid, params.avoid_taus, params.avoid_values,
                             player, tau, x_rel)


def avoidance_control(params, tau, x_rel):
    """``u^A`` (eq. 15): ``(v_i, omega_i)`` maximising ``dV^A/dt`` at ``x_rel``."""
    return _avoid_input(params, "vehicle", tau, x_rel)


def pursuit_input(params, tau, x_rel):
    """The minimising player of eq. (14): ``(v_I, omega_I, w_x, w_y)``, the intruder's control and the worst
    combined wind ``R(-theta_i)(d_I - d_i)`` in the vehicle's body frame."""
    return _avoid_input(params, "intruder", tau, x_rel)


def vehicle_intruder_values(params, state):
    """``V^A`` of every vehicle against the intruder, shape ``(N,)`` (``FAR`` when the intruder is absent)."""
    tau = state.t - state.t_appear
    rel = relative_state(params.vehicle_model.pose(state.x), state.intruder_x[None, :])
    vals = jax.vmap(lambda r: avoid_value(params, tau, r))(rel)
    return vals


RECOVERY_GAIN = 2.0  # [1/s] turn rate per radian of bearing error when the error has left the tracking table


def tracking_control(params, error):
    """The robust tracker ``kappa(e)`` (SPP eq. 26) at the tracking error ``e`` (3,): ``(v, omega)``, and the worst
    wind of the same game (in the vehicle's body frame, as it enters the error dynamics: the vehicle's own wind
    in the world frame is ``-R(theta) d``).

    ``kappa`` is bang-bang: each input at the bound picked by the sign of its switching function ``p . B_i(e)``
    (``p`` the interpolated gradient of ``W = -V``). It keeps the error inside ``{V <= V(e_0)}`` only if it is
    re-evaluated often enough: the core runs it at the inner control rate (``EnvConfig.control_dt``), not at the
    decision rate, because held for 0.1 s it chatters out of the invariant set (see ``docs/numerics.md``). Outside
    the table (the guarantee already broken) the vehicle heads for its reference at full speed, so that it
    recovers instead of flying off with a gradient read at the table's edge."""
    dyn = params.tracking_dynamics
    grid = params.tracking_grid
    lo, hi = jnp.asarray(grid.lo), jnp.asarray(grid.hi)
    e = jnp.clip(error, lo, hi)
    p = hj.interpolation.interpolate_gradient(grid, params.tracking_grads, e)
    pp = tuple(p[i] for i in range(3))
    ee = tuple(e[i] for i in range(3))
    u = jnp.stack(dyn.optimal_control(ee, pp))
    d = jnp.stack(dyn.optimal_disturbance(ee, pp))
    inside = jnp.all((error[:2] >= lo[:2]) & (error[:2] <= hi[:2]))
    box = dyn.control_space.blocks[0]
    bearing = jnp.arctan2(error[1], error[0])
    recover = jnp.stack([jnp.asarray(box.hi[0], u.dtype),
                         jnp.clip(RECOVERY_GAIN * bearing, box.lo[1], box.hi[1]).astype(u.dtype)])
    return jnp.where(inside, u, recover), d[2:4]


# ------------------------------------------------------------------------------------------------ buffer game
def _require_buffer(params):
    if params.buffer_values is None or params.buffer_grid is None:
        raise ValueError("this policy plays the buffer game and needs V^B in the params: build them with "
                         "stp_env.sim.build.with_buffer (the evaluation does so for the 'worst' vehicles and the "
                         "'optimal-max-k' intruder).")


def buffer_game(params):
    """The dynamics of the buffer game (intruder paper eqs. 46-47): eq. (44) with *every* player minimising (the
    vehicle, the intruder and both winds bring the intruder toward the vehicle's avoid region)."""
    return params.avoid_dynamics.with_modes(control_mode="min", disturbance_mode="min")


def buffer_value(params, x_rel):
    """``V^B(0, t_BRD)`` at the intruder's relative state ``x_rel`` (3,); ``FAR`` outside its grid."""
    _require_buffer(params)
    grid = params.buffer_grid
    v = hj.interpolation.interpolate(grid, params.buffer_values, x_rel)
    return jnp.where(_inside(grid, x_rel), v, FAR)


def buffer_gradient(params, x_rel):
    """Spatial gradient of :func:`buffer_value` by one-cell central differences, ``(3,)`` (zero outside the grid)."""
    _require_buffer(params)
    grid = params.buffer_grid
    steps = jnp.asarray(np.eye(3) * np.asarray(grid.spacing)[:, None], x_rel.dtype)
    g = jnp.stack([(hj.interpolation.interpolate(grid, params.buffer_values, x_rel + steps[i])
                    - hj.interpolation.interpolate(grid, params.buffer_values, x_rel - steps[i]))
                   / (2 * steps[i, i]) for i in range(3)])
    return jnp.where(_inside(grid, x_rel), g, 0.0)


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
