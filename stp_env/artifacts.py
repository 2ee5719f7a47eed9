"""A cache of computed artifacts (reachability tables, plans): ``.npz`` arrays plus JSON metadata.

Every artifact is keyed by a hash of its *kind*, every parameter that shaped it, :data:`FORMAT_VERSION` and
the version of the code that computes it (:func:`code_version`: a hash of the modules it depends on, the solver,
the dynamics and the reachability sets for the reachability tables, and the planner and the scenarios too for plans,
read as syntax trees without docstrings and comments, so that editing prose keeps the cache; a float32 solve
compiled differently can move a boundary node, so results of older code are recomputed rather than reused).
Loading checks all of it, and the content hash of the array file; anything that does not match (a changed
parameter, another format version, a truncated or tampered file, unreadable JSON) is reported with a warning and
recomputed, never silently reused. The metadata must be a JSON object of the expected structure (array names,
shapes, which arrays may hold non-finite values); the arrays must match it. Both files are read under the loader
contract (:mod:`stp_env.loaders`: regular files only, size caps, bounded JSON nesting, no pickles): loading a cache
file never runs code, and a FIFO or a device in place of one is reported and recomputed, never waited on. A process
waiting for another one computing the same artifact says so on stderr. Writes are atomic (temporary file, then
rename), so an interrupted computation leaves no half-written artifact behind; temporary files are named after
their writer's process (``.stp-tmp-<pid>-<host>-*``) and those of writers that are no longer running are removed
on the next use of the cache. Before computing an artifact that is not cached, the store checks that it can write
the cache directory (:class:`CacheNotWritableError`), so that a long computation is not lost at the end.

The cache directory is ``$STP_ENV_CACHE_DIR`` if set, else the user cache directory of ``platformdirs``.
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import hashlib
import json
import os
import stat
import sys
import tempfile
import time
import warnings
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from stp_env import loaders
from stp_env.files import TEMP_PREFIX, is_regular_file, move_aside, remove_stale_temporaries, writer_tag

try:  # POSIX advisory locks; elsewhere concurrent processes may compute the same artifact twice (still atomic)
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None

FORMAT_VERSION = 1
CACHE_ENV_VAR = "STP_ENV_CACHE_DIR"
SHIPPED_DIR = Path(__file__).resolve().parent / "data" / "artifacts"  # artifacts that ship with the package
_REACHABILITY = ("hj", "dynamics.py", "angles.py", "kinematics.py", "reach")
_NUMERICS = (*_REACHABILITY, "planning", "scenarios")
_COOBSERVATION = (*_REACHABILITY, "coobservation")
REACHABILITY_KINDS = frozenset({"tracking_bound", "avoid_region", "avoid_certificate", "relative_buffer"})
"""Kinds computed by the solver, the dynamics and the reachability sets alone: their key holds
:data:`REACHABILITY_CODE_VERSION`, so that an edit to the planner or the scenarios keeps them (and the shipped tracking
bound) valid. Kinds named ``coobs_*`` hold :data:`COOBSERVATION_CODE_VERSION`; every other kind (plans)
:data:`CODE_VERSION`."""


def code_fingerprint(source: str) -> str:
    """What of a module's source can change a computed result: its syntax tree without docstrings (comments are
    not in the tree). Editing prose leaves cached artifacts valid; any change to the code invalidates them."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


def _code_version(names) -> str:
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in names:
        path = root / name
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:  # subpackages too (scenarios/catalog)
            h.update(file.relative_to(root).as_posix().encode())
            h.update(code_fingerprint(file.read_text(encoding="utf-8")).encode())
    return h.hexdigest()[:16]


CODE_VERSION = _code_version(_NUMERICS)
REACHABILITY_CODE_VERSION = _code_version(_REACHABILITY)
COOBSERVATION_CODE_VERSION = _code_version(_COOBSERVATION)


def code_version(kind: str) -> str:
    """The version of the code that computes artifacts of ``kind``, part of their key (:data:`REACHABILITY_KINDS`)."""
    if kind in REACHABILITY_KINDS:
        return REACHABILITY_CODE_VERSION
    if kind.startswith("coobs_"):
        return COOBSERVATION_CODE_VERSION
    return CODE_VERSION


class StaleArtifactWarning(UserWarning):
    """A cached artifact was missing, stale or corrupted and is being recomputed."""


class CacheNotWritableError(OSError):
    """The artifact cache directory cannot be written, and an artifact that is not cached must be computed."""


def _temp_file(root: Path, suffix: str) -> tuple[int, str]:
    return tempfile.mkstemp(dir=root, prefix=TEMP_PREFIX + writer_tag(), suffix=suffix)


def probe_writable(directory) -> None:
    """Create and remove a file in ``directory``: raises ``OSError`` if files cannot be written there (permissions,
    a read-only file system, a path that is not a directory), whoever the user is."""
    fd, probe = _temp_file(Path(directory), ".probe")
    os.close(fd)
    os.remove(probe)


def _metadata_problem(meta: Any) -> str | None:
    """What is wrong with the structure of an artifact's metadata (``None``: nothing)."""
    if not isinstance(meta, dict):
        return f"metadata is a JSON {type(meta).__name__}, not an object"
    arrays = meta.get("arrays")
    if not isinstance(arrays, list) or not all(isinstance(a, str) for a in arrays):
        return "metadata 'arrays' is not a list of array names"
    shapes = meta.get("shapes", {})
    if not isinstance(shapes, dict) or not all(
            isinstance(v, list) and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in v)
            for v in shapes.values()):
        return "metadata 'shapes' is not a map of array names to shapes"
    nonfinite = meta.get("nonfinite", [])
    if not isinstance(nonfinite, list) or not all(isinstance(a, str) for a in nonfinite):
        return "metadata 'nonfinite' is not a list of array names"
    if not isinstance(meta.get("content_sha256"), str):
        return "metadata has no content hash"
    return None


def _arrays_problem(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
    """What is wrong with loaded arrays against their metadata (``None``: nothing)."""
    if sorted(arrays) != sorted(meta["arrays"]):
        return "array names differ from the metadata"
    shapes = meta.get("shapes", {})
    allowed_nonfinite = set(meta.get("nonfinite", [])) if "nonfinite" in meta else None
    for name, a in arrays.items():
        if a.dtype.kind not in "biufc":
            return f"array {name!r} has dtype {a.dtype}; only numeric arrays are stored"
        if name in shapes and list(a.shape) != shapes[name]:
            return f"array {name!r} has shape {list(a.shape)}, the metadata says {shapes[name]}"
        if allowed_nonfinite is not None and name not in allowed_nonfinite and a.dtype.kind in "fc" \
                and not np.all(np.isfinite(a)):
            return f"array {name!r} has non-finite values that were not computed"
    return None


def default_cache_dir() -> Path:
    env = os.environ.get(CACHE_ENV_VAR)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("stp-env", appauthor=False))


def to_jsonable(obj: Any) -> Any:
    """Canonical JSON form of parameters: dataclasses become ``{"__type__": name, fields...}``, tuples lists,
    numpy scalars Python numbers."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out = {"__type__": type(obj).__name__}
        for f in dataclasses.fields(obj):
            out[f.name] = to_jsonable(getattr(obj, f.name))
        return out
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return {"__ndarray_sha256__": hashlib.sha256(np.ascontiguousarray(obj).tobytes()).hexdigest(),
                "shape": list(obj.shape), "dtype": str(obj.dtype)}
    if isinstance(obj, float) and not np.isfinite(obj):
        return repr(obj)
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise TypeError(f"Cannot describe parameter of type {type(obj).__name__} in artifact metadata.")


def parameter_key(kind: str, params: Any) -> str:
    text = json.dumps({"kind": kind, "format_version": FORMAT_VERSION, "code_version": code_version(kind),
                       "params": to_jsonable(params)},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _file_sha256(path: Path) -> str:
    """The SHA-256 of a regular file (:func:`stp_env.loaders.open_regular`: a FIFO or a device is a
    :class:`~stp_env.loaders.LoadError`, never a wait)."""
    h = hashlib.sha256()
    with loaders.open_regular(path, "artifact-arrays") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _library_versions() -> dict[str, str]:
    import jax

    from stp_env.version import __version__

    return {"stp_env": __version__, "jax": jax.__version__, "numpy": np.__version__}


@dataclasses.dataclass(frozen=True)
class Artifact:
    """A loaded artifact: its arrays and metadata, and whether it came from the cache."""

    arrays: dict[str, np.ndarray]
    metadata: dict[str, Any]
    path: Path
    from_cache: bool


def _identity_problem(meta: dict, npz_path: Path, kind: str, params: Any, key: str) -> str | None:
    """Whether well-formed metadata describes this artifact as computed by this code (``None``: it does)."""
    if meta.get("format_version") != FORMAT_VERSION:
        return f"format version {meta.get('format_version')} != {FORMAT_VERSION}"
    if meta.get("code_version") != code_version(kind):
        return f"computed by other code (code version {meta.get('code_version')} != {code_version(kind)})"
    if meta.get("key") != key or meta.get("kind") != kind \
            or meta.get("params") != json.loads(json.dumps(to_jsonable(params))):
        return "parameters changed"
    if meta.get("content_sha256") != _file_sha256(npz_path):
        return "array file does not match its content hash (corrupted or modified)"
    return None


def _read_artifact(npz_path: Path, json_path: Path, kind: str, params: Any, key: str
                   ) -> tuple[Artifact | None, str | None]:
    """The artifact at ``npz_path`` / ``json_path`` if everything about it checks out, else ``None`` and why.

    Both files go through the loader contract (:mod:`stp_env.loaders`: regular files only, so a FIFO never blocks;
    size caps; bounded JSON nesting; the arrays' headers checked before anything is allocated; no pickles)."""
    if not npz_path.exists() and not json_path.exists():
        return None, "missing"
    try:
        meta = loaders.read_json(json_path, "artifact-metadata")
        problem = _metadata_problem(meta) or _identity_problem(meta, npz_path, kind, params, key)
        if problem is None:
            arrays = loaders.read_npz(npz_path, "artifact-arrays")
            problem = _arrays_problem(arrays, meta)
            if problem is None:
                return Artifact(arrays=arrays, metadata=meta, path=npz_path, from_cache=True), None
    except loaders.LoadError as err:
        problem = f"unreadable ({err.path.name}: {err.problem.rstrip('.')})"
    except (OSError, ValueError, KeyError, TypeError, AttributeError, EOFError, zipfile.BadZipFile) as err:
        problem = f"unreadable ({type(err).__name__}: {err})"
    return None, problem


def _move_aside_odd_entries(*paths: Path) -> str:
    """Move every one of ``paths`` that is there but is not a regular file (a directory, FIFO, socket or link) aside
    (:func:`stp_env.files.move_aside`), so that the recomputed artifact can take its place; what to add to the
    warning (empty when nothing was moved)."""
    moved = [f"{p.name} was not a regular file, moved aside to {m.name}" for p in paths
             if (p.exists() or p.is_symlink()) and not is_regular_file(p) and (m := move_aside(p)) is not None]
    return "".join(f"; {m}" for m in moved)


class ArtifactStore:
    """Directory of artifacts. ``ArtifactStore()`` uses :func:`default_cache_dir`.

    ``shipped``: a read-only directory of artifacts that came with the package (:data:`SHIPPED_DIR`; ``None``:
    none), consulted when the cache has no file for an artifact. A shipped file is only used if it was computed by
    the current code (:func:`code_version`) with the same parameters; ``stp-env data artifacts`` regenerates
    them and ``tests/test_artifacts.py`` fails while one is stale."""

    def __init__(self, root: str | os.PathLike | None = None, *, shipped: str | os.PathLike | None = SHIPPED_DIR):
        self.root = Path(root) if root is not None else default_cache_dir()
        self.shipped = Path(shipped) if shipped is not None else None
        self._swept = False

    def _sweep(self) -> None:
        """Remove dead writers' temporary files, once per store."""
        if not self._swept:
            self._swept = True
            remove_stale_temporaries(self.root)

    def check_writable(self, what: str = "an artifact") -> None:
        """Raise :class:`CacheNotWritableError` (naming the directory and ``STP_ENV_CACHE_DIR``) unless the cache
        directory exists or can be created and a file can be written in it."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            probe_writable(self.root)
        except OSError as err:
            raise CacheNotWritableError(
                f"cannot write the artifact cache directory {self.root} ({type(err).__name__}: "
                f"{err.strerror or err}), where {what} must be saved; set {CACHE_ENV_VAR} (or --cache-dir) to a "
                "writable directory.") from None

    def paths(self, kind: str, params: Any) -> tuple[Path, Path, str]:
        key = parameter_key(kind, params)
        stem = f"{kind}-{key[:20]}"
        return self.root / f"{stem}.npz", self.root / f"{stem}.json", key

    def load(self, kind: str, params: Any) -> Artifact | None:
        """The cached artifact, or ``None`` (with a :class:`StaleArtifactWarning` saying why) if it is missing,
        stale or corrupted. When the cache has no file for it, a valid shipped copy (:data:`SHIPPED_DIR`, checked
        the same way: same parameters, format and code version, content hash) is returned instead."""
        npz_path, json_path, key = self.paths(kind, params)
        if not npz_path.exists() and not json_path.exists():
            if self.shipped is None:
                return None
            artifact, _ = _read_artifact(self.shipped / npz_path.name, self.shipped / json_path.name, kind, params,
                                         key)
            return artifact
        artifact, problem = _read_artifact(npz_path, json_path, kind, params, key)
        if artifact is None:
            moved = _move_aside_odd_entries(npz_path, json_path)
            warnings.warn(f"Recomputing {kind} artifact {npz_path.name} (and {json_path.name}, in {self.root}): "
                          f"{problem}{moved}.", StaleArtifactWarning, stacklevel=3)
        return artifact

    def save(self, kind: str, params: Any, arrays: Mapping[str, np.ndarray],
             extra_metadata: Mapping[str, Any] | None = None) -> Artifact:
        npz_path, json_path, key = self.paths(kind, params)
        self.root.mkdir(parents=True, exist_ok=True)
        arrays = {name: np.asarray(a) for name, a in arrays.items()}
        for name, a in arrays.items():
            if a.dtype == object:
                raise TypeError(f"Artifact array {name!r} has dtype object; only numeric arrays are stored.")
        self._sweep()
        fd, tmp_npz = _temp_file(self.root, ".npz")
        os.close(fd)
        tmp_json = None
        try:
            with open(tmp_npz, "wb") as fh:
                np.savez(fh, **arrays)
            meta = {
                "kind": kind,
                "key": key,
                "format_version": FORMAT_VERSION,
                "code_version": code_version(kind),
                "params": to_jsonable(params),
                "arrays": sorted(arrays),
                "shapes": {name: list(a.shape) for name, a in arrays.items()},
                "nonfinite": sorted(name for name, a in arrays.items()
                                    if a.dtype.kind in "fc" and not np.all(np.isfinite(a))),
                "content_sha256": _file_sha256(Path(tmp_npz)),
                "library_versions": _library_versions(),
                "created_unix": time.time(),
                **(to_jsonable(dict(extra_metadata)) if extra_metadata else {}),
            }
            fd, tmp_json = _temp_file(self.root, ".json")
            with os.fdopen(fd, "w") as fh:
                json.dump(meta, fh, indent=1, sort_keys=True)
            _move_aside_odd_entries(npz_path, json_path)  # os.replace cannot put a file where a directory is
            os.replace(tmp_npz, npz_path)
            os.replace(tmp_json, json_path)
        finally:
            for tmp in (tmp_npz, tmp_json):
                if tmp is not None and os.path.exists(tmp):
                    os.remove(tmp)
        return Artifact(arrays=arrays, metadata=meta, path=npz_path, from_cache=False)

    def load_or_compute(self, kind: str, params: Any, compute: Callable[[], Mapping[str, np.ndarray]],
                        extra_metadata: Mapping[str, Any] | None = None) -> Artifact:
        """The cached artifact if valid, else ``compute()`` saved and returned. The cache directory is checked
        to be writable before ``compute()`` runs (:class:`CacheNotWritableError`)."""
        self._sweep()
        cached = self.load(kind, params)
        if cached is not None:
            return cached
        self.check_writable(f"the {kind} artifact")
        with self._computing(kind, params):
            # Another process (a parallel test worker, a second CLI run) may have computed it while we waited.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", StaleArtifactWarning)
                cached = self.load(kind, params)
            if cached is not None:
                return cached
            return self.save(kind, params, compute(), extra_metadata)

    @contextlib.contextmanager
    def _computing(self, kind: str, params: Any):
        """Holds an exclusive advisory lock on ``<kind>-<key>.lock`` while one artifact is computed, so that
        processes sharing the cache compute each artifact once (the others wait, then load it). A process that has
        to wait says so on stderr (which artifact, which lock file). A lock path that is not a regular file (a FIFO,
        a directory) is not waited on: the artifact is computed without the lock, with a warning (writes stay
        atomic)."""
        if fcntl is None:
            yield
            return
        npz_path, _, _ = self.paths(kind, params)
        lock_path = npz_path.with_suffix(".lock")
        flags = (os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
                 | getattr(os, "O_NOFOLLOW", 0))
        try:
            fd = os.open(lock_path, flags, 0o644)
        except OSError as err:
            fd, problem = None, f"cannot be opened ({err.strerror or err})"
        else:
            problem = None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                fd, problem = None, "is not a regular file"
        if fd is None:
            moved = _move_aside_odd_entries(lock_path)  # the next run locks again
            warnings.warn(f"Computing the {kind} artifact {npz_path.name} without its lock: {lock_path} {problem}"
                          f"{moved}.",
                          StaleArtifactWarning, stacklevel=4)
            yield
            return
        with os.fdopen(fd, "a") as fh:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                print(f"stp-env: waiting for another process computing the {kind} artifact {npz_path.name} (lock "
                      f"{lock_path}); it is loaded from the cache when that process is done.", file=sys.stderr,
                      flush=True)
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
