"""Wind models (one per :data:`~stp_env.sim.types.WIND_MODELS` entry). Every agent has its own wind in the disk
of its bound (``d_r`` for vehicles, ``d_I`` for the intruder; intruder paper eq. 43), and a heading-rate
disturbance in ``[-d_theta, d_theta]`` where the vehicle model has one (SPP eq. 28).

* ``uniform``: a new wind uniformly in the disk every step (the papers' simulations).
* ``constant``: one wind per agent and episode, uniform in the disk.
* ``gusts``: Ornstein-Uhlenbeck per component, ``dw = -w/T dt + sigma dB`` with stationary deviation half the
  bound, projected back into the disk.
* ``worst``: from the HJ games, re-evaluated at every inner step of the core (:func:`worst`). A vehicle avoiding
  the intruder gets the minimising wind of the avoid game (eq. 14) and the intruder the matching one; a vehicle
  tracking its plan gets the wind that grows its tracking error most (SPP eq. 25). Heading disturbances are zero in
  this model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stp_env.sim import tables
from stp_env.sim.physics import disk_sample, relative_state, rotate
from stp_env.sim.reference import nominal_reference
from stp_env.sim.types import AVOIDING, FLYING, PRESENT, EnvParams, EnvState


def _radii(params: EnvParams):
    n = params.n_vehicles
    return jnp.concatenate([jnp.full((n,), params.vehicle_bounds[3]), params.intruder_bounds[3:4]])


def _heading_bounds(params: EnvParams):
    n = params.n_vehicles
    return jnp.concatenate([jnp.full((n,), params.vehicle_bounds[4]), params.intruder_bounds[4:5]])


def initial_wind(key, params: EnvParams):
    """Wind state at reset ``(N + 1, 2)``: a disk sample for the persistent models, zeros otherwise."""
    n = params.n_vehicles
    if params.wind_model in ("constant", "gusts"):
        u = jax.random.uniform(key, (n + 1, 2))
        return disk_sample(u, _radii(params))
    return jnp.zeros((n + 1, 2))


def _project(w, radius):
    norm = jnp.linalg.norm(w, axis=-1, keepdims=True)
    return w * jnp.minimum(1.0, radius[:, None] / jnp.maximum(norm, 1e-12))


def worst(state: EnvState, params: EnvParams):
    """The ``worst`` model's winds ``(N + 1, 2)`` at ``state`` (world frame, each on its disk's boundary)."""
    n = params.n_vehicles
    radii = _radii(params)
    tau = state.t - state.t_appear
    rel = relative_state(state.x, state.intruder_x[None, :])
    game = jax.vmap(lambda r: tables.pursuit_input(params, tau, r))(rel)          # (N, 4)
    wc = game[:, 2:4]
    wc_dir = wc / jnp.maximum(jnp.linalg.norm(wc, axis=1, keepdims=True), 1e-12)
    # combined wind R(-theta_i)(d_I - d_i): the vehicle takes -R(theta_i) wc_dir d_r, the intruder +R(theta_i) ...
    w_avoid = -rotate(state.x[:, 2], wc_dir) * radii[:n, None]
    x_ref, _ = nominal_reference(params, state.t)
    err = relative_state(state.x, x_ref)
    d_err = jax.vmap(lambda e: tables.tracking_control(params, e)[1])(err)       # (N, 2) body frame
    d_dir = d_err / jnp.maximum(jnp.linalg.norm(d_err, axis=1, keepdims=True), 1e-12)
    # The error dynamics see minus the vehicle's wind, rotated into its frame: the vehicle takes -R(theta) d.
    w_track = -rotate(state.x[:, 2], d_dir) * radii[:n, None]
    present = state.intruder_status == PRESENT
    avoiding = (state.status == FLYING) & (state.mode == AVOIDING) & present
    w_veh = jnp.where(avoiding[:, None], w_avoid, w_track)
    vals = jnp.where((state.status == FLYING) & present,
                     jax.vmap(lambda r: tables.avoid_value(params, tau, r))(rel), jnp.inf)
    j = jnp.argmin(vals)
    w_int = rotate(state.x[j, 2], wc_dir[j]) * radii[n]
    w_int = jnp.where(jnp.isfinite(vals[j]), w_int, jnp.zeros(2))
    return jnp.concatenate([w_veh, w_int[None]], axis=0)


def sample(key, state: EnvState, params: EnvParams):
    """``(winds (N + 1, 2), heading disturbances (N + 1,), new wind state (N + 1, 2))`` for this step (held over
    its inner steps; the ``"worst"`` model's winds come from :func:`worst` at every inner step instead)."""
    n = params.n_vehicles
    k1, k2 = jax.random.split(key)
    radii = _radii(params)
    hd = (2 * jax.random.uniform(k2, (n + 1,)) - 1) * _heading_bounds(params)
    model = params.wind_model
    if model == "uniform":
        w = disk_sample(jax.random.uniform(k1, (n + 1, 2)), radii)
        return w, hd, state.wind
    if model == "constant":
        return state.wind, hd, state.wind
    if model == "gusts":
        tc = params.gust_time_constant
        sigma = 0.5 * radii[:, None] * jnp.sqrt(2.0 / tc)
        w = state.wind - state.wind / tc * params.dt + sigma * jnp.sqrt(params.dt) * jax.random.normal(k1, (n + 1, 2))
        w = _project(w, radii)
        return w, hd, w
    if model == "worst":  # state-dependent: the core calls worst() at every inner step
        return jnp.zeros((n + 1, 2)), jnp.zeros((n + 1,)), state.wind
    raise ValueError(f"wind_model {model!r} is not known.")
