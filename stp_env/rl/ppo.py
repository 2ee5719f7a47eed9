"""The PPO settings every training run of the package shares, and the model they make.

:class:`PPOConfig` is the base of the training configurations (the learned intruder's
:class:`stp_env.rl.train.TrainConfig`, the co-observation attacker's
:class:`stp_env.coobservation.learned.AttackerTrainConfig`): one set of names, defaults and checks for the
algorithm's settings, and one :func:`make_model` that turns them into a Stable-Baselines3 model (actor and critic of
``net_arch`` tanh layers each; imported lazily: Stable-Baselines3 is the optional ``rl`` extra).
"""

from __future__ import annotations

import dataclasses

from stp_env.arguments import check_int, check_real

ALGORITHMS = ("ppo", "a2c")


RANGES = {"learning_rate": (0.0, 1.0, True), "gamma": (0.0, 1.0, True), "gae_lambda": (0.0, 1.0, True),
          "ent_coef": (0.0, None, False), "clip_range": (0.0, None, True), "log_std_init": (-20.0, 5.0, False)}
"""``(lo, hi, lo_open)`` of every real PPO setting: the learning rate in ``(0, 1]``, the discount and GAE's lambda
in ``(0, 1]``, the entropy coefficient ``>= 0``, the clip range ``> 0``, the initial log standard deviation in
``[-20, 5]``."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class PPOConfig:
    """The algorithm's settings (unknown fields are a ``TypeError``; bad values a ``ValueError``).

    Attributes:
        algo: ``"ppo"`` or ``"a2c"`` (A2C uses ``n_steps``, ``learning_rate``, ``gamma``, ``gae_lambda``,
            ``ent_coef``).
        net_arch: hidden layer widths of actor and critic (tanh).
        total_timesteps, n_envs, n_steps (per env per rollout), batch_size, n_epochs, learning_rate, gamma,
            gae_lambda, ent_coef, clip_range: the usual PPO settings. Training runs whole rollouts of
            ``n_envs * n_steps`` env steps (:attr:`trained_timesteps`).
        log_std_init: the initial log standard deviation of the Gaussian policy's actions.
        seed: one integer for torch, SB3 and the JAX env keys; torch_threads: CPU threads for torch.
    """

    algo: str = "ppo"
    net_arch: tuple[int, ...] = (64, 64)
    total_timesteps: int = 2_000_000
    n_envs: int = 64
    n_steps: int = 128
    batch_size: int = 2048
    n_epochs: int = 10
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    clip_range: float = 0.2
    log_std_init: float = 0.0
    seed: int = 0
    torch_threads: int = 1

    def __post_init__(self) -> None:
        if self.algo not in ALGORITHMS:
            raise ValueError(f"algo {self.algo!r} is not known; allowed: {', '.join(ALGORITHMS)}.")
        for name in ("total_timesteps", "n_envs", "n_steps", "batch_size", "n_epochs", "torch_threads"):
            check_int(getattr(self, name), name, 1, None)
        check_int(self.seed, "seed", 0, None)
        for name, (lo, hi, lo_open) in RANGES.items():  # the documented range of every real setting
            check_real(getattr(self, name), name, lo, hi, lo_open=lo_open)
        object.__setattr__(self, "net_arch", tuple(self.net_arch))
        if not self.net_arch or any(isinstance(w, bool) or not isinstance(w, int) or w < 1 for w in self.net_arch):
            raise ValueError(f"net_arch must be widths >= 1; got {self.net_arch!r}.")
        if (self.n_envs * self.n_steps) % self.batch_size and self.algo == "ppo":
            raise ValueError(f"n_envs * n_steps ({self.n_envs * self.n_steps}) must be a multiple of batch_size "
                             f"({self.batch_size}).")

    @property
    def trained_timesteps(self) -> int:
        """``total_timesteps`` rounded up to whole rollouts (``n_envs * n_steps`` steps each): what PPO trains."""
        rollout = self.n_envs * self.n_steps
        return -(-self.total_timesteps // rollout) * rollout


def make_model(config: PPOConfig, venv):
    """The untrained Stable-Baselines3 model of ``config`` on ``venv`` (CPU; torch's threads are the caller's)."""
    import torch
    from stable_baselines3 import A2C, PPO

    policy_kwargs = {"net_arch": {"pi": list(config.net_arch), "vf": list(config.net_arch)},
                     "activation_fn": torch.nn.Tanh, "log_std_init": config.log_std_init}
    if config.algo == "a2c":
        return A2C("MlpPolicy", venv, n_steps=config.n_steps, learning_rate=config.learning_rate,
                   gamma=config.gamma, gae_lambda=config.gae_lambda, ent_coef=config.ent_coef,
                   policy_kwargs=policy_kwargs, seed=config.seed, device="cpu", verbose=0)
    return PPO("MlpPolicy", venv, n_steps=config.n_steps, batch_size=config.batch_size, n_epochs=config.n_epochs,
               learning_rate=config.learning_rate, gamma=config.gamma, gae_lambda=config.gae_lambda,
               ent_coef=config.ent_coef, clip_range=config.clip_range, policy_kwargs=policy_kwargs,
               seed=config.seed, device="cpu", verbose=0)
