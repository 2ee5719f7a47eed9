"""The after-avoidance vehicle's episode as pure JAX functions: what the SB3 ``VecEnv`` of
:mod:`stp_env.rl.vehicle_env` and the gymnax view (:class:`stp_env.rl.gymnax_env.VehicleGymnaxEnv`) both step.

Where a vehicle policy may differ from ``u*`` (eq. 38) without breaking a guarantee: on its plan only inside the
tracking tube's free set (:func:`stp_env.policies.tube_keeping`; on the crossing at 6 m/s wind it is empty: the
tracking value is flat below ``V(0)``, so the tube leaves no room and the filter is ``kappa``), never while forced
(``u^A``), and after the intruder has left, where the paper replans the forced vehicles (Algorithm 4) and ``u*``'s
stand-in flies to the target at the planning speed (:func:`stp_env.policies.fallback_control`). So an episode of
this env is one forced vehicle's flight from the intruder's departure to its target:

* **Reset**: an intruder episode is drawn as :func:`stp_env.rl.functional.reset_one` draws one (reset at the
  intruder's appearance), every vehicle flies ``u*`` and the intruder its policy until the intruder leaves; the
  *ego* is the vehicle forced first. A draw that forced no vehicle is redrawn (up to :data:`MAX_DRAWS` times; then
  the episode is *empty*: it ends at its first step with reward 0 and ``info["empty"]``).
* **Step**: the ego flies the agent's action, held over the step, through :func:`stp_env.policies.hj_filter`
  (after the avoidance that is the action itself); the other vehicles fly ``u*``. The episode ends when the ego is
  done (arrived, collided, out of the domain: terminated), or at ``STA + late_limit`` or the episode's end
  (truncated).
* **Reward**: the core's reward of the ego (progress toward its target, the arrival bonus, on time or late, the
  collision penalty: :class:`stp_env.sim.RewardConfig`) minus ``energy`` times ``(v / v_max)^2 dt`` of the
  commanded speed (the project's choice of energy proxy: the papers give none).
* **Observation**: the ego's row of :func:`stp_env.sim.observe` (the vehicle observation every vehicle has), so a
  policy trained here runs for every vehicle of a fleet (``learned:NAME`` vehicle policies).

:func:`evaluate_ego` flies the same episodes (same keys) with the ego on ``u*``, on a learned MLP, or on the fallback
at the full speed of ``U`` (a hand-made comparator: what the learned policy is measured against besides ``u*``), in
one compiled program per policy. The SB3 ``VecEnv`` is :mod:`stp_env.rl.vehicle_env`'s.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.policies.vehicles import fallback_control, hj_filter, switching
from stp_env.rl import functional as F
from stp_env.sim import core, engine, observations
from stp_env.sim.bounds import V_MAX
from stp_env.sim.jit import sim_jit
from stp_env.sim.physics import action_to_control
from stp_env.sim.types import AFTER_AVOIDANCE, ARRIVED, COLLIDED, FLYING, PRESENT, EnvParams

MAX_DRAWS = 8
"""Intruder episodes drawn per reset until one forces a vehicle."""
MAX_WINDOW_STEPS = 10_000
"""Upper bound on the steps flown while the intruder is present (``t_IAT / dt`` is far below it)."""
EGO_POLICIES = ("u*", "learned", "fallback-vmax")
"""What :func:`evaluate_ego` flies the ego with: ``u*`` (the fallback at the planning speed, at every inner step),
a learned MLP (its action held over the step, as in training), or the fallback at ``U``'s top speed."""


def check_params(params: EnvParams) -> EnvParams:
    """``params`` if its episode reaches every vehicle's STA (an ego flies to its target), else ``ValueError``."""
    if float(params.episode.t_end) < float(jnp.max(params.vehicles.sta)):
        raise ValueError(f"the episode ends at {float(params.episode.t_end):.1f} s, before the last STA "
                         f"({float(jnp.max(params.vehicles.sta)):.1f} s): build the params with "
                         "EnvConfig(episode='full') so that a forced vehicle can fly to its target.")
    return params


def _intruder_actions(params: EnvParams, a_intruder):
    return jnp.concatenate([jnp.zeros((params.vehicles.n, 2), a_intruder.dtype), a_intruder[None, :]], axis=0)


def _draw(key, params: EnvParams, intruder):
    """One intruder episode flown on ``u*`` until the intruder leaves: ``(state, ego)`` (``ego`` -1 if none was
    forced)."""
    k_reset, k_run = jax.random.split(key)
    state = F.reset_one(k_reset, params, "intruder")

    def cond(carry):
        s, _, i = carry
        return (s.intruder_status == PRESENT) & (i < MAX_WINDOW_STEPS)

    def body(carry):
        s, k, i = carry
        k, k_i, k_s = jax.random.split(k, 3)
        s, _ = core.step(k_s, s, _intruder_actions(params, intruder(k_i, s, params)), params,
                         vehicle_policy=switching)
        return s, k, i + 1

    state, _, _ = jax.lax.while_loop(cond, body, (state, k_run, jnp.asarray(0, jnp.int32)))
    candidate = (state.status == FLYING) & (state.mode == AFTER_AVOIDANCE)
    first = jnp.argmin(jnp.where(candidate, state.avoid_start, jnp.inf))
    return state, jnp.where(jnp.any(candidate), first, -1).astype(jnp.int32)


def ego_reset(key, params: EnvParams, intruder):
    """``(state, ego)`` after up to :data:`MAX_DRAWS` draws (module docstring)."""
    def cond(carry):
        _, ego, _, tries = carry
        return (ego < 0) & (tries < MAX_DRAWS)

    def body(carry):
        _, _, k, tries = carry
        k, k_draw = jax.random.split(k)
        s, ego = _draw(k_draw, params, intruder)
        return s, ego, k, tries + 1

    k0, k = jax.random.split(key)
    s, ego = _draw(k0, params, intruder)
    s, ego, _, _ = jax.lax.while_loop(cond, body, (s, ego, k, jnp.asarray(1, jnp.int32)))
    return s, ego


def ego_law(ego, law):
    """Every vehicle on ``u*`` except ``ego``, which flies ``ego_law`` through :func:`hj_filter`."""
    filtered = hj_filter(law)

    def law(key, s, params):
        base = switching(key, s, params)
        mine = filtered(key, s, params)
        return base.at[jnp.maximum(ego, 0)].set(jnp.where(ego >= 0, mine[jnp.maximum(ego, 0)],
                                                          base[jnp.maximum(ego, 0)]))

    return law


def held(action, n):
    return lambda key, s, params: jnp.broadcast_to(action, (n, 2))


def fallback_vmax(key, state, params):
    """The fallback of :func:`stp_env.policies.fallback_control` at ``U``'s top speed (not the planning speed)."""
    del key
    return fallback_control(state, params, speed=params.vehicles.bounds[V_MAX])


def ego_done(state, ego, params: EnvParams, late_limit):
    """``(terminated, truncated)`` of the ego's episode."""
    e = jnp.maximum(ego, 0)
    terminated = (ego < 0) | (state.status[e] != FLYING)
    deadline = jnp.minimum(params.vehicles.sta[e] + late_limit, params.episode.t_end)
    truncated = (state.t >= deadline - 1e-6 * params.episode.dt) & ~terminated
    return terminated, truncated


def ego_stats(state, ego, params: EnvParams):
    """The ego's outcome so far and the fleet's collisions and guarantee violations."""
    e = jnp.maximum(ego, 0)
    has = ego >= 0
    return {
        "empty": ~has,
        "arrived": has & (state.status[e] == ARRIVED),
        "on_time": has & (state.status[e] == ARRIVED) & (state.arrival_time[e] <= params.vehicles.sta[e] + 1e-6),
        "delay": jnp.where(has, state.arrival_time[e] - params.vehicles.sta[e], jnp.nan),
        "ego_collided": has & (state.status[e] == COLLIDED),
        "ego_min_separation": jnp.where(has, state.min_separation[e], jnp.inf),
        "collisions": jnp.sum(state.status == COLLIDED).astype(jnp.int32),
        "guarantee_violations": jnp.sum(state.guarantee_violation).astype(jnp.int32),
        "time": state.t,
    }


def ego_step(key, state, ego, action, params: EnvParams, energy):
    """One step with the ego's ``action`` held (module docstring). Returns ``(state, reward)``."""
    n = params.vehicles.n
    action = jnp.clip(jnp.asarray(action, state.x.dtype), -1.0, 1.0)
    new, rewards = core.step(key, state, jnp.zeros((n + 1, 2), state.x.dtype), params,
                             vehicle_policy=ego_law(ego, held(action, n)))
    e = jnp.maximum(ego, 0)
    v, _ = action_to_control(action, params.vehicles.bounds)
    cost = energy * (v / params.vehicles.bounds[V_MAX]) ** 2 * params.episode.dt
    reward = jnp.where((ego >= 0) & (state.status[e] == FLYING), rewards[e] - cost, 0.0)
    return new, reward


def ego_obs(state, ego, params: EnvParams):
    return observations.observe(state, params)[0][jnp.maximum(ego, 0)].astype(jnp.float32)


STAT_NAMES = ("empty", "arrived", "on_time", "delay", "ego_collided", "ego_min_separation", "collisions",
              "guarantee_violations")


def ego_params(scenario: str = "crossing", kbar: int = 2, intruder: str = "learned:crossing-kbar2", *,
               progress: bool = False):
    """``(params, intruder policy)`` of the ego env: ``scenario`` planned for ``kbar``, every intruder appearing on a
    vehicle's avoid boundary, the episode to the vehicles' targets (``EnvConfig(episode="full")``), ``V^B`` loaded
    when the intruder reads it."""
    from stp_env import assembly, requirements, sim
    from stp_env.policies.intruders import resolve_intruder
    from stp_env.scenarios import make

    spec = make(scenario, kbar=kbar)
    params = assembly.params_for(spec, sim.EnvConfig(spawn_mode="boundary", episode="full"), progress=progress)
    params = requirements.with_required_tables(params, spec, intruder=intruder, kbar=kbar, progress=progress)
    return params, resolve_intruder(intruder)


# ------------------------------------------------------------------------------------------------ evaluation
@functools.partial(sim_jit, static_argnames=("intruder", "kind", "max_steps"))
def _evaluate(keys, params: EnvParams, intruder, kind: str, weights, energy, late_limit, max_steps: int):
    def one(key):
        k_reset, k_run = jax.random.split(key)
        s, ego = ego_reset(k_reset, params, intruder)
        n = params.vehicles.n

        def law_for(s):
            if kind == "u*":
                return switching
            if kind == "fallback-vmax":
                return ego_law(ego, fallback_vmax)
            h = ego_obs(s, ego, params)
            for w, b in weights[:-1]:
                h = jnp.tanh(h @ w.T + b)
            a = jnp.clip(h @ weights[-1][0].T + weights[-1][1], -1.0, 1.0)
            return ego_law(ego, held(a, n))

        def cond(carry):
            s, _, i, _ = carry
            term, trunc = ego_done(s, ego, params, late_limit)
            return ~(term | trunc) & (i < max_steps)

        def body(carry):
            s, k, i, spent = carry
            k, k_s = jax.random.split(k)
            law = law_for(s)
            e = jnp.maximum(ego, 0)
            s2, _ = core.step(k_s, s, jnp.zeros((n + 1, 2), s.x.dtype), params, vehicle_policy=law)
            # energy of the ego's applied speed over the step (its distance flown, to first order)
            v = jnp.hypot(*(s2.x[e, :2] - s.x[e, :2])) / params.episode.dt
            spent = spent + jnp.where(s.status[e] == FLYING, (v / params.vehicles.bounds[V_MAX]) ** 2, 0.0)
            return s2, k, i + 1, spent

        s, _, _, spent = jax.lax.while_loop(cond, body, (s, k_run, jnp.asarray(0, jnp.int32),
                                                         jnp.asarray(0.0, jnp.float32)))
        stats = ego_stats(s, ego, params)
        stats["energy"] = spent * params.episode.dt
        return stats

    return engine.vmap_across_devices(one)(keys)


def evaluate_ego(params: EnvParams, intruder, kind: str = "u*", *, mlp=None, episodes: int = 256, seed: int = 0,
                 batch: int = 64, energy: float = 0.002, late_limit: float = 60.0, max_steps: int = 20_000):
    """The ego's outcomes over ``episodes`` held-out episodes (keys ``seed, seed + 1, ...``, the same for every
    ``kind``): a dict of arrays (``STAT_NAMES`` and ``energy``: the integral of ``(v / v_max)^2`` over the ego's
    flight [s], its speed from its motion). ``kind``: one of :data:`EGO_POLICIES`; ``mlp``: the learned policy's
    :class:`stp_env.policies.learned.MLPIntruder` for ``"learned"`` (tanh layers)."""
    if kind not in EGO_POLICIES:
        raise ValueError(f"kind {kind!r} is not known; allowed: {', '.join(EGO_POLICIES)}.")
    check_params(params)
    if (kind == "learned") != (mlp is not None):
        raise ValueError("pass mlp exactly when kind is 'learned'.")
    if mlp is not None and mlp.activation != "tanh":
        raise ValueError("evaluate_ego flies tanh MLPs (SB3's default).")
    weights = (tuple((jnp.asarray(w), jnp.asarray(b)) for w, b in (*mlp.hidden, mlp.action))
               if mlp is not None else ((jnp.zeros((2, 1)), jnp.zeros(2)),))
    out = []
    for start in range(0, episodes, batch):
        count = min(batch, episodes - start)
        keys = jnp.stack([F.key_for_seed(seed + start + i) for i in range(count)])
        out.append(jax.device_get(_evaluate(keys, params, intruder, kind, weights, energy, late_limit, max_steps)))
    return {k: np.concatenate([np.asarray(o[k]) for o in out]) for k in out[0]}


def replay_check(mlp, check: dict) -> dict:
    """The ego's outcomes with the learned ``mlp`` on ``check``'s episodes (``scenario``, ``kbar``, ``intruder``,
    ``episodes``, ``seed``): on time and arrived per episode, and the delays [s] (``None`` where it did not arrive).
    A shipped vehicle policy records them (``examples/train_vehicle_policy.py ship``); the tests replay them."""
    params, intruder = ego_params(check.get("scenario", "crossing"), check.get("kbar", 2), check["intruder"])
    r = evaluate_ego(params, intruder, "learned", mlp=mlp, episodes=check["episodes"], seed=check["seed"],
                     batch=check["episodes"])
    return {"on_time": [bool(v) for v in r["on_time"]], "arrived": [bool(v) for v in r["arrived"]],
            "delay_s": [round(float(v), 2) if np.isfinite(v) else None for v in r["delay"]]}
