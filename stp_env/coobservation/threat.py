"""The compromised-vehicle threat in the UAV simulator, by composition around the pure core (``stp_env.sim``).

:func:`step` takes the core's ``EnvParams`` and a :class:`ThreatParams` (forbidden zones and the observation
schedule as arrays), runs one ``stp_env.sim.core.step`` with the vehicles' actions, except that from
``t_compromise`` on the compromised vehicle's action is the attacker's, and then records what the co-observation
paper's defence sees:

* **co-observations**: at each scheduled time, whether the observed vehicle is within the observation radius of
  its observer (the partner vehicle's actual position, or a fixed point); a miss is reported (``missed``);
* **detections**: the first missed observation that involves the compromised vehicle at or after the compromise
  (``detect_time``); misses that do not (an honest vehicle off its plan) are false alarms;
* **forbidden-region entries** of every flying vehicle (``entered``, ``entry_time``);
* the compromised vehicle's **departure** from its plan (``departure_time``: the first step at or after the
  compromise at which it is more than ``depart_distance`` from its nominal position, the deviation the schedule's
  ellipses allow an honest observer, Section II-F's growth of the observation radius, or is lost: collided, e.g.
  with the teammate it flew into, or left the domain; a vehicle that flies its plan does neither) and its
  **closest approach** to a zone after the compromise (``closest_zone``, the largest edge distance of
  :func:`zone_depth`: <= 0 inside), from which :func:`attempts` counts entry attempts and their time margins.

An attack *succeeds* when the compromised vehicle entered a forbidden zone and was never detected
(:func:`outcomes`). Everything is jittable and batched with ``vmap`` (:func:`rollout`); attackers are jittable
``policy(key, state, params, threat) -> (2,)`` (scripted ones in :mod:`stp_env.coobservation.attackers`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.coobservation.admm import polygon_halfplanes
from stp_env.coobservation.schedule import Observation
from stp_env.policies import nominal_tracking
from stp_env.sim import core, engine
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import COLLIDED, FLYING, OUT_OF_BOUNDS, EnvParams, EnvState, replace

INF = jnp.inf
NEVER = 1e9  # [s] time of the placeholder observations that pad a schedule
# an attacker's "action": its vehicle flies its plan (numpy, so that importing does no JAX work)
FLY_PLAN = np.full((2,), np.nan, np.float32)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ThreatParams:
    """Forbidden zones and the observation schedule (``P`` zones of up to ``K`` edges, ``M`` observations,
    ``B`` entry points)."""

    normals: jax.Array        # (P, K, 2) outward unit normals of each zone's edges (padded by repetition)
    offsets: jax.Array        # (P, K) [m]: inside is n . p <= m for every edge
    obs_time: jax.Array       # (M,) [s]
    obs_agent: jax.Array      # (M,) int: the observed vehicle
    obs_partner: jax.Array    # (M,) int: the observing vehicle, -1 for a fixed point
    obs_point: jax.Array      # (M, 2) [m]: the fixed observer (when obs_partner < 0)
    radius: jax.Array         # () [m] observation radius
    entry_points: jax.Array   # (B, 2) [m]: points just inside the zones, along their boundaries (attackers' aims)
    depart_distance: jax.Array  # () [m]: the compromised vehicle has left its plan farther than this from it


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ThreatState:
    """The core's state and the threat's bookkeeping (``N`` vehicles, ``M`` scheduled observations)."""

    sim: EnvState
    compromised: jax.Array    # () int: the compromised vehicle, -1 for none
    t_compromise: jax.Array   # () [s]: the attacker acts from this time on
    entered: jax.Array        # (N,) bool: has been inside a forbidden zone
    entry_time: jax.Array     # (N,) [s] first entry (inf: never)
    inside: jax.Array         # (N,) bool: inside a zone now
    checked: jax.Array        # (M,) bool: the observation's time has come
    missed: jax.Array         # (M,) bool: ... and the two were farther apart than the radius
    obs_distance: jax.Array   # (M,) [m] distance at the observation (inf: not yet)
    detect_time: jax.Array    # () [s] first missed observation of the compromised vehicle after t_compromise
    false_alarms: jax.Array   # () int: missed observations not involving it (or before t_compromise)
    max_track_error: jax.Array  # (N,) [m] largest distance from the nominal position while honest
    departure_time: jax.Array  # () [s] first time the compromised vehicle was off its plan (inf: never)
    closest_zone: jax.Array   # () [m] the compromised vehicle's smallest zone depth since the compromise (inf: none)


def threat_params(observations, forbidden, radius: float, entry_depth: float = 20.0,
                  points_per_edge: int = 16, pad_to: int | None = None,
                  depart_distance: float = 20.0) -> ThreatParams:
    """Arrays of a schedule (:class:`stp_env.coobservation.schedule.Observation`, times in seconds) and forbidden
    convex polygons. ``entry_depth`` [m]: how far inside a zone the attackers' entry points lie.
    ``depart_distance`` [m]: how far from its nominal position the compromised vehicle counts as having left its
    plan (default: the scenario's tracking margin, 20 m). ``pad_to``: add
    placeholder observations (at :data:`NEVER`, never due, counted as checked) up to this many, so that schedules
    of different lengths share one compiled rollout."""
    if not observations:
        raise ValueError("the schedule has no observations.")
    if not forbidden:
        raise ValueError("no forbidden zones given.")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a finite number > 0; got {radius!r}.")
    if not (math.isfinite(depart_distance) and depart_distance > 0):
        raise ValueError(f"depart_distance must be a finite number > 0; got {depart_distance!r}.")
    hp = [polygon_halfplanes(p) for p in forbidden]
    k = max(len(m) for _, m in hp)
    normals = np.stack([np.concatenate([n, np.repeat(n[:1], k - len(n), 0)]) for n, _ in hp])
    offsets = np.stack([np.concatenate([m, np.repeat(m[:1], k - len(m))]) for _, m in hp])
    entry = []
    for poly, (n, _) in zip(forbidden, hp):
        v = np.asarray(poly, float)
        if np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]) < 0:
            v = v[::-1]
        for a, b, nn in zip(v, np.roll(v, -1, 0), n):
            s = (np.arange(points_per_edge) + 0.5) / points_per_edge
            entry.append(a + s[:, None] * (b - a) - entry_depth * nn)
    obs = sorted(observations, key=lambda o: o.time)
    if pad_to is not None:
        if pad_to < len(obs):
            raise ValueError(f"pad_to ({pad_to}) is less than the {len(obs)} observations.")
        obs = obs + [Observation(time=NEVER, agent=0, point=(0.0, 0.0))] * (pad_to - len(obs))
    return ThreatParams(
        normals=jnp.asarray(normals, jnp.float32), offsets=jnp.asarray(offsets, jnp.float32),
        obs_time=jnp.asarray([o.time for o in obs], jnp.float32),
        obs_agent=jnp.asarray([o.agent for o in obs], jnp.int32),
        obs_partner=jnp.asarray([-1 if o.partner is None else o.partner for o in obs], jnp.int32),
        obs_point=jnp.asarray([o.point if o.point is not None else (0.0, 0.0) for o in obs], jnp.float32),
        radius=jnp.asarray(radius, jnp.float32),
        entry_points=jnp.asarray(np.concatenate(entry), jnp.float32),
        depart_distance=jnp.asarray(depart_distance, jnp.float32))


def zone_depth(p, threat: ThreatParams):
    """``max_k (n_k . p - m_k)`` for each zone: ``(..., P)``, <= 0 inside."""
    d = jnp.einsum("...j,pkj->...pk", p, threat.normals) - threat.offsets
    return jnp.max(d, axis=-1)


def in_forbidden(p, threat: ThreatParams):
    """Whether points ``p`` (..., 2) lie in some forbidden zone (boundary included)."""
    return jnp.any(zone_depth(p, threat) <= 0.0, axis=-1)


def _events(ts: ThreatState, sim_state: EnvState, params: EnvParams, threat: ThreatParams) -> ThreatState:
    t = sim_state.t
    x = sim_state.x[:, :2]
    n = x.shape[0]
    c = ts.compromised
    # forbidden-region entries (flying vehicles)
    inside = (sim_state.status == FLYING) & in_forbidden(x, threat)
    first = inside & ~ts.entered
    # scheduled observations due at this step
    due = ~ts.checked & (jnp.abs(t - threat.obs_time) <= 0.5 * params.episode.dt)
    pa = x[threat.obs_agent]
    pb = jnp.where((threat.obs_partner >= 0)[:, None], x[jnp.maximum(threat.obs_partner, 0)], threat.obs_point)
    dist = jnp.linalg.norm(pa - pb, axis=-1)
    # a vehicle that collided or left the domain is lost: it can neither observe nor be observed
    lost = (sim_state.status == COLLIDED) | (sim_state.status == OUT_OF_BOUNDS)
    lost_pair = lost[threat.obs_agent] | ((threat.obs_partner >= 0) & lost[jnp.maximum(threat.obs_partner, 0)])
    miss = due & ((dist > threat.radius) | lost_pair)
    involves = (c >= 0) & ((threat.obs_agent == c) | (threat.obs_partner == c))
    after = threat.obs_time >= ts.t_compromise - 0.5 * params.episode.dt
    detect = miss & involves & after
    detect_time = jnp.where(jnp.isinf(ts.detect_time) & jnp.any(detect), t, ts.detect_time)
    # honest tracking error (every vehicle but the compromised one once it is compromised)
    x_ref, _ = core.nominal_reference(params, t)
    err = jnp.linalg.norm(x - x_ref[:, :2], axis=-1)
    honest = ~((jnp.arange(n) == c) & (t >= ts.t_compromise)) & (sim_state.status == FLYING)
    # the compromised vehicle's departure from its plan and closest approach to a zone (since the compromise)
    ci = jnp.maximum(c, 0)
    active = (c >= 0) & (t >= ts.t_compromise - 1e-6)
    lost_c = (sim_state.status[ci] == COLLIDED) | (sim_state.status[ci] == OUT_OF_BOUNDS)
    off = active & (((sim_state.status[ci] == FLYING) & (err[ci] > threat.depart_distance)) | lost_c)
    departure_time = jnp.where(jnp.isinf(ts.departure_time) & off, t, ts.departure_time)
    depth = jnp.min(zone_depth(x[ci], threat))
    closest_zone = jnp.where(active, jnp.minimum(ts.closest_zone, depth), ts.closest_zone)
    return replace(
        ts, sim=sim_state, inside=inside, entered=ts.entered | inside,
        entry_time=jnp.where(first, t, ts.entry_time),
        checked=ts.checked | due, missed=ts.missed | miss, obs_distance=jnp.where(due, dist, ts.obs_distance),
        detect_time=detect_time, false_alarms=ts.false_alarms + jnp.sum(miss & ~(involves & after)),
        max_track_error=jnp.where(honest, jnp.maximum(ts.max_track_error, err), ts.max_track_error),
        departure_time=departure_time, closest_zone=closest_zone)


def reset(key, params: EnvParams, threat: ThreatParams, compromised, t_compromise) -> ThreatState:
    """A new episode: the core's reset, nobody compromised yet (``compromised = -1`` for none)."""
    sim_state = core.reset(key, params)
    n = params.vehicles.n
    m = threat.obs_time.shape[0]
    dtype = sim_state.t.dtype
    ts = ThreatState(
        sim=sim_state, compromised=jnp.asarray(compromised, jnp.int32),
        t_compromise=jnp.asarray(t_compromise, dtype), entered=jnp.zeros((n,), bool),
        entry_time=jnp.full((n,), INF, dtype), inside=jnp.zeros((n,), bool), checked=threat.obs_time >= NEVER,
        missed=jnp.zeros((m,), bool), obs_distance=jnp.full((m,), INF, dtype), detect_time=jnp.asarray(INF, dtype),
        false_alarms=jnp.asarray(0, jnp.int32), max_track_error=jnp.zeros((n,), dtype),
        departure_time=jnp.asarray(INF, dtype), closest_zone=jnp.asarray(INF, dtype))
    return _events(ts, sim_state, params, threat)


def attacker_active(ts: ThreatState):
    return (ts.compromised >= 0) & (ts.sim.t >= ts.t_compromise - 1e-6)


def step(key, ts: ThreatState, vehicle_actions, attacker_action, params: EnvParams, threat: ThreatParams,
         feedback=None, vehicle_policy=nominal_tracking):
    """One step: ``vehicle_actions`` ``(N, 2)`` in ``[-1, 1]``, of which the compromised vehicle's row is replaced by
    ``attacker_action`` ``(2,)`` once the attack is active (:data:`FLY_PLAN`: it flies its plan this step).
    ``feedback`` ``(N,)`` (default: every vehicle): the
    vehicles that run ``vehicle_policy`` (the tracker) at every inner control step of the core
    (``EnvConfig.control_dt``) instead of holding their action over the step; the attacker's action is held. The
    core's intruder slot gets the zero action (there is no intruder: it never appears). Returns the new
    :class:`ThreatState`."""
    n = params.vehicles.n
    att = jnp.asarray(attacker_action, vehicle_actions.dtype)
    # FLY_PLAN (NaN): the attacker lets its vehicle fly the plan this step (the tracker, at every inner step)
    mine = (jnp.arange(n) == ts.compromised) & attacker_active(ts) & ~jnp.any(jnp.isnan(att))
    a = jnp.where(mine[:, None], att[None, :], vehicle_actions)
    feedback = jnp.ones((n,), bool) if feedback is None else jnp.asarray(feedback, bool)
    feedback = feedback & ~mine

    def policy(k, s, p):
        return jnp.where(feedback[:, None], vehicle_policy(k, s, p), a)

    actions = jnp.concatenate([a, jnp.zeros((1, 2), a.dtype)], axis=0)
    sim_state, _ = core.step(key, ts.sim, actions, params, vehicle_policy=policy)
    return _events(ts, sim_state, params, threat)


def episode_done(ts: ThreatState, params: EnvParams):
    """The episode ends at ``t_end`` (the last scheduled observation has been checked)."""
    return ts.sim.t >= params.episode.t_end - 0.5 * params.episode.dt


def draw_attack(key, params: EnvParams, t_lo: float, t_hi: float):
    """A random compromised vehicle and a compromise time uniform on the simulator's step grid in
    ``[t_lo, t_hi]``."""
    k1, k2 = jax.random.split(key)
    c = jax.random.randint(k1, (), 0, params.vehicles.n)
    steps = jnp.floor((t_hi - t_lo) / params.episode.dt)
    t = t_lo + jnp.floor(jax.random.uniform(k2, ()) * (steps + 1.0)) * params.episode.dt
    return c, t


@functools.partial(sim_jit, static_argnames=("attacker", "n_envs", "n_steps", "vehicle_policy", "record"))
def rollout(key, params: EnvParams, threat: ThreatParams, attacker, n_envs: int, n_steps: int, t_window,
            vehicle_policy=nominal_tracking, record: bool = False):
    """``n_envs`` episodes of ``n_steps`` steps; episode ``i`` uses ``fold_in(key, i)``: a random compromised
    vehicle and compromise time in ``t_window = (lo, hi)`` [s] (:func:`draw_attack`; ``lo < 0``: nobody is
    compromised). The honest vehicles (and the compromised one before ``t_compromise``) run ``vehicle_policy``.

    Returns the final :class:`ThreatState` (batched) and, with ``record=True``, the positions ``(n_envs, n_steps,
    N, 2)``."""

    def one(ep_key):
        k_attack, k_reset, k_run = jax.random.split(ep_key, 3)
        c, t_c = draw_attack(k_attack, params, t_window[0], t_window[1])
        c = jnp.where(t_window[0] < 0, -1, c)
        ts0 = reset(k_reset, params, threat, c, t_c)

        def body(ts, k):
            k_v, k_a, k_s = jax.random.split(k, 3)
            a_v = vehicle_policy(k_v, ts.sim, params)
            a_att = attacker(k_a, ts, params, threat, a_v[jnp.maximum(ts.compromised, 0)])
            return step(k_s, ts, a_v, a_att, params, threat, vehicle_policy=vehicle_policy), None

        return engine.play(body, ts0, jax.random.split(k_run, n_steps), stop=lambda ts: episode_done(ts, params),
                           record=(lambda ts, _: ts.sim.x[:, :2]) if record else None)

    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(n_envs))
    return engine.vmap_across_devices(one)(keys)


def steps_for(params: EnvParams) -> int:
    """Steps from ``t_start`` to ``t_end``."""
    return round(float((params.episode.t_end - params.episode.t_start) / params.episode.dt))


def outcomes(final: ThreatState) -> dict:
    """Per-episode outcomes as numpy arrays: ``attacked`` (someone compromised), ``entered`` (the compromised
    vehicle entered a zone), ``detected``, ``success`` (entered and never detected), ``delay`` (detection time
    minus entry time, NaN where not both), ``false_alarms``, ``honest_entries`` (other vehicles inside a zone),
    ``max_track_error`` of the honest vehicles, ``all_checked`` (the whole schedule was evaluated), ``collisions``
    (vehicles that collided)."""
    c = np.asarray(final.compromised)
    entered_all = np.asarray(final.entered)
    entry_time = np.asarray(final.entry_time)
    n_ep, n = entered_all.shape
    idx = np.clip(c, 0, n - 1)
    attacked = c >= 0
    entered = attacked & entered_all[np.arange(n_ep), idx]
    detect_time = np.asarray(final.detect_time)
    detected = attacked & np.isfinite(detect_time)
    t_entry = entry_time[np.arange(n_ep), idx]
    both = entered & detected
    delay = np.full(n_ep, np.nan)
    delay[both] = detect_time[both] - t_entry[both]
    others = entered_all & ~((np.arange(n)[None, :] == c[:, None]) & attacked[:, None])
    return {
        "attacked": attacked, "entered": entered, "detected": detected, "success": entered & ~detected,
        "delay": delay, "false_alarms": np.asarray(final.false_alarms), "honest_entries": others.sum(axis=1),
        "max_track_error": np.asarray(final.max_track_error).max(axis=1),
        "all_checked": np.asarray(final.checked).all(axis=1),
        "collisions": (np.asarray(final.sim.status) == COLLIDED).sum(axis=1),
    }


def attempt_margin(final: ThreatState, threat: ThreatParams, speed, dt):
    """The time margin [s] of one episode's attack (unbatched ``final``): the smallest, over the scheduled
    observations of the compromised vehicle from its departure on (due at or after ``departure_time - dt / 2``),
    of ``(radius - distance) / speed``, the distance between the vehicle and its observer at the observation and
    ``speed`` the fastest ground speed ``v_max + wind`` (the ellipse's, Def. 3): how many seconds longer the
    vehicle could have flown away and still been seen. It is >= 0 exactly when no observation of it was missed
    since it left its plan, so an entry with a margin >= 0 is undetected; ``-inf`` where an observation was
    missed because a vehicle of the pair was lost (collided or left the domain); ``+inf`` where it never departed.
    """
    return _margin(final.compromised, final.departure_time, final.checked, final.missed, final.obs_distance,
                   threat, speed, dt)


def _margin(compromised, departure_time, checked, missed, obs_distance, threat: ThreatParams, speed, dt):
    c = jnp.maximum(compromised, 0)
    involves = (threat.obs_agent == c) | (threat.obs_partner == c)
    scheduled = threat.obs_time < NEVER
    relevant = involves & scheduled & checked & (threat.obs_time >= departure_time - 0.5 * dt)
    lost = missed & (obs_distance <= threat.radius)
    slack = jnp.where(lost, -INF, (threat.radius - obs_distance) / speed)
    return jnp.min(jnp.where(relevant, slack, INF))


def attempts(final: ThreatState, params: EnvParams, threat: ThreatParams) -> dict:
    """Entry attempts of a batch of episodes (numpy arrays, one entry per episode).

    The compromised vehicle *departs* at the first step after the compromise at which it flies more than
    ``threat.depart_distance`` from its nominal position or is lost (``departure_time``). An episode holds an
    *attempt* when its vehicle departed and then entered a zone or was detected (missed an observation): it left
    its plan and reached a zone or was caught trying; an excursion that came back without entering a zone or
    missing an observation is no attempt. One compromise per episode, so at most one attempt.

    Returns ``departed``, ``attempt``, ``undetected`` (an attempt that entered a zone and was never detected),
    ``margin`` (:func:`attempt_margin`, NaN where no attempt), ``lost`` (an attempt whose margin is ``-inf``: a
    vehicle of an observation pair was lost) and ``closest_zone`` [m] (the vehicle's smallest zone depth after
    the compromise, <= 0 inside)."""
    from stp_env.sim.bounds import V_MAX, WIND

    bounds = np.asarray(params.vehicles.bounds)
    speed = float(bounds[V_MAX] + bounds[WIND])
    dt = float(params.episode.dt)
    o = outcomes(final)
    departed = o["attacked"] & np.isfinite(np.asarray(final.departure_time))
    attempt = departed & (o["entered"] | o["detected"])
    fields = [np.asarray(getattr(final, k)) for k in
              ("compromised", "departure_time", "checked", "missed", "obs_distance")]
    margin = np.asarray(jax.vmap(lambda *f: _margin(*f, threat, speed, dt))(*fields), np.float64)
    margin = np.where(attempt, margin, np.nan)
    return {"departed": departed, "attempt": attempt, "undetected": attempt & o["entered"] & ~o["detected"],
            "margin": margin, "lost": attempt & np.isneginf(margin),
            "closest_zone": np.asarray(final.closest_zone, np.float64)}
