"""A trained intruder as a jittable policy ``(key, state, params) -> (2,)`` of the simulation core.

An SB3 ``ActorCriticPolicy`` (PPO/A2C with a Box action space, an MLP on the flat observation) is exported to a
small ``.npz`` of numpy weights (:func:`export_mlp`; needs torch). :func:`load_mlp` / :func:`mlp_intruder` read it
back with numpy only and evaluate the deterministic action (the Gaussian mean, clipped to ``[-1, 1]``, as
``model.predict(obs, deterministic=True)``) in JAX on :func:`stp_env.sim.observe`'s intruder row, so a learned
intruder runs inside :func:`stp_env.sim.rollout` and the evaluation library like any scripted one.

Shipped intruders (``stp_env/data/intruders/``): :func:`load_intruder` ``("town-kbar2")`` (the SB3 model is the
``.zip`` beside it; reproduced by ``python examples/train_intruder.py train --ship``: a clone of ``optimal-max-k`` on
the core observation, then 524,288 PPO steps, seed 0, a 64 x 64 tanh MLP). Over 1,000 held-out ``town`` episodes
(``stp-env evaluate --scenario town --kbar 2 --spawn-mode outside --intruder learned:town-kbar2 optimal-max-k greedy
max-k bezier3 --episodes 1000 --seed 20240601``, vehicles on ``switching`` with the HJ filter) it forces on average
0.520 vehicles, against 0.519 for the earlier shipped policy (PPO from scratch, 4.2 M steps), 0.511 for
``optimal-max-k``, 0.504 for ``greedy``, 0.489 for ``max-k`` and 0.047 for the random-Bezier ``bezier3`` (95 %
half-widths 0.031; 0.013 for ``bezier3``); at most 1 vehicle (k̄ = 2), no collision, no guarantee violation.
``"crossing-kbar2"`` and ``"pinwheel-kbar3"``: clones of ``optimal-max-k`` on the ``"game"`` observation
(:mod:`stp_env.policies.observations`) with PPO after them, as strong as the script on 5,000 held-out episodes each
(model cards and the evaluation: ``docs/learned_intruders.md``); ``"crossing-kbar2-scratch"`` and
``"pinwheel-kbar3-scratch"``: PPO in JAX from a random network (no clone): as strong as the script on the crossing,
stronger on the pinwheel. Their files record a small check that ``tests/test_learned_intruders.py`` replays.

A file records the observation set it was trained on (``metadata["observation"]``, ``"core"`` when absent) and the
spawn mode it was trained with; :func:`load_intruder` returns an :class:`~stp_env.policies.intruders.Intruder`
record that says so (``tables=("buffer",)`` for the game observation), so every runner loads ``V^B`` for it.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from importlib import resources
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stp_env.files import atomic_open
from stp_env.loaders import LoadError, parse_json, read_npz
from stp_env.policies.observations import (
    OBSERVATION_TABLES,
    OBSERVATIONS,
    intruder_observation,
    observation_size,
)

ACTIVATIONS = {"tanh": jnp.tanh, "relu": lambda x: jnp.maximum(x, 0.0)}
FORMAT_VERSION = 1
MAX_LAYERS = 64


@dataclasses.dataclass(frozen=True)
class MLPIntruder:
    """Weights of a deterministic MLP intruder: ``hidden`` ``(W, b)`` pairs with ``activation``, then the action
    layer. ``W`` is ``(out, in)`` (torch's layout). ``metadata``: how it was trained (JSON-able)."""

    hidden: tuple[tuple[np.ndarray, np.ndarray], ...]
    action: tuple[np.ndarray, np.ndarray]
    activation: str
    metadata: dict

    @property
    def observation(self) -> str:
        """The observation set it was trained on (:mod:`stp_env.policies.observations`; ``"core"`` if unrecorded)."""
        return self.metadata.get("observation", "core")

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
    """Write the deterministic actor of an SB3 ``ActorCriticPolicy`` model (or of sb3-contrib's maskable one: the
    same layers) to ``path`` (``.npz``)."""
    import torch
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy = model.policy
    if not isinstance(policy, ActorCriticPolicy) and type(policy).__name__ != "MaskableActorCriticPolicy":
        raise ValueError(f"export_mlp needs an ActorCriticPolicy (PPO, A2C, sb3-contrib's MaskablePPO); got "
                         f"{type(policy).__name__}.")
    if not isinstance(policy.pi_features_extractor, FlattenExtractor) or policy.squash_output:
        raise ValueError("export_mlp supports a flat MLP actor without squashing only.")
    layers = list(policy.mlp_extractor.policy_net)
    linear = [m for m in layers if isinstance(m, torch.nn.Linear)]
    acts = {type(m).__name__ for m in layers if not isinstance(m, torch.nn.Linear)}
    names = {"Tanh": "tanh", "ReLU": "relu"}
    if len(acts) > 1 or not acts <= set(names) or len(layers) != 2 * len(linear):
        raise ValueError(f"export_mlp supports Linear + one activation (Tanh or ReLU); got {layers}.")
    layers = [(m.weight.detach().cpu().numpy(), m.bias.detach().cpu().numpy()) for m in [*linear, policy.action_net]]
    return write_mlp(layers, path, names[acts.pop()] if acts else "tanh", metadata)


def write_mlp(layers, path, activation: str = "tanh", metadata: dict | None = None) -> Path:
    """Write an MLP's ``[(W, b), ...]`` layers (``W`` ``(out, in)``; the last one the action layer, no activation)
    to ``path`` (``.npz``, this module's format): what :func:`export_mlp` writes for an SB3 model and the JAX trainer
    (:mod:`stp_env.rl.jax_train`) for its own."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; allowed: {', '.join(ACTIVATIONS)}.")
    arrays = {}
    for i, (w, b) in enumerate(layers):
        arrays[f"w{i}"] = np.asarray(w, np.float32)
        arrays[f"b{i}"] = np.asarray(b, np.float32)
    meta = {"format_version": FORMAT_VERSION, "activation": activation, "n_layers": len(layers), **(metadata or {})}
    path = Path(path)
    if path.suffix != ".npz":  # as np.savez names it
        path = path.with_name(path.name + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as fh:
        np.savez(fh, metadata=np.asarray(json.dumps(meta, sort_keys=True)), **arrays)
    return path


def load_mlp(path, n_outputs: int = 2) -> MLPIntruder:
    """Read an :func:`export_mlp` file (numpy only, nothing unpickled: reading it never runs code).

    Everything is checked before the policy is built: the loader contract (:func:`stp_env.loaders.read_npz`: a
    regular file of at most 256 MiB whose arrays decompress to at most 1 GiB), the metadata (a JSON object, nested
    at most 64 levels, with this module's format version, a known activation and ``n_layers``), every layer's
    weights ``w{i}`` ``(out, in)`` and bias ``b{i}`` ``(out,)`` as real arrays whose shapes chain, an action layer of
    ``n_outputs`` outputs (2 for an intruder's action; other users of the format, e.g. a discrete policy's logits,
    pass their own), and finite values (a NaN weight would give the intruder a NaN action, and a NaN state, in every
    episode). Any problem is a ``ValueError`` naming the file and what is wrong."""
    arrays = read_npz(path, "learned-policy")
    return _mlp_from_arrays(arrays, path, n_outputs)


def _mlp_from_arrays(arrays: dict, path, n_outputs: int = 2) -> MLPIntruder:
    def bad(what):
        return ValueError(f"{path}: not a valid learned-intruder file: {what}.")

    raw = arrays.get("metadata")
    if raw is None or raw.shape != () or raw.dtype.kind != "U":
        raise bad("no 'metadata' string")
    try:
        meta = parse_json(str(raw), path, "learned-intruder file's metadata")
    except LoadError as err:
        raise bad(err.problem.rstrip(".")) from None
    if not isinstance(meta, dict):
        raise bad(f"metadata is a JSON {type(meta).__name__}, not an object")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: format version {meta.get('format_version')!r}, expected {FORMAT_VERSION}.")
    activation, n_layers = meta.get("activation"), meta.get("n_layers")
    if not isinstance(activation, str) or activation not in ACTIVATIONS:
        raise ValueError(f"{path}: unknown activation {activation!r}; allowed: {', '.join(ACTIVATIONS)}.")
    if isinstance(n_layers, bool) or not isinstance(n_layers, int) or not 1 <= n_layers <= MAX_LAYERS:
        raise bad(f"n_layers must be an integer in [1, {MAX_LAYERS}]; got {n_layers!r}")
    expected = {"metadata"} | {f"{p}{i}" for i in range(n_layers) for p in "wb"}
    missing, extra = sorted(expected - set(arrays)), sorted(set(arrays) - expected)
    if missing or extra:
        raise bad(f"arrays {missing} missing, {extra} unexpected for {n_layers} layer(s)")
    pairs = []
    width = None
    for i in range(n_layers):
        w, b = arrays[f"w{i}"], arrays[f"b{i}"]
        for name, a, ndim in ((f"w{i}", w, 2), (f"b{i}", b, 1)):
            if a.dtype.kind != "f" or a.ndim != ndim or 0 in a.shape:
                raise bad(f"{name} must be a non-empty {ndim}-D float array; got dtype {a.dtype}, shape {a.shape}")
            if not np.all(np.isfinite(a.astype(np.float32))):  # as evaluated: 1e300 is finite, not in float32
                raise bad(f"{name} has {int(np.sum(~np.isfinite(a.astype(np.float32))))} non-finite value(s) (NaN or "
                          "inf, or beyond float32)")
        if b.shape[0] != w.shape[0] or (width is not None and w.shape[1] != width):
            raise bad(f"layer {i}: w{i} {w.shape} and b{i} {b.shape} do not follow the previous layer's "
                      f"{width} outputs")
        width = w.shape[0]
        pairs.append((w.astype(np.float32), b.astype(np.float32)))
    if meta.get("observation", "core") not in OBSERVATIONS:
        raise bad(f"unknown observation set {meta.get('observation')!r}; allowed: {', '.join(OBSERVATIONS)}")
    if width != n_outputs:
        what = "an intruder action has 2 (speed, turn rate)" if n_outputs == 2 else f"expected {n_outputs}"
        raise bad(f"the action layer has {width} outputs; {what}")
    return MLPIntruder(hidden=tuple(pairs[:-1]), action=pairs[-1], activation=activation, metadata=meta)


def mlp_intruder(mlp: MLPIntruder, name: str = "learned"):
    """A jittable intruder policy ``(key, state, params) -> (2,)``: the MLP's deterministic action on the
    intruder observation of the set it was trained on (:attr:`MLPIntruder.observation`). Raises ``ValueError`` (at
    trace time) if ``params`` gives another observation size."""
    act = ACTIVATIONS[mlp.activation]
    observation = mlp.observation
    hidden = [(jnp.asarray(w), jnp.asarray(b)) for w, b in mlp.hidden]
    w_out, b_out = jnp.asarray(mlp.action[0]), jnp.asarray(mlp.action[1])

    def policy(key, state, params):
        del key
        size = observation_size(params, observation)
        if size != mlp.obs_size:
            raise ValueError(f"The intruder MLP takes {mlp.obs_size} observations but these params give {size} "
                             "(n_nearest differs from training).")
        h = intruder_observation(state, params, observation)
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
    """A shipped learned intruder by name (see :func:`shipped_intruders`), an :func:`export_mlp` file, or a training
    run's directory (its ``intruder.npz``), as a jittable policy. Cached, so that repeated loads reuse one function
    (and its compiled rollouts)."""
    if not isinstance(name_or_path, str):
        raise ValueError(f"a learned intruder is a shipped name or an .npz path; got {name_or_path!r}.")
    path = Path(name_or_path)
    if path.is_dir():  # a training run's directory (stp-env train-intruder --out DIR): its exported policy
        if not (path / "intruder.npz").is_file():
            raise ValueError(f"{name_or_path}: a directory without intruder.npz; pass a finished training run's "
                             "directory (stp-env train-intruder writes DIR/intruder.npz at the end) or the .npz.")
        path = path / "intruder.npz"
    elif path.suffix == ".zip":
        exported = path.parent / "intruder.npz"
        hint = (f"use {exported} (or the directory {path.parent})" if exported.is_file()
                else "use the intruder.npz that stp-env train-intruder writes beside it at the end of training")
        raise ValueError(f"{name_or_path}: a Stable-Baselines3 model archive is not loaded (it is pickled code); "
                         f"{hint}.")
    if path.suffix != ".npz":
        if name_or_path not in shipped_intruders():
            raise ValueError(f"unknown intruder {name_or_path!r}; shipped: {', '.join(shipped_intruders())} "
                             "(or pass the path of an .npz from export_mlp).")
        path = Path(str(resources.files("stp_env") / "data" / "intruders" / f"{name_or_path}.npz"))
    mlp = load_mlp(path)
    if mlp.metadata.get("role", "intruder") != "intruder":
        raise ValueError(f"{path}: not an intruder (metadata role {mlp.metadata.get('role')!r}; a learned vehicle "
                         "policy is passed as --vehicle-policy learned:NAME).")
    return learned_record(mlp, name=f"learned:{path.stem}")


def learned_record(mlp: MLPIntruder, name: str = "learned"):
    """The :class:`~stp_env.policies.intruders.Intruder` record of a learned intruder: its policy
    (:func:`mlp_intruder`), the tables it reads (its observation set's: ``V^B`` for ``"game"``) and where it
    appears when the configuration leaves it open (where it was trained to: ``metadata["spawn_mode"]``, else
    outside)."""
    from stp_env.policies.record import Intruder
    from stp_env.sim.types import SPAWN_MODES

    spawn = mlp.metadata.get("spawn_mode", "outside")
    return Intruder(mlp_intruder(mlp, name=name), tables=OBSERVATION_TABLES.get(mlp.observation, ()),
                    spawn=spawn if spawn in SPAWN_MODES else "outside",
                    description=f"learned ({mlp.observation} observation)")
