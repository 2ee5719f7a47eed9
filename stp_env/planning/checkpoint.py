"""Checkpoints of sequential planning: the plans of the vehicles planned so far, so that a long run resumes.

Sequential planning (:func:`stp_env.planning.stp.plan_rtt`) plans vehicles in priority order, each against the
nominal trajectories of those before it, so the first ``k`` vehicles' plans are all it needs to go on with vehicle
``k + 1``. A checkpoint is one ``.npz`` file holding those plans (trajectories padded with NaN, lengths kept) and a
key: a hash of every input of the planning problem and of the planner's code version
(:data:`stp_env.artifacts.CODE_VERSION`). It is rewritten atomically after every vehicle (a temporary file in the
same directory, then a rename), so an interrupted run leaves the last complete prefix; it is read with
``allow_pickle=False``. Resuming with a checkpoint of another problem is refused: silently mixing plans would break
the sequential guarantee.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from stp_env.planning.plan import SinglePlan

FORMAT = 1


class CheckpointMismatchError(ValueError):
    """The checkpoint file belongs to another planning problem (other inputs or other planner code)."""


def problem_key(*parts) -> str:
    """A hash of the planning inputs: numbers, strings, arrays (by dtype, shape and bytes), nested sequences and
    dicts, and anything else by ``repr`` (frozen dataclasses such as dynamics and solver settings)."""
    from stp_env.artifacts import CODE_VERSION

    h = hashlib.sha256(f"stp-plan-checkpoint:{FORMAT}:{CODE_VERSION}".encode())

    def feed(x):
        if isinstance(x, np.ndarray):
            h.update(f"array:{x.dtype.str}:{x.shape}:".encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif isinstance(x, dict):
            h.update(b"dict:")
            for k in sorted(x):
                feed(str(k))
                feed(x[k])
        elif isinstance(x, (list, tuple)):
            h.update(f"seq:{len(x)}:".encode())
            for item in x:
                feed(item)
        elif x is None or isinstance(x, (bool, int, float, str)):
            h.update(f"{type(x).__name__}:{x!r};".encode())
        elif hasattr(x, "__array__"):
            feed(np.asarray(x))
        else:
            h.update(f"repr:{x!r};".encode())

    for part in parts:
        feed(part)
    return h.hexdigest()


def save(path, key: str, plans: list[tuple[int, SinglePlan]]) -> None:
    """Writes the plans ``[(vehicle index, plan), ...]`` (in priority order) to ``path``, atomically."""
    path = Path(path)
    n = len(plans)
    k = max((len(p.times) for _, p in plans), default=0)
    times = np.full((n, k), np.nan)
    states = np.full((n, k, 3), np.nan)
    controls = np.full((n, k, 2), np.nan)
    for r, (_, p) in enumerate(plans):
        m = len(p.times)
        times[r, :m], states[r, :m], controls[r, :m] = p.times, p.states, p.controls
    arrays = {
        "key": np.asarray(key), "format": np.asarray(FORMAT),
        "index": np.asarray([i for i, _ in plans], np.int64).reshape(n),
        "lengths": np.asarray([len(p.times) for _, p in plans], np.int64).reshape(n),
        "times": times, "states": states, "controls": controls,
        "t_ldt": np.asarray([p.t_ldt for _, p in plans], np.float64).reshape(n),
        "sta": np.asarray([p.sta for _, p in plans], np.float64).reshape(n),
        "arrival_time": np.asarray([p.arrival_time for _, p in plans], np.float64).reshape(n),
        "n_steps": np.asarray([p.n_steps for _, p in plans], np.int64).reshape(n),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(path, key: str) -> list[tuple[int, SinglePlan]]:
    """The plans stored in ``path`` (``[]`` if it does not exist).

    Raises:
        CheckpointMismatchError: if the file was written for another problem or by other planner code.
        ValueError: if the file is not a readable checkpoint.
    """
    path = Path(path)
    if not path.exists():
        return []
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError) as err:
        raise ValueError(f"planning checkpoint {path}: not a readable .npz file ({err}).") from err
    needed = {"key", "format", "index", "lengths", "times", "states", "controls", "t_ldt", "sta", "arrival_time",
              "n_steps"}
    if not needed <= set(arrays) or int(arrays["format"]) != FORMAT:
        raise ValueError(f"planning checkpoint {path}: not a checkpoint of this format (arrays {sorted(arrays)}).")
    if str(arrays["key"]) != key:
        raise CheckpointMismatchError(
            f"planning checkpoint {path} was written for another planning problem or planner version; delete it "
            "or choose another checkpoint path.")
    plans = []
    for r, m in enumerate(arrays["lengths"]):
        plans.append((int(arrays["index"][r]), SinglePlan(
            t_ldt=float(arrays["t_ldt"][r]), sta=float(arrays["sta"][r]), times=arrays["times"][r, :m].copy(),
            states=arrays["states"][r, :m].copy(), controls=arrays["controls"][r, :m].copy(),
            arrival_time=float(arrays["arrival_time"][r]), n_steps=int(arrays["n_steps"][r]))))
    return plans
