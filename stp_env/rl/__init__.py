"""Learned intruders: the intruder's single-agent view of the core for Gymnasium and Stable-Baselines3.

* :class:`IntruderEnv` (:mod:`stp_env.rl.gym_env`): a Gymnasium env of the intruder; the vehicles run a baseline
  policy (``switching`` = ``u*`` with the HJ safety filter, eq. 38) inside the core.
* :class:`IntruderVecEnv` (:mod:`stp_env.rl.vec_env`): a native SB3 ``VecEnv`` of ``n`` of them, one compiled JAX
  program per step (auto-reset included).
* :mod:`stp_env.rl.train`: ``TrainConfig`` and ``train`` (PPO by default), the evaluation callback;
  :mod:`stp_env.rl.ppo`: the PPO settings every training configuration shares, and the model they make;
  :mod:`stp_env.rl.jax_vec_env`: the base of the batched JAX ``VecEnv``s.
* :mod:`stp_env.policies.learned`: a trained MLP as a jittable intruder policy
  ``(key, state, params) -> (2,)`` (``load_intruder("town-kbar2")`` for the shipped one).

The functional layer (:mod:`stp_env.rl.functional`) needs only JAX; the env classes need ``gymnasium`` and
``stable-baselines3`` (the ``rl`` extra).
"""

from __future__ import annotations

__all__ = ["HORIZONS", "IntruderEnv", "IntruderVecEnv", "key_for_seed"]


def __getattr__(name):
    # Everything on first use: importing the package (its command line, stp_env.rl.cli, for --help) imports no JAX.
    if name in ("HORIZONS", "key_for_seed"):
        from stp_env.rl import functional
        return getattr(functional, name)
    if name == "IntruderEnv":
        from stp_env.rl.gym_env import IntruderEnv
        return IntruderEnv
    if name == "IntruderVecEnv":
        from stp_env.rl.vec_env import IntruderVecEnv
        return IntruderVecEnv
    raise AttributeError(f"module 'stp_env.rl' has no attribute {name!r}")
