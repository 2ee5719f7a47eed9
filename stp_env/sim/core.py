"""The pure simulation core: ``reset(key, params)``, ``step(key, state, actions, params)``, ``observe``.

One step of length ``dt`` (intruder paper Sections II and IV):

1. The intruder appears when ``t >= t_`` (Assumption 1) at a state outside every flying vehicle's avoid region
   (Assumption 3; :mod:`stp_env.sim.spawn`) and is removed once ``t - t_ >= t_IAT``. Vehicles that were avoiding
   switch to the after-avoidance mode then (eq. 40).
2. Vehicles on the ground take off at their departure time (from their plan's first state).
3. Avoid start (eqs. 17-18): a flying vehicle whose relative state reaches ``V^A(t - t_, t_IAT) <= margin`` is
   forced; ``t_i = t``. The set of forced vehicles is ``N^RP`` (eq. 39).
4. The step is ``control_substeps`` inner steps of the vehicles' low-level loop (the autopilot rate: real
   vehicles run their trackers much faster than their decision rate). In each inner step: the papers' controllers
   are evaluated at the current state (the tracker ``kappa`` of SPP eq. 26 for the nominal trajectory, and
   ``u^A`` of eq. 15 against the intruder) and the avoid start of item 3 is checked; the vehicles' controls are
   the vehicle policy's (when one is passed to :func:`step`: a feedback law evaluated at every inner step) or the
   agents' actions (held over the step); with the safety filter on, forced vehicles apply ``u^A`` instead until
   the intruder leaves (eq. 38). Each action in ``[-1, 1]^2`` (clipped) maps to the agent's ``(v, omega)``
   bounds. The intruder's action is held over the step.
5. Wind (:mod:`stp_env.sim.winds`: held over the step, except state-dependent models such as ``"worst"``,
   re-evaluated every inner step), then the motion of the vehicle model under zero-order hold
   (:mod:`stp_env.sim.vehicle_models`; the papers' :class:`~stp_env.sim.vehicle_models.Dubins` by default, exact:
   :func:`~stp_env.sim.physics.dubins_step`); the intruder flies Dubins.
6. Events, from the closest approaches over the inner steps: collisions (vehicle-vehicle and vehicle-intruder
   within ``R_c``, vehicle-building where the signed distance is <= 0), leaving the domain, arrival in the target
   disk (and whether before the STA). A collision of a vehicle whose assumptions held (the intruder appeared
   outside its avoid region, and it applied ``u^A`` at every inner step from ``t_i`` on) is a *guarantee
   violation*, unless a vehicle flying the after-avoidance fallback takes part in it (a collision between two such
   vehicles, or one of them hitting another vehicle or a building): the fallback stands in for replanning
   (Algorithm 4), which is what the paper's guarantee after the intruder leaves rests on, and carries no guarantee
   of its own. Such collisions still count as collisions. A vehicle that applied ``kappa`` at every inner step of
   its nominal flight (except where its tracking value ``V(e)`` was at most ``tables.tracking_free_level``, the set
   in which a tube-keeping filter lets another control through: :func:`stp_env.policies.tube_keeping`) and still
   got farther than ``r_e`` from its nominal position breaks the robust-tracking guarantee (SPP eqs. 24-26): that
   is a guarantee violation too (``tracking_violation``), whatever the intruder does. A vehicle outside what the
   proofs certify (``EnvParams.vehicles.certified`` false: a plan that is not a flight of ``U^p``, or an
   uncertified inner period or avoid margin, accepted only with
   ``EnvConfig.allow_uncertified``) has its assumptions failed from the start: its collisions and tracking errors
   are not guarantee violations. A flying vehicle whose state is not finite (or every flying vehicle, while the
   present intruder's is not) has its assumptions failed at that step: a NaN never makes an episode look clean.

Waiting and finished vehicles are outside the airspace: they neither move nor collide. Actions of agents that
cannot act (waiting, finished, an absent intruder) are ignored.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.sim import fleet, gates, tables
from stp_env.sim import spawn as spawn_lib
from stp_env.sim import wind as wind_lib
from stp_env.sim.physics import action_to_control, dubins_step, relative_state
from stp_env.sim.reference import nominal_reference
from stp_env.sim.rewards import rewards
from stp_env.sim.status import done_vehicles, flying, intruder_present, on_plan, poses
from stp_env.sim.types import (
    AFTER_AVOIDANCE,
    ARRIVED,
    AVOIDING,
    COLLIDED,
    FLYING,
    GONE,
    NOMINAL,
    OUT_OF_BOUNDS,
    PENDING,
    PRESENT,
    WAITING,
    EnvParams,
    EnvState,
    replace,
)

COMPLIANCE_TOL = 1e-3  # |a - a^A| in action units below which a vehicle counts as applying u^A


# ------------------------------------------------------------------------------------------------ plans
def building_distance(params: EnvParams, p):
    """Signed distance to the buildings at positions ``p`` (..., 2) [m] (bilinear in the table)."""
    grid = params.tables.sdf_grid
    q = jnp.clip(p, jnp.asarray(grid.lo), jnp.asarray(grid.hi))
    flat = q.reshape(-1, 2)
    d = jax.vmap(lambda z: tables.interpolate(grid, params.tables.sdf, z))(flat)
    return d.reshape(p.shape[:-1])


# ------------------------------------------------------------------------------------------------ reset
def reset(key, params: EnvParams) -> EnvState:
    """A new episode at ``params.episode.t_start``: vehicles already departed are on their nominal trajectories (zero
    tracking error), the others wait; the intruder appears at ``t_ ~ U(appear_window)``."""
    n = params.vehicles.n
    _, k_wind, k_intruder, k_spawn = jax.random.split(key, 4)
    t0 = params.episode.t_start
    t_appear = appear_time(key, params)
    model = params.vehicles.model
    x_nom, _ = nominal_reference(params, t0)
    departed = params.vehicles.departure <= t0
    arrived = fleet.arrived_at_start(params)
    status = jnp.where(arrived, ARRIVED, jnp.where(departed, FLYING, WAITING)).astype(jnp.int32)
    x = jnp.where(departed[:, None], model.from_pose(x_nom), model.from_pose(params.vehicles.starts))
    # The spawn state, drawn now from the nominal states at the first step time >= t_ (see spawn.spawn).
    t_app = t0 + jnp.ceil(jnp.maximum(t_appear - t0, 0.0) / params.episode.dt - 1e-4) * params.episode.dt
    x_app, _ = nominal_reference(params, t_app)
    d_app = jnp.hypot(*(x_app[:, :2] - params.vehicles.targets).T)
    v = params.vehicles
    fly_app = (v.departure <= t_app) & (v.nominal_arrival > t_app) & (d_app > v.target_radii)
    x_spawn = spawn_lib.spawn(k_spawn, x_app, fly_app, params)
    inf = jnp.full((n,), jnp.inf, t0.dtype)
    state = EnvState(
        t=t0,
        step_count=jnp.zeros((), jnp.int32),
        x=x,
        status=status,
        mode=jnp.full((n,), NOMINAL, jnp.int32),
        avoid_start=inf,
        complied=jnp.ones((n,), bool),
        assumption_ok=jnp.asarray(params.vehicles.certified, bool),
        used_filter=jnp.zeros((n,), bool),
        min_separation=inf,
        arrival_time=jnp.where(arrived, jnp.minimum(params.vehicles.nominal_arrival, t0),
                               jnp.inf),  # before the episode
        collision_time=inf,
        collided_with_intruder=jnp.zeros((n,), bool),
        guarantee_violation=jnp.zeros((n,), bool),
        wind=wind_lib.initial_wind(k_wind, params),
        intruder_x=jnp.zeros((3,), t0.dtype),
        intruder_status=jnp.asarray(PENDING, jnp.int32),
        t_appear=t_appear,
        intruder_key=k_intruder,
        intruder_memory=jnp.concatenate([x_spawn, jnp.zeros((1,), t0.dtype)]),
        intruder_distance=inf,
        avoid_value=jnp.full((n,), tables.FAR, t0.dtype),
        avoid_action=jnp.zeros((n, model.action_dim), t0.dtype),
        track_action=jnp.zeros((n, model.action_dim), t0.dtype),
        tracking_error=jnp.zeros((n,), t0.dtype),
        tracking_value=jnp.zeros((n,), t0.dtype),
        max_tracking_error=jnp.zeros((n,), t0.dtype),
        tracked=jnp.ones((n,), bool),
        tracking_violation=jnp.zeros((n,), bool),
    )
    return lifecycle(state, params)


def appear_time(key, params: EnvParams):
    """The time ``t_ ~ U(appear_window)`` at which the intruder of the episode reset with ``key`` appears (drawn
    by :func:`reset`; the evaluator orders its batches by it without resetting)."""
    lo, hi = params.intruder.appear_window[0], params.intruder.appear_window[1]
    k_appear = jax.random.split(key, 4)[0]
    return lo + (hi - lo) * jax.random.uniform(k_appear, (), dtype=params.episode.t_start.dtype)


# ------------------------------------------------------------------------------------------------ helpers
def avoid_read_needed(params: EnvParams, state: EnvState, rel):
    """Which vehicles' avoid reads can matter, ``(N,)``: a flying vehicle while the intruder is present, whose relative
    state ``rel`` ``(N, 3)`` lies in the avoid table's box or that is avoiding. The others' ``V^A`` is ``FAR`` whether
    read or not (:func:`stp_env.sim.tables.avoid_value` outside the box), and their ``u^A`` is applied by no one (the
    core and the baseline filters apply it only to avoiding vehicles): they get ``FAR`` and a zero action."""
    inside = jax.vmap(lambda r: tables.inside_avoid_box(params, r))(rel)
    return flying(state) & intruder_present(state) & (inside | (state.mode == AVOIDING))


def avoid_reads(params: EnvParams, state: EnvState):
    """``V^A`` ``(N,)`` and ``u^A`` as actions ``(N, 2)`` of every vehicle against the present intruder (the values
    in ``state.avoid_value`` and ``state.avoid_action``, refreshed every inner step): ``FAR`` and zero actions where
    no read is needed (:func:`avoid_read_needed`). The needed reads are gathered over the whole batch and only they
    are computed (:func:`stp_env.sim.gates.where_needed`; each vehicle's read is its own: the same values as reading
    every vehicle, ``tests/test_gates.py``)."""
    rel = relative_state(poses(params, state), state.intruder_x[None, :])
    tau = state.t - state.t_appear
    value_dtype, action_dtype = state.avoid_value.dtype, state.avoid_action.dtype

    def read(vehicle, shared):
        r, x = vehicle
        params, tau = shared
        value = tables.avoid_value(params, tau, r)
        u = tables.avoidance_control(params, tau, r)
        action = params.vehicles.model.command_to_action(x, u[0], u[1], params.vehicles.bounds)
        return value.astype(value_dtype), action.astype(action_dtype)

    fill = (np.asarray(tables.FAR, value_dtype), np.zeros(state.avoid_action.shape[1:], action_dtype))
    return gates.where_needed(avoid_read_needed(params, state, rel), read, fill, (rel, state.x), (params, tau))


def tracking_actions(params: EnvParams, state: EnvState):
    """``kappa`` (SPP eq. 26) of every vehicle for its nominal trajectory at ``state.t``, as actions ``(N, 2)``,
    the tracking errors ``||e_p||`` ``(N,)`` [m] and the tracking values ``V(e)`` ``(N,)`` [m]."""
    x_ref, _ = nominal_reference(params, state.t)
    err = relative_state(poses(params, state), x_ref)
    u, _, value = jax.vmap(lambda e: tables.tracking_control_and_value(params, e))(err)
    return (params.vehicles.model.command_to_action(state.x, u[:, 0], u[:, 1], params.vehicles.bounds),
            jnp.hypot(err[:, 0], err[:, 1]), value)


def refresh_controllers(state: EnvState, params: EnvParams) -> EnvState:
    """The papers' controllers and values at the state: ``V^A`` and ``u^A`` against the intruder, ``kappa``, the
    tracking error and its value (every inner step; :func:`lifecycle` at the step's end)."""
    track_action, err, value = tracking_actions(params, state)
    avoid_value, avoid_action = avoid_reads(params, state)
    return replace(state, avoid_value=avoid_value, avoid_action=avoid_action, track_action=track_action,
                   tracking_error=err, tracking_value=value)


def observe_controllers(state: EnvState, params: EnvParams) -> EnvState:
    """:func:`refresh_controllers`, and the largest tracking error of the vehicles flying their plans."""
    state = refresh_controllers(state, params)
    worst = jnp.where(on_plan(state), jnp.maximum(state.max_tracking_error, state.tracking_error),
                      state.max_tracking_error)
    return replace(state, max_tracking_error=worst)


def avoid_start(state: EnvState, params: EnvParams) -> EnvState:
    """Eqs. (17)-(18): a flying vehicle in the nominal mode whose ``V^A`` reached the margin starts avoiding now."""
    start = (flying(state) & intruder_present(state) & (state.mode == NOMINAL)
             & (state.avoid_value <= params.tables.avoid_margin))
    return replace(state, mode=jnp.where(start, AVOIDING, state.mode),
                   avoid_start=jnp.where(start, state.t, state.avoid_start))


def episode_over(state: EnvState, params: EnvParams):
    """``(terminated, truncated)``: every vehicle done and the intruder gone; or the time limit. (Part of a fleet:
    every vehicle of the whole fleet, :mod:`stp_env.sim.fleet`.)"""
    terminated = jnp.all(done_vehicles(state)) & (state.intruder_status == GONE)
    if params.vehicles.outside_waiting is not None:
        terminated = terminated & ~params.vehicles.outside_waiting
    truncated = (state.t >= params.episode.t_end - 1e-6 * params.episode.dt) & ~terminated
    return terminated, truncated


# ------------------------------------------------------------------------------------------------ step
def lifecycle(state: EnvState, params: EnvParams) -> EnvState:
    """Items 1-3 of the module docstring at the state's time ``t``. ``reset`` and ``step`` end with it, so every
    state a policy sees is up to date (a vehicle knows it is forced in the step it is)."""
    t = state.t
    # 1. the intruder leaves after the whole steps that fit in t_IAT (Assumption 1: present at most t_IAT). Half a
    # step of tolerance: elapsed times on the grid carry float32 rounding (one ulp, about 1e-4 s at plan times of
    # 1,000-2,000 s), far above any tolerance tied to exact arithmetic.
    whole_steps = jnp.floor(params.intruder.t_iat / params.episode.dt + 1e-3)
    leaving = intruder_present(state) & (t - state.t_appear >= (whole_steps - 0.5) * params.episode.dt)
    mode = jnp.where(leaving & (state.mode == AVOIDING), AFTER_AVOIDANCE, state.mode)
    intruder_status = jnp.where(leaving, GONE, state.intruder_status)
    state = replace(state, mode=mode, intruder_status=intruder_status)
    # 2. departures
    # A vehicle takes off at t_LDT, between two steps: it starts on its nominal trajectory (zero tracking error).
    depart = (state.status == WAITING) & (t >= params.vehicles.departure - 1e-6 * params.episode.dt)
    x_nom, _ = nominal_reference(params, t)
    state = replace(state, status=jnp.where(depart, FLYING, state.status),
                    x=jnp.where(depart[:, None], params.vehicles.model.from_pose(x_nom), state.x))
    # ... or appears (after departures, so that vehicles taking off now count)
    appear = (state.intruder_status == PENDING) & (t >= state.t_appear - 1e-6 * params.episode.dt)
    state = replace(state,
                    intruder_x=jnp.where(appear, state.intruder_memory[:3], state.intruder_x),
                    t_appear=jnp.where(appear, t, state.t_appear),
                    intruder_status=jnp.where(appear, PRESENT, state.intruder_status))
    state = observe_controllers(state, params)
    # Assumption 3 per vehicle: checked when the intruder appears, or when a vehicle takes off while it is here.
    check = (appear & flying(state)) | (depart & intruder_present(state))
    assumption_ok = jnp.where(check, state.assumption_ok & (state.avoid_value > params.tables.avoid_margin),
                              state.assumption_ok)
    d_int = jnp.where(flying(state) & intruder_present(state),
                      jnp.hypot(*(state.x[:, :2] - state.intruder_x[None, :2]).T), jnp.inf)
    state = replace(state, assumption_ok=assumption_ok, intruder_distance=d_int)
    # 3. avoid start (eqs. 17-18)
    return avoid_start(state, params)


class Closest(NamedTuple):
    """Closest approaches over a step's inner steps (the events of item 6 are decided on them) [m]. The
    vehicle-vehicle distances are kept squared: the minimum of the squares is the square of the minimum (the square
    root rounds monotonically), so one square root per step, at its end, gives the same distances as one per inner
    step, bit for bit (``tests/test_sim.py``; ``python benchmarks/core_revisions.py --base REV`` measures the
    saving against an earlier core)."""

    pair_sq: jax.Array    # (N, N) vehicle-vehicle, squared [m^2] (the diagonal is huge)
    intruder: jax.Array   # (N,) vehicle-intruder
    building: jax.Array   # (N,) signed distance to the buildings


class Events(NamedTuple):
    """What happened to each vehicle in a step (item 6), ``(N,)`` each; the rewards are made of these."""

    collided: jax.Array       # bool: with a vehicle, the intruder or a building
    hit_vehicle: jax.Array    # bool: within R_c of another flying vehicle
    hit_intruder: jax.Array   # bool: within R_c of the intruder
    arrived: jax.Array        # bool: in its target disk (and not collided or out)
    d_target: jax.Array       # [m] distance to its target after the step


def _vehicle_controls(key, s: EnvState, actions, fly, present, params: EnvParams, vehicle_policy):
    """Item 4: the vehicles' actions at inner step state ``s``: the policy's feedback law or the held actions,
    then the safety filter of eq. 38. Returns the actions ``(N, 2)`` and ``s`` with ``complied``, ``tracked`` and
    ``used_filter`` updated."""
    if vehicle_policy is None:
        a_veh = actions[:params.vehicles.n, :params.vehicles.model.action_dim]
    else:
        a_veh = jnp.clip(vehicle_policy(key, s, params), -1.0, 1.0)
    avoiding = fly & present & (s.mode == AVOIDING)
    use_filter = avoiding & params.episode.safety_filter
    a_veh = jnp.where(use_filter[:, None], s.avoid_action, a_veh)
    complied = s.complied & ~(avoiding & (_max_abs(a_veh - s.avoid_action) > COMPLIANCE_TOL))
    # a vehicle on its plan may fly another control than kappa where its tracking value leaves room for one inner
    # step of it (the tube-keeping filter's free set, stp_env.sim.margins.tube_free_level): it still counts as
    # tracking, so that leaving the tube from there is a guarantee violation, not an assumption failure
    free = s.tracking_value <= params.tables.tracking_free_level
    deviates = _max_abs(a_veh - s.track_action) > COMPLIANCE_TOL
    tracked = s.tracked & ~(on_plan(s) & deviates & ~free)
    return a_veh, replace(s, complied=complied, tracked=tracked, used_filter=use_filter)


def _motion(s: EnvState, a_veh, control_i, fly, present, winds, head_dist, h, params: EnvParams) -> EnvState:
    """Item 5: every flying vehicle and the present intruder move over ``h`` under their controls and winds."""
    n = params.vehicles.n
    v_i, om_i = control_i
    model = params.vehicles.model
    control = model.action_to_control(a_veh, params.vehicles.bounds)
    x = jnp.where(fly[:, None], model.step(s.x, control, winds[:n], head_dist[:n], h), s.x)
    xi = jnp.where(present, dubins_step(s.intruder_x, v_i, om_i + head_dist[n], winds[n], h), s.intruder_x)
    return replace(s, x=x, intruder_x=xi, t=on_grid(s.t + h, params.episode.t_start, h))


def _max_abs(d):
    """``max(|d|)`` over each row of ``d`` (N, K), as elementwise maxima: the same value as ``jnp.max(..., axis=1)``
    (a maximum does not round), without the library reduce XLA:CPU makes of a short row (about 1.5 % of a batched
    step)."""
    a = jnp.abs(d)
    out = a[:, 0]
    for k in range(1, d.shape[1]):
        out = jnp.maximum(out, a[:, k])
    return out


def on_grid(t, origin, spacing):
    """``t`` rounded to the grid ``origin + k spacing``. Times are float32: adding ``dt = 0.1`` (itself rounded)
    step after step to a plan time of 1,000-2,000 s drifts by 2e-3 to 1e-2 s per 100 steps, so the intruder
    stayed one step longer than ``t_IAT`` (10.1 s) and the avoid tables were read at a shifted time. Rounding each
    new time to the grid leaves one rounding error (one float32 ulp, about 2.4e-4 s at 2,000-4,000 s) instead of a
    sum of them (``docs/numerics.md``)."""
    return origin + jnp.round((t - origin) / spacing) * spacing


def _closest_approach(closest: Closest, s: EnvState, params: EnvParams) -> Closest:
    """``closest`` updated with the distances at inner step state ``s``."""
    n = params.vehicles.n
    p = s.x[:, :2]
    diff = p[:, None, :] - p[None, :, :]
    # The two squares summed in the elementwise kernel: ``jnp.sum(diff ** 2, axis=-1)`` became a library reduce
    # (XLA:CPU's YNNPACK fusion) that took 12 % of a batched town step. The kernel fuses the multiply-add (one
    # rounding instead of two), so a squared distance can differ by an ulp from the reduce's (docs/numerics.md)
    sq = diff[..., 0] ** 2 + diff[..., 1] ** 2
    return Closest(pair_sq=jnp.minimum(closest.pair_sq, sq + jnp.eye(n) * 1e30),
                   intruder=jnp.minimum(closest.intruder, jnp.hypot(*(p - s.intruder_x[None, :2]).T)),
                   building=jnp.minimum(closest.building, building_distance(params, p)))


def _events(state: EnvState, sub: EnvState, closest: Closest, params: EnvParams):
    """Item 6: collisions, leaving the domain, arrivals and guarantee violations of the step from ``state`` (its
    start) to ``sub`` (its end, before the lifecycle). Returns the new state (lifecycle at ``t + dt`` done) and
    the :class:`Events`."""
    fly = flying(state)
    present = intruder_present(state)
    x, xi, t = sub.x, sub.intruder_x, on_grid(state.t + params.episode.dt, params.episode.t_start, params.episode.dt)
    p = x[:, :2]
    lo, hi = params.episode.domain_lo, params.episode.domain_hi
    out = fly & jnp.any((p < lo) | (p > hi), axis=1)
    hit_building = fly & (closest.building <= 0.0)
    pair_ok = fly[:, None] & fly[None, :]
    dist = jnp.where(pair_ok, jnp.sqrt(closest.pair_sq), jnp.inf)
    near = dist <= params.episode.collision_radius
    hit_vehicle = jnp.any(near, axis=1)
    # A vehicle flying the after-avoidance fallback (eq. 40 without replanning) has no guarantee: collisions it
    # takes part in are collisions, not guarantee violations (the paper's guarantee after t_IAT rests on Algorithm 4).
    fallback = fly & (state.mode == AFTER_AVOIDANCE)
    # A plan that is not intruder-aware (no k̄: no buffer regions, induced obstacles of R_c + 2 r_e only) promises
    # nothing about a vehicle that leaves its plan to avoid the intruder: its collisions with other vehicles and
    # buildings are collisions, not guarantee violations. Its avoidance of the intruder itself (V^A, a game of the
    # pair) and the tracking of vehicles on their plans are guaranteed by any plan.
    unplanned = fly & (state.mode != NOMINAL) & (params.intruder.kbar < 0)
    unguarded = fallback | unplanned
    guarded_pair = ~(unguarded[:, None] | unguarded[None, :])
    hit_guarded_vehicle = jnp.any(near & guarded_pair, axis=1)
    d_int = jnp.where(fly & present, closest.intruder, jnp.inf)
    hit_intruder = d_int <= params.episode.collision_radius
    collided = fly & (hit_vehicle | hit_intruder | hit_building)
    d_target = jnp.hypot(*(p - params.vehicles.targets).T)
    arrived = fly & ~collided & ~out & (d_target <= params.vehicles.target_radii)
    status = jnp.where(collided, COLLIDED, jnp.where(out, OUT_OF_BOUNDS, jnp.where(arrived, ARRIVED, state.status)))
    min_sep = jnp.minimum(state.min_separation, jnp.where(fly, jnp.minimum(jnp.min(dist, axis=1), d_int), jnp.inf))
    guarded_hit = hit_guarded_vehicle | hit_intruder | (hit_building & ~unguarded)
    # Fail closed: a state that is not finite (a plug-in wind or vehicle model that returned NaN or inf) is outside
    # every assumption (bounded disturbances, the model of the motion); its comparisons above are all false, so the
    # vehicle would otherwise look clean. Its assumptions fail, and so do every flying vehicle's while the intruder's
    # state is not finite.
    finite = jnp.all(jnp.isfinite(x), axis=1) & ~(present & ~jnp.all(jnp.isfinite(xi)))
    assumption_ok = sub.assumption_ok & (~fly | finite)
    violation = collided & guarded_hit & assumption_ok & sub.complied

    new_state = replace(
        sub, t=t, step_count=state.step_count + 1, x=x, status=status.astype(jnp.int32), assumption_ok=assumption_ok,
        min_separation=min_sep,
        arrival_time=jnp.where(arrived, t, state.arrival_time),
        collision_time=jnp.where(collided, t, state.collision_time),
        collided_with_intruder=state.collided_with_intruder | (collided & hit_intruder),
        intruder_x=xi, intruder_distance=d_int,
    )
    new_state = lifecycle(new_state, params)
    # a vehicle outside the proofs (EnvParams.vehicles.certified false) has assumption failures, not tracking violations
    tracking_violation = (new_state.tracked & params.vehicles.certified
                          & (new_state.max_tracking_error > params.tables.tracking_bound))
    new_state = replace(new_state, tracking_violation=tracking_violation,
                        guarantee_violation=state.guarantee_violation | violation | tracking_violation)
    return new_state, Events(collided=collided, hit_vehicle=hit_vehicle, hit_intruder=hit_intruder,
                             arrived=arrived, d_target=d_target)


def step(key, state: EnvState, actions, params: EnvParams, vehicle_policy=None):
    """Advance one step from ``t`` to ``t + dt``. ``actions``: ``(N + 1, 2)`` in ``[-1, 1]`` (vehicles, then the
    intruder; clipped; NaN is the adapters' job to reject). ``vehicle_policy``: ``None`` (the vehicles apply their
    actions, held over the step) or a jittable ``(key, state, params) -> (N, 2)`` feedback law, evaluated at every
    inner step in place of the vehicles' actions (the papers' controllers read ``state.track_action`` and
    ``state.avoid_action``, refreshed every inner step). Returns ``(state, rewards)``, rewards ``(N + 1,)``.

    The parts, in order: wind (:mod:`stp_env.sim.wind`), then per inner step :func:`_vehicle_controls`,
    :func:`_motion` and :func:`_closest_approach`; then :func:`_events` and :func:`_rewards`."""
    k_wind, k_policy = jax.random.split(key)
    n = params.vehicles.n
    fly = flying(state)
    present = intruder_present(state)
    m_sub = params.episode.control_substeps
    h = params.episode.dt / m_sub

    actions = jnp.clip(actions, -1.0, 1.0)
    control_i = action_to_control(actions[n, :2], params.intruder.bounds)
    winds_held, head_dist, wind_state = wind_lib.sample(k_wind, state, params)

    def move(carry, m):
        """Inner step ``m``: controls at the carried state, then motion over ``h``; closest approaches."""
        s, closest = carry
        a_veh, s = _vehicle_controls(jax.random.fold_in(k_policy, m), s, actions, fly, present, params,
                                     vehicle_policy)
        winds = wind_lib.inner(s, params, winds_held)
        s = _motion(s, a_veh, control_i, fly, present, winds, head_dist, h, params)
        return s, _closest_approach(closest, s, params)

    def inner(carry, m):
        s, closest = move(carry, m)
        # the controllers for the next inner step; after the last one the lifecycle at t + dt refreshes them
        nxt = jax.lax.cond(m < m_sub - 1, lambda s: avoid_start(observe_controllers(s, params), params),
                           lambda s: s, s)
        return (nxt, closest), None

    far = jnp.full((n,), jnp.inf, state.x.dtype)
    init = (state, Closest(pair_sq=jnp.full((n, n), jnp.inf, state.x.dtype), intruder=far, building=far))
    # Every inner step ends with the controllers refreshed for the next one; the step continues from the last inner
    # step's state before that refresh (the lifecycle at t + dt comes first). One scan over all M inner steps, not
    # M - 1 plus a last one written apart: the step's program holds the inner step once, which halves its compile;
    # the last inner step's refresh, which the lifecycle would overwrite, is skipped by a branch on the scan index,
    # so the carried state after the scan is that last inner step's state (one state in the carry, not two: each
    # carried copy is a buffer copy per inner step).
    (sub, closest), _ = jax.lax.scan(inner, init, jnp.arange(m_sub))
    new_state, ev = _events(state, replace(sub, wind=wind_state), closest, params)
    return new_state, rewards(state, new_state, ev, params)
