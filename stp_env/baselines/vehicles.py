"""Vehicle policies of the intruder paper (Section IV-D/E) as jittable ``(key, state, params) -> (N, 2)``.

* :func:`nominal_tracking` (``u^PP``): the robust tracker ``kappa`` (SPP eq. 26) of each vehicle's nominal
  trajectory while on the plan; after an avoidance (eq. 40) the :func:`fallback_control`.
* :func:`switching` (``u*``, eq. 38): ``u^A`` (eq. 15) from the avoid-start time ``t_i`` until the intruder
  leaves, else :func:`nominal_tracking`.
* :func:`safety_filter`: wraps any vehicle policy (learned or not) in the least-restrictive HJ filter: the
  policy's action is kept except where the vehicle is forced (its relative state reached the avoid boundary,
  eqs. 17-18), where ``u^A`` replaces it. ``switching == safety_filter(nominal_tracking)``.

After the intruder leaves, eq. (40) replans the affected vehicles (Algorithm 4,
:func:`stp_env.planning.replan.replan`, a level-set solve per vehicle: not jittable). The fallback here is the
documented faster substitute: fly at the fastest planning speed toward the target, turning at up to the full rate
(proportional in the heading error). It does not guarantee the new STA of Algorithm 4.
"""

from __future__ import annotations

import jax.numpy as jnp

from stp_env.sim.physics import wrap_angle
from stp_env.sim.types import AFTER_AVOIDANCE, AVOIDING, PRESENT

HEADING_GAIN = 2.0  # [1/s] fallback turn rate per radian of heading error


def fallback_control(state, params):
    """Head for the target at the fastest planning speed: ``(N, 2)`` actions."""
    pose = params.vehicle_model.pose(state.x)
    d = params.targets - pose[:, :2]
    err = wrap_angle(jnp.arctan2(d[:, 1], d[:, 0]) - pose[:, 2])
    omega = jnp.clip(HEADING_GAIN * err, -params.vehicle_bounds[2], params.vehicle_bounds[2])
    v = jnp.full_like(omega, params.planning_v_max)
    return params.vehicle_model.command_to_action(state.x, v, omega, params.vehicle_bounds)


def nominal_tracking(key, state, params):
    """``u^PP``: track the nominal trajectory with ``kappa`` (SPP eq. 26, computed by the core into
    ``state.track_action`` at every inner control step); fallback after an avoidance."""
    del key
    after = state.mode == AFTER_AVOIDANCE
    return jnp.where(after[:, None], fallback_control(state, params), state.track_action)


def safety_filter(policy):
    """The least-restrictive HJ safety filter around ``policy`` (eq. 38 with ``policy`` in place of ``u^PP``)."""

    def filtered(key, state, params):
        a = policy(key, state, params)
        forced = (state.mode == AVOIDING) & (state.intruder_status == PRESENT)
        return jnp.where(forced[:, None], state.avoid_action, a)

    filtered.__name__ = f"safety_filter({getattr(policy, '__name__', 'policy')})"
    return filtered


switching = safety_filter(nominal_tracking)
switching.__name__ = "switching"
switching.__doc__ = "``u*`` (eq. 38): ``u^A`` while forced and the intruder is present, else ``u^PP``."

VEHICLE_POLICIES = {"switching": switching, "nominal": nominal_tracking}


def vehicle_policy(name: str):
    """A vehicle policy by name: one of :data:`VEHICLE_POLICIES`."""
    if name not in VEHICLE_POLICIES:
        raise ValueError(f"vehicle_policy {name!r} is not known; allowed: {', '.join(VEHICLE_POLICIES)}.")
    return VEHICLE_POLICIES[name]
