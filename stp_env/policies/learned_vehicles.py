"""A trained vehicle policy as a jittable vehicle policy ``(key, state, params) -> (N, 2)``, inside the HJ filters.

The file format is the learned intruders' (:func:`stp_env.policies.learned.export_mlp`: numpy weights, nothing
unpickled) with ``metadata["role"] == "vehicle"``: one MLP shared by every vehicle (parameter sharing), applied to
each vehicle's row of :func:`stp_env.sim.observe` (the deterministic action, the Gaussian mean clipped to
``[-1, 1]``). ``vehicle_policy("learned:NAME")`` wraps it in :func:`stp_env.policies.vehicles.hj_filter`: ``kappa`` on
the plan wherever the tracking tube leaves no room, ``u^A`` while forced (eq. 38); the learned action elsewhere
(after an avoidance, where the paper replans: Algorithm 4). ``stp-env evaluate --vehicle-policy learned:NAME`` and
every runner that takes a vehicle policy by name load it (:func:`stp_env.policies.vehicles.vehicle_policy`).

Shipped policies (``stp_env/data/vehicles/``): ``crossing-after-avoidance`` (``docs/learned_vehicles.md``: how it
was trained, what it improves over ``u*`` and what it does not guarantee).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import jax.numpy as jnp

from stp_env.policies.learned import ACTIVATIONS, MLPIntruder, load_mlp

ROLE = "vehicle"


def mlp_vehicles(mlp: MLPIntruder, name: str = "learned"):
    """The MLP's deterministic action on every vehicle's observation row, ``(N, 2)`` (no filter). Raises
    ``ValueError`` (at trace time) if ``params`` gives another observation size than the MLP takes."""
    from stp_env.sim import observations

    act = ACTIVATIONS[mlp.activation]
    hidden = [(jnp.asarray(w), jnp.asarray(b)) for w, b in mlp.hidden]
    w_out, b_out = jnp.asarray(mlp.action[0]), jnp.asarray(mlp.action[1])

    def policy(key, state, params):
        del key
        h = observations.observe(state, params)[0]
        if h.shape[1] != mlp.obs_size:
            raise ValueError(f"The vehicle MLP takes {mlp.obs_size} observations but these params give "
                             f"{h.shape[1]} (n_nearest differs from training).")
        for w, b in hidden:
            h = act(h @ w.T + b)
        return jnp.clip(h @ w_out.T + b_out, -1.0, 1.0)

    policy.__name__ = name
    return policy


def shipped_vehicle_policies() -> list[str]:
    folder = resources.files("stp_env") / "data" / "vehicles"
    return sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".npz")) if folder.is_dir() else []


def load_vehicle_mlp(name_or_path: str) -> MLPIntruder:
    """The MLP of a shipped vehicle policy (by name) or of an ``.npz`` file, checked to be a vehicle policy."""
    if not isinstance(name_or_path, str):
        raise ValueError(f"a learned vehicle policy is a shipped name or an .npz path; got {name_or_path!r}.")
    path = Path(name_or_path)
    if path.suffix != ".npz":
        if name_or_path not in shipped_vehicle_policies():
            shipped = ", ".join(shipped_vehicle_policies()) or "none"
            raise ValueError(f"unknown learned vehicle policy {name_or_path!r}; shipped: {shipped} (or pass the "
                             "path of an .npz written by examples/train_vehicle_policy.py).")
        path = Path(str(resources.files("stp_env") / "data" / "vehicles" / f"{name_or_path}.npz"))
    mlp = load_mlp(path)
    if mlp.metadata.get("role") != ROLE:
        raise ValueError(f"{path}: not a vehicle policy (metadata role {mlp.metadata.get('role')!r}; a learned "
                         "intruder is passed as an intruder: --intruder learned:NAME).")
    return mlp
