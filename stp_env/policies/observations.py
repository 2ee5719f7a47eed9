"""The intruder's observation sets: what a learned intruder sees, as jittable ``(state, params) -> (m,)``.

* ``"core"``: :func:`stp_env.sim.observe`'s intruder row (present flag, position, heading, ``tau / t_IAT``, time to
  appear, ``|N^RP| / F``, then the ``K`` nearest flying vehicles in its body frame with their ``V^A`` and forced
  flags). What every learned intruder before the game features saw.
* ``"game"``: the core row followed by features of the two games the bound is built from, so that a policy can
  learn the multi-vehicle hop that the scripted :func:`stp_env.policies.intruders.optimal_max_k` plays:

  ======================  ====================================================================================
  1                       ``|N^RP| / k̄`` (progress toward the bound)
  9 per candidate (x 3)   the unforced flying vehicles in the order the buffer game ranks them (those inside
                          the ``V^B`` table by ``V^B``, eq. 47's value, smallest first; then the others by
                          distance): present, inside the table, inside the buffer region (``V^B <= 0`` with a
                          direction), ``V^B / d_sense``, distance ``/ d_sense``, the heading error to the
                          time-optimal hop toward it (``-grad_p V^B`` turned into the world frame, or the
                          bearing to the vehicle where ``V^B > 0``) ``/ pi`` and its ``sin, cos``, and
                          ``V^A / d_sense`` (eq. 14's value of that vehicle against the intruder)
  3                       whether every flying vehicle is forced already, and the avoid game's pursuit input
                          (eq. 14's minimiser, as an action in ``[-1, 1]``) against the flying vehicle with the
                          smallest ``V^A`` (zeros when none is inside the table)
  ======================  ====================================================================================

  It reads the relative buffer table: whoever runs an intruder that sees it loads ``V^B``
  (:func:`stp_env.assembly.with_buffer`), as for the ``optimal-max-k`` script. Every entry is in ``[-2, 2]``.

The set is recorded in a learned intruder's file (``metadata["observation"]``; absent means ``"core"``), so the
loader (:func:`stp_env.policies.learned.load_intruder`) computes exactly what the policy was trained on.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stp_env.sim import tables
from stp_env.sim.observations import observe
from stp_env.sim.physics import control_to_action, relative_state, wrap_angle
from stp_env.sim.types import FLYING

OBSERVATIONS = ("core", "game")
OBSERVATION_TABLES = {"game": ("buffer",)}
"""The tables each observation set reads beyond the scenario's own, by name (absent: none): a learned intruder's
record lists them (:func:`stp_env.policies.learned.load_intruder`), and a trainer whose learner sees the set loads
them (:func:`stp_env.requirements.with_required_tables`)."""
N_CANDIDATES = 3
CANDIDATE_FEATURES = 9


def check_observation(name: str) -> str:
    if name not in OBSERVATIONS:
        raise ValueError(f"observation {name!r} is not known; allowed: {', '.join(OBSERVATIONS)}.")
    return name


def game_features(state, params):
    """The ``"game"`` features (module docstring), ``(1 + 9 * 3 + 3,)`` float32."""
    ds = params.intruder.d_sense
    xi = state.intruder_x
    fly = state.status == FLYING
    unforced = fly & ~jnp.isfinite(state.avoid_start)
    rel = relative_state(state.x, xi[None, :])
    vb = jax.vmap(lambda r: tables.buffer_value(params, r))(rel)
    dist = jnp.hypot(*(state.x[:, :2] - xi[None, :2]).T)
    in_table = vb < tables.FAR
    rank = jnp.where(unforced, jnp.where(in_table, vb, tables.FAR + dist), jnp.inf)
    kk = min(N_CANDIDATES, int(state.x.shape[0]))
    neg, idx = jax.lax.top_k(-rank, kk)
    present = jnp.isfinite(neg)

    def candidate(j, ok):
        heading, inside = tables.buffer_hop(params, rel[j], state.x[j, 2])
        d = state.x[j, :2] - xi[:2]
        direction = jnp.where(inside, heading, jnp.arctan2(d[1], d[0]))
        err = wrap_angle(direction - xi[2])
        f = jnp.stack([jnp.ones(()), in_table[j], inside, jnp.clip(vb[j] / ds, -2.0, 2.0),
                       jnp.clip(dist[j] / ds, 0.0, 2.0), err / jnp.pi, jnp.sin(err), jnp.cos(err),
                       jnp.clip(state.avoid_value[j] / ds, -2.0, 2.0)]).astype(jnp.float32)
        return f * ok

    block = jax.vmap(candidate)(idx, present).reshape(-1)
    if kk < N_CANDIDATES:
        block = jnp.concatenate([block, jnp.zeros(((N_CANDIDATES - kk) * CANDIDATE_FEATURES,), jnp.float32)])
    tau = state.t - state.t_appear
    vals = jnp.where(fly, state.avoid_value, jnp.inf)
    j = jnp.argmin(vals)
    pose = params.vehicles.model.pose(state.x)
    d = tables.pursuit_input(params, tau, relative_state(pose, xi[None, :])[j])
    pursuit = jnp.where(vals[j] < tables.FAR, control_to_action(d[0], d[1], params.intruder.bounds), 0.0)
    all_forced = jnp.any(fly) & ~jnp.any(unforced)
    kbar = jnp.maximum(params.intruder.kbar, 1)
    progress = jnp.sum(jnp.isfinite(state.avoid_start)) / kbar
    return jnp.concatenate([jnp.clip(progress, 0.0, 2.0)[None].astype(jnp.float32), block,
                            jnp.stack([all_forced, pursuit[0], pursuit[1]]).astype(jnp.float32)])


def intruder_observation(state, params, observation: str = "core"):
    """The intruder's observation of set ``observation`` (float32, entries in ``[-2, 2]``)."""
    core = observe(state, params)[1].astype(jnp.float32)
    if observation == "core":
        return core
    if observation == "game":
        return jnp.concatenate([core, game_features(state, params)])
    raise ValueError(f"observation {observation!r} is not known; allowed: {', '.join(OBSERVATIONS)}.")


def observation_size(params, observation: str = "core") -> int:
    """The length of :func:`intruder_observation` for ``params``."""
    from stp_env.sim.observations import _abstract_state

    check_observation(observation)
    if "buffer" in OBSERVATION_TABLES.get(observation, ()):
        tables._require_buffer(params)
    return int(jax.eval_shape(lambda s: intruder_observation(s, params, observation),
                              _abstract_state(params)).shape[0])
