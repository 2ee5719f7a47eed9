"""What the agents and a centralised critic see of the core's state: :func:`observe` (each vehicle's and the
intruder's observation, in the body frame; the table of entries is its docstring), :func:`global_state` and the
sizes of both, read from the code that builds them (:func:`observation_sizes`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stp_env.sim import fleet
from stp_env.sim.core import reset
from stp_env.sim.physics import relative_state, rotate
from stp_env.sim.reference import nominal_reference
from stp_env.sim.status import done_vehicles, flying, intruder_present, poses
from stp_env.sim.types import AFTER_AVOIDANCE, AVOIDING, PENDING, WAITING, EnvParams, EnvState


def _scale(params: EnvParams):
    center = 0.5 * (params.episode.domain_lo + params.episode.domain_hi)
    half = 0.5 * jnp.max(params.episode.domain_hi - params.episode.domain_lo)
    return center, half


def observation_sizes(params: EnvParams) -> tuple[int, int]:
    """``(vehicle observation size, intruder observation size)``: the shapes :func:`observe` returns for
    ``params`` (traced abstractly, nothing computed), so that they cannot drift from the code that builds them."""
    obs_v, obs_i = jax.eval_shape(observe, _abstract_state(params), params)
    return int(obs_v.shape[1]), int(obs_i.shape[0])


def vehicle_observation_size(params: EnvParams) -> int:
    return observation_sizes(params)[0]


def intruder_observation_size(params: EnvParams) -> int:
    return observation_sizes(params)[1]


def global_state_size(params: EnvParams) -> int:
    """The length of :func:`global_state` for ``params``."""
    return int(jax.eval_shape(global_state, _abstract_state(params), params).shape[0])


def _abstract_state(params: EnvParams):
    """The shapes and dtypes of an :class:`EnvState` for ``params`` (``jax.ShapeDtypeStruct`` leaves)."""
    return jax.eval_shape(reset, jax.random.key(0), params)


def _own_vehicle_features(state: EnvState, params: EnvParams):
    """The first 9 entries of each vehicle's observation row ``(N, 9)``: position ``(p - centre) / L``, ``cos,
    sin`` of the heading, flying / finished / waiting flags, avoiding / after-avoidance flags (observation and
    global state share them)."""
    center, half = _scale(params)
    x = poses(params, state)
    c, s = jnp.cos(x[:, 2]), jnp.sin(x[:, 2])
    return jnp.concatenate([
        (x[:, :2] - center) / half, c[:, None], s[:, None],
        flying(state)[:, None], done_vehicles(state)[:, None], (state.status == WAITING)[:, None],
        (state.mode == AVOIDING)[:, None], (state.mode == AFTER_AVOIDANCE)[:, None],
    ], axis=1).astype(x.dtype)


def global_state(state: EnvState, params: EnvParams):
    """The global state (the PettingZoo ``state()``), entries in ``[-2, 2]``: per vehicle the first 9 entries of
    its observation row (:func:`_own_vehicle_features`), then the intruder's ``(x, y)`` scaled as the vehicles',
    ``cos, sin``, present flag, ``tau / t_IAT`` (0 when absent), and the time since the episode start over its
    length."""
    center, half = _scale(params)
    xi = state.intruder_x
    present = intruder_present(state)
    tau = jnp.where(present, (state.t - state.t_appear) / params.intruder.t_iat, 0.0)
    length = jnp.maximum(params.episode.t_end - params.episode.t_start, 1.0)
    intr = jnp.stack([(xi[0] - center[0]) / half, (xi[1] - center[1]) / half, jnp.cos(xi[2]), jnp.sin(xi[2]),
                      present.astype(xi.dtype), tau, (state.t - params.episode.t_start) / length])
    veh = _own_vehicle_features(state, params).ravel()
    return jnp.clip(jnp.concatenate([veh, intr.astype(veh.dtype)]), -2.0, 2.0).astype(jnp.float32)


def _nearest(p_from, p_all, valid, k):
    """Indices of the ``k`` nearest valid points to each row of ``p_from`` and whether each exists."""
    d = jnp.sqrt(jnp.sum((p_from[:, None, :] - p_all[None, :, :]) ** 2, axis=-1))
    d = jnp.where(valid, d, jnp.inf)
    neg, idx = jax.lax.top_k(-d, k)
    return idx, jnp.isfinite(neg)


def observe(state: EnvState, params: EnvParams):
    """Observations ``(vehicle_obs (N, 20 + 5K), intruder_obs (8 + 7K,))``, every entry in ``[-2, 2]``.

    Vehicle row (positions scaled by the domain half-size ``L``, relative ones by ``d_sense``):

    ====== =====================================================================================
    0-1    own position ``(p - centre) / L``
    2-3    ``cos theta, sin theta``
    4-6    flying, finished (arrived / collided / out), waiting flags
    7-8    avoiding, after-avoidance flags
    9      ``(STA - t) / T`` (``T`` = episode length)
    10-11  target centre in the body frame ``/ L``
    12-15  tracking error in the body frame: ``e_x, e_y`` ``/ (10 r_e)``, ``cos e_theta, sin e_theta``
    16-19  intruder within ``d_sense``: visible flag, ``p_x, p_y`` in the body frame ``/ d_sense``, and
           ``V^A / d_sense`` (1 when not visible)
    20+    the ``K`` nearest flying vehicles: present flag, ``p_x, p_y`` (body frame) ``/ d_sense``,
           ``cos, sin`` of the relative heading
    ====== =====================================================================================

    Intruder row: present flag; position ``/ L`` (2); ``cos, sin``; ``tau / t_IAT``; time until it appears
    ``/ T``; ``|N^RP| / F`` (``F``: the whole fleet's size, :mod:`stp_env.sim.fleet`); then for the ``K`` nearest
    flying vehicles: present flag, their position in the intruder's body frame ``/ d_sense`` (2), ``cos, sin`` of
    their heading relative to the intruder's, the avoid value ``V^A / d_sense`` of that vehicle against the
    intruder, forced flag.
    """
    n, k = params.vehicles.n, params.episode.n_nearest
    center, half = _scale(params)
    ds = params.intruder.d_sense
    T = jnp.maximum(params.episode.t_end - params.episode.t_start, 1.0)
    fly = flying(state)
    present = intruder_present(state)
    x = poses(params, state)
    target_body = rotate(-x[:, 2], params.vehicles.targets - x[:, :2]) / half
    x_ref, _ = nominal_reference(params, state.t)
    err = relative_state(x, x_ref)
    r_scale = 10.0 * jnp.maximum(params.tables.tracking_bound, 1e-6)
    rel_i = relative_state(x, state.intruder_x[None, :])
    vals = state.avoid_value
    visible = fly & present & (jnp.hypot(rel_i[:, 0], rel_i[:, 1]) <= ds)
    intr = jnp.stack([visible.astype(x.dtype), rel_i[:, 0] / ds, rel_i[:, 1] / ds,
                      jnp.where(visible, jnp.minimum(vals / ds, 1.0), 1.0)], axis=1)
    intr = intr * jnp.concatenate([jnp.ones((n, 1)), jnp.repeat(visible[:, None], 2, 1), jnp.ones((n, 1))], 1)
    own = jnp.concatenate([
        _own_vehicle_features(state, params),
        ((params.vehicles.sta - state.t) / T)[:, None], target_body,
        err[:, :2] / r_scale, jnp.cos(err[:, 2:3]), jnp.sin(err[:, 2:3]),
    ], axis=1).astype(x.dtype)
    parts = [own, intr]
    if k > 0:
        valid = fly[None, :] & ~jnp.eye(n, dtype=bool)
        kk = min(k, n)
        idx, exists = _nearest(x[:, :2], x[:, :2], valid, kk)
        exists = exists & fly[:, None]
        other = x[idx]                                            # (N, kk, 3)
        rel = relative_state(x[:, None, :], other)                # (N, kk, 3)
        block = jnp.stack([exists.astype(x.dtype), rel[..., 0] / ds, rel[..., 1] / ds,
                           jnp.cos(rel[..., 2]), jnp.sin(rel[..., 2])], axis=-1) * exists[..., None]
        block = block.reshape(n, 5 * kk)
        if kk < k:
            block = jnp.concatenate([block, jnp.zeros((n, 5 * (k - kk)), x.dtype)], axis=1)
        parts.append(block)
    vehicle_obs = jnp.clip(jnp.concatenate(parts, axis=1), -2.0, 2.0)

    xi = state.intruder_x
    tau = state.t - state.t_appear
    own_i = jnp.stack([present.astype(x.dtype), (xi[0] - center[0]) / half, (xi[1] - center[1]) / half,
                       jnp.cos(xi[2]), jnp.sin(xi[2]), jnp.where(present, tau / params.intruder.t_iat, 0.0),
                       jnp.where(state.intruder_status == PENDING, (state.t_appear - state.t) / T, 0.0),
                       jnp.sum(jnp.isfinite(state.avoid_start)) / fleet.fleet_size(params)])
    own_i = own_i * jnp.where(present, 1.0, jnp.asarray([1, 0, 0, 0, 0, 1, 1, 1], x.dtype))
    parts_i = [own_i]
    if k > 0:
        kk = min(k, n)
        idx, exists = _nearest(xi[None, :2], x[:, :2], fly[None, :], kk)
        idx, exists = idx[0], exists[0] & present
        rel = relative_state(xi[None, :], x[idx])                 # (kk, 3)
        block = jnp.stack([exists.astype(x.dtype), rel[:, 0] / ds, rel[:, 1] / ds, jnp.cos(rel[:, 2]),
                           jnp.sin(rel[:, 2]), jnp.minimum(vals[idx] / ds, 1.0),
                           jnp.isfinite(state.avoid_start[idx]).astype(x.dtype)], axis=-1) * exists[:, None]
        block = block.reshape(7 * kk)
        if kk < k:
            block = jnp.concatenate([block, jnp.zeros((7 * (k - kk),), x.dtype)])
        parts_i.append(block)
    intruder_obs = jnp.clip(jnp.concatenate(parts_i), -2.0, 2.0)
    return vehicle_obs, intruder_obs
