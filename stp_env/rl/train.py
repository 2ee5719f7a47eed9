"""Training learned intruders with Stable-Baselines3 on the native batched VecEnv (one module; scripts and the
``stp-env train-intruder`` subcommand are thin wrappers around :func:`train`).

``train(TrainConfig(...))`` builds an :class:`~stp_env.rl.IntruderVecEnv` (the vehicles run ``switching``,
``u*`` with the HJ safety filter, inside the core), trains PPO (or A2C) with the given seed, and writes to
``out_dir``: ``config.json`` (the config and ``devices``, the count the batch was shared among), SB3 logs
(``progress.csv``, TensorBoard events with ``"tensorboard"`` in ``log_formats``), ``checkpoints/`` every
``checkpoint_every`` steps, ``evaluations.csv`` (one row per evaluation,
:func:`summarize`: mean, 95 % interval and max of ``|N^RP|``, collisions, guarantee violations, episodes above k̄,
with Clopper-Pearson bounds), ``best_model.zip`` (best mean ``|N^RP|``), ``model.zip`` and ``intruder.npz`` (the
deterministic actor for :func:`stp_env.policies.learned.load_intruder`). Same config, same seed, same machine: same run
(torch uses ``torch_threads`` CPU threads; JAX keys come from :func:`stp_env.rl.key_for_seed`).

SuperSuit
---------
SuperSuit's vector wrappers take the PettingZoo env with ``keep_finished=True`` (no agent death) and a scripted
intruder (one observation space for the vehicles); ``docs/training.md`` ("Multi-agent clients") and
``tests/test_clients.py``. :class:`~stp_env.rl.IntruderVecEnv` stays the batched route for the intruder (the
vehicles run a baseline policy inside the core, so only the intruder learns).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from stp_env import assembly, requirements, sim
from stp_env.arguments import check_int, check_real
from stp_env.evaluation.summary import forced_summary
from stp_env.files import append_csv_row, write_text
from stp_env.rl.ppo import PPOConfig, make_model
from stp_env.sim import engine
from stp_env.sim.types import SPAWN_MODES

LOG_FORMATS = ("stdout", "csv", "tensorboard", "log", "json")
TRAINERS = ("sb3", "jax")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainConfig(PPOConfig):
    """Everything that shapes a training run (unknown fields are a ``TypeError``).

    Attributes:
        scenario: registry name; kbar: override the scenario's k̄ (``None``: its default).
        horizon: ``"intruder"`` (appearance to departure) or ``"episode"`` (:mod:`stp_env.rl.functional`).
        vehicle_policy: the vehicles' baseline policy (``"switching"``: u* with the safety filter; ``"worst"``: the
            buffer game's worst vehicles, for which the relative buffer table ``V^B`` of the k̄ is loaded).
        spawn_mode: where the intruder appears (:class:`stp_env.sim.EnvConfig`): ``"outside"`` every avoid region
            (Assumption 3), on a vehicle's avoid ``"boundary"`` (where the max-k intruders start) or ``"mixed"``.
        wind_model: how each agent's wind in its disk is drawn (:mod:`stp_env.sim.winds`; ``"converging"``: the
            buffer game's helping winds, where the pinwheel reaches k̄ = 3).
        backend: the vehicles' plant (:mod:`stp_env.sim.backends`: ``"jax"``, the papers' Dubins model, or
            ``"pymunk-dynamic[:param=value,...]"``, the rigid body with actuator lag, where the tracking bound no
            longer holds: docs/model_mismatch.md); control_dt: ``None`` (the certified inner period) or another
            period of the vehicles' tracker and safety filter [s] (e.g. 0.1: once per step; uncertified, so the
            vehicles' collisions count as assumption failures); avoid_margin: ``None`` (the certified margin of the
            inner period, which grows with it: one inner step of the value's fastest fall) or a margin [m] (below
            the certified one: uncertified).
        forced_reward: per vehicle newly forced to avoid (eq. 39); collision_reward: per collision the intruder
            causes; shaping_reward: times the decrease of ``min V^A`` over the vehicles unforced before each step
            [per m] (both potentials of a step over the same vehicles, so forcing one is rewarded; before that fix
            the potential jumped by up to ``d_sense`` when a vehicle was forced, and with ``forced_reward = 1`` the
            intruder learned to approach and not force); kbar_reward: once when ``|N^RP|`` reaches k̄ (the k̄-th
            forced vehicle, on top of its ``forced_reward``).
        observation: the intruder's observation set (:mod:`stp_env.policies.observations`): ``"core"`` (the
            nearest vehicles' relative states, ``V^A`` and forced flags) or ``"game"`` (and the buffer game's
            features: the unforced vehicles ranked by ``V^B``, the hop heading toward each; loads ``V^B``).
        clone: ``None`` or a scripted intruder (:data:`stp_env.policies.INTRUDERS`) to start from: its actions
            are cloned on ``clone_steps`` steps of every training env, then ``clone_rounds`` DAgger rounds, and the
            critic is fitted to its returns, before PPO (:mod:`stp_env.rl.imitation`); clone_epochs: passes over
            the data per fit.
        algo, net_arch, total_timesteps, n_envs, n_steps, batch_size, n_epochs, learning_rate, gamma, gae_lambda,
        ent_coef, clip_range, log_std_init, seed, torch_threads: the algorithm's settings
        (:class:`stp_env.rl.ppo.PPOConfig`). ``total_timesteps`` is rounded up to whole rollouts
        (:attr:`trained_timesteps`; :func:`train` says so and records both in ``intruder.npz``).
        eval_every: evaluate every this many env steps (0: only at the end); eval_episodes: episodes per
            evaluation, from seeds ``eval_seed, eval_seed + 1, ...`` (held out from training's ``seed + i``).
        checkpoint_every: save a checkpoint every this many env steps (0: never).
        out_dir: output folder; log_formats: SB3 logger formats.
        trainer: ``"sb3"`` (Stable-Baselines3 on the batched VecEnv, this module) or ``"jax"`` (the PPO of
            :mod:`stp_env.rl.jax_ppo` on the gymnax view, rollouts and updates compiled together:
            :mod:`stp_env.rl.jax_train`; PPO only, no clone, ``torch_threads`` and ``log_formats`` unused).
    """

    scenario: str = "town"
    kbar: int | None = None
    horizon: str = "intruder"
    vehicle_policy: str = "switching"
    spawn_mode: str = "outside"
    wind_model: str = "uniform"
    backend: str = "jax"
    control_dt: float | None = None
    avoid_margin: float | None = None
    forced_reward: float = 5.0
    collision_reward: float = 10.0
    shaping_reward: float = 0.01
    kbar_reward: float = 0.0
    observation: str = "core"
    clone: str | None = None
    clone_steps: int = 200
    clone_rounds: int = 2
    clone_epochs: int = 30
    eval_every: int = 200_000
    eval_episodes: int = 256
    eval_seed: int = 1_000_000
    checkpoint_every: int = 500_000
    out_dir: str = "runs/intruder"
    log_formats: tuple[str, ...] = ("stdout", "csv")
    trainer: str = "sb3"

    def __post_init__(self) -> None:
        from stp_env.rl.functional import check_horizon, check_vehicle_policy

        super().__post_init__()
        if self.trainer not in TRAINERS:
            raise ValueError(f"trainer {self.trainer!r} is not known; allowed: {', '.join(TRAINERS)}.")
        if self.trainer == "jax" and (self.algo != "ppo" or self.clone is not None):
            raise ValueError("the jax trainer runs PPO from a fresh network: algo must be 'ppo' and clone None.")
        check_horizon(self.horizon)
        check_vehicle_policy(self.vehicle_policy)
        if self.spawn_mode not in SPAWN_MODES:
            raise ValueError(f"spawn_mode {self.spawn_mode!r} is not known; allowed: {', '.join(SPAWN_MODES)}.")
        check_int(self.eval_episodes, "eval_episodes", 1, None)
        for name in ("eval_every", "checkpoint_every", "eval_seed"):
            check_int(getattr(self, name), name, 0, None)
        if self.kbar is not None and (isinstance(self.kbar, bool) or not isinstance(self.kbar, int) or self.kbar < 1):
            raise ValueError(f"kbar must be None or an integer >= 1; got {self.kbar!r}.")
        object.__setattr__(self, "log_formats", tuple(self.log_formats))
        unknown = sorted(set(self.log_formats) - set(LOG_FORMATS))
        if unknown:
            raise ValueError(f"unknown log formats {unknown}; allowed: {', '.join(LOG_FORMATS)}.")
        for name in ("forced_reward", "collision_reward", "shaping_reward", "kbar_reward"):
            check_real(getattr(self, name), name)
        from stp_env.policies import INTRUDERS
        from stp_env.policies.observations import check_observation

        check_observation(self.observation)
        from stp_env.sim import winds

        winds.make(self.wind_model)  # a registered name (ValueError otherwise)
        self.env_config()  # the backend and the inner period, checked before anything runs
        if self.clone is not None and self.clone not in INTRUDERS:
            raise ValueError(f"clone {self.clone!r} is not a scripted intruder; allowed: {', '.join(INTRUDERS)}.")
        check_int(self.clone_steps, "clone_steps", 1, None)
        check_int(self.clone_rounds, "clone_rounds", 0, None)
        check_int(self.clone_epochs, "clone_epochs", 1, None)

    def env_config(self) -> sim.EnvConfig:
        rewards = sim.RewardConfig(forced=self.forced_reward, intruder_collision=self.collision_reward,
                                   shaping=self.shaping_reward, kbar_reached=self.kbar_reward)
        from stp_env.sim.backends import vehicle_model

        inner = {} if self.control_dt is None else {"control_dt": self.control_dt, "allow_uncertified": True}
        if self.avoid_margin is not None:
            inner.update(avoid_margin=self.avoid_margin, allow_uncertified=True)
        return sim.EnvConfig(rewards=rewards, spawn_mode=self.spawn_mode, wind_model=self.wind_model,
                             vehicle_model=vehicle_model(self.backend), **inner)

    def scenario_object(self):
        from stp_env.scenarios import make

        return make(self.scenario) if self.kbar is None else make(self.scenario, kbar=self.kbar)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def evaluate_on_vec_env(predict, venv, n_episodes: int, seed: int, track=None) -> dict:
    """Run ``n_episodes`` episodes of ``predict(obs) -> actions`` on an :class:`IntruderVecEnv`, each env's
    first episode after ``venv.seed(seed + k n_envs)`` (so episode ``j`` is seeded ``seed + j``). Returns
    per-episode arrays of the final infos' ``n_forced``, ``collisions``, ``intruder_collisions``,
    ``guarantee_violations``, and ``returns``; with ``track(venv) -> (n_envs,)``, also ``tracked_min``: the
    smallest value it gave over the states each step of the episode started from."""
    from stp_env.rl.vec_env import STAT_NAMES

    n = venv.num_envs
    rows = {name: [] for name in (*STAT_NAMES, "returns", *(("tracked_min",) if track is not None else ()))}
    for start in range(0, n_episodes, n):
        venv.seed(seed + start)
        obs = venv.reset()
        finished = np.zeros(n, bool)
        returns = np.zeros(n)
        lowest = np.full(n, np.inf)
        final = [None] * n
        while not finished.all():
            if track is not None:
                lowest = np.where(finished, lowest, np.minimum(lowest, np.asarray(track(venv))))
            obs, rewards, dones, infos = venv.step(predict(obs))
            returns += np.where(finished, 0.0, rewards)
            for i in np.flatnonzero(dones & ~finished):
                final[i] = {**infos[i], "returns": returns[i], "tracked_min": lowest[i]}
            finished |= dones
        for i in range(min(n, n_episodes - start)):
            for name in rows:
                rows[name].append(final[i][name])
    return {k: np.asarray(v) for k, v in rows.items()}


def summarize(result: dict, kbar: int, *, confidence: float = 0.95) -> dict:
    """An evaluation's row (``evaluations.csv``, ``eval/*`` in the logs): the package's one episode summary
    (:func:`stp_env.evaluation.summary.forced_summary`) under the training log's names, and the mean return.
    ``episodes_above_kbar_upper`` and ``violation_episodes_upper`` are exact one-sided Clopper-Pearson bounds at
    ``confidence`` on the rates of episodes above k̄ and of episodes with a guarantee violation."""
    s = forced_summary(result["n_forced"], kbar, result["collisions"], result["guarantee_violations"],
                       confidence=confidence)
    return {
        "episodes": s["episodes"],
        "mean_n_forced": s["forced_mean"],
        "ci95_n_forced": s["forced_ci95"],
        "max_n_forced": s["forced_max"],
        "episodes_reaching_kbar": s["kbar_reached"],
        "episodes_above_kbar": s["exceed"],
        "episodes_above_kbar_upper": s["exceed_upper"],
        "collisions": s["collisions"],
        "guarantee_violations": s["guarantee_violations"],
        "violation_episodes": s["violation_episodes"],
        "violation_episodes_upper": s["violation_upper"],
        "mean_return": float(result["returns"].mean()),
    }


def _callbacks(config: TrainConfig, eval_env, out: Path, kbar: int):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

    class IntruderEvalCallback(BaseCallback):
        """Evaluates the deterministic policy every ``eval_every`` env steps on held-out seeds; logs ``eval/*``,
        appends to ``evaluations.csv`` and keeps ``best_model.zip`` (best mean ``|N^RP|``)."""

        def __init__(self):
            super().__init__()
            self.next_eval = config.eval_every if config.eval_every else math.inf
            self.best = -math.inf
            self.history: list[dict] = []

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += config.eval_every
                self.evaluate()
            return True

        def evaluate(self) -> dict:
            def predict(obs):
                return self.model.predict(obs, deterministic=True)[0]

            start = time.perf_counter()
            row = {"timesteps": self.num_timesteps,
                   **summarize(evaluate_on_vec_env(predict, eval_env, config.eval_episodes, config.eval_seed),
                               kbar),
                   "seconds": round(time.perf_counter() - start, 2)}
            for key, value in row.items():
                if key != "timesteps":
                    self.logger.record(f"eval/{key}", value)
            append_csv_row(out / "evaluations.csv", row)
            if row["mean_n_forced"] > self.best:
                self.best = row["mean_n_forced"]
                self.model.save(out / "best_model")
            self.history.append(row)
            return row

    callbacks = [IntruderEvalCallback()]
    if config.checkpoint_every:
        callbacks.append(CheckpointCallback(save_freq=max(config.checkpoint_every // config.n_envs, 1),
                                            save_path=str(out / "checkpoints"), name_prefix="intruder"))
    return callbacks


def learning_curves(history, out, kbar: int) -> Path | None:
    """``out/learning_curves.png`` from a run's held-out evaluations (the rows of ``evaluations.csv``): the mean
    ``|N^RP|`` with its 95 % interval, and the share of episodes reaching k̄ with its Clopper-Pearson interval,
    against the training steps (a cloned start is the point at 0 steps). ``None`` without evaluations."""
    if not history:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stp_env.evaluation.stats import clopper_pearson_interval
    from stp_env.files import atomic_open

    steps = np.asarray([r["timesteps"] for r in history], float)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    ax = axes[0]
    mean = np.asarray([r["mean_n_forced"] for r in history])
    half = np.asarray([r["ci95_n_forced"] for r in history])  # the normal interval's half-width
    ax.plot(steps, mean, "o-", label="mean |N^RP|")
    ax.fill_between(steps, mean - half, mean + half, alpha=0.25, label="95 % interval")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("vehicles forced per held-out episode")
    ax.legend(loc="lower right")
    ax = axes[1]
    rate = np.asarray([r["episodes_reaching_kbar"] / r["episodes"] for r in history])
    bounds = np.asarray([clopper_pearson_interval(r["episodes_reaching_kbar"], r["episodes"]) for r in history])
    ax.plot(steps, 100 * rate, "o-", label=f"episodes reaching k̄ = {kbar}")
    ax.fill_between(steps, 100 * bounds[:, 0], 100 * bounds[:, 1], alpha=0.25, label="95 % interval")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("% of held-out episodes")
    ax.legend(loc="lower right")
    fig.suptitle(f"{Path(out).name}: held-out evaluations during training")
    fig.tight_layout()
    target = Path(out) / "learning_curves.png"
    with atomic_open(target, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return target


def build_params(config: TrainConfig, *, store=None, progress: bool = False) -> sim.EnvParams:
    """The training environment's ``EnvParams``: the scenario's, with the relative buffer table ``V^B`` of its k̄
    when the vehicles play the buffer game (``worst``), the observation reads it (``"game"``) or the clone's
    teacher does (``optimal-max-k``)."""

    scenario = config.scenario_object()
    params = assembly.params_for(scenario, config.env_config(), store=store, progress=progress)
    return requirements.with_required_tables(params, scenario, vehicle_policy=config.vehicle_policy,
                                             intruder=config.clone, observation=config.observation,
                                             kbar=int(params.intruder.kbar), store=store, progress=progress)


def train(config: TrainConfig, *, params: sim.EnvParams | None = None):
    """Train an intruder with Stable-Baselines3 (see the module docstring). ``params``: prebuilt :class:`EnvParams`
    (must match the config's scenario and rewards; used by tests to skip the build). Returns ``(model,
    eval_history)``. (:func:`stp_env.rl.trainers.train` runs either trainer by ``config.trainer``.)"""
    if config.trainer != "sb3":
        raise ValueError(f"stp_env.rl.train.train is the SB3 trainer; trainer {config.trainer!r} runs with "
                         "stp_env.rl.trainers.train.")
    import torch
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecMonitor

    from stp_env.policies.learned import export_mlp
    from stp_env.rl.vec_env import IntruderVecEnv

    torch.set_num_threads(config.torch_threads)
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / "evaluations.csv").exists():
        (out / "evaluations.csv").unlink()
    # the device count the training batch is shared among: another count is another compiled program (the same
    # training only to rounding), as the evaluation records it
    write_text(json.dumps({**config.to_json(), "devices": engine.shares(config.n_envs)}, indent=2),
               out / "config.json")
    if params is None:
        params = build_params(config)
    env_kwargs = {"params": params, "horizon": config.horizon, "vehicle_policy": config.vehicle_policy,
                  "observation": config.observation}
    venv = VecMonitor(IntruderVecEnv(config.n_envs, **env_kwargs),
                      info_keywords=("n_forced", "collisions", "guarantee_violations"))
    eval_env = IntruderVecEnv(config.n_envs, **env_kwargs)
    kbar = int(params.intruder.kbar)
    model = make_model(config, venv)
    model.set_logger(configure(str(out), list(config.log_formats)))
    callbacks = _callbacks(config, eval_env, out, kbar)
    clone = None
    if config.clone is not None:
        from stp_env.policies import INTRUDERS
        from stp_env.rl.imitation import clone_intruder

        clone = clone_intruder(model, IntruderVecEnv(config.n_envs, **env_kwargs), INTRUDERS[config.clone],
                               n_steps=config.clone_steps, dagger_rounds=config.clone_rounds,
                               epochs=config.clone_epochs, gamma=config.gamma, seed=config.seed)
        clone["teacher"] = config.clone
        callbacks[0].init_callback(model)
        callbacks[0].evaluate()  # the clone, before PPO: timesteps 0 in evaluations.csv
    total = config.trained_timesteps
    if total != config.total_timesteps:
        from stp_env.progress import note

        note(f"train-intruder: {config.total_timesteps} timesteps rounded up to {total}, whole rollouts of n_envs x "
             f"n_steps = {config.n_envs} x {config.n_steps} = {config.n_envs * config.n_steps} steps", True)
    start = time.perf_counter()
    model.learn(total_timesteps=total, callback=callbacks)
    final = callbacks[0].evaluate()
    final["train_seconds"] = round(time.perf_counter() - start, 1)
    model.save(out / "model")
    export_mlp(model, out / "intruder.npz", metadata={
        "scenario": config.scenario, "kbar": kbar, "horizon": config.horizon, "seed": config.seed,
        "vehicle_policy": config.vehicle_policy, "spawn_mode": config.spawn_mode, "wind_model": config.wind_model,
        "backend": config.backend, "control_dt": config.control_dt, "avoid_margin": config.avoid_margin,
        "kbar_reward": config.kbar_reward, "total_timesteps": int(model.num_timesteps),
        "requested_timesteps": config.total_timesteps,
        "observation": config.observation, "clone": clone, "final_eval": {k: v for k, v in final.items()}})
    learning_curves(callbacks[0].history, out, kbar)
    venv.close()
    eval_env.close()
    return model, callbacks[0].history
