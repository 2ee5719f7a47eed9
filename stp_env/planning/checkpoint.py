"""Checkpoints of sequential planning: the plans of the vehicles planned so far, so that a long run resumes.

Sequential planning (:func:`stp_env.planning.stp.plan_rtt`) plans vehicles in priority order, each against the
nominal trajectories of those before it, so the first ``k`` vehicles' plans are all it needs to go on with vehicle
``k + 1``. A checkpoint is one ``.npz`` file holding those plans (trajectories padded with NaN, lengths kept) and a
key: a hash of every input of the planning problem and of the planner's code version
(:data:`stp_env.artifacts.CODE_VERSION`). It is rewritten atomically after every vehicle (a temporary file in the
same directory, then a rename), so an interrupted run leaves the last complete prefix; it is read with
``allow_pickle=False``. Resuming with a checkpoint of another problem is refused: silently mixing plans would break
the sequential guarantee.

Files of :data:`FORMAT` 2 hold the trajectories losslessly packed (:func:`stp_env.planning.plan.pack_trajectories`)
and compressed: a planner integrates every trajectory to its horizon, so the padded float64 form of format 1 grew
to 14.8 MB at 50 of the bay area's 200 vehicles, where format 2 takes 1.1 MB (about 0.4 s more per save). Both are
read; :func:`convert` rewrites a file in either format with the same key and the same bits, e.g. to carry a long
run's progress to a machine whose planner code writes the other.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from stp_env.planning.plan import SinglePlan, pack_trajectories, unpack_trajectories

FORMAT = 2
FORMATS = (1, 2)  # the file formats read and written (1: padded float64 trajectories, uncompressed)
KEY_FORMAT = 1  # part of the key; the file format is not (a converted file keeps its key)


class CheckpointMismatchError(ValueError):
    """The checkpoint file belongs to another planning problem (other inputs or other planner code)."""


def problem_key(*parts) -> str:
    """A hash of the planning inputs: numbers, strings, arrays (by dtype, shape and bytes), nested sequences and
    dicts, and anything else by ``repr`` (frozen dataclasses such as dynamics and solver settings)."""
    from stp_env.artifacts import CODE_VERSION

    h = hashlib.sha256(f"stp-plan-checkpoint:{KEY_FORMAT}:{CODE_VERSION}".encode())

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


def _arrays(key: str, plans: list[tuple[int, SinglePlan]], file_format: int) -> dict[str, np.ndarray]:
    n = len(plans)
    k = max((len(p.times) for _, p in plans), default=0)
    times = np.full((n, k), np.nan)
    states = np.full((n, k, 3), np.nan)
    controls = np.full((n, k, 2), np.nan)
    for r, (_, p) in enumerate(plans):
        m = len(p.times)
        times[r, :m], states[r, :m], controls[r, :m] = p.times, p.states, p.controls
    arrays = {
        "key": np.asarray(key), "format": np.asarray(file_format),
        "index": np.asarray([i for i, _ in plans], np.int64).reshape(n),
        "lengths": np.asarray([len(p.times) for _, p in plans], np.int64).reshape(n),
        "times": times, "states": states, "controls": controls,
        "t_ldt": np.asarray([p.t_ldt for _, p in plans], np.float64).reshape(n),
        "sta": np.asarray([p.sta for _, p in plans], np.float64).reshape(n),
        "arrival_time": np.asarray([p.arrival_time for _, p in plans], np.float64).reshape(n),
        "n_steps": np.asarray([p.n_steps for _, p in plans], np.int64).reshape(n),
    }
    return pack_trajectories(arrays) if file_format == 2 else arrays


def save(path, key: str, plans: list[tuple[int, SinglePlan]], *, file_format: int = FORMAT) -> None:
    """Writes the plans ``[(vehicle index, plan), ...]`` (in priority order) to ``path``, atomically, in
    ``file_format`` (:data:`FORMATS`)."""
    if file_format not in FORMATS:
        raise ValueError(f"file_format must be one of {FORMATS}; got {file_format!r}.")
    path = Path(path)
    arrays = _arrays(key, plans, file_format)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            (np.savez_compressed if file_format == 2 else np.savez)(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _read(path) -> tuple[str, list[tuple[int, SinglePlan]]]:
    """The key and the plans of the checkpoint file ``path`` (either format)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError) as err:
        raise ValueError(f"planning checkpoint {path}: not a readable .npz file ({err}).") from err
    common = {"key", "format", "index", "lengths", "t_ldt", "sta", "arrival_time", "n_steps"}
    trajectories = {1: {"times", "states", "controls"}, 2: {"packed_trajectories"}}
    stored = arrays.get("format")
    file_format = (int(stored) if stored is not None and stored.shape == () and np.issubdtype(stored.dtype, np.integer)
                   else None)
    if file_format not in FORMATS or not common | trajectories[file_format] <= set(arrays):
        raise ValueError(f"planning checkpoint {path}: not a checkpoint of formats {FORMATS} (arrays "
                         f"{sorted(arrays)}).")
    if file_format == 2:
        arrays.update(unpack_trajectories(arrays))
    plans = []
    for r, m in enumerate(arrays["lengths"]):
        plans.append((int(arrays["index"][r]), SinglePlan(
            t_ldt=float(arrays["t_ldt"][r]), sta=float(arrays["sta"][r]), times=arrays["times"][r, :m].copy(),
            states=arrays["states"][r, :m].copy(), controls=arrays["controls"][r, :m].copy(),
            arrival_time=float(arrays["arrival_time"][r]), n_steps=int(arrays["n_steps"][r]))))
    return str(arrays["key"]), plans


def load(path, key: str) -> list[tuple[int, SinglePlan]]:
    """The plans stored in ``path`` (``[]`` if it does not exist), either format.

    Raises:
        CheckpointMismatchError: if the file was written for another problem or by other planner code.
        ValueError: if the file is not a readable checkpoint.
    """
    path = Path(path)
    if not path.exists():
        return []
    stored, plans = _read(path)
    if stored != key:
        raise CheckpointMismatchError(
            f"planning checkpoint {path} was written for another planning problem or planner version; delete it "
            "or choose another checkpoint path.")
    return plans


def convert(src, dst, file_format: int = FORMAT) -> int:
    """Rewrites the checkpoint ``src`` to ``dst`` in ``file_format`` with the same key and the same bits (a planner
    of either format then resumes from it); returns the number of vehicles. ``dst`` may be ``src``."""
    key, plans = _read(src)
    save(dst, key, plans, file_format=file_format)
    return len(plans)
