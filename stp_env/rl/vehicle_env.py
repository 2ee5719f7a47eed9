"""The after-avoidance vehicle's view for Stable-Baselines3: a single-agent VecEnv and a batched evaluation for learning
a vehicle policy under the HJ filters. The episode (reset, step, reward, observation, ends) is
:mod:`stp_env.rl.ego`'s; :func:`evaluate_ego` flies the same episodes (same keys) with the ego on ``u*``, on a
learned MLP, or on the fallback at the full speed of ``U`` (a hand-made comparator: what the learned policy is
measured against besides ``u*``), in one compiled program per policy.
"""

from __future__ import annotations

import functools

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from stp_env.baselines.vehicles import switching
from stp_env.rl import functional as F
from stp_env.rl.ego import (
    STAT_NAMES,
    check_params,
    ego_done,
    ego_law,
    ego_obs,
    ego_params,
    ego_reset,
    ego_stats,
    ego_step,
    fallback_vmax,
    held,
)
from stp_env.rl.jax_vec_env import JaxVecEnv
from stp_env.sim import core, engine
from stp_env.sim.bounds import V_MAX
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import FLYING, EnvParams

EGO_POLICIES = ("u*", "learned", "fallback-vmax")
"""What :func:`evaluate_ego` flies the ego with: ``u*`` (the fallback at the planning speed, at every inner step),
a learned MLP (its action held over the step, as in training), or the fallback at ``U``'s top speed."""


# ------------------------------------------------------------------------------------------------ batched env
@functools.partial(sim_jit, static_argnames=("intruder",))
def batch_reset(keys, params: EnvParams, intruder):
    def one(key, params):
        key, k_reset = jax.random.split(key)
        s, ego = ego_reset(k_reset, params, intruder)
        return key, s, ego, ego_obs(s, ego, params)

    return engine.vmap_across_devices(one, shared=params)(keys)


@functools.partial(sim_jit, static_argnames=("intruder",))
def batch_step(keys, states, egos, actions, params: EnvParams, intruder, energy, late_limit):
    """One step of ``n`` ego envs with auto-reset: ``(keys, states, egos, obs, rewards, terminated, truncated,
    terminal_obs, stats)``."""
    def one(key, s, ego, a, params):
        key, k = jax.random.split(key)
        s, r = ego_step(k, s, ego, a, params, energy)
        term, trunc = ego_done(s, ego, params, late_limit)
        return key, s, r, term, trunc, ego_obs(s, ego, params), ego_stats(s, ego, params)

    step = engine.vmap_across_devices(one, shared=params)
    keys, states, rewards, term, trunc, obs, stats = step(keys, states, egos, actions)
    done = term | trunc

    def reset_done(operand):
        keys, states, egos, obs = operand
        new_keys, new_states, new_egos, new_obs = batch_reset.__wrapped__(keys, params, intruder)

        def pick(a, b):
            return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

        return (pick(new_keys, keys), jax.tree.map(pick, new_states, states), pick(new_egos, egos),
                pick(new_obs, obs))

    keys, next_states, next_egos, next_obs = jax.lax.cond(jnp.any(done), reset_done, lambda o: o,
                                                          (keys, states, egos, obs))
    return keys, next_states, next_egos, next_obs, rewards, term, trunc, obs, stats


class EgoVehicleVecEnv(JaxVecEnv):
    """``n_envs`` ego-vehicle envs in one batched JAX state (module docstring); SB3's ``VecEnv`` conventions as
    :class:`stp_env.rl.IntruderVecEnv` (seeding, auto-reset with ``terminal_observation``).

    Args:
        n_envs: batch size.
        params: the environment (:func:`stp_env.assembly.params_for`; with ``V^B`` if the intruder reads it).
        intruder: a jittable intruder policy (``stp_env.evaluation.resolve_intruder(name)``).
        energy: weight of the energy term per second at full speed.
        late_limit: seconds after the ego's STA at which its episode is truncated.
    """

    def __init__(self, n_envs: int, params: EnvParams, intruder, *, energy: float = 0.002, late_limit: float = 60.0):
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise ValueError(f"n_envs must be an integer >= 1; got {n_envs!r}.")
        for name, value in (("energy", energy), ("late_limit", late_limit)):
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite number >= 0; got {value!r}.")
        self.params, self.intruder = check_params(params), intruder
        self.energy, self.late_limit = float(energy), float(late_limit)
        size = core.vehicle_observation_size(params)
        super().__init__(n_envs, gym.spaces.Box(-2.0, 2.0, (size,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self._keys = self._egos = None

    def reset(self) -> np.ndarray:
        keys = jnp.asarray(self._keys_for_reset())
        self._keys, self._states, self._egos, obs = batch_reset(keys, self._on_devices("params"), self.intruder)
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return np.asarray(obs)

    def step_wait(self):
        if self._states is None:
            raise RuntimeError("Call reset() before step().")
        if self._actions is None:
            raise RuntimeError("Call step_async() before step_wait().")
        out = batch_step(self._keys, self._states, self._egos, jnp.asarray(self._actions),
                         self._on_devices("params"), self.intruder, self.energy, self.late_limit)
        self._keys, self._states, self._egos = out[0], out[1], out[2]
        self._actions = None
        obs, rewards, term, trunc, terminal_obs, stats = jax.device_get(out[3:])
        dones = term | trunc
        columns = [np.asarray(stats[name]).tolist() for name in STAT_NAMES]
        infos = [dict(zip(STAT_NAMES, values)) for values in zip(*columns)]
        for i in np.flatnonzero(dones).tolist():
            infos[i]["terminal_observation"] = terminal_obs[i]
            infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self._keys = self._egos = None
        super().close()


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
    :class:`stp_env.baselines.learned.MLPIntruder` for ``"learned"`` (tanh layers)."""
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
    A shipped vehicle policy records them (``scripts/train_vehicle_policy.py ship``); the tests replay them."""
    params, intruder = ego_params(check.get("scenario", "crossing"), check.get("kbar", 2), check["intruder"])
    r = evaluate_ego(params, intruder, "learned", mlp=mlp, episodes=check["episodes"], seed=check["seed"],
                     batch=check["episodes"])
    return {"on_time": [bool(v) for v in r["on_time"]], "arrived": [bool(v) for v in r["arrived"]],
            "delay_s": [round(float(v), 2) if np.isfinite(v) else None for v in r["delay"]]}
