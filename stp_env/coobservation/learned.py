"""A learned attacker (Stable-Baselines3 PPO) whose reward is entering a forbidden zone without missing an
observation, trained on the batched JAX wrapper, and exported to a small ``.npz`` (numpy weights, no pickle).

* :func:`make_vec_env` (:class:`~stp_env.coobservation.attacker_vec_env.AttackerVecEnv`): a native SB3
  ``VecEnv`` of ``n`` attacker episodes in one JAX program per step.
  An episode starts at the compromise (a random vehicle at a random time on the simulator's grid in
  ``t_window``; the core is reset *at* that time with every vehicle on its plan, as the intruder's training env
  does) and ends at the end of the schedule or at the detection. The attacker decides every ``action_repeat``
  simulator steps. Observation: :func:`stp_env.coobservation.attackers.attacker_observation`.
* Action (``residual``, the default): a correction to the tracker's action, applied as
  ``clip(planned + RESIDUAL_SCALE * a, -1, 1)`` with ``planned`` recomputed every simulator step, so that the zero
  action flies the plan and training starts from an honest vehicle (residual policy learning); every action is
  still reachable. ``residual=False``: the action is the vehicle's command itself.
* Reward: ``+1`` at the first entry into a forbidden zone, ``-2`` at the detection (an entry that is detected nets
  ``-1``, so entering is only worth it undetected), plus a potential-based shaping ``gamma phi(s') - phi(s)`` with
  ``phi = -shaping * distance / 1 km`` to the best entry point before the entry and to the next observation point
  after it (it does not change which policies are optimal). With ``margin_reward = m > 0`` (an attacker that must
  *try*, e.g. against a schedule secured so that no undetected entry exists) an episode that entered a zone also
  earns, when it ends, ``m (1 + clip(margin, -MARGIN_SCALE, 3 s) / MARGIN_SCALE)``: the attempt's time margin
  (:func:`stp_env.coobservation.threat.attempt_margin`, the searched attacker's objective) turned into a reward
  that grows as the attack comes closer to passing unseen, so that the best attack is the one with the largest
  margin even where every attack is detected (``m > 1`` makes a detected entry worth more than no attempt).
* :func:`train` (PPO, modest budgets; optionally started from a scripted ``teacher`` by behaviour cloning,
  :func:`demonstrations` and :func:`stp_env.rl.imitation.imitate`, since the reward of an entry is rare under
  random exploration)
  writes ``attacker.npz`` with :func:`stp_env.policies.learned.export_mlp`;
  :func:`mlp_attacker` turns it into a jittable attacker for :func:`stp_env.coobservation.threat.rollout`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.coobservation import attackers, threat
from stp_env.files import write_text
from stp_env.policies import nominal_tracking
from stp_env.rl.imitation import imitate
from stp_env.rl.ppo import PPOConfig, make_model
from stp_env.sim import engine

ACTIVATIONS = {"tanh": jnp.tanh, "relu": lambda x: jnp.maximum(x, 0.0)}
RESIDUAL_SCALE = 2.0  # a residual action of +-1 moves the command across its whole range [-1, 1]


def command(planned, action, residual: bool):
    """The compromised vehicle's command in ``[-1, 1]`` from the policy's ``action``: ``planned`` (the tracker's)
    plus the scaled correction when ``residual``, else the action itself."""
    if residual:
        return jnp.clip(planned + RESIDUAL_SCALE * action, -1.0, 1.0)
    return action


def _phi(ts, params, tp, shaping):
    c = jnp.maximum(ts.compromised, 0)
    x = ts.sim.x[c, :2]
    _, aim = attackers.next_observation(ts, params, tp, c, ts.sim.t)
    entry, _ = attackers.best_entry(x, aim, tp)
    target = jnp.where(ts.entered[c], aim, entry)
    return -shaping * jnp.linalg.norm(target - x) / attackers.DISTANCE_SCALE


def reset_one(key, params, tp, t_window):
    """A new attacker episode at the compromise time (see the module docstring)."""
    k_draw, k_reset = jax.random.split(key)
    c, t_c = threat.draw_attack(k_draw, params, t_window[0], t_window[1])
    at = params.replace(episode=dict(t_start=t_c))
    ts = threat.reset(k_reset, at, tp, c, t_c)
    return ts, attackers.attacker_observation(ts, params, tp)


MARGIN_SCALE = 60.0
"""Margins [s] at or below ``-MARGIN_SCALE`` (and lost attempts, ``-inf``) earn no margin reward."""


def margin_bonus(ts, params, tp, margin_reward):
    """``margin_reward (1 + clip(margin, -MARGIN_SCALE, 3) / MARGIN_SCALE)`` for an episode that entered a zone,
    0 otherwise (the module docstring)."""
    from stp_env.sim.bounds import V_MAX, WIND

    c = jnp.maximum(ts.compromised, 0)
    speed = params.vehicles.bounds[V_MAX] + params.vehicles.bounds[WIND]
    margin = threat.attempt_margin(ts, tp, speed, params.episode.dt)
    bonus = margin_reward * (1.0 + jnp.clip(margin, -MARGIN_SCALE, 3.0) / MARGIN_SCALE)
    return jnp.where(ts.entered[c], bonus, 0.0)


def step_one(key, ts, action, params, tp, action_repeat: int, gamma: float, shaping: float, residual: bool = True,
             margin_reward=0.0):
    """``action_repeat`` simulator steps with the attacker's ``action`` (:func:`command`); returns ``(state, obs,
    reward, done)``."""
    phi0 = _phi(ts, params, tp, shaping)
    c = jnp.maximum(ts.compromised, 0)

    def sub(carry, k):
        s, r, _ = carry
        k_v, k_s = jax.random.split(k)
        a_v = nominal_tracking(k_v, s.sim, params)
        new = threat.step(k_s, s, a_v, command(a_v[c], action, residual), params, tp)
        entered = new.entered[c] & ~s.entered[c]
        detected = jnp.isfinite(new.detect_time) & ~jnp.isfinite(s.detect_time)
        rew = 1.0 * entered - 2.0 * detected
        done = threat.episode_done(new, params) | jnp.isfinite(new.detect_time)
        return (new, r + rew, done), None

    # stop: once done (the episode ended or the attacker was detected), the steps change nothing and earn nothing
    (ts, r, done), _ = engine.play(sub, (ts, jnp.zeros(()), jnp.asarray(False)), jax.random.split(key, action_repeat),
                                   stop=lambda carry: carry[2])
    r = r + jnp.where(done, margin_bonus(ts, params, tp, margin_reward), gamma * _phi(ts, params, tp, shaping)) - phi0
    return ts, attackers.attacker_observation(ts, params, tp), r, done


@functools.partial(jax.jit, static_argnames=("action_repeat", "residual"))
def batch_step(keys, states, actions, params, tp, t_window, action_repeat: int, gamma: float, shaping: float,
               residual: bool = True, margin_reward=0.0):
    """One decision of ``n`` envs with auto-reset. Returns ``(keys, states, obs, rewards, dones, terminal_obs,
    stats)``; ``stats``: ``entered``, ``detected`` of the finished episode."""
    def one(key, ts, a, shared):
        params, tp = shared
        key, k_step, k_reset = jax.random.split(key, 3)
        ts, obs, r, done = step_one(k_step, ts, a, params, tp, action_repeat, gamma, shaping, residual,
                                    margin_reward)
        c = jnp.maximum(ts.compromised, 0)
        stats = jnp.stack([ts.entered[c], jnp.isfinite(ts.detect_time)]).astype(jnp.float32)
        new_ts, new_obs = reset_one(k_reset, params, tp, t_window)
        pick = functools.partial(jnp.where, done)
        return key, jax.tree.map(pick, new_ts, ts), pick(new_obs, obs), r, done, obs, stats

    return engine.vmap_across_devices(one, shared=(params, tp))(keys, states, actions)


@jax.jit
def batch_reset(keys, params, tp, t_window):
    def one(key, shared):
        params, tp = shared
        key, k = jax.random.split(key)
        ts, obs = reset_one(k, params, tp, t_window)
        return key, ts, obs

    return engine.vmap_across_devices(one, shared=(params, tp))(keys)


def make_vec_env(n_envs: int, params, tp, t_window, *, action_repeat: int = 5, gamma: float = 0.99,
                 shaping: float = 1.0, seed: int = 0, residual: bool = True, margin_reward: float = 0.0):
    """A Stable-Baselines3 ``VecEnv`` (imported lazily: needs the ``rl`` extra). ``seed``: an integer in
    ``[0, 2**63 - 1]`` (:func:`stp_env.seeds.prng_key`: every seed its own keys)."""
    from stp_env.coobservation.attacker_vec_env import AttackerVecEnv
    from stp_env.seeds import prng_key

    base = jax.random.key_data(prng_key(seed))  # raw key data: the keys are selected with jnp.where
    return AttackerVecEnv(n_envs, params, tp, t_window, base, (batch_reset, batch_step), action_repeat=action_repeat,
                          gamma=gamma, shaping=shaping, residual=residual, margin_reward=margin_reward)


@dataclasses.dataclass(frozen=True, kw_only=True)
class AttackerTrainConfig(PPOConfig):
    """A modest PPO run (defaults: about 0.5 M decisions): the algorithm's settings
    (:class:`stp_env.rl.ppo.PPOConfig`, with the attacker's defaults below) and the attacker's env and imitation."""

    total_timesteps: int = 500_000
    n_envs: int = 32
    batch_size: int = 1024
    n_epochs: int = 5
    log_std_init: float = -1.0  # exploration noise std e^-1 = 0.37 (of the residual: about 9 m/s and 1.5 rad/s)
    action_repeat: int = 5
    shaping: float = 1.0
    margin_reward: float = 0.0  # > 0: reward an entry by its time margin (an attacker that must try; module doc)
    residual: bool = True
    teacher: str | None = None  # a scripted attacker (attackers.ATTACKERS) to imitate before PPO (residual only)
    demo_decisions: int = 3000  # decisions of every env recorded from the teacher
    imitation_epochs: int = 20


def outcome_rates(infos, dones) -> tuple[int, int, int, int]:
    """``(finished, entered, detected, succeeded)`` counts of the episodes that ended in one vector step of
    :class:`~stp_env.coobservation.attacker_vec_env.AttackerVecEnv` (its ``infos`` carry ``entered`` and
    ``detected`` at an episode's end; success is an entry that was not detected)."""
    n = e = d = s = 0
    for info, done in zip(infos, dones):
        if done and "entered" in info:
            n += 1
            e += info["entered"]
            d += info["detected"]
            s += info["entered"] and not info["detected"]
    return n, e, d, s


def _outcome_logger():
    """An SB3 callback that logs, per PPO iteration, the share of the finished episodes that entered a zone
    (``rollout/entered_rate``), were detected (``rollout/detected_rate``) and got in undetected
    (``rollout/success_rate``): the reward mixes these with the shaping, so it alone does not say which."""
    from stable_baselines3.common.callbacks import BaseCallback

    class OutcomeLogger(BaseCallback):
        def _on_rollout_start(self) -> None:
            self.counts = np.zeros(4, int)

        def _on_step(self) -> bool:
            self.counts += outcome_rates(self.locals["infos"], self.locals["dones"])
            return True

        def _on_rollout_end(self) -> None:
            n = self.counts[0]
            if n:
                for name, k in zip(("entered", "detected", "success"), self.counts[1:]):
                    self.logger.record(f"rollout/{name}_rate", k / n)

    return OutcomeLogger()


@functools.partial(jax.jit, static_argnames=("teacher",))
def teacher_residuals(keys, states, params, tp, teacher):
    """The residual actions (:func:`command`) that reproduce a scripted ``teacher``'s command at each env's state
    ``(n, 2)``: ``(command - planned) / RESIDUAL_SCALE``, and 0 where the teacher flies the plan."""
    def one(key, ts):
        c = jnp.maximum(ts.compromised, 0)
        k_v, k_t = jax.random.split(key)
        planned = nominal_tracking(k_v, ts.sim, params)[c]
        cmd = teacher(k_t, ts, params, tp, planned)
        return jnp.where(jnp.any(jnp.isnan(cmd)), 0.0, jnp.clip((cmd - planned) / RESIDUAL_SCALE, -1.0, 1.0))

    return jax.vmap(one)(keys, states)


def demonstrations(venv, params, tp, teacher, n_decisions: int, progress: bool = True):
    """``(observations, residual actions)`` of ``teacher`` flying every env of ``venv`` (an
    :func:`make_vec_env` env, residual) for ``n_decisions`` decisions, episodes restarting as in training."""
    from tqdm.auto import tqdm

    obs = venv.reset()
    xs, ys = [], []
    for _ in tqdm(range(n_decisions), desc="teacher demonstrations", unit="decision", disable=not progress):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(venv._keys)  # not the keys the step will use
        act = np.asarray(teacher_residuals(keys, venv._states, params, tp, teacher))
        xs.append(obs)
        ys.append(act)
        venv.step_async(act)
        obs, _rew, _done, _infos = venv.step_wait()
    return np.concatenate(xs).astype(np.float32), np.concatenate(ys).astype(np.float32)


def train(params, tp, t_window, config: AttackerTrainConfig, out_dir, progress: bool = True) -> Path:
    """Train PPO on :func:`make_vec_env`'s env and write ``out_dir/attacker.npz`` (and ``config.json``, the
    training log ``progress.csv`` with the outcome rates of :func:`_outcome_logger`). Returns the path of the
    ``.npz``."""
    import torch
    from stable_baselines3.common.logger import configure

    from stp_env.policies.learned import export_mlp

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.torch_threads)
    venv = make_vec_env(config.n_envs, params, tp, t_window, action_repeat=config.action_repeat, gamma=config.gamma,
                        shaping=config.shaping, seed=config.seed, residual=config.residual,
                        margin_reward=config.margin_reward)
    model = make_model(config, venv)
    model.set_logger(configure(str(out), ["csv"]))
    imitation = None
    if config.teacher is not None:
        if not config.residual:
            raise ValueError("teacher: imitation needs the residual action (residual=True).")
        if config.teacher not in attackers.ATTACKERS:
            raise ValueError(f"teacher {config.teacher!r} is not a scripted attacker; allowed: "
                             f"{', '.join(attackers.ATTACKERS)}.")
        obs, act = demonstrations(venv, params, tp, attackers.ATTACKERS[config.teacher], config.demo_decisions,
                                  progress)
        imitation = {"teacher": config.teacher, "samples": len(obs),
                     "loss": imitate(model.policy, obs, act, config.imitation_epochs, seed=config.seed)}
    model.learn(config.total_timesteps, callback=_outcome_logger(), progress_bar=progress)
    meta = {"objective": "enter a forbidden zone without missing an observation",
            "config": dataclasses.asdict(config), "t_window": [float(t) for t in t_window],
            "residual": config.residual, "residual_scale": RESIDUAL_SCALE, "imitation": imitation,
            "devices": engine.shares(config.n_envs)}
    write_text(json.dumps(meta, indent=1), out / "config.json")
    return export_mlp(model, out / "attacker.npz", metadata=meta)


def mlp_attacker(path, name: str = "learned"):
    """The exported MLP as a jittable attacker ``(key, state, params, threat, planned) -> (2,)`` (the deterministic
    action, through :func:`command`: a residual policy corrects ``planned``, the tracker's action; files without
    the ``residual`` entry are direct policies)."""
    from stp_env.policies.learned import load_mlp

    mlp = load_mlp(path)
    if mlp.obs_size != attackers.OBS_SIZE:
        raise ValueError(f"{path}: the MLP takes {mlp.obs_size} inputs; the attacker observation has "
                         f"{attackers.OBS_SIZE}.")
    residual, scale = mlp.metadata.get("residual", False), mlp.metadata.get("residual_scale")
    if not isinstance(residual, bool) or (residual and scale != RESIDUAL_SCALE):
        raise ValueError(f"{path}: metadata 'residual' must be true or false, and a residual policy's "
                         f"'residual_scale' {RESIDUAL_SCALE}; got {residual!r}, {scale!r}.")
    act = ACTIVATIONS[mlp.activation]
    hidden = [(jnp.asarray(w), jnp.asarray(b)) for w, b in mlp.hidden]
    w_out, b_out = jnp.asarray(mlp.action[0]), jnp.asarray(mlp.action[1])

    def policy(key, state, params, tp, planned):
        del key
        h = attackers.attacker_observation(state, params, tp)
        for w, b in hidden:
            h = act(w @ h + b)
        return command(planned, jnp.clip(w_out @ h + b_out, -1.0, 1.0), residual)

    policy.__name__ = name
    return policy
