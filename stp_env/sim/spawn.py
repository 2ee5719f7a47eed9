"""Where the intruder appears (Assumptions 1 and 3; Observation 1 of the intruder paper).

* ``"outside"``: candidates uniform within ``spawn_radius`` of a random flying vehicle (uniform in the domain when
  none flies), random heading; the first candidate inside the domain and outside every flying vehicle's avoid
  region ``{V^A(0, t_IAT) <= margin}`` is taken.
* ``"mixed"``: either of the two, with probability 1/2 per episode (one compiled program for both).
* ``"boundary"``: candidates on the boundary of a random flying vehicle's avoid region (a random bearing and
  relative heading, the radius found by bisection of ``V^A(0, t_IAT) = margin + 1 m`` along the bearing), kept if
  inside the domain and outside every other vehicle's avoid region: the most dangerous legal start.

``M`` candidates are drawn at once (fixed shapes under jit). If none is legal, the candidate with the largest
smallest avoid value is used, and the vehicles whose region it lies in get ``assumption_ok = False`` (the core
checks this for every vehicle when the intruder appears).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stp_env.sim import gates, tables
from stp_env.sim.fleet import random_vehicle
from stp_env.sim.physics import relative_state, rotate, wrap_angle
from stp_env.sim.types import EnvParams

N_CANDIDATES = 64
N_BISECT = 24
SPAWN_CLEARANCE = 2.0  # extra clearance from the avoid regions, in tracking-error bounds r_e


def _min_value(params: EnvParams, x, fly, xi):
    """Smallest ``V^A(0)`` over flying vehicles for an intruder at ``xi`` (``FAR`` if none flies)."""
    rel = relative_state(x, xi[None, :])
    vals = jax.vmap(lambda r: tables.avoid_value(params, 0.0, r))(rel)
    return jnp.min(jnp.where(fly, vals, tables.FAR))


def radius_on_level(params: EnvParams, direction, rel_heading, level, tau=0.0):
    """The distance along the unit ``direction`` (vehicle frame) at which an intruder of relative heading
    ``rel_heading`` is on (just outside) the level ``V^A(tau, t_IAT) = level`` of the avoid region (``tau``: the time
    since the intruder appeared [s]): bisection (``N_BISECT`` halvings) between the vehicle and the table's edge on
    that bearing."""
    grid = params.tables.avoid_grid
    r_hi0 = 0.999 * min(-grid.lo[0], grid.hi[0], -grid.lo[1], grid.hi[1])  # inside the table on every bearing

    def value(r):
        return tables.avoid_value(params, tau, jnp.stack([r * direction[0], r * direction[1], rel_heading]))

    def bisect(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        inside = value(mid) <= level
        return jnp.where(inside, mid, lo), jnp.where(inside, hi, mid)

    dtype = params.episode.collision_radius.dtype  # float32, or float64 when x64 is on and params are cast
    _, hi = jax.lax.fori_loop(0, N_BISECT, bisect, (jnp.zeros((), dtype), jnp.asarray(r_hi0, dtype)))
    return hi


def _candidate_outside(key, x, fly, params: EnvParams):
    k1, k2, k3, k4 = jax.random.split(key, 4)
    j, any_fly = random_vehicle(k1, fly, params)
    u = jax.random.uniform(k2, (2,))
    r_c = params.episode.collision_radius
    r = r_c + (params.intruder.spawn_radius - r_c) * jnp.sqrt(u[0])
    a = 2 * jnp.pi * u[1]
    near = x[j, :2] + r * jnp.array([jnp.cos(a), jnp.sin(a)])
    lo, hi = params.episode.domain_lo, params.episode.domain_hi
    anywhere = lo + jax.random.uniform(k3, (2,)) * (hi - lo)
    p = jnp.where(any_fly, near, anywhere)
    theta = jax.random.uniform(k4, (), minval=-jnp.pi, maxval=jnp.pi)
    return jnp.array([p[0], p[1], theta])


def _candidate_boundary(key, x, fly, params: EnvParams):
    k1, k2, k3 = jax.random.split(key, 3)
    j, any_fly = random_vehicle(k1, fly, params)
    bearing = jax.random.uniform(k2, (), minval=-jnp.pi, maxval=jnp.pi)
    rel_heading = jax.random.uniform(k3, (), minval=-jnp.pi, maxval=jnp.pi)
    direction = jnp.array([jnp.cos(bearing), jnp.sin(bearing)])
    level = params.tables.avoid_margin + SPAWN_CLEARANCE * params.tables.tracking_bound + 1.0
    p_rel = radius_on_level(params, direction, rel_heading, level) * direction
    xj = x[j]
    p = xj[:2] + rotate(xj[2], p_rel)
    cand = jnp.array([p[0], p[1], wrap_angle(xj[2] + rel_heading)])
    return jnp.where(any_fly, cand, _candidate_outside(key, x, fly, params))


def spawn(key, x, fly, params: EnvParams):
    """The intruder's state at appearance (3,), for vehicles at ``x`` (N, 3) of which ``fly`` (N,) are flying.

    The core calls it at reset with the *nominal* states at the appearance time (vehicles track their plans
    within ``r_e`` until then), so candidates keep ``2 r_e`` of extra clearance from the avoid regions; the core
    checks Assumption 3 again against the actual states when the intruder appears."""
    k_mode, k_cand = jax.random.split(key)
    keys = jax.random.split(k_cand, N_CANDIDATES)
    boundary = jax.random.uniform(k_mode) < params.intruder.spawn_boundary_probability
    outside = jax.vmap(lambda k: _candidate_outside(k, x, fly, params))(keys)
    # The boundary candidates (a bisection of N_BISECT table reads each) only when some episode of the batch spawns
    # on a boundary: an episode that does not takes ``outside`` either way, so the gate is exact (stp_env.sim.gates)
    cands = gates.when_any(
        boundary, lambda ks: jnp.where(boundary, jax.vmap(lambda k: _candidate_boundary(k, x, fly, params))(ks),
                                       outside),
        lambda ks: outside, keys)
    inside = jnp.all((cands[:, :2] >= params.episode.domain_lo) & (cands[:, :2] <= params.episode.domain_hi), axis=1)
    minv = jax.vmap(lambda c: _min_value(params, x, fly, c))(cands)
    legal = inside & (minv > params.tables.avoid_margin + SPAWN_CLEARANCE * params.tables.tracking_bound)
    fallback = jnp.argmax(jnp.where(inside, minv, -jnp.inf))
    return cands[jnp.where(jnp.any(legal), jnp.argmax(legal), fallback)]
