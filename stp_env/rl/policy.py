"""A trained intruder as a jittable policy ``(key, state, params) -> (2,)`` of the simulation core.

An SB3 ``ActorCriticPolicy`` (PPO/A2C with a Box action space, an MLP on the flat observation) is exported to a
small ``.npz`` of numpy weights (:func:`export_mlp`; needs torch). :func:`load_mlp` / :func:`mlp_intruder` read it
back with numpy only and evaluate the deterministic action (the Gaussian mean, clipped to ``[-1, 1]``, as
``model.predict(obs, deterministic=True)``) in JAX on :func:`stp_env.sim.observe`'s intruder row, so a learned
intruder runs inside :func:`stp_env.sim.rollout` and the evaluation library like any scripted one.

Shipped intruders: :func:`load_intruder` ``("town-kbar2")`` (``stp_env/data/intruders/``; the SB3 model is the
``.zip`` beside it; reproduced by ``python scripts/train_intruder.py train --ship``: PPO, 4.2 M steps, seed 0, a
64 x 64 tanh MLP). Over 1,000 held-out ``town`` episodes (``scripts/train_intruder.py compare``: full core
episodes, vehicles on ``switching`` with the HJ filter, default ``EnvConfig``) it forces on average 0.528 vehicles
(95 % interval 0.497-0.559), against 0.048 (0.035-0.061) for the random-Bezier intruder ``bezier3``, 0.508
(0.477-0.539) for ``greedy`` and 0.488 (0.457-0.519) for the HJ strategy ``max-k``; at most 1 vehicle (k̄ = 2), no
collision, no guarantee violation.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from importlib import resources
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stp_env.sim.core import intruder_observation_size, observe

ACTIVATIONS = {"tanh": jnp.tanh, "relu": lambda x: jnp.maximum(x, 0.0)}
FORMAT_VERSION = 1


@dataclasses.dataclass(frozen=True)
class MLPIntruder:
    """Weights of a deterministic MLP intruder: ``hidden`` ``(W, b)`` pairs with ``activation``, then the action
    layer. ``W`` is ``(out, in)`` (torch's layout). ``metadata``: how it was trained (JSON-able)."""

    hidden: tuple[tuple[np.ndarray, np.ndarray], ...]
    action: tuple[np.ndarray, np.ndarray]
    activation: str
    metadata: dict

    @property
    def obs_size(self) -> int:
        first = self.hidden[0][0] if self.hidden else self.action[0]
        return int(first.shape[1])

    def action_numpy(self, obs: np.ndarray) -> np.ndarray:
        """The same function in numpy (for checks against SB3's ``predict``)."""
        act = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}[self.activation]
        h = np.asarray(obs, np.float32)
        for w, b in self.hidden:
            h = act(h @ w.T + b)
        return np.clip(h @ self.action[0].T + self.action[1], -1.0, 1.0)


def export_mlp(model, path, metadata: dict | None = None) -> Path:
    """Write the deterministic actor of an SB3 ``ActorCriticPolicy`` model to ``path`` (``.npz``)."""
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy = model.policy
    if not isinstance(policy, ActorCriticPolicy):
        raise ValueError(f"export_mlp needs an ActorCriticPolicy (PPO, A2C); got {type(policy).__name__}.")
    if not isinstance(policy.pi_features_extractor, FlattenExtractor) or policy.squash_output:
        raise ValueError("export_mlp supports a flat MLP actor without squashing only.")
    layers = list(policy.mlp_extractor.policy_net)
    linear = [m for m in layers if isinstance(m, torch.nn.Linear)]
    acts = {type(m).__name__ for m in layers if not isinstance(m, torch.nn.Linear)}
    names = {"Tanh": "tanh", "ReLU": "relu"}
    if len(acts) > 1 or not acts <= set(names) or len(layers) != 2 * len(linear):
        raise ValueError(f"export_mlp supports Linear + one activation (Tanh or ReLU); got {layers}.")
    arrays = {}
    for i, m in enumerate([*linear, policy.action_net]):
        arrays[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float32)
        arrays[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float32)
    meta = {"format_version": FORMAT_VERSION, "activation": names[acts.pop()] if acts else "tanh",
            "n_layers": len(linear) + 1, **(metadata or {})}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, metadata=np.asarray(json.dumps(meta, sort_keys=True)), **arrays)
    return path


def load_mlp(path) -> MLPIntruder:
    """Read an :func:`export_mlp` file (numpy only)."""
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["metadata"]))
        if meta.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"{path}: format version {meta.get('format_version')!r}, expected {FORMAT_VERSION}.")
        pairs = [(data[f"w{i}"], data[f"b{i}"]) for i in range(meta["n_layers"])]
    if meta["activation"] not in ACTIVATIONS:
        raise ValueError(f"{path}: unknown activation {meta['activation']!r}.")
    return MLPIntruder(hidden=tuple(pairs[:-1]), action=pairs[-1], activation=meta["activation"], metadata=meta)


def mlp_intruder(mlp: MLPIntruder, name: str = "learned"):
    """A jittable intruder policy ``(key, state, params) -> (2,)``: the MLP's deterministic action on the
    intruder observation. Raises ``ValueError`` (at trace time) if ``params`` gives another observation size."""
    act = ACTIVATIONS[mlp.activation]
    hidden = [(jnp.asarray(w), jnp.asarray(b)) for w, b in mlp.hidden]
    w_out, b_out = jnp.asarray(mlp.action[0]), jnp.asarray(mlp.action[1])

    def policy(key, state, params):
        del key
        size = intruder_observation_size(params)
        if size != mlp.obs_size:
            raise ValueError(f"The intruder MLP takes {mlp.obs_size} observations but these params give {size} "
                             "(n_nearest differs from training).")
        h = observe(state, params)[1].astype(jnp.float32)
        for w, b in hidden:
            h = act(w @ h + b)
        return jnp.clip(w_out @ h + b_out, -1.0, 1.0)

    policy.__name__ = name
    return policy


def shipped_intruders() -> list[str]:
    folder = resources.files("stp_env") / "data" / "intruders"
    return sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".npz")) if folder.is_dir() else []


@functools.cache
def load_intruder(name_or_path: str = "town-kbar2"):
    """A shipped learned intruder by name (see :func:`shipped_intruders`) or an :func:`export_mlp` file, as a
    jittable policy. Cached, so that repeated loads reuse one function (and its compiled rollouts)."""
    path = Path(name_or_path)
    if path.suffix != ".npz":
        if name_or_path not in shipped_intruders():
            raise ValueError(f"unknown intruder {name_or_path!r}; shipped: {', '.join(shipped_intruders())} "
                             "(or pass the path of an .npz from export_mlp).")
        path = Path(str(resources.files("stp_env") / "data" / "intruders" / f"{name_or_path}.npz"))
    return mlp_intruder(load_mlp(path), name=f"learned:{path.stem}")
