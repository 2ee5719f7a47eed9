"""Vehicle policies of the intruder paper (Section IV-D/E) as jittable ``(key, state, params) -> (N, 2)``.

* :func:`nominal_tracking` (``u^PP``): the robust tracker ``kappa`` (SPP eq. 26) of each vehicle's nominal
  trajectory while on the plan; after an avoidance (eq. 40) the :func:`fallback_control`.
* :func:`switching` (``u*``, eq. 38): ``u^A`` (eq. 15) from the avoid-start time ``t_i`` until the intruder
  leaves, else :func:`nominal_tracking`.
* :func:`safety_filter`: wraps any vehicle policy (learned or not) in the least-restrictive HJ filter: the
  policy's action is kept except where the vehicle is forced (its relative state reached the avoid boundary,
  eqs. 17-18), where ``u^A`` replaces it. ``switching == safety_filter(nominal_tracking)``.
* :func:`tube_keeping` / :func:`hj_filter`: the filter of a policy that may leave its plan: ``kappa`` wherever the
  tracking value leaves no room for one inner step of another control, and ``u^A`` while forced.
* :func:`worst`: the vehicle behaviour the relative buffer region ``V^B`` assumes (eqs. 22/46-47, Fig. 6): while
  the intruder is present, every flying vehicle not yet forced plays the minimising player of the buffer game,
  from the gradient of ``V^B``: the game's speed (that of :func:`stp_env.sim.tables.worst_control`) and a turn
  toward the heading of steepest descent of ``V^B`` (:func:`stp_env.sim.tables.buffer_descent`), i.e. the control
  that brings the intruder into its avoid region fastest. The turn is proportional, not the game's bang-bang turn
  rate: on the 12.5 m x 6 degree ``V^B`` grid the turn's switching function (``p_x y - p_y x - p_theta``) is
  small and noisy near the head-on line, and its sign flips made the vehicles weave off the head-on approach, the
  one along which the avoid region reaches farthest (``d^A``), which delayed the hop by 0.3 s in ``fig6``. Where
  ``V^B > 0`` (the intruder cannot reach the avoid region within ``t_BRD``, and the table's gradient carries no
  direction) it turns toward the intruder at full speed.
  Forced vehicles apply ``u^A`` (the safety filter), and the others ``u^PP`` when no intruder is present. Needs the
  buffer table (:func:`stp_env.assembly.with_buffer`).

After the intruder leaves, eq. (40) replans the affected vehicles (Algorithm 4,
:func:`stp_env.planning.replan.replan`, a level-set solve per vehicle: not jittable). The fallback here is the
documented faster substitute: fly at the fastest planning speed toward the target, turning at up to the full rate
(proportional in the heading error). It does not guarantee the new STA of Algorithm 4.
"""

from __future__ import annotations

import functools
from pathlib import Path

import jax
import jax.numpy as jnp

from stp_env import catalog
from stp_env.sim import status, tables
from stp_env.sim.bounds import OMEGA_MAX, V_MAX
from stp_env.sim.physics import control_to_action, relative_state, wrap_angle
from stp_env.sim.types import AFTER_AVOIDANCE, AVOIDING, FLYING, NOMINAL, PRESENT

HEADING_GAIN = 2.0  # [1/s] fallback turn rate per radian of heading error


def fallback_control(state, params, speed=None):
    """Head for the target at ``speed`` [m/s] (default: the fastest planning speed): ``(N, 2)`` actions."""
    pose = params.vehicles.model.pose(state.x)
    d = params.vehicles.targets - pose[:, :2]
    err = wrap_angle(jnp.arctan2(d[:, 1], d[:, 0]) - pose[:, 2])
    omega = jnp.clip(HEADING_GAIN * err, -params.vehicles.bounds[OMEGA_MAX], params.vehicles.bounds[OMEGA_MAX])
    v = jnp.full_like(omega, params.vehicles.planning_v_max if speed is None else speed)
    return params.vehicles.model.command_to_action(state.x, v, omega, params.vehicles.bounds)


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


def tube_keeping(policy):
    """Keep ``policy``'s vehicles in their tracking tubes: a vehicle flying its plan (nominal mode, never forced)
    applies ``policy``'s action only while its tracking value ``V(e)`` is at most
    ``params.tables.tracking_free_level`` (one inner step of ``V``'s fastest rise under any control below ``V(0)``:
    :func:`stp_env.sim.margins.tube_free_level`), and the tracker ``kappa`` otherwise, so that its error stays
    within ``r_e`` as every other vehicle's plan assumes (STP's separation rests on every vehicle staying in its
    tube). Other vehicles (after an avoidance, waiting) keep ``policy``'s action; forced ones get ``u^A`` from
    :func:`safety_filter`. Where the tracking value is flat below ``V(0)`` the free set is empty and the filter is
    ``kappa`` on the plan (``docs/learned_vehicles.md`` measures it on the crossing)."""

    def kept(key, state, params):
        a = policy(key, state, params)
        hold = status.on_plan(state) & ~(state.tracking_value <= params.tables.tracking_free_level)
        return jnp.where(hold[:, None], state.track_action, a)

    kept.__name__ = f"tube_keeping({getattr(policy, '__name__', 'policy')})"
    return kept


def hj_filter(policy):
    """Both HJ filters around ``policy``: :func:`tube_keeping` on the plan and ``u^A`` while forced (eq. 38)."""
    filtered = safety_filter(tube_keeping(policy))
    filtered.__name__ = f"hj_filter({getattr(policy, '__name__', 'policy')})"
    return filtered


switching = safety_filter(nominal_tracking)
switching.__name__ = "switching"
switching.__doc__ = "``u*`` (eq. 38): ``u^A`` while forced and the intruder is present, else ``u^PP``."

def _toward_intruder(state, params):
    """Full speed, turning toward the intruder at up to the full rate (proportional in the bearing error)."""
    d = state.intruder_x[None, :2] - state.x[:, :2]
    err = wrap_angle(jnp.arctan2(d[:, 1], d[:, 0]) - state.x[:, 2])
    b = params.vehicles.bounds
    omega = jnp.clip(HEADING_GAIN * err, -b[OMEGA_MAX], b[OMEGA_MAX])
    return control_to_action(jnp.full_like(omega, b[V_MAX]), omega, b)


def worst_unfiltered(key, state, params):
    """The buffer game's minimising vehicle control for the unforced vehicles while the intruder is present, else
    :func:`nominal_tracking` (:func:`worst` adds the safety filter)."""
    rel = relative_state(state.x, state.intruder_x[None, :])
    v, phi, norm = jax.vmap(lambda r: tables.buffer_descent(params, r))(rel)
    b = params.vehicles.bounds
    # the game's speed (v_max when moving ahead lowers V^B), turning proportionally toward the descent heading
    omega = jnp.clip(HEADING_GAIN * wrap_angle(phi), -b[OMEGA_MAX], b[OMEGA_MAX])
    game = control_to_action(v, omega, b)
    # V^B's gradient is informative where the intruder can reach the avoid region within t_BRD (V^B <= 0); farther
    # out the table holds the transported plateau of the clamped target (gradient ~0): close in head-on there.
    inside = (jax.vmap(lambda r: tables.buffer_value(params, r))(rel) <= 0.0) & (norm > 1e-3)
    toward = jnp.where(inside[:, None], game, _toward_intruder(state, params))
    attack = ((state.status == FLYING) & (state.mode == NOMINAL) & ~jnp.isfinite(state.avoid_start)
              & (state.intruder_status == PRESENT))
    return jnp.where(attack[:, None], toward, nominal_tracking(key, state, params))


worst = safety_filter(worst_unfiltered)
worst.__name__ = "worst"
worst.__doc__ = ("The buffer game's worst vehicles (see the module docstring): ``u^A`` while forced and the intruder "
                 "is present, else the control that brings the intruder into the avoid region fastest.")

VEHICLE_POLICIES = {"switching": switching, "nominal": nominal_tracking, "worst": worst}
VEHICLE_POLICY_TABLES = {"worst": ("buffer",)}
"""The tables each vehicle policy of :data:`VEHICLE_POLICIES` reads beyond the scenario's own, by name (absent:
none); :func:`stp_env.requirements.with_required_tables` loads them (the ``worst`` vehicles read ``V^B``)."""
BUFFER_GAME_VEHICLE_POLICIES = frozenset(name for name, read in VEHICLE_POLICY_TABLES.items() if "buffer" in read)
"""The vehicle policies that read the buffer table, as names (a view of :data:`VEHICLE_POLICY_TABLES`)."""


LEARNED_PREFIX = "learned:"


@functools.cache
def learned_vehicle_policy(name_or_path: str):
    """A learned vehicle policy (:mod:`stp_env.policies.learned_vehicles`: a shipped name or an ``.npz``) inside
    both HJ filters (:func:`hj_filter`), jittable; cached (one function, one compiled rollout, per file)."""
    from stp_env.policies.learned_vehicles import load_vehicle_mlp, mlp_vehicles

    name = f"learned:{Path(name_or_path).stem}"
    policy = hj_filter(mlp_vehicles(load_vehicle_mlp(name_or_path), name=name))
    policy.__name__ = name
    return policy


def vehicle_policy(name: str):
    """A vehicle policy by name: one of :data:`VEHICLE_POLICIES`, or ``"learned:NAME_OR_PATH"`` for a learned
    vehicle policy inside both HJ filters (:func:`learned_vehicle_policy`)."""
    if isinstance(name, str) and name.startswith(LEARNED_PREFIX):
        return learned_vehicle_policy(name[len(LEARNED_PREFIX):])
    if isinstance(name, str) and name not in VEHICLE_POLICIES and name in catalog.plugins("vehicle_policies"):
        policy = catalog.load_plugin("vehicle_policies", name)  # an installed plug-in (stp_env.catalog)
        if not callable(policy):
            raise ValueError(f"vehicle policy plug-in {name!r} is not callable.")
        return policy
    if name not in VEHICLE_POLICIES:
        raise ValueError(f"vehicle_policy {name!r} is not known; allowed: "
                         f"{', '.join(catalog.names('vehicle_policies', VEHICLE_POLICIES))}, or "
                         f"'{LEARNED_PREFIX}NAME_OR_PATH' for a learned vehicle policy.")
    return VEHICLE_POLICIES[name]
