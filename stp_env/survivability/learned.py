"""A learned planning policy for the mission environment (:mod:`stp_env.survivability.gym_env`): an SB3 PPO
actor exported to numpy weights (:func:`stp_env.policies.learned.export_mlp`, an ``.npz`` read with
``allow_pickle=False``), evaluated with numpy only: the action is the argmax of the actor's logits.

The shipped policy (``stp_env/data/survivability/ppo.npz``) is trained and compared with ``pi_S`` and ``pi_Nf`` by
``python examples/survivability_ppo.py`` (see the script and ``docs/survivability.md``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from stp_env.policies.learned import MLPIntruder, load_mlp

SHIPPED = "ppo"


class DiscretePolicy:
    """Deterministic actions of an exported actor: ``argmax`` of its logits (as ``model.predict(obs,
    deterministic=True)`` for a ``Discrete`` action space). An actor trained with action masking (metadata
    ``"action_masking": true``, sb3-contrib's ``MaskablePPO``) takes the argmax over the valid primitives only, read
    from the observation's per-primitive valid flags (:mod:`stp_env.survivability.gym_env`), as ``predict`` does
    with ``action_masks``; with no valid primitive (the episode is over) it takes the plain argmax."""

    def __init__(self, mlp: MLPIntruder):
        self.mlp = mlp
        self.act = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}[mlp.activation]
        self.masked = bool(mlp.metadata.get("action_masking", False))

    @property
    def obs_size(self) -> int:
        return self.mlp.obs_size

    def logits(self, obs) -> np.ndarray:
        h = np.asarray(obs, np.float32)
        for w, b in self.mlp.hidden:
            h = self.act(h @ w.T + b)
        return h @ self.mlp.action[0].T + self.mlp.action[1]

    def valid(self, obs) -> np.ndarray:
        """The valid flags of the observation's primitives, ``(A,)`` bool."""
        from stp_env.survivability.gym_env import N_ACTION_FEATURES, N_STATE_FEATURES

        n = self.mlp.action[1].shape[0]
        flags = np.asarray(obs, np.float32)[N_STATE_FEATURES:N_STATE_FEATURES + N_ACTION_FEATURES * n]
        return flags[::N_ACTION_FEATURES] > 0.5

    def __call__(self, obs) -> int:
        z = self.logits(obs)
        if self.masked:
            ok = self.valid(obs)
            if ok.any():
                z = np.where(ok, z, -np.inf)
        return int(np.argmax(z))


def load_policy(name_or_path: str = SHIPPED, n_actions: int = 25) -> DiscretePolicy:
    """The shipped policy (``"ppo"``) or an exported ``.npz``, for a mission with ``n_actions`` motion primitives
    (25 on the paper's network): its action layer must have ``n_actions`` outputs and its input layer the
    environment's observation size (:func:`stp_env.survivability.gym_env.observation_size`)."""
    from stp_env.survivability.gym_env import observation_size

    path = Path(name_or_path)
    if path.suffix != ".npz":
        if name_or_path != SHIPPED:
            raise ValueError(f"unknown policy {name_or_path!r}; shipped: {SHIPPED!r} (or the path of an .npz).")
        path = Path(str(resources.files("stp_env") / "data" / "survivability" / f"{SHIPPED}.npz"))
        if not path.exists():
            raise ValueError(f"no policy is shipped in this installation ({path} is missing); train one with "
                             "'python examples/survivability_ppo.py train --ship' or pass the path of an .npz.")
    if not path.exists():
        raise ValueError(f"{path} does not exist.")
    policy = DiscretePolicy(load_mlp(path, n_outputs=n_actions))
    if policy.obs_size != observation_size(n_actions):
        raise ValueError(f"{path}: the policy takes {policy.obs_size} observations; the mission environment with "
                         f"{n_actions} primitives gives {observation_size(n_actions)}.")
    return policy
