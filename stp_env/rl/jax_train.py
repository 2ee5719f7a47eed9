"""Training a learned intruder with the JAX PPO (``stp-env train-intruder --trainer jax``).

``train_jax(TrainConfig(..., trainer="jax"))`` trains :mod:`stp_env.rl.jax_ppo` on the intruder's gymnax view
(:class:`stp_env.rl.gymnax_env.IntruderGymnaxEnv`, the same episodes, rewards and observations as the SB3 route of
:mod:`stp_env.rl.train`): each PPO iteration (a rollout of ``n_envs x n_steps`` steps and ``n_epochs`` of updates)
is one compiled call, and the host only reports between them. It writes to ``out_dir``, as the SB3 route does:

* ``config.json`` (the configuration, ``devices`` the batch is shared among, ``fingerprint``);
* ``progress.csv``: one row per iteration (steps, seconds, steps/s including the updates, the episodes that ended
  in the rollout: their count, mean return, mean ``|N^RP|``, share reaching k̄; the losses, ``approx_kl``,
  ``clip_fraction``, ``explained_variance``, ``std``);
* ``evaluations.csv``: the deterministic policy on ``eval_episodes`` held-out episodes every ``eval_every`` steps and
  at the end (:func:`stp_env.rl.train.summarize`), the episodes the SB3 route's evaluations use (env ``j`` seeded
  ``eval_seed + j``, the Gymnasium view's key rule), so the two trainers' curves compare episode for episode;
* ``checkpoints/runner.npz`` every ``checkpoint_every`` steps (everything the next iteration needs: the policy,
  Adam's state, every env's state and key), and ``checkpoints/intruder_<steps>.npz`` (the policy then); a run
  started again with ``resume=True`` (``--resume``) continues from the checkpoint if it was written by the same
  configuration (its fingerprint; ``total_timesteps`` and the reporting settings may differ) and its content is
  intact (a digest of its arrays), else it starts afresh and says why;
* ``intruder.npz`` (the deterministic actor, :func:`stp_env.policies.learned.write_mlp`: ``learned:OUT`` flies it
  in ``stp-env evaluate``, ``render``, ``falsify`` and the PettingZoo env) and ``learning_curves.png``.

Same configuration, same machine and device count: the same run.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.files import append_csv_row, atomic_open, write_text
from stp_env.rl import functional as F
from stp_env.rl import jax_ppo
from stp_env.rl.train import TrainConfig, build_params, learning_curves, summarize
from stp_env.rl.vec_env import STAT_NAMES
from stp_env.sim import engine

RUNNER_FILE = "runner.npz"
CHECKPOINT_FORMAT = 1
RESUMABLE_CHANGES = ("total_timesteps", "out_dir", "log_formats", "eval_every", "eval_episodes", "checkpoint_every",
                     "torch_threads")
"""Fields a resumed run may change: the budget and what is reported; anything else is another run."""


def fingerprint(config: TrainConfig) -> str:
    """What makes two runs the same run (every field but :data:`RESUMABLE_CHANGES`), and the device count."""
    fields = {k: v for k, v in config.to_json().items() if k not in RESUMABLE_CHANGES}
    fields["devices"] = engine.shares(config.n_envs)
    return hashlib.sha256(json.dumps(fields, sort_keys=True, default=str).encode()).hexdigest()[:20]


def make_env(config: TrainConfig, params):
    from stp_env.rl.gymnax_env import IntruderGymnaxEnv

    return IntruderGymnaxEnv(params, horizon=config.horizon, vehicle_policy=config.vehicle_policy,
                             observation=config.observation)


# ------------------------------------------------------------------------------------------------ held-out episodes
def held_out_keys(seed: int, n_episodes: int, n_steps: int):
    """``(reset_keys (E, 2), step_keys (E, T, 2))`` of the episodes ``seed, seed + 1, ...`` as the Gymnasium and
    SB3 views key them (:mod:`stp_env.rl.functional`): the env key of seed ``s`` is split at the reset and at
    every step, the second half going to the reset or the step."""

    def split(key, _):
        key, k = jax.random.split(key)
        return key, k

    keys = jnp.asarray(np.stack([np.asarray(F.key_for_seed(seed + j)) for j in range(n_episodes)]))

    @jax.jit
    def all_keys(keys):
        keys, k_reset = jax.vmap(jax.random.split, out_axes=1)(keys)
        _, k_steps = engine.play(split, keys, jnp.zeros((n_steps, n_episodes)), batched=True,
                                 record=lambda _, k: k)
        return k_reset, jnp.swapaxes(k_steps, 0, 1)

    return all_keys(keys)


def episode_steps(config: TrainConfig, params) -> int:
    """At most how many steps an episode of the training horizon lasts."""
    if config.horizon == "intruder":
        return int(np.ceil(float(params.intruder.t_iat) / float(params.episode.dt) - 1e-6)) + 1
    from stp_env.sim import steps_for

    return steps_for(params)


def make_evaluator(env, stat_names):
    """``run(policy, env_params, reset_keys, step_keys)``: :func:`stp_env.rl.jax_ppo.evaluate_deterministic`,
    compiled once for every policy."""

    @jax.jit
    def run(policy, env_params, reset_keys, step_keys):
        return jax_ppo.evaluate_deterministic(env, env_params, policy, reset_keys, step_keys, stat_names)

    return run


# ------------------------------------------------------------------------------------------------ checkpoints
def _digest(leaves, record) -> str:
    h = hashlib.sha256()
    for a in leaves:
        a = np.ascontiguousarray(a)
        h.update(str((a.shape, a.dtype.str)).encode())
        h.update(a.tobytes())
    h.update(json.dumps(record, sort_keys=True).encode())
    return h.hexdigest()


def _host_leaves(runner):
    return [np.asarray(jax.device_get(x)) for x in jax.tree.leaves(runner)]


def save_runner(runner, path: Path, *, fingerprint_: str, iteration: int, timesteps: int,
                logs: dict | None = None) -> None:
    """``runner`` (every leaf) with its provenance: the run's fingerprint, the iteration, the run's log rows so far
    (``logs``: ``{"progress": [...], "evaluations": [...]}``, rewritten from here on a resume) and a digest of the
    arrays and the logs."""
    leaves = _host_leaves(runner)
    logs = {"progress": [], "evaluations": [], **(logs or {})}
    meta = {"format": CHECKPOINT_FORMAT, "fingerprint": fingerprint_, "iteration": iteration,
            "timesteps": timesteps, "n_leaves": len(leaves), "logs": logs, "digest": _digest(leaves, logs)}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as fh:
        # key order kept: the log rows are rewritten as csv columns in it on a resume
        np.savez(fh, metadata=np.asarray(json.dumps(meta)), **{f"leaf{i}": a for i, a in enumerate(leaves)})


def load_runner(path: Path, template, fingerprint_: str):
    """``(runner, metadata)`` from :func:`save_runner`'s file, if it belongs to this run (fingerprint), its arrays
    match the fresh runner ``template`` leaf for leaf (shapes and dtypes) and its digest holds; else ``ValueError``
    naming the file and what is wrong (the loader contract, ``docs/threat-model.md``). Numpy only, nothing
    unpickled."""
    from stp_env.loaders import LoadError, parse_json, read_npz

    arrays = read_npz(path, "jax-checkpoint")
    raw = arrays.pop("metadata", None)
    if raw is None or raw.shape != () or raw.dtype.kind != "U":
        raise LoadError(path, "not a training checkpoint (no metadata string)")
    meta = parse_json(str(raw), path, "checkpoint metadata")
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        raise LoadError(path, f"not a training checkpoint of format {CHECKPOINT_FORMAT}")
    if meta.get("fingerprint") != fingerprint_:
        raise LoadError(path, "written by another configuration (its fingerprint differs)")
    t_leaves, treedef = jax.tree.flatten(template)
    if meta.get("n_leaves") != len(t_leaves) or set(arrays) != {f"leaf{i}" for i in range(len(t_leaves))}:
        raise LoadError(path, "its arrays are not this run's")
    leaves = [arrays[f"leaf{i}"] for i in range(len(t_leaves))]
    for a, t in zip(leaves, t_leaves):
        if a.shape != tuple(np.shape(t)) or a.dtype != np.dtype(t.dtype):
            raise LoadError(path, "its arrays are not this run's (shapes or types differ)")
    logs = meta.get("logs")
    if (not isinstance(logs, dict) or set(logs) != {"progress", "evaluations"}
            or not all(isinstance(rows, list) and all(isinstance(r, dict) for r in rows) for rows in logs.values())):
        raise LoadError(path, "its log rows are not lists of records")
    if _digest(leaves, logs) != meta.get("digest"):
        raise LoadError(path, "its content does not match its digest")
    it, steps = meta.get("iteration"), meta.get("timesteps")
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (it, steps)):
        raise LoadError(path, "bad iteration or step count")
    placed = [jax.device_put(a, t.sharding) if isinstance(t, jax.Array) else a for a, t in zip(leaves, t_leaves)]
    return jax.tree.unflatten(treedef, placed), meta


# ------------------------------------------------------------------------------------------------ the run
def _rewrite_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        path.unlink(missing_ok=True)
        return
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def policy_layers(policy) -> list:
    """The actor's layers as numpy ``(W, b)`` pairs (the exported format)."""
    return [(np.asarray(w), np.asarray(b)) for w, b in jax.device_get(policy["actor"])]


def export_policy(policy, path, config: TrainConfig, kbar: int, extra: dict) -> Path:
    from stp_env.policies.learned import write_mlp

    return write_mlp(policy_layers(policy), path, "tanh", {
        "scenario": config.scenario, "kbar": kbar, "horizon": config.horizon, "seed": config.seed,
        "vehicle_policy": config.vehicle_policy, "spawn_mode": config.spawn_mode, "wind_model": config.wind_model,
        "backend": config.backend, "control_dt": config.control_dt, "avoid_margin": config.avoid_margin,
        "kbar_reward": config.kbar_reward, "observation": config.observation, "trainer": "jax", "clone": None,
        "requested_timesteps": config.total_timesteps, **extra})


@dataclasses.dataclass(frozen=True)
class PPORun:
    """One training run of :mod:`stp_env.rl.jax_ppo` and what it writes (:func:`run_ppo`): the intruder's
    (:func:`train_jax`) and a vehicle's (:mod:`stp_env.rl.self_play`) differ only in these fields.

    ``evaluate(policy) -> dict``: the held-out evaluation's row; ``export(policy, path, extra)``: the policy file;
    ``progress_fields(metrics, episodes) -> dict``: the role's columns of ``progress.csv``; ``postfix(row)``: what
    the progress bar shows; ``stem``: the policy file's name (``OUT/<stem>.npz``, ``checkpoints/<stem>_<steps>.npz``);
    ``initial_policy``: the policy to start from (``None``: a fresh network); ``curves(history, out)``: the figure."""

    env: Any
    env_params: Any
    settings: jax_ppo.PPOSettings
    net_arch: tuple
    log_std_init: float
    seed: int
    out: Path
    requested_timesteps: int
    eval_every: int
    checkpoint_every: int
    fingerprint: str
    stat_names: tuple
    evaluate: Callable
    export: Callable
    progress_fields: Callable
    postfix: Callable
    label: str
    stem: str
    kbar: int | None = None
    initial_policy: Any = None
    curves: Callable | None = None


def run_ppo(r: PPORun, *, resume: bool = False, show: bool = False):
    """Train (the module docstring's loop and outputs). Returns ``(policy, eval_history)``."""
    from tqdm.auto import tqdm

    from stp_env import progress as progress_lib

    s = r.settings
    r.out.mkdir(parents=True, exist_ok=True)
    runner = jax_ppo.init_runner(jax.random.PRNGKey(r.seed), r.env, r.env_params, s, r.net_arch, r.log_std_init)
    if r.initial_policy is not None:
        runner = runner._replace(policy=r.initial_policy, opt_state=jax_ppo.optimizer(s).init(r.initial_policy))
    iteration, start_steps, meta = 0, 0, None
    ckpt = r.out / "checkpoints" / RUNNER_FILE
    if resume and ckpt.exists():
        try:
            runner, meta = load_runner(ckpt, runner, r.fingerprint)
        except ValueError as err:
            progress_lib.note(f"{r.label}: not resumed: {err}; starting afresh", True)
        else:
            iteration, start_steps = meta["iteration"], meta["timesteps"]
            progress_lib.note(f"{r.label}: resuming from {ckpt} at {start_steps} steps", show)
    logs = meta["logs"] if iteration else {"progress": [], "evaluations": []}
    for name, rows in logs.items():  # the logs as of the checkpoint (a fresh run: none)
        _rewrite_csv(r.out / f"{name}.csv", rows)
    history = logs["evaluations"]
    step_fn, runner = jax_ppo.compile_iteration(jax_ppo.make_iteration(r.env, s, r.stat_names, kbar=r.kbar),
                                                runner, s.n_envs)
    whole = jax_ppo.replicated(s.n_envs)
    env_params = r.env_params if whole is None else jax.device_put(r.env_params, whole)

    def evaluate(policy, steps: int) -> dict:
        t0 = time.perf_counter()
        with progress_lib.phase(f"{r.label}: the held-out evaluation at {steps} steps", show):
            result = r.evaluate(policy)
        row = {"timesteps": steps, **result, "seconds": round(time.perf_counter() - t0, 2)}
        row = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}  # JSON for checkpoints
        append_csv_row(r.out / "evaluations.csv", row)
        history.append(row)
        return row

    n_iterations = -(-r.requested_timesteps // s.rollout)
    total = n_iterations * s.rollout
    if total != r.requested_timesteps:
        progress_lib.note(f"{r.label}: {r.requested_timesteps} timesteps rounded up to {total}, whole rollouts of "
                          f"n_envs x n_steps = {s.rollout} steps", show)
    next_eval = _next_multiple(start_steps, r.eval_every)
    next_ckpt = _next_multiple(start_steps, r.checkpoint_every)
    bar = tqdm(total=total, initial=start_steps, unit="step", unit_scale=True, disable=not show,
               desc=f"{r.label} (jax)", smoothing=0.1)
    progress_lib.compiling_until_first_update(bar)
    train_start = time.perf_counter()
    train_seconds = 0.0
    shown = {}
    while iteration < n_iterations:
        t0 = time.perf_counter()
        runner, metrics = step_fn(runner, env_params)
        metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
        seconds = time.perf_counter() - t0
        train_seconds += seconds
        iteration += 1
        steps = iteration * s.rollout
        row = _progress_row(steps, seconds, s.rollout, metrics, r.progress_fields)
        append_csv_row(r.out / "progress.csv", row)
        logs["progress"].append(row)
        bar.update(s.rollout)
        if row["episodes"]:
            shown = r.postfix(row)
        bar.set_postfix(steps_per_s=row["steps_per_s"], **shown, refresh=False)
        if r.eval_every and steps >= next_eval and iteration < n_iterations:
            next_eval = _next_multiple(steps, r.eval_every)
            evaluate(runner.policy, steps)
        if r.checkpoint_every and steps >= next_ckpt:
            next_ckpt = _next_multiple(steps, r.checkpoint_every)
            save_runner(runner, ckpt, fingerprint_=r.fingerprint, iteration=iteration, timesteps=steps, logs=logs)
            r.export(runner.policy, r.out / "checkpoints" / f"{r.stem}_{steps}.npz", {"total_timesteps": steps})
    bar.close()
    final = evaluate(runner.policy, total)
    final["train_seconds"] = round(time.perf_counter() - train_start, 1)
    r.export(runner.policy, r.out / f"{r.stem}.npz", {"total_timesteps": total, "final_eval": dict(final),
                                                      "iteration_seconds": round(train_seconds, 1)})
    if r.curves is not None:
        r.curves(history, r.out)
    return runner.policy, history


def train_jax(config: TrainConfig, *, params=None, resume: bool = False, progress: bool | None = None,
              initial_policy=None):
    """Train an intruder (module docstring). ``params``: prebuilt core parameters (tests); ``initial_policy``: the
    policy's parameters to start from (self-play's rounds; ``None``: a fresh network). Returns ``(policy,
    eval_history)`` with ``policy`` the final policy's parameters (:mod:`stp_env.rl.jax_ppo`)."""
    from stp_env import progress as progress_lib

    if config.trainer != "jax":
        raise ValueError(f"train_jax needs trainer='jax'; got {config.trainer!r}.")
    show = progress_lib.enabled(progress)
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if params is None:
        params = build_params(config, progress=show)
    kbar = int(params.intruder.kbar)
    env = make_env(config, params)
    fp = fingerprint(config)
    if initial_policy is not None:  # another start is another run
        fp = hashlib.sha256((fp + _digest(_host_leaves(initial_policy), {})).encode()).hexdigest()[:20]
    write_text(json.dumps({**config.to_json(), "devices": engine.shares(config.n_envs), "fingerprint": fp},
                          indent=2), out / "config.json")
    evaluator = make_evaluator(env, STAT_NAMES)
    eval_keys = held_out_keys(config.eval_seed, config.eval_episodes, episode_steps(config, params))

    def evaluate(policy):
        return summarize({k: np.asarray(v) for k, v in evaluator(policy, params, *eval_keys).items()}, kbar)

    def progress_fields(m, per_episode):
        return {"mean_n_forced": per_episode("n_forced_sum"), "kbar_reached_rate": per_episode("kbar_reached"),
                "kbar_exceeded": int(m["kbar_exceeded"]), "collisions": int(m["collisions_sum"]),
                "guarantee_violations": int(m["guarantee_violations_sum"])}

    run = PPORun(env=env, env_params=params, settings=jax_ppo.PPOSettings.of(config), net_arch=config.net_arch,
                 log_std_init=config.log_std_init, seed=config.seed, out=out,
                 requested_timesteps=config.total_timesteps, eval_every=config.eval_every,
                 checkpoint_every=config.checkpoint_every, fingerprint=fp, stat_names=STAT_NAMES, kbar=kbar,
                 evaluate=evaluate, export=lambda policy, path, extra: export_policy(policy, path, config, kbar, extra),
                 progress_fields=progress_fields,
                 postfix=lambda row: {"n_forced": row["mean_n_forced"], "reach_kbar": row["kbar_reached_rate"]},
                 label="train-intruder", stem="intruder", initial_policy=initial_policy,
                 curves=lambda history, out: learning_curves(history, out, kbar))
    return run_ppo(run, resume=resume, show=show)


def _next_multiple(steps: int, every: int) -> int:
    return (steps // every + 1) * every if every else 0


def _progress_row(steps: int, seconds: float, rollout: int, m: dict, fields) -> dict:
    episodes = m["episodes"]

    def per_episode(name):
        return round(m[name] / episodes, 4) if episodes else float("nan")

    return {"timesteps": steps, "seconds": round(seconds, 3), "steps_per_s": round(rollout / seconds),
            "episodes": int(episodes), "mean_return": per_episode("return_sum"), **fields(m, per_episode),
            **{k: round(m[k], 6) for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction",
                                           "explained_variance", "std")}}


__all__ = ["RESUMABLE_CHANGES", "PPORun", "episode_steps", "export_policy", "fingerprint", "held_out_keys",
           "load_runner", "make_env", "run_ppo", "save_runner", "train_jax"]
