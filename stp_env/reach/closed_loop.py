"""The reachability games flown in closed loop, sampled as the simulator samples them: the certification of the
tracking-error bound and of the avoid margin (``docs/numerics.md``, "Certified in closed loop").

Both games of the papers are two-player games of the relative Dubins dynamics (:class:`stp_env.dynamics.RelativeDubins`,
intruder paper eq. 44): the *own* vehicle holds the control (the tracker ``kappa`` of SPP eq. 26, or the avoidance
control ``u^A`` of eq. 15) and the *other* player the disturbance: the other vehicle's control (the reference in
``U^p``, or the intruder) together with the combined wind. A value table says what each player should do: the own
control maximises, the disturbance minimises ``grad V . f`` (the roles of the dynamics). On the grid, and with the
own control held for an inner period ``h`` (the simulator's ``control_dt``), the closed loop can do worse than the
value promises; these rollouts measure by how much.

:func:`rollout` flies the two players in the world frame with the exact Dubins motion of
:mod:`stp_env.kinematics`, each input held for ``h`` (the other player's control for ``hold`` inner periods, as a plan
holds a sample, or a held intruder action), the combined wind applied to the other player (the relative motion is the
same as with each player's own wind: only the difference of the two winds moves the relative state).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from stp_env.dynamics import RelativeDubins
from stp_env.kinematics import dubins_step, relative_state, rotate

CERTIFIED_CONTROL_DT = (0.005, 0.02)
"""[s] The inner control periods (``EnvConfig.control_dt``) the guarantees are certified at: the tracking-error bound
and the avoid margin are certified in closed loop at both ends of this range (:func:`stp_env.reach.tracking.
compute_tracking_bound`, :func:`stp_env.reach.avoid.compute_avoid_region`) and the simulator refuses periods outside
it unless asked to run uncertified (``EnvConfig.allow_uncertified``)."""

Gradient = Callable[[jax.Array, jax.Array], jax.Array]
"""``(t, x_rel) -> grad V`` (3,): the gradient a player reads, ``t`` the game's time (``tau`` for the avoid game)."""


def rollout(dynamics: RelativeDubins, own_gradient: Gradient, other_gradient: Gradient, x_rel0, *, h: float,
            n_steps: int, hold: int = 1, t0=0.0):
    """Fly the game from the relative state ``x_rel0`` (3,) for ``n_steps`` inner periods ``h``.

    The own player applies ``dynamics.optimal_control`` of ``own_gradient`` at every period; the other player's
    control (the first two components of ``dynamics.optimal_disturbance`` of ``other_gradient``) is re-read every
    ``hold`` periods and held in between, the combined wind (the last two) every period. Returns the relative state
    after each period ``(n_steps, 3)``, the other player's control over each period ``(n_steps, 2)`` and the combined
    wind over each period in the world frame, where the own player starts at the origin heading along ``x``
    ``(n_steps, 2)`` (applied to the other player; the own player's own wind would be its negative). Jittable;
    ``n_steps`` and ``hold`` are static."""
    x_rel0 = jnp.asarray(x_rel0, jnp.float32)
    own0 = jnp.zeros(3, jnp.float32)
    other0 = x_rel0  # the own body frame is the world frame at the start
    # the components of optimal_disturbance: other's (v, omega), then wind, own and other heading disturbances
    k_wind = 2 if dynamics.wind > 0 else None
    k_own = 2 + 2 * (dynamics.wind > 0) if dynamics.own_heading_disturbance > 0 else None
    k_oth = (2 + 2 * (dynamics.wind > 0) + (dynamics.own_heading_disturbance > 0)
             if dynamics.other_heading_disturbance > 0 else None)

    def body(carry, k):
        own, other, u_other = carry
        x = relative_state(own, other)
        t = t0 + k * h
        xs = tuple(x[i] for i in range(3))
        p_own = own_gradient(t, x)
        p_other = p_own if other_gradient is own_gradient else other_gradient(t, x)
        u = jnp.stack(dynamics.optimal_control(xs, tuple(p_own[i] for i in range(3))))
        d = jnp.stack(dynamics.optimal_disturbance(xs, tuple(p_other[i] for i in range(3))))
        u_other = jnp.where(k % hold == 0, d[:2], u_other)
        zero = jnp.zeros((), own.dtype)
        wind = rotate(own[2], d[k_wind:k_wind + 2]) if k_wind is not None else jnp.zeros(2, own.dtype)
        own_turn = d[k_own] if k_own is not None else zero
        other_turn = d[k_oth] if k_oth is not None else zero
        own = dubins_step(own, u[0], u[1] + own_turn, jnp.zeros(2, own.dtype), h)
        other = dubins_step(other, u_other[0], u_other[1] + other_turn, wind, h)
        return (own, other, u_other), (relative_state(own, other), u_other, wind)

    _, (xs, controls, winds) = jax.lax.scan(body, (own0, other0, jnp.zeros(2, jnp.float32)), jnp.arange(n_steps))
    return xs, controls, winds
