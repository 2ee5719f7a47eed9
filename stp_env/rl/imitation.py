"""Starting a learned policy from a scripted one: behaviour cloning (with DAgger) of a Stable-Baselines3 actor, and
a critic fitted to the teacher's returns, so that PPO starts from the teacher's strength instead of from scratch.

* :func:`imitate`: fit an actor-critic policy's mean action to recorded actions (mean squared error).
* :func:`fit_values`: fit its value head to recorded returns (so the first PPO updates do not run on a random
  critic's advantages, which would pull the clone away from the teacher before the critic has learned anything).
* :func:`intruder_demonstrations`: a scripted intruder's (or a DAgger mixture's) decisions on an
  :class:`stp_env.rl.IntruderVecEnv`, labelled with the teacher's action at every visited state, with the
  discounted returns of the episodes flown.
* :func:`clone_intruder`: the whole start (demonstrations, cloning, DAgger rounds, critic), as ``train-intruder
  --clone NAME`` runs it.

DAgger (Ross, Gordon and Bagnell, 2011): after the first fit, the *student* flies and the teacher labels the states
the student visits; the data are pooled and the actor refitted. The clone then knows what the teacher does in the
states its own small errors lead to, which plain cloning never shows it.
"""

from __future__ import annotations

import functools

import jax
import numpy as np


def imitate(policy, obs, actions, epochs: int, lr: float = 1e-3, batch: int = 1024, seed: int = 0,
            progress: bool = False) -> float:
    """Fit the mean action of an SB3 actor-critic ``policy`` to ``actions`` (behaviour cloning, mean squared
    error); returns the final epoch's loss."""
    import torch

    params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]

    def loss_of(x, y):
        latent = policy.mlp_extractor.forward_actor(policy.pi_features_extractor(x))
        return torch.mean((policy.action_net(latent) - y) ** 2)

    return _fit(params, loss_of, obs, actions, epochs, lr, batch, seed, progress and "cloning the actor")


def fit_values(policy, obs, returns, epochs: int, lr: float = 1e-3, batch: int = 1024, seed: int = 0,
               progress: bool = False) -> float:
    """Fit the value head of an SB3 actor-critic ``policy`` to ``returns`` (mean squared error); returns the final
    epoch's loss."""
    import torch

    params = [*policy.mlp_extractor.value_net.parameters(), *policy.value_net.parameters()]

    def loss_of(x, y):
        latent = policy.mlp_extractor.forward_critic(policy.vf_features_extractor(x))
        return torch.mean((policy.value_net(latent)[:, 0] - y) ** 2)

    return _fit(params, loss_of, obs, returns, epochs, lr, batch, seed, progress and "fitting the critic")


def _fit(params, loss_of, inputs, targets, epochs, lr, batch, seed, desc) -> float:
    import torch
    from tqdm.auto import tqdm

    opt = torch.optim.Adam(params, lr=lr)
    x = torch.as_tensor(np.asarray(inputs, np.float32))
    y = torch.as_tensor(np.asarray(targets, np.float32))
    gen = torch.Generator().manual_seed(seed)
    loss_value = float("nan")
    for _ in tqdm(range(epochs), desc=desc or "", unit="epoch", disable=not desc):
        perm = torch.randperm(len(x), generator=gen)
        total = 0.0
        for i in range(0, len(x), batch):
            idx = perm[i:i + batch]
            loss = loss_of(x[idx], y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        loss_value = total / len(x)
    return loss_value


def teacher_actions(teacher, keys, states, params):
    """The scripted intruder ``teacher``'s action ``(n, 2)`` at every env's state (jitted once per teacher)."""
    return _teacher_fn(teacher)(keys, states, params)


def scripted_predict(venv, teacher):
    """``predict(obs) -> actions`` that plays the scripted intruder ``teacher`` on ``venv`` (an
    :class:`stp_env.rl.IntruderVecEnv`): it reads the envs' states, not the observations (for evaluating a script
    on the same episodes as a learned policy)."""
    def predict(_obs):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(venv._keys)  # not the keys the step will use
        return np.asarray(teacher_actions(teacher, keys, venv._states, venv.params))

    return predict


@functools.cache
def _teacher_fn(teacher):
    """The batched, jitted ``teacher`` (one compiled program per teacher and process)."""
    return jax.jit(jax.vmap(lambda k, s, p: teacher(k, s, p), in_axes=(0, 0, None)))


def intruder_demonstrations(venv, teacher, n_steps: int, gamma: float, *, student=None, seed: int = 0,
                            progress: bool = True):
    """``(observations, teacher actions, discounted returns)`` of ``n_steps`` steps of every env of ``venv``
    (an :class:`stp_env.rl.IntruderVecEnv`, seeded ``seed``), each state labelled with the teacher's action.

    ``student``: ``None`` (the teacher flies) or ``predict(obs) -> actions`` (DAgger: the student flies, the teacher
    labels). Returns are discounted by ``gamma`` within each episode and bootstrapped with 0 at the end of the
    record (episodes cut there are dropped from the returns' data: ``returns`` is ``NaN`` for them, and the caller
    keeps the finite ones)."""
    from tqdm.auto import tqdm

    venv.seed(seed)
    obs = venv.reset()
    xs, ys, rs, ds = [], [], [], []
    label = scripted_predict(venv, teacher)
    for _ in tqdm(range(n_steps), desc="teacher demonstrations" if student is None else "DAgger",
                  unit="step", disable=not progress):
        act = label(obs).astype(np.float32)
        xs.append(obs)
        ys.append(act)
        fly = act if student is None else np.asarray(student(obs), np.float32)
        venv.step_async(fly)
        obs, rewards, dones, _infos = venv.step_wait()
        rs.append(rewards)
        ds.append(dones)
    rewards, dones = np.asarray(rs, np.float64), np.asarray(ds, bool)
    returns = np.full(rewards.shape, np.nan)
    acc = np.full(rewards.shape[1], np.nan)  # NaN until an episode end is seen (cut episodes have no return)
    for t in range(len(rewards) - 1, -1, -1):
        acc = np.where(dones[t], rewards[t], rewards[t] + gamma * acc)
        returns[t] = acc
    return (np.concatenate(xs).astype(np.float32), np.concatenate(ys).astype(np.float32),
            returns.reshape(-1).astype(np.float32))


def clone_intruder(model, venv, teacher, *, n_steps: int, dagger_rounds: int, epochs: int, gamma: float,
                   seed: int = 0, progress: bool = True) -> dict:
    """Start ``model`` (an SB3 PPO/A2C on ``venv``) from ``teacher``: clone its actions on ``n_steps`` steps of
    every env, then ``dagger_rounds`` DAgger rounds of as many steps (the student flies, the teacher labels), and
    fit the critic to the returns of the episodes that ended within the records (teacher's and student's).
    Returns the record of what was done (samples, losses, the clone's agreement with the teacher)."""
    obs, act, ret = intruder_demonstrations(venv, teacher, n_steps, gamma, seed=seed, progress=progress)
    record = {"samples": [len(obs)], "actor_loss": [imitate(model.policy, obs, act, epochs, seed=seed,
                                                                            progress=progress)]}
    finite = np.isfinite(ret)
    value_obs, value_ret = [obs[finite]], [ret[finite]]

    def student(o):
        return model.predict(o, deterministic=True)[0]

    for r in range(dagger_rounds):
        o2, a2, r2 = intruder_demonstrations(venv, teacher, n_steps, gamma, student=student, seed=seed + 1 + r,
                                            progress=progress)
        obs, act = np.concatenate([obs, o2]), np.concatenate([act, a2])
        value_obs.append(o2[np.isfinite(r2)])
        value_ret.append(r2[np.isfinite(r2)])
        record["samples"].append(len(obs))
        record["actor_loss"].append(imitate(model.policy, obs, act, epochs, seed=seed + 1 + r, progress=progress))
    value_obs, value_ret = np.concatenate(value_obs), np.concatenate(value_ret)
    record["value_samples"] = len(value_obs)  # states of episodes that ended within the record
    record["value_loss"] = (fit_values(model.policy, value_obs, value_ret, epochs, seed=seed, progress=progress)
                            if len(value_obs) else None)
    return record


def agreement(predict, obs, actions, tolerance: float = 0.1) -> float:
    """The share of states where ``predict(obs)`` is within ``tolerance`` of ``actions`` in every component."""
    got = np.asarray(predict(obs), np.float32)
    return float(np.mean(np.all(np.abs(got - np.asarray(actions, np.float32)) <= tolerance, axis=1)))
