"""One entry point for both intruder trainers: :func:`train` runs :attr:`TrainConfig.trainer`'s
(``"sb3"``: :func:`stp_env.rl.train.train`, Stable-Baselines3; ``"jax"``: :func:`stp_env.rl.jax_train.train_jax`).
``stp-env train-intruder`` and the training sweeps (:mod:`stp_env.rl.sweep`) call it."""

from __future__ import annotations

from stp_env.rl.train import TrainConfig


def train(config: TrainConfig, *, params=None, resume: bool = False):
    """``(model or policy, eval_history)`` of a training run of ``config`` (``params``: prebuilt core parameters).
    ``resume``: continue a JAX run from its checkpoint (SB3 runs do not resume)."""
    if config.trainer == "jax":
        from stp_env.rl.jax_train import train_jax

        return train_jax(config, params=params, resume=resume)
    if resume:
        raise ValueError("resume continues a JAX trainer's run (trainer='jax'); SB3 runs start afresh.")
    from stp_env.rl.train import train as train_sb3

    return train_sb3(config, params=params)
