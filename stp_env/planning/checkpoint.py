"""Checkpoints of sequential planning: the plans of the vehicles planned so far, so that a long run resumes.

Sequential planning (:func:`stp_env.planning.stp.plan_rtt`) plans vehicles in priority order, each against the
nominal trajectories of those before it, so the first ``k`` vehicles' plans are all it needs to go on with vehicle
``k + 1``. A checkpoint is one ``.npz`` file holding those plans (trajectories padded with NaN, lengths kept) and a
key: a hash of every input of the planning problem and of the planner's code version
(:data:`stp_env.artifacts.CODE_VERSION`). It is rewritten atomically after every vehicle (a temporary file in the
same directory, then a rename), so an interrupted run leaves the last complete prefix. It is read as untrusted data
(``docs/threat-model.md``): under the loader contract (:mod:`stp_env.loaders`: a regular file, size caps, nothing
unpickled), its structure checked (:func:`_read`), and, before a run resumes from it, its trajectories checked
as a finished plan's are (:func:`check_plans`). Resuming with a checkpoint of another problem is refused: silently
mixing plans would break the sequential guarantee.

Files of :data:`FORMAT` 2 hold the trajectories losslessly packed (:func:`stp_env.planning.plan.pack_trajectories`)
and compressed: a planner integrates every trajectory to its horizon, so the padded float64 form of format 1 grew
to 14.8 MB at 50 of the bay area's 200 vehicles, where format 2 takes 1.1 MB (about 0.4 s more per save). Both are
read; :func:`convert` rewrites a file in either format with the same key and the same bits, e.g. to carry a long
run's progress to a machine whose planner code writes the other.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from stp_env.arguments import INT32_MAX
from stp_env.files import atomic_open
from stp_env.loaders import LoadError, loader, read_npz
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
    with atomic_open(path, "wb") as f:
        (np.savez_compressed if file_format == 2 else np.savez)(f, **arrays)
        f.flush()
        os.fsync(f.fileno())


_INTEGER_FIELDS = ("index", "lengths", "n_steps")
_TIME_FIELDS = ("t_ldt", "sta", "arrival_time")
_TRAJECTORY_WIDTHS = {"times": None, "states": 3, "controls": 2}


def _read(path) -> tuple[str, list[tuple[int, SinglePlan]]]:
    """The key and the plans of the checkpoint file ``path`` (either format), read under the loader contract
    (:func:`stp_env.loaders.read_npz`: a regular file, size caps, no pickles) and checked for structure before
    anything is built from it: exactly the arrays of its format, a string key, an integer format, one entry per
    vehicle in every per-vehicle array (integers where integers belong), each length between 1 and the padded width,
    distinct vehicle indices, ``n_steps >= 0``. Any problem is a one-line ``ValueError`` naming the file. (Whether
    the trajectories are flights of the problem is checked by :func:`check_plans` when a run resumes.)"""
    path = Path(path)

    def bad(problem: str) -> ValueError:
        return ValueError(f"{path}: not a readable planning checkpoint ({problem}).")

    try:
        arrays = read_npz(path, "plan-checkpoint")
    except LoadError as err:
        raise bad(err.problem.rstrip(".")) from None
    common = {"key", "format", "index", "lengths", *_TIME_FIELDS, "n_steps"}
    trajectories = {1: set(_TRAJECTORY_WIDTHS), 2: {"packed_trajectories"}}
    stored = arrays.get("format")
    file_format = (int(stored) if stored is not None and stored.shape == () and np.issubdtype(stored.dtype, np.integer)
                   else None)
    if file_format not in FORMATS or set(arrays) != common | trajectories[file_format]:
        raise ValueError(f"planning checkpoint {path}: not a checkpoint of formats {FORMATS} (arrays "
                         f"{sorted(arrays)[:20]}).")
    key = arrays["key"]
    if key.shape != () or key.dtype.kind != "U":
        raise bad(f"its key is a {key.dtype} array of shape {key.shape}, not a string")
    index = arrays["index"]
    n = index.shape[0] if index.ndim == 1 else -1
    for name in (*_INTEGER_FIELDS, *_TIME_FIELDS):
        a = arrays[name]
        kinds = "iu" if name in _INTEGER_FIELDS else "fiu"
        if a.shape != (max(n, 0),) or n < 0 or a.dtype.kind not in kinds:
            raise bad(f"{name} is a {a.dtype} array of shape {a.shape}; expected {n if n >= 0 else 'one'} "
                      f"{'integers' if name in _INTEGER_FIELDS else 'numbers'}, one per vehicle")
    lengths = arrays["lengths"].astype(np.int64)
    if len(set(index.tolist())) != n or np.any(index < 0) or np.any(index > INT32_MAX):
        raise bad("the vehicle indices are not distinct integers >= 0")
    if np.any(arrays["n_steps"] < 0) or np.any(arrays["n_steps"] > INT32_MAX):
        raise bad("n_steps must be integers >= 0")
    if np.any(lengths < 1):
        raise bad(f"trajectory lengths must be >= 1; got {lengths.min()}")
    width = int(lengths.max(initial=0))
    if n * width * 6 * 8 > loader("plan-checkpoint").max_array_bytes:
        raise bad(f"{n} trajectories of up to {width} samples are more than a checkpoint may hold")
    if file_format == 2:
        try:
            arrays.update(unpack_trajectories(arrays))
        except (ValueError, TypeError, IndexError) as err:
            raise bad(f"packed trajectories: {err}") from None
    for name, columns in _TRAJECTORY_WIDTHS.items():
        a = arrays[name]
        shape = (n, a.shape[1] if a.ndim >= 2 else -1) + (() if columns is None else (columns,))
        if a.shape != shape or a.dtype.kind != "f" or a.shape[1] < width:
            raise bad(f"{name} is a {a.dtype} array of shape {a.shape}; expected float {n} x (>= {width})"
                      f"{'' if columns is None else f' x {columns}'}")
    plans = []
    for r, m in enumerate(lengths):
        plans.append((int(index[r]), SinglePlan(
            t_ldt=float(arrays["t_ldt"][r]), sta=float(arrays["sta"][r]), times=arrays["times"][r, :m].copy(),
            states=arrays["states"][r, :m].copy(), controls=arrays["controls"][r, :m].copy(),
            arrival_time=float(arrays["arrival_time"][r]), n_steps=int(arrays["n_steps"][r]))))
    return str(key), plans


def check_plans(path, plans: list[tuple[int, SinglePlan]], *, starts, targets, target_radii, stas, priorities,
                tracking_bound: float, time_step: float, planning_v, planning_omega_max: float,
                model=None) -> None:
    """The checks of a finished plan (:func:`stp_env.planning.verify.trajectory_faults`), run on the plans a
    checkpoint holds before a run resumes from them: every stored time, state and control finite; samples from the
    departure ``time_step`` apart; the first at the vehicle's start; controls in ``U^p``; each sample the exact step
    of the one before; the recorded arrival the first sample in the shrunk target; and each plan's STA the
    problem's (``model``: the planning model whose motion the samples follow,
    :class:`stp_env.planning.model.PlanningModel`; default Dubins). A checkpoint with the right key and other
    contents (edited, or written by a faulty planner) is a one-line ``ValueError`` naming the file and the first
    faulty vehicle, never a resumed plan of NaN."""
    from types import SimpleNamespace

    from stp_env.planning.plan import Plan, VehiclePlan
    from stp_env.planning.verify import trajectory_faults

    order = sorted(range(len(starts)), key=lambda i: priorities[i])
    rank = {i: r for r, i in enumerate(order)}
    vehicles = [SimpleNamespace(start=tuple(float(v) for v in starts[i]), target=tuple(float(v) for v in targets[i]),
                                target_radius=float(target_radii[i]), priority=int(priorities[i]))
                for i in range(len(starts))]
    problem = SimpleNamespace(vehicles=vehicles, time_step=float(time_step), planning_omega_max=planning_omega_max,
                              planning_v=tuple(float(v) for v in planning_v))
    empty = np.zeros(0)
    for i, single in plans:
        if not 0 <= i < len(starts):
            raise ValueError(f"{path}: vehicle {i} of the checkpoint is not a vehicle of this problem; delete the "
                             "checkpoint or choose another checkpoint path.")
        plan = Plan(vehicles=(VehiclePlan(index=i, priority=rank[i], plan=single, obstacle_lags=empty,
                                          obstacle_radii=empty),),
                    tracking_bound=float(tracking_bound), collision_radius=0.0, kbar=None)
        why = trajectory_faults(plan, problem, model=model).get(i, [])
        if not (single.sta == float(stas[i])):
            why.append(f"STA {single.sta:.6g} s, the problem's {float(stas[i]):.6g} s")
        if why:
            raise ValueError(f"{path}: vehicle {i} (priority {rank[i]}) of the checkpoint is not a plan of this "
                             f"problem: {'; '.join(why)}; delete the checkpoint or choose another checkpoint path.")


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
