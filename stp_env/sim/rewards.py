"""The rewards of a step (:class:`stp_env.sim.config.RewardConfig`, by name): the vehicles' progress, arrival and
collision terms, the intruder's per-vehicle forced and collision bonuses, the bonus for reaching k̄, and its optional
shaping by the avoid-region value (a potential-based term over the vehicles unforced before the step)."""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.sim.status import flying, intruder_present
from stp_env.sim.types import EnvParams, EnvState


def rewards(state: EnvState, new_state: EnvState, ev, params: EnvParams):
    """The rewards of the step ``(N + 1,)`` from its events ``ev`` (:class:`stp_env.sim.core.Events`)."""
    w = params.episode.reward_weights
    fly = flying(state)
    present = intruder_present(state)
    d_prev = jnp.hypot(*(state.x[:, :2] - params.vehicles.targets).T)
    r_veh = jnp.where(fly, w.progress * (d_prev - ev.d_target), 0.0)
    on_time = new_state.t <= params.vehicles.sta + 1e-6
    r_veh = (r_veh + jnp.where(ev.arrived, jnp.where(on_time, w.arrival, w.late_arrival), 0.0)
             + jnp.where(ev.collided, w.collision, 0.0))
    newly_forced = jnp.isfinite(new_state.avoid_start) & ~jnp.isfinite(state.avoid_start)
    intruder_hits = ev.collided & (ev.hit_intruder | (ev.hit_vehicle & jnp.isfinite(state.avoid_start)))
    r_int = w.forced * jnp.sum(newly_forced) + w.intruder_collision * jnp.sum(intruder_hits)
    n_before = jnp.sum(jnp.isfinite(state.avoid_start))
    reached = (n_before < params.intruder.kbar) & (n_before + jnp.sum(newly_forced) >= params.intruder.kbar)
    r_int = r_int + jnp.where(reached, w.kbar_reached, 0.0)
    # Both potentials over the vehicles unforced *before* the step: forcing one lowers the potential (a positive
    # shaping reward) instead of removing it from the minimum (which would make the potential jump up).
    unforced = flying(state) & ~jnp.isfinite(state.avoid_start)
    shaping = w.shaping * (_potential(state, params, unforced) - _potential(new_state, params, unforced))
    r_int = r_int + jnp.where(present & intruder_present(new_state), shaping, 0.0)
    return jnp.concatenate([r_veh, r_int[None]]).astype(jnp.float32)


def _potential(state: EnvState, params: EnvParams, mask):
    """``min_i V^A_i`` over the vehicles in ``mask`` (the intruder's shaping potential), capped at ``d_sense``."""
    return jnp.minimum(jnp.min(jnp.where(mask & flying(state), state.avoid_value, jnp.inf)), params.intruder.d_sense)
