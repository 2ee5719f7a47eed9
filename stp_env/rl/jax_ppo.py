"""PPO written in JAX: rollouts and updates of many iterations in one compiled program, on any gymnax environment.

Why our own: the JAX PPO libraries were tried first on the intruder's gymnax view (``docs/training.md``, "Training
in JAX"): rejax 0.1.3 expects gymnax's 0.0.x step (``obs, state, reward, done, info``) and does not run on a gymnax
1.x environment, which returns ``terminated`` and ``truncated`` apart; JaxMARL's IPPO/MAPPO are scripts (hydra
configurations, wandb), not a library to call. So this module is a short PPO on optax (DeepMind's gradient library;
Adam and gradient clipping), written to match Stable-Baselines3's PPO so that the two trainers are the same
algorithm and can be compared step for step:

* a Gaussian policy with a state-independent ``log_std``; actor and critic are separate MLPs of ``net_arch`` tanh
  layers, initialised orthogonally (gains ``sqrt(2)``, ``0.01`` for the action layer, ``1`` for the value layer);
* the sampled action is stored, its clip to ``[-1, 1]`` is what the environment gets;
* GAE(``gamma``, ``gae_lambda``); a truncated episode's last reward gets ``gamma V(final observation)`` (as SB3
  does with ``TimeLimit.truncated``);
* ``n_epochs`` passes over the rollout in shuffled minibatches of ``batch_size``, advantages normalised per
  minibatch, the clipped surrogate (``clip_range``), the value loss ``0.5 (R - V)^2``, the entropy bonus
  ``ent_coef``, global gradient norm clipped at 0.5, Adam (``eps = 1e-5``) at ``learning_rate``.

The actor's layers are stored as the exported files store them (``W`` is ``(out, in)``,
:mod:`stp_env.policies.learned`), and :func:`actor_mean` is the same arithmetic as
:func:`stp_env.policies.learned.mlp_intruder`: the deterministic policy the trainer evaluates is the one
``learned:`` flies.

The environment: ``env.batch_step(keys, states, actions, params)`` when it has one
(:meth:`stp_env.rl.gymnax_env.IntruderGymnaxEnv.batch_step`), else ``jax.vmap(env.step)``; its ``info`` may carry
per-episode numbers (``n_forced`` ...), which :func:`make_iteration` sums over the episodes that end.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from stp_env.sim.engine import MESH_AXIS

LOG_2PI_E = math.log(2.0 * math.pi * math.e)
MAX_GRAD_NORM = 0.5
VF_COEF = 0.5
ADAM_EPS = 1e-5


# ------------------------------------------------------------------------------------------------ the networks
def init_mlp(key, sizes, gains) -> list:
    """``[(W, b), ...]`` for layer widths ``sizes`` (inputs first); layer ``i`` orthogonal with gain ``gains[i]``,
    ``W`` ``(out, in)``, ``b`` zero."""
    layers = []
    for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
        key, sub = jax.random.split(key)
        w = jax.nn.initializers.orthogonal(scale=gains[i])(sub, (n_in, n_out), jnp.float32).T
        layers.append((w, jnp.zeros((n_out,), jnp.float32)))
    return layers


def mlp(layers, x):
    """The MLP on one input ``x`` ``(in,)``: tanh hidden layers, a linear last layer (``W @ h + b``, as
    :func:`stp_env.policies.learned.mlp_intruder` evaluates it)."""
    h = x
    for w, b in layers[:-1]:
        h = jnp.tanh(w @ h + b)
    w, b = layers[-1]
    return w @ h + b


def init_policy(key, obs_size: int, action_size: int, net_arch, log_std_init: float) -> dict:
    """The policy's parameters: ``actor`` and ``critic`` layers and ``log_std`` ``(action_size,)``."""
    k_actor, k_critic = jax.random.split(key)
    hidden = list(net_arch)
    root2 = math.sqrt(2.0)
    return {
        "actor": init_mlp(k_actor, [obs_size, *hidden, action_size], [root2] * len(hidden) + [0.01]),
        "critic": init_mlp(k_critic, [obs_size, *hidden, 1], [root2] * len(hidden) + [1.0]),
        "log_std": jnp.full((action_size,), log_std_init, jnp.float32),
    }


def actor_mean(policy: dict, obs):
    """The Gaussian mean for one observation."""
    return mlp(policy["actor"], obs)


def deterministic_action(policy: dict, obs):
    """The deterministic action (the mean, clipped to ``[-1, 1]``) for one observation."""
    return jnp.clip(actor_mean(policy, obs), -1.0, 1.0)


def value(policy: dict, obs):
    return mlp(policy["critic"], obs)[0]


def log_prob(mean, log_std, action):
    return jnp.sum(-0.5 * ((action - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * math.log(2.0 * math.pi),
                   axis=-1)


def entropy(log_std):
    return jnp.sum(log_std + 0.5 * LOG_2PI_E)


# ------------------------------------------------------------------------------------------------ settings
@dataclasses.dataclass(frozen=True)
class PPOSettings:
    """The algorithm's numbers (checked by the caller's configuration, :class:`stp_env.rl.ppo.PPOConfig`)."""

    n_envs: int
    n_steps: int
    batch_size: int
    n_epochs: int
    learning_rate: float
    gamma: float
    gae_lambda: float
    ent_coef: float
    clip_range: float

    @property
    def rollout(self) -> int:
        return self.n_envs * self.n_steps

    @property
    def n_minibatches(self) -> int:
        return self.rollout // self.batch_size

    @classmethod
    def of(cls, config) -> PPOSettings:
        return cls(**{f.name: getattr(config, f.name) for f in dataclasses.fields(cls)})


def data_shares(settings: PPOSettings) -> int:
    """Among how many devices the update shares each minibatch: the devices the env batch is shared among
    (:func:`stp_env.sim.engine.shares`) when the envs and the minibatch divide evenly among them, else 1. Each device
    shuffles its own envs' transitions and takes its part of every minibatch (a minibatch is then a random sample
    stratified by device, where SB3 samples the whole rollout); the gradients are summed over the devices."""
    from stp_env.sim import engine

    n = engine.shares(settings.n_envs)
    return n if n > 1 and settings.n_envs % n == 0 and settings.batch_size % n == 0 else 1


def optimizer(settings: PPOSettings):
    return optax.chain(optax.clip_by_global_norm(MAX_GRAD_NORM), optax.adam(settings.learning_rate, eps=ADAM_EPS))


class Runner(NamedTuple):
    """What one PPO iteration carries to the next: the policy, the optimiser's state, the envs and the key."""

    policy: Any
    opt_state: Any
    env_keys: Any  # (n_envs, 2) uint32: each env's key stream
    env_states: Any
    obs: Any
    episode_returns: Any  # (n_envs,) the running return of each env's episode
    key: Any


class Transition(NamedTuple):
    obs: Any
    action: Any
    log_prob: Any
    value: Any
    reward: Any
    done: Any


def batch_step_of(env):
    """``(keys, states, actions, params) -> (obs, states, reward, terminated, truncated, info)`` for a batch."""
    if hasattr(env, "batch_step"):
        return env.batch_step
    return jax.vmap(env.step, in_axes=(0, 0, 0, None))


def init_runner(key, env, env_params, settings: PPOSettings, net_arch, log_std_init: float) -> Runner:
    """A fresh policy and ``n_envs`` fresh envs from ``key``."""
    k_policy, k_envs, k_reset, key = jax.random.split(key, 4)
    obs_size = int(np.prod(env.observation_space(env_params).shape))
    action_size = int(np.prod(env.action_space(env_params).shape))
    policy = init_policy(k_policy, obs_size, action_size, net_arch, log_std_init)
    opt_state = optimizer(settings).init(policy)
    env_keys = jax.random.split(k_envs, settings.n_envs)
    obs, env_states = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(k_reset, settings.n_envs),
                                                             env_params)
    return Runner(policy, opt_state, env_keys, env_states, obs, jnp.zeros((settings.n_envs,), jnp.float32), key)


def make_iteration(env, settings: PPOSettings, stat_names=(), *, kbar: int | None = None):
    """``iteration(runner, env_params) -> (runner, metrics)``: one rollout of ``n_steps`` steps of every env and the
    update on it. ``metrics``: scalars (losses, ``approx_kl``, ``clip_fraction``, ``explained_variance``) and sums
    over the episodes that ended in the rollout: ``episodes``, ``return_sum`` and, for each name of ``stat_names``
    in the env's ``info``, ``<name>_sum`` (its value at the episode's end); with ``kbar``, ``kbar_reached``
    (episodes whose ``n_forced`` reached it) and ``kbar_exceeded``."""
    step_batch = batch_step_of(env)
    opt = optimizer(settings)
    s = settings

    def env_step(carry, env_params):
        runner = carry
        key, k_act = jax.random.split(runner.key)
        policy = runner.policy
        mean = jax.vmap(actor_mean, in_axes=(None, 0))(policy, runner.obs)
        values = jax.vmap(value, in_axes=(None, 0))(policy, runner.obs)
        action = mean + jnp.exp(policy["log_std"]) * jax.random.normal(k_act, mean.shape, mean.dtype)
        logp = log_prob(mean, policy["log_std"], action)
        split = jax.vmap(jax.random.split)(runner.env_keys)
        obs, states, reward, terminated, truncated, info = step_batch(split[:, 1], runner.env_states,
                                                                      jnp.clip(action, -1.0, 1.0), env_params)
        done = terminated | truncated
        final_value = jax.vmap(value, in_axes=(None, 0))(policy, info["final_observation"])
        reward = reward.astype(jnp.float32)
        learn_reward = reward + s.gamma * jnp.where(truncated & ~terminated, final_value, 0.0)
        returns = runner.episode_returns + reward
        ended = done.astype(jnp.float32)
        stats = {"episodes": jnp.sum(ended), "return_sum": jnp.sum(returns * ended)}
        for name in stat_names:
            stats[f"{name}_sum"] = jnp.sum(info[name].astype(jnp.float32) * ended)
        if kbar is not None:
            n_forced = info["n_forced"]
            stats["kbar_reached"] = jnp.sum((n_forced >= kbar) & done).astype(jnp.float32)
            stats["kbar_exceeded"] = jnp.sum((n_forced > kbar) & done).astype(jnp.float32)
        runner = runner._replace(env_keys=split[:, 0], env_states=states, obs=obs,
                                 episode_returns=jnp.where(done, 0.0, returns), key=key)
        return runner, (Transition(carry.obs, action, logp, values, learn_reward, done), stats)

    def gae(traj: Transition, last_value):
        def back(carry, t):
            next_adv, next_value = carry
            non_terminal = 1.0 - t.done.astype(jnp.float32)
            delta = t.reward + s.gamma * next_value * non_terminal - t.value
            adv = delta + s.gamma * s.gae_lambda * non_terminal * next_adv
            return (adv, t.value), adv

        _, adv = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value), traj, reverse=True)
        return adv, adv + traj.value

    shares = data_shares(s)

    def total(x):
        """The sum over every device's part of the minibatch (its own sum with one share)."""
        return x if shares == 1 else jax.lax.psum(x, MESH_AXIS)

    def loss_fn(policy, batch, adv_mean, adv_std):
        # sums over this device's part divided by the whole minibatch's size: this device's share of the loss, whose
        # gradients the devices add up (no collective inside the differentiated function)
        obs, action, old_logp, adv, ret = batch
        mean = jax.vmap(actor_mean, in_axes=(None, 0))(policy, obs)
        v = jax.vmap(value, in_axes=(None, 0))(policy, obs)
        logp = log_prob(mean, policy["log_std"], action)
        adv = (adv - adv_mean) / (adv_std + 1e-8)
        ratio = jnp.exp(logp - old_logp)
        n = s.batch_size
        pg = -jnp.sum(jnp.minimum(adv * ratio, adv * jnp.clip(ratio, 1.0 - s.clip_range, 1.0 + s.clip_range))) / n
        v_loss = jnp.sum((ret - v) ** 2) / n
        ent = entropy(policy["log_std"]) / shares
        loss = pg - s.ent_coef * ent + VF_COEF * v_loss
        aux = {"policy_loss": pg, "value_loss": v_loss, "entropy": ent,
               "approx_kl": jnp.sum((ratio - 1.0) - (logp - old_logp)) / n,
               "clip_fraction": jnp.sum((jnp.abs(ratio - 1.0) > s.clip_range).astype(jnp.float32)) / n}
        return loss, aux

    def grad_fn(policy, batch):
        adv = batch[3]
        adv_mean = total(jnp.sum(adv)) / s.batch_size
        adv_std = jnp.sqrt(total(jnp.sum((adv - adv_mean) ** 2)) / (s.batch_size - 1))  # torch's (unbiased) std
        grads, aux = jax.grad(loss_fn, has_aux=True)(policy, batch, adv_mean, adv_std)
        return total(grads), total(aux)

    def epochs(policy, opt_state, key, data):
        """``n_epochs`` passes over ``data`` (leaves ``(n_steps, envs, ...)``: every env, or a device's share)."""
        n_local = data[0].shape[0] * data[0].shape[1]
        size = s.batch_size // shares
        flat = jax.tree.map(lambda a: a.reshape((n_local, *a.shape[2:])), data)
        if shares > 1:
            key = jax.random.fold_in(key, jax.lax.axis_index(MESH_AXIS))

        def epoch(carry, _):
            policy, opt_state, key = carry
            key, k_perm = jax.random.split(key)
            perm = jax.random.permutation(k_perm, n_local)
            shuffled = jax.tree.map(lambda a: a[perm].reshape((s.n_minibatches, size, *a.shape[1:])), flat)

            def minibatch(carry, batch):
                policy, opt_state = carry
                grads, aux = grad_fn(policy, batch)
                updates, opt_state = opt.update(grads, opt_state, policy)
                return (optax.apply_updates(policy, updates), opt_state), aux

            (policy, opt_state), aux = jax.lax.scan(minibatch, (policy, opt_state), shuffled)
            return (policy, opt_state, key), aux

        (policy, opt_state, _), aux = jax.lax.scan(epoch, (policy, opt_state, key), None, s.n_epochs)
        return policy, opt_state, jax.tree.map(jnp.mean, aux)

    def update(runner: Runner, traj: Transition, adv, ret):
        data = (traj.obs, traj.action, traj.log_prob, adv, ret)
        key, k_update = jax.random.split(runner.key)
        if shares == 1:
            policy, opt_state, aux = epochs(runner.policy, runner.opt_state, k_update, data)
        else:
            from jax.sharding import Mesh, PartitionSpec

            whole, envs = PartitionSpec(), PartitionSpec(None, MESH_AXIS)
            policy, opt_state, aux = jax.shard_map(
                epochs, mesh=Mesh(jax.devices(), (MESH_AXIS,)), in_specs=(whole, whole, whole, envs),
                out_specs=whole, check_vma=False)(runner.policy, runner.opt_state, k_update, data)
        return runner._replace(policy=policy, opt_state=opt_state, key=key), aux

    def iteration(runner: Runner, env_params):
        runner, (traj, stats) = jax.lax.scan(lambda r, _: env_step(r, env_params), runner, None, s.n_steps)
        last_value = jax.vmap(value, in_axes=(None, 0))(runner.policy, runner.obs)
        adv, ret = gae(traj, last_value)
        runner, aux = update(runner, traj, adv, ret)
        var = jnp.var(ret)
        explained = jnp.where(var > 0, 1.0 - jnp.var(ret - traj.value) / var, jnp.nan)
        metrics = {**jax.tree.map(jnp.sum, stats), **aux, "explained_variance": explained,
                   "std": jnp.mean(jnp.exp(runner.policy["log_std"]))}
        return runner, metrics

    return iteration


def make_train_chunk(iteration, n_iterations: int):
    """``chunk(runner, env_params) -> (runner, metrics stacked over iterations)``: ``n_iterations`` iterations in
    one ``lax.scan`` (jit it; the host loop between chunks reports progress and writes checkpoints)."""

    def chunk(runner, env_params):
        return jax.lax.scan(lambda r, _: iteration(r, env_params), runner, None, n_iterations)

    return chunk


ENV_BATCHED = ("env_keys", "env_states", "obs", "episode_returns")
"""The :class:`Runner` fields with the envs on their leading axis."""


def runner_shardings(runner: Runner, n_envs: int):
    """Where a runner's arrays live when the env batch is shared among the devices (:func:`stp_env.sim.engine.shares`
    ``> 1``): the env-batched fields split along their first axis as the env's ``batch_step`` splits them, the
    rest whole on every device; ``None`` with one share. Given as a compiled iteration's input and output shardings,
    every call takes the runner as the previous call left it (no second compile, no copy)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    from stp_env.sim import engine

    if engine.shares(n_envs) == 1 or n_envs % len(jax.devices()):
        return None
    mesh = Mesh(jax.devices(), (engine.MESH_AXIS,))
    split, whole = NamedSharding(mesh, PartitionSpec(engine.MESH_AXIS)), NamedSharding(mesh, PartitionSpec())
    return Runner(**{name: jax.tree.map(lambda _, where=(split if name in ENV_BATCHED else whole): where,
                                        getattr(runner, name))
                     for name in Runner._fields})


def replicated(n_envs: int):
    """The sharding of what every device holds whole, beside :func:`runner_shardings` (``None`` with one share)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    from stp_env.sim import engine

    if engine.shares(n_envs) == 1 or n_envs % len(jax.devices()):
        return None
    return NamedSharding(Mesh(jax.devices(), (engine.MESH_AXIS,)), PartitionSpec())


def compile_iteration(iteration, runner: Runner, n_envs: int):
    """``(jitted iteration, runner placed for it)``: the runner donated to each call, its shardings fixed
    (:func:`runner_shardings`)."""
    shardings = runner_shardings(runner, n_envs)
    if shardings is None:
        return jax.jit(iteration, donate_argnums=0), runner
    whole = replicated(n_envs)
    fn = jax.jit(iteration, donate_argnums=0, in_shardings=(shardings, whole), out_shardings=(shardings, whole))
    return fn, jax.device_put(runner, shardings)


# ------------------------------------------------------------------------------------------------ evaluation
def evaluate_deterministic(env, env_params, policy, reset_keys, step_keys, stat_names=()):
    """Episodes of the deterministic policy, one per row of ``reset_keys`` ``(E, 2)``, stepped with
    ``step_keys`` ``(E, T, 2)`` (the key :meth:`step_env` gets at each step; at most ``T`` steps): per-episode
    ``returns``, ``length`` and each name of ``stat_names`` of ``info`` at the episode's end (at step ``T`` if it
    did not end). An episode's state stays as it ended (the episode engine's stop rule,
    :func:`stp_env.sim.engine.play`). Jittable; ``policy`` is an argument, so one compile serves every evaluation
    of a run."""
    from stp_env.sim import engine

    obs, state = jax.vmap(env.reset_env, in_axes=(0, None))(reset_keys, env_params)
    no_action = jnp.zeros(env.action_space(env_params).shape, jnp.float32)
    info = jax.eval_shape(lambda: env.step_env(step_keys[0, 0], jax.tree.map(lambda a: a[0], state), no_action,
                                               env_params))[4]
    n = reset_keys.shape[0]
    carry = {"obs": obs, "state": state, "done": jnp.zeros((n,), bool), "returns": jnp.zeros((n,), jnp.float32),
             "length": jnp.zeros((n,), jnp.int32),
             **{name: jnp.zeros((n, *info[name].shape), info[name].dtype) for name in stat_names}}

    def step(c, k):
        obs, state, reward, terminated, info = env.step_env(k, c["state"], deterministic_action(policy, c["obs"]),
                                                            env_params)
        ended = terminated | env.is_truncated(state, env_params)
        return {"obs": obs, "state": state, "done": ended, "returns": c["returns"] + reward,
                "length": c["length"] + 1, **{name: info[name] for name in stat_names}}, None

    final, _ = engine.play(step, carry, jnp.swapaxes(step_keys, 0, 1), stop=lambda c: c["done"], batched=True)
    return {name: final[name] for name in ("returns", "length", *stat_names)}
