"""Scripted attackers of a compromised vehicle: jittable ``policy(key, state, params, threat, planned) -> (2,)``
actions in ``[-1, 1]`` (see :mod:`stp_env.coobservation.threat`); ``planned`` is the action the vehicle's tracker
would apply at the start of the step. An attacker that returns :data:`~stp_env.coobservation.threat.FLY_PLAN`
lets the vehicle fly its plan for the step (the tracker at every inner control step, as the honest vehicles do).

Both go for the *entry point* (a point just inside a forbidden zone, :attr:`ThreatParams.entry_points`) that
minimises the detour ``|p - e| + |e - o|`` from the vehicle's position ``p`` to its next observation point ``o``
(its own nominal position at the next observation that involves it: its formation slot, within the observation
radius of its observer), straight at full speed; once inside, straight back to ``o`` (slowing down on arrival, so
that it waits there if early), and back on its nominal trajectory (the tracker) once it has rejoined it.

* :func:`reckless`: attacks at once, whatever the schedule ("straight for the region, then back to the next
  observation point in time").
* :func:`opportunistic`: attacks only when the round trip fits before the next observation at the speed it can
  count on whatever the wind, ``v_max - wind``, with ``slack`` seconds to spare (turns); otherwise it flies its
  plan and waits for a window. Against a schedule whose reachability regions miss the forbidden zones no window
  ever opens, so it never enters.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from stp_env.coobservation import threat as threat_lib
from stp_env.sim import core
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN, WIND
from stp_env.sim.physics import control_to_action, wrap_angle

HEADING_GAIN = 3.0   # [1/s] turn rate per radian of heading error
ARRIVE_TIME = 2.0    # [s] slow down within this many seconds of the aim point
REJOIN_DISTANCE = 30.0  # [m] back on the nominal trajectory within this distance


def next_observation(state, params, threat, c, t):
    """``(time, aim point)`` of the first scheduled observation involving vehicle ``c`` after ``t``: the time and
    ``c``'s own nominal position then (``inf`` and its goal if there is none)."""
    involves = (threat.obs_agent == c) | (threat.obs_partner == c)
    later = involves & (threat.obs_time > t + 0.5 * params.episode.dt)
    t_next = jnp.min(jnp.where(later, threat.obs_time, jnp.inf))
    x_ref, _ = core.nominal_reference(params, jnp.where(jnp.isfinite(t_next), t_next, params.episode.t_end))
    return t_next, x_ref[c, :2]


def best_entry(p, o, threat):
    """The entry point minimising ``|p - e| + |e - o|`` and that detour length [m]."""
    e = threat.entry_points
    d = jnp.linalg.norm(e - p, axis=-1) + jnp.linalg.norm(o - e, axis=-1)
    k = jnp.argmin(d)
    return e[k], d[k]


def steer(x, point, speed, bounds):
    """Action turning the state ``x`` (3,) toward ``point`` at ``speed`` [m/s]."""
    d = point - x[:2]
    err = wrap_angle(jnp.arctan2(d[1], d[0]) - x[2])
    omega = jnp.clip(HEADING_GAIN * err, -bounds[OMEGA_MAX], bounds[OMEGA_MAX])
    return control_to_action(speed, omega, bounds)


def _attack_action(state, params, threat, planned, go):
    """The shared strategy; ``go``: whether to head for the zone now (before entering)."""
    c = jnp.maximum(state.compromised, 0)
    sim = state.sim
    x = sim.x[c]
    t = sim.t
    b = params.vehicles.bounds
    _t_next, aim = next_observation(state, params, threat, c, t)
    entry, _ = best_entry(x[:2], aim, threat)
    to_zone = steer(x, entry, b[V_MAX], b)
    dist_aim = jnp.linalg.norm(aim - x[:2])
    back = steer(x, aim, jnp.clip(dist_aim / ARRIVE_TIME, b[V_MIN], b[V_MAX]), b)
    del planned
    track = threat_lib.FLY_PLAN
    x_ref, _ = core.nominal_reference(params, t)
    rejoined = jnp.linalg.norm(x_ref[c, :2] - x[:2]) < REJOIN_DISTANCE
    entered = state.entered[c]
    after = jnp.where(rejoined, track, back)
    before = jnp.where(go, to_zone, jnp.where(rejoined, track, back))
    return jnp.where(entered, after, before)


def reckless(key, state, params, threat, planned):
    """Straight for the zone at once, then straight back to the next observation point."""
    del key
    return _attack_action(state, params, threat, planned, jnp.asarray(True))


def opportunistic(slack: float = 5.0):
    """Only when ``detour / (v_max - wind) <= t_next - t - slack`` (see the module docstring)."""

    def policy(key, state, params, threat, planned):
        del key
        c = jnp.maximum(state.compromised, 0)
        x = state.sim.x[c]
        t_next, aim = next_observation(state, params, threat, c, state.sim.t)
        _, detour = best_entry(x[:2], aim, threat)
        b = params.vehicles.bounds
        speed = jnp.maximum(b[V_MAX] - b[WIND], 1e-3)
        go = detour / speed <= t_next - state.sim.t - slack
        return _attack_action(state, params, threat, planned, go)

    policy.__name__ = "opportunistic"
    return policy


def observer_disks(params, threat, c, t_next):
    """The observers of vehicle ``c`` at its next observation time ``t_next``: centres ``(M, 2)`` (the partner's
    nominal position then, or the fixed point) and a mask ``(M,)`` of the observations that are due then and
    involve ``c``."""
    x_ref, _ = core.nominal_reference(params, jnp.where(jnp.isfinite(t_next), t_next, params.episode.t_end))
    due = ((threat.obs_agent == c) | (threat.obs_partner == c)) & (jnp.abs(threat.obs_time - t_next) < 1e-3)
    other = jnp.where(threat.obs_agent == c, threat.obs_partner, threat.obs_agent)
    centre = jnp.where((other >= 0)[:, None], x_ref[jnp.maximum(other, 0), :2], threat.obs_point)
    return centre, due


def toward_within(o, p, centres, mask, radius):
    """The point of the segment from ``o`` to ``p`` farthest toward ``p`` that stays within ``radius`` of every
    masked centre (``o`` itself must be within: the vehicle's own nominal position is). The observation disks'
    intersection is convex, so the points of the segment inside it are a segment from ``o``."""
    d = p - o
    f = o - centres                                            # (M, 2)
    dd = jnp.maximum(d @ d, 1e-9)
    df = f @ d
    ff = jnp.sum(f * f, axis=-1) - radius**2
    root = (-df + jnp.sqrt(jnp.maximum(df**2 - dd * ff, 0.0))) / dd
    s = jnp.clip(jnp.min(jnp.where(mask, root, 1.0)), 0.0, 1.0)
    return o + s * d


def after_entry(state, params, threat, c, own, centres, due, radius):
    """The compromised vehicle ``c``'s action once inside a zone: until the first observation of it after the entry,
    toward the nearest point from which the observers ``centres`` (``due``) see it (``radius`` inside their reach,
    :func:`toward_within`), arriving in about ``ARRIVE_TIME``; after that observation, back to its own slot ``own``
    and, once within ``REJOIN_DISTANCE`` of its plan, the plan."""
    sim = state.sim
    x, t = sim.x[c], sim.t
    b = params.vehicles.bounds
    aim = toward_within(own, x[:2], centres, due, radius)
    dist_aim = jnp.linalg.norm(aim - x[:2])
    back = steer(x, aim, jnp.clip(dist_aim / ARRIVE_TIME, b[V_MIN], b[V_MAX]), b)
    involves = (threat.obs_agent == c) | (threat.obs_partner == c)
    seen_since = jnp.any(involves & (threat.obs_time > state.entry_time[c]) & (threat.obs_time <= t))
    x_ref, _ = core.nominal_reference(params, t)
    rejoined = jnp.linalg.norm(x_ref[c, :2] - x[:2]) < REJOIN_DISTANCE
    dist_own = jnp.linalg.norm(own - x[:2])
    rejoin = jnp.where(rejoined, threat_lib.FLY_PLAN,
                       steer(x, own, jnp.clip(dist_own / ARRIVE_TIME, b[V_MIN], b[V_MAX]), b))
    return jnp.where(seen_since, rejoin, back)


def optimistic(slack: float = 2.0, margin: float = 10.0):
    """The attacker the reachability ellipses are built against (their worst case, up to turns): it counts on the
    fastest ground speed, ``v_max + wind`` (which the ``tailwind`` wind model gives it), and it returns not to its
    own formation slot but to the nearest point from which every observer of its next observation still sees it
    (``margin`` [m] inside the observation radius, around the observers' nominal positions). It attacks when the
    detour ``|p - e| + |e - a(e)|`` (``a(e)``: that point, toward the entry point ``e``) fits before that
    observation with ``slack`` seconds for the turns; after the entry it flies to ``a`` (waiting there if early),
    and after that observation back to its plan. Against a schedule secured by ellipses of speed ``v_max + wind``
    grown by the observation radius no window can open; against one that leaves out the wind, or the radius, it
    can."""

    def policy(key, state, params, threat, planned):
        del key, planned
        c = jnp.maximum(state.compromised, 0)
        sim = state.sim
        x, t = sim.x[c], sim.t
        b = params.vehicles.bounds
        t_next, own = next_observation(state, params, threat, c, t)
        centres, due = observer_disks(params, threat, c, t_next)
        r = threat.radius - margin
        # before the entry: the entry point with the shortest detour through the nearest visible point
        e = threat.entry_points
        aims = jax.vmap(lambda q: toward_within(own, q, centres, due, r))(e)
        detour = jnp.linalg.norm(e - x[:2], axis=-1) + jnp.linalg.norm(aims - e, axis=-1)
        k = jnp.argmin(detour)
        go = detour[k] / (b[V_MAX] + b[WIND]) <= t_next - t - slack
        to_zone = steer(x, e[k], b[V_MAX], b)
        before = jnp.where(go, to_zone, threat_lib.FLY_PLAN)
        return jnp.where(state.entered[c], after_entry(state, params, threat, c, own, centres, due, r), before)

    policy.__name__ = "optimistic"
    return policy


def honest(key, state, params, threat, planned):
    """No attack: the compromised vehicle keeps flying its plan (the false-alarm baseline)."""
    del key, state, params, threat, planned
    return threat_lib.FLY_PLAN


ATTACKERS = {"reckless": reckless, "opportunistic": opportunistic(), "optimistic": optimistic(), "honest": honest}


# ------------------------------------------------------------------------------------------------ observation
OBS_SIZE = 10
DISTANCE_SCALE = 1000.0  # [m]
TIME_SCALE = 60.0        # [s]


def attacker_observation(state, params, threat):
    """What an attacker sees (``(OBS_SIZE,)``, entries in ``[-2, 2]``; zeros while it is not active):

    ====== ==============================================================================================
    0-1    its next observation point (own nominal position at the next observation) in its body frame / 1 km
    2-3    the best entry point (:func:`best_entry`) in its body frame / 1 km
    4      time to the next observation / 60 s
    5      the detour through the entry point over the distance it can fly by then at ``v_max`` (clipped at 2)
    6      entered a zone already; 7 inside a zone now
    8-9    ``cos, sin`` of its heading
    ====== ==============================================================================================
    """
    from stp_env.coobservation.threat import attacker_active
    from stp_env.sim.physics import rotate

    c = jnp.maximum(state.compromised, 0)
    x = state.sim.x[c]
    t = state.sim.t
    t_next, aim = next_observation(state, params, threat, c, t)
    entry, detour = best_entry(x[:2], aim, threat)
    left = jnp.where(jnp.isfinite(t_next), t_next - t, 0.0)
    reach = params.vehicles.bounds[V_MAX] * left
    obs = jnp.concatenate([
        rotate(-x[2], aim - x[:2]) / DISTANCE_SCALE,
        rotate(-x[2], entry - x[:2]) / DISTANCE_SCALE,
        jnp.stack([left / TIME_SCALE, jnp.minimum(detour / jnp.maximum(reach, 1.0), 2.0),
                   state.entered[c].astype(x.dtype), state.inside[c].astype(x.dtype), jnp.cos(x[2]), jnp.sin(x[2])]),
    ])
    return jnp.where(attacker_active(state), jnp.clip(obs, -2.0, 2.0), 0.0).astype(jnp.float32)
