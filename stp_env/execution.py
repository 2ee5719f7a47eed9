"""One execution seam for the long jobs: a job is a list of independent pieces, and an executor runs them, in this
process (:class:`LocalExecutor`) or on a Ray cluster (:class:`RayExecutor`), with the same results bit for bit.

A :class:`Job` is a module-level function ``function(context, argument) -> dict[str, numpy array]``, one shared
``context`` (shipped to every worker once) and one small ``argument`` per piece. A piece is a pure function of its
context and argument: its randomness comes from the seed, the configuration and the piece's index (all in the
context and the argument), never from where or when it runs, so any executor gives the same arrays. The results come
back as a list in piece order whatever the order pieces finish in, and the caller combines them in that order.

Given ``out_dir``, every finished piece is written there at once (an ``.npz`` of its arrays, written to a temporary
file and moved into place; read back through :func:`stp_env.loaders.read_npz`, which unpickles nothing: a piece file
never runs code), under a folder named by the job's fingerprint (a hash of everything the pieces depend on, the
package's source included). A job that was killed resumes: the pieces already written are read back, and only the
others run. A piece file proves where it came from: it carries the job's fingerprint, its index and a digest of its
content (:data:`PROVENANCE`), and is read back only when all three are what this job writes; anything else in its
place (another job's or another seed's piece, a piece moved or edited, an empty file, a directory) is moved aside
and runs again, with one warning naming the file. The digest finds a changed or misplaced piece, not a forger who
recomputes it (``docs/threat-model.md``).

Big constants (the ``EnvParams`` with its reachability tables and plans) are built once by the driver and travel
inside the context: :func:`to_host` turns a pytree's arrays into NumPy arrays (which Ray's object store holds as
plain buffers and workers on a node read without copying), :func:`to_device` turns them back, exactly (dtype, shape,
weak type and bits). A worker keeps what it derives from a context (device arrays, policies, compiled programs) in a
small per-process cache, :func:`memo`, keyed by the job's token, so that its later pieces reuse them.

Ray is an optional extra (``pip install 'stp-env[ray]'``): nothing here imports it until a :class:`RayExecutor` is
made. ``docs/ray.md`` says how to run on a cluster.
"""

from __future__ import annotations

import abc
import collections
import dataclasses
import functools
import hashlib
import json
import os
import re
import uuid
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stp_env.files import atomic_open, move_aside, remove_stale_temporaries

RAY_HINT = "pip install 'stp-env[ray]'"
"""What installs Ray (named in the error when it is missing)."""
MEMO_SIZE = 32
"""How many derived objects (device arrays, policies, programs) a process keeps for the jobs it ran last."""
PIECE_PREFIX = "piece-"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_HEX = re.compile(r"[0-9a-f]{16,128}")


@dataclasses.dataclass(frozen=True)
class Job:
    """Independent pieces of work.

    Attributes:
        name: a short name (letters, digits, ``_.-``): the folder of its pieces and what progress messages say.
        function: a module-level function ``function(context, argument) -> dict[str, np.ndarray]`` (importable by
            name on every worker: it travels by reference, never as code in a file).
        context: what every piece shares (shipped once per job; arrays as NumPy, see :func:`to_host`).
        arguments: one argument per piece (small: ints, tuples), in piece order.
        fingerprint: hex digest of everything the pieces' results depend on (:func:`digest`); ``None``: the job
            cannot resume (and is run without ``out_dir``).
        units: per piece, how much work it is (for progress bars; default 1 each).
    """

    name: str
    function: Callable[[Any, Any], dict]
    context: Any
    arguments: tuple
    fingerprint: str | None = None
    units: tuple | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.fullmatch(self.name):
            raise ValueError(f"a job's name must be 1-64 letters, digits, '_', '.' or '-'; got {self.name!r}.")
        if not callable(self.function):
            raise ValueError(f"a job's function must be callable; got {type(self.function).__name__}.")
        object.__setattr__(self, "arguments", tuple(self.arguments))
        if not self.arguments:
            raise ValueError(f"job {self.name}: no piece to run.")
        if self.fingerprint is not None and (not isinstance(self.fingerprint, str)
                                             or not _HEX.fullmatch(self.fingerprint)):
            raise ValueError(f"job {self.name}: the fingerprint must be a lowercase hex digest; got "
                             f"{self.fingerprint!r}.")
        units = (1,) * len(self.arguments) if self.units is None else tuple(int(u) for u in self.units)
        if len(units) != len(self.arguments) or any(u < 0 for u in units):
            raise ValueError(f"job {self.name}: units must be one non-negative number per piece.")
        object.__setattr__(self, "units", units)

    def __len__(self) -> int:
        return len(self.arguments)

    def folder(self, out_dir) -> Path:
        """Where the pieces of this job are written under ``out_dir``."""
        if self.fingerprint is None:
            raise ValueError(f"job {self.name} has no fingerprint: it cannot be resumed from {out_dir}.")
        return Path(out_dir) / f"{self.name}-{self.fingerprint[:24]}"


# ------------------------------------------------------------------------------------------------ pieces on disk
PROVENANCE = ("__piece_fingerprint__", "__piece_index__", "__piece_digest__")
"""The arrays every piece file carries besides its results: the job's fingerprint, the piece's index and a SHA-256
digest of both and of every result array (:func:`piece_digest`). A piece is read back only when all three are what
this job would write."""


def piece_path(folder, index: int) -> Path:
    return Path(folder) / f"{PIECE_PREFIX}{index:06d}.npz"


def check_result(result, where: str) -> dict[str, np.ndarray]:
    """A piece's result as a dict of NumPy arrays (numeric, boolean or string; never objects), or a ``ValueError``
    naming ``where``."""
    if not isinstance(result, dict):
        raise ValueError(f"{where}: a piece must return a dict of arrays; got {type(result).__name__}.")
    out = {}
    for key, value in result.items():
        if not isinstance(key, str) or not key or "\n" in key:
            raise ValueError(f"{where}: a piece's array names must be non-empty one-line strings; got {key!r}.")
        if key in PROVENANCE:
            raise ValueError(f"{where}: the array name {key!r} is reserved for the piece's provenance.")
        array = np.asarray(value)
        if array.dtype.hasobject or array.dtype.kind not in "biufcUS":
            raise ValueError(f"{where}: array {key!r} has dtype {array.dtype}; pieces hold numbers and strings only.")
        out[key] = array
    return out


def piece_digest(fingerprint: str, index: int, arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 hex digest of a piece: its job's fingerprint, its index and every array (name, dtype, shape, bytes)
    in name order."""
    h = hashlib.sha256(f"stp-env piece v1\n{fingerprint}\n{int(index)}\n".encode())
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        h.update(f"{len(key)}:{key} {a.dtype.str} {a.shape}\n".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write_piece(folder, index: int, result: dict, fingerprint: str) -> Path:
    """``result`` (arrays) as ``piece-<index>.npz`` in ``folder`` with its provenance (:data:`PROVENANCE`),
    atomically: the file is complete or absent."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = piece_path(folder, index)
    arrays = check_result(result, str(path))
    stamp = dict(zip(PROVENANCE, (np.array(fingerprint), np.array(int(index), np.int64),
                                  np.array(piece_digest(fingerprint, index, arrays)))))
    with atomic_open(path, "wb") as fh:
        np.savez(fh, **arrays, **stamp)
    return path


def read_piece(path) -> dict[str, np.ndarray]:
    """The arrays of a piece file, its provenance included (the ``job-piece`` loader of :mod:`stp_env.loaders`:
    nothing is unpickled); a ``ValueError`` naming the file when it is not one."""
    from stp_env.loaders import read_npz

    return read_npz(path, "job-piece")


def verified_piece(path, fingerprint: str, index: int) -> dict[str, np.ndarray]:
    """The results of the piece file ``path`` when it is what job ``fingerprint`` writes as piece ``index``; else a
    ``ValueError`` saying why (not a piece file, no provenance, another job, another index, content changed)."""
    arrays = read_piece(path)
    missing = [k for k in PROVENANCE if k not in arrays]
    if missing:
        raise ValueError(f"{path}: no provenance (written by another version, or not a piece)")
    stamp = {k: arrays.pop(k) for k in PROVENANCE}
    their_fingerprint, their_index, their_digest = (stamp[k] for k in PROVENANCE)
    if their_fingerprint.shape or their_fingerprint.dtype.kind != "U" or str(their_fingerprint) != fingerprint:
        raise ValueError(f"{path}: written by another job (fingerprint {str(their_fingerprint)[:16]!r}, this job's "
                         f"{fingerprint[:16]!r})")
    if their_index.shape or their_index.dtype.kind not in "iu" or int(their_index) != index:
        raise ValueError(f"{path}: holds piece {their_index!s}, not piece {index}")
    if their_digest.shape or str(their_digest) != piece_digest(fingerprint, index, arrays):
        raise ValueError(f"{path}: its content does not match its digest (changed after it was written)")
    return arrays


def _done_pieces(job: Job, folder: Path) -> dict[int, dict]:
    """The pieces of ``job`` already written in ``folder`` whose provenance is this job's (:func:`verified_piece`).
    Every other entry in a piece's place is moved aside and runs again, with one warning for the job that names
    each file and why."""
    done, rejected = {}, []
    for index in range(len(job)):
        path = piece_path(folder, index)
        if not (path.exists() or path.is_symlink()):
            continue
        try:
            done[index] = verified_piece(path, job.fingerprint, index)
        except ValueError as err:
            rejected.append(str(err))
            move_aside(path)
    if rejected:
        shown = "; ".join(rejected[:5]) + (f"; and {len(rejected) - 5} more" if len(rejected) > 5 else "")
        warnings.warn(f"job {job.name}: {len(rejected)} piece file(s) in {folder} are not this job's and run again "
                      f"(moved aside as *.rejected-*): {shown}", RuntimeWarning, stacklevel=3)
    return done


# ------------------------------------------------------------------------------------------------ executors
class Executor(abc.ABC):
    """Runs a :class:`Job`'s pieces and returns their results in piece order (:meth:`run`). Subclasses say how the
    missing pieces are computed (:meth:`compute`)."""

    def run(self, job: Job, *, out_dir=None, progress: Callable[[int], None] | None = None,
            on_piece: Callable[[int, dict], None] | None = None) -> list[dict]:
        """Every piece's result (a dict of arrays), in piece order.

        ``out_dir``: write each finished piece there and read back those already written (a job that was killed
        resumes; the job needs a fingerprint). ``progress``: called with each finished piece's units.
        ``on_piece(index, result)``: called as each piece computed in this run finishes (in the order they finish;
        a job that keeps its own record, such as the survivability study's missions file, appends there). An
        exception it raises stops the job: pieces not yet finished are cancelled and the exception propagates."""
        if not isinstance(job, Job):
            raise ValueError(f"expected a Job; got {type(job).__name__}.")
        folder = None if out_dir is None else job.folder(out_dir)
        results: dict[int, dict] = {}
        if folder is not None:
            remove_stale_temporaries(folder)  # a killed writer's half-written piece
            results.update(_done_pieces(job, folder))
            if progress is not None and results:
                progress(sum(job.units[i] for i in results))
        todo = [i for i in range(len(job)) if i not in results]

        def finished(index: int, result: dict) -> None:
            result = check_result(result, f"job {job.name}, piece {index}")
            if folder is not None:
                write_piece(folder, index, result, job.fingerprint)
            results[index] = result
            if progress is not None:
                progress(job.units[index])
            if on_piece is not None:
                on_piece(index, result)

        if todo:
            self.compute(job, todo, finished)
        missing = [i for i in range(len(job)) if i not in results]
        if missing:
            raise RuntimeError(f"job {job.name}: pieces {missing[:5]} did not finish.")
        return [results[i] for i in range(len(job))]

    @abc.abstractmethod
    def compute(self, job: Job, indices: Sequence[int], finished: Callable[[int, dict], None]) -> None:
        """Compute the pieces ``indices`` of ``job``, calling ``finished(index, result)`` as each one ends."""

    def describe(self) -> str:
        return type(self).__name__


class LocalExecutor(Executor):
    """In this process, one piece after the other, in order."""

    def compute(self, job, indices, finished) -> None:
        try:
            for index in indices:
                finished(index, job.function(job.context, job.arguments[index]))
        finally:
            forget(getattr(job.context, "token", None))

    def describe(self) -> str:
        return "in-process"


def require_ray():
    """The ``ray`` module, or a one-line ``ValueError`` naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise ValueError(f"running on Ray needs the ray package: {RAY_HINT}") from None
    return ray


def _package_path() -> str:
    """The folder that holds this ``stp_env`` package (what workers started here need on their path)."""
    return str(Path(__file__).resolve().parent.parent)


class RayExecutor(Executor):
    """Every piece a Ray task (``max_retries``: a piece whose worker died runs again elsewhere); the context is put
    in the object store once per job.

    ``address``: the cluster's (``ray start --head`` prints it; ``"auto"``: the one on this machine); ``None``:
    ``RAY_ADDRESS`` if set, else a new local cluster of ``num_cpus`` CPUs. A Ray session already initialised in
    this process is used as it is. Workers of a local cluster get this package's folder on ``PYTHONPATH`` (they
    import the piece functions by name); on a remote cluster every node must have the package installed
    (``docs/ray.md``), or pass ``runtime_env``.
    """

    def __init__(self, address: str | None = None, *, num_cpus: int | None = None, max_retries: int = 3,
                 runtime_env: dict | None = None):
        if address is not None and (not isinstance(address, str) or not address.strip()):
            raise ValueError(f"the Ray address must be a non-empty string; got {address!r}.")
        if num_cpus is not None and (isinstance(num_cpus, bool) or not isinstance(num_cpus, int) or num_cpus < 1):
            raise ValueError(f"num_cpus must be an integer >= 1; got {num_cpus!r}.")
        if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
            raise ValueError(f"max_retries must be an integer >= 0; got {max_retries!r}.")
        self.ray = require_ray()
        self.max_retries = max_retries
        self.started = False
        if not self.ray.is_initialized():
            address = address or os.environ.get("RAY_ADDRESS") or None
            if runtime_env is None and address is None:
                paths = [_package_path(), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
                runtime_env = {"env_vars": {"PYTHONPATH": os.pathsep.join(dict.fromkeys(paths))}}
            kwargs = {"include_dashboard": False, "log_to_driver": True}
            if address is None and num_cpus is not None:
                kwargs["num_cpus"] = num_cpus
            try:
                with warnings.catch_warnings():
                    # JAX warns at every fork of a process that imported it; Ray's fork is followed by exec at once
                    warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
                    self.ray.init(address=address, runtime_env=runtime_env, **kwargs)
            except ConnectionError as err:
                raise ValueError(f"cannot reach the Ray cluster at {address}: {err}") from None
            self.started = True
        self._remote = self.ray.remote(max_retries=max_retries, retry_exceptions=False)(_run_piece)

    def compute(self, job, indices, finished) -> None:
        ray = self.ray
        context = ray.put(job.context)
        pending = {self._remote.remote(job.function, context, job.arguments[i]): i for i in indices}
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    index = pending.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayTaskError as err:  # the piece raised: the same error here
                        cause = getattr(err, "cause", None)
                        raise (cause if isinstance(cause, Exception) else err) from None
                    finished(index, {k: np.array(v) for k, v in result.items()})  # owned, writable copies
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)

    def workers(self) -> int:
        """CPUs of the cluster (how many pieces run at once)."""
        return int(self.ray.cluster_resources().get("CPU", 0))

    def shutdown(self) -> None:
        """Stop the local cluster this executor started (nothing when it joined one)."""
        if self.started:
            self.ray.shutdown()
            self.started = False

    def describe(self) -> str:
        return f"Ray ({self.workers()} CPUs)"


def _run_piece(function, context, argument):
    """A piece on a Ray worker."""
    return check_result(function(context, argument), f"piece {argument!r}")


def check_executor(executor) -> Executor:
    """``executor``, or a :class:`LocalExecutor` for ``None``; a ``ValueError`` for anything else."""
    if executor is None:
        return LocalExecutor()
    if not isinstance(executor, Executor):
        raise ValueError(f"executor must be an Executor (LocalExecutor, RayExecutor); got {type(executor).__name__}.")
    return executor


def executor_for(use_ray: bool = False, address: str | None = None) -> Executor:
    """What the command line's ``--ray`` / ``--ray-address ADDRESS`` ask for: a :class:`RayExecutor` when either is
    given (``address`` or ``RAY_ADDRESS``, else a local cluster), else a :class:`LocalExecutor`."""
    if use_ray or address:
        return RayExecutor(address)
    return LocalExecutor()


# ------------------------------------------------------------------------------------------------ artifacts
@dataclasses.dataclass(frozen=True)
class HostLeaf:
    """A JAX array leaf as a NumPy array and its weak type (:func:`to_host`)."""

    array: np.ndarray
    weak_type: bool


def to_host(tree):
    """``tree`` (a pytree such as ``EnvParams``) with every JAX array a :class:`HostLeaf` (NumPy data plus its weak
    type): what travels to workers. Static fields stay as they are; :func:`to_device` is the exact inverse."""
    import jax

    def leaf(x):
        if isinstance(x, jax.Array):
            if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
                raise ValueError("to_host: PRNG key arrays do not travel; pass their key data.")
            return HostLeaf(np.asarray(x), bool(getattr(x, "weak_type", False)))
        return x

    return jax.tree.map(leaf, tree)


def to_device(tree):
    """The inverse of :func:`to_host`: every :class:`HostLeaf` a JAX array of the same dtype, shape, weak type and
    bits."""
    import jax
    import jax.numpy as jnp

    def leaf(x):
        if isinstance(x, HostLeaf):
            value = jnp.asarray(x.array)
            return _weak(value) if x.weak_type else value
        return x

    return jax.tree.map(leaf, tree, is_leaf=lambda x: isinstance(x, HostLeaf))


def _weak(value):
    """``value`` weakly typed, as JAX types a lifted Python scalar: same dtype, shape, bits and placement.

    JAX has no public function that sets an array's weak type (checked on JAX 0.10.2). Its public way to ask for one
    is an abstract value, ``jax.ShapeDtypeStruct(..., weak_type=True)``: the identity traced with that argument is a
    program whose result is weakly typed, and it is called with ``value`` (JAX checks the argument's shape and dtype,
    not its weak type), compiled once per shape and dtype."""
    import jax

    spec = jax.ShapeDtypeStruct(value.shape, value.dtype, weak_type=True)
    return _identity().trace(spec).lower().compile()(value)


@functools.cache
def _identity():
    """``jax.jit`` of the identity (made on first use: this module does not import JAX at its import)."""
    import jax

    return jax.jit(lambda x: x)


def digest(*parts) -> str:
    """SHA-256 hex digest of ``parts``: JSON-able values, NumPy or JAX arrays, :class:`HostLeaf` and pytrees of
    them (arrays by dtype, shape and bytes; static pytree fields by their ``repr``)."""
    import jax

    h = hashlib.sha256()

    def add(x):
        if isinstance(x, HostLeaf):
            add(x.array)
            h.update(b"weak" if x.weak_type else b"strong")
        elif isinstance(x, (np.ndarray, np.generic)) or isinstance(x, jax.Array):
            a = np.ascontiguousarray(np.asarray(x))
            h.update(f"array {a.dtype.str} {a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(x, sort_keys=True, default=repr).encode())

    for part in parts:
        leaves, treedef = jax.tree.flatten(part, is_leaf=lambda x: isinstance(x, HostLeaf))
        h.update(str(treedef).encode())
        for x in leaves:
            add(x)
    return h.hexdigest()


def new_token() -> str:
    """A job's token: what :func:`memo` keys a process's derived objects by."""
    return uuid.uuid4().hex


# ------------------------------------------------------------------------------------------------ per-process memo
_MEMO: collections.OrderedDict = collections.OrderedDict()


def memo(token: str, what, build: Callable[[], Any]):
    """``build()`` once per process for ``(token, what)`` (the last :data:`MEMO_SIZE` are kept): a worker's pieces
    of one job share the device arrays, policies and programs derived from its context."""
    key = (token, what)
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return _MEMO[key]
    value = build()
    _MEMO[key] = value
    while len(_MEMO) > MEMO_SIZE:
        _MEMO.popitem(last=False)
    return value


def forget(token: str | None) -> None:
    """Drop what :func:`memo` keeps for ``token``."""
    for key in [k for k in _MEMO if k[0] == token]:
        del _MEMO[key]
