"""A cache of computed artifacts (reachability tables, plans): ``.npz`` arrays plus JSON metadata.

Every artifact is keyed by a hash of its *kind*, every parameter that shaped it, :data:`FORMAT_VERSION` and
:data:`CODE_VERSION` (a hash of the source of the modules that compute artifacts: the solver, the dynamics, the
sets, the planner and the scenarios; a float32 solve compiled differently can move a boundary node, so results of
older code are recomputed rather than reused).
Loading checks all of it, and the content hash of the array file; anything that does not match (a changed
parameter, another format version, a truncated or tampered file, unreadable JSON) is reported with a warning and
recomputed, never silently reused. Arrays are read with ``allow_pickle=False``. Writes are atomic (temporary
file, then rename), so an interrupted computation leaves no half-written artifact behind.

The cache directory is ``$STP_ENV_CACHE_DIR`` if set, else the user cache directory of ``platformdirs``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

FORMAT_VERSION = 1
CACHE_ENV_VAR = "STP_ENV_CACHE_DIR"
_NUMERICS = ("hj", "dynamics.py", "reach", "planning", "scenarios")


def _code_version() -> str:
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in _NUMERICS:
        path = root / name
        for file in sorted(path.glob("*.py")) if path.is_dir() else [path]:
            h.update(file.name.encode())
            h.update(file.read_bytes())
    return h.hexdigest()[:16]


CODE_VERSION = _code_version()


class StaleArtifactWarning(UserWarning):
    """A cached artifact was missing, stale or corrupted and is being recomputed."""


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
    text = json.dumps({"kind": kind, "format_version": FORMAT_VERSION, "code_version": CODE_VERSION,
                       "params": to_jsonable(params)},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _library_versions() -> dict[str, str]:
    import jax

    import stp_env

    return {"stp_env": stp_env.__version__, "jax": jax.__version__, "numpy": np.__version__}


@dataclasses.dataclass(frozen=True)
class Artifact:
    """A loaded artifact: its arrays and metadata, and whether it came from the cache."""

    arrays: dict[str, np.ndarray]
    metadata: dict[str, Any]
    path: Path
    from_cache: bool


class ArtifactStore:
    """Directory of artifacts. ``ArtifactStore()`` uses :func:`default_cache_dir`."""

    def __init__(self, root: str | os.PathLike | None = None):
        self.root = Path(root) if root is not None else default_cache_dir()

    def paths(self, kind: str, params: Any) -> tuple[Path, Path, str]:
        key = parameter_key(kind, params)
        stem = f"{kind}-{key[:20]}"
        return self.root / f"{stem}.npz", self.root / f"{stem}.json", key

    def load(self, kind: str, params: Any) -> Artifact | None:
        """The cached artifact, or ``None`` (with a :class:`StaleArtifactWarning` saying why) if it is missing,
        stale or corrupted."""
        npz_path, json_path, key = self.paths(kind, params)
        if not npz_path.exists() and not json_path.exists():
            return None
        problem = None
        try:
            meta = json.loads(json_path.read_text())
            if meta.get("format_version") != FORMAT_VERSION:
                problem = (f"format version {meta.get('format_version')} != {FORMAT_VERSION}")
            elif meta.get("code_version") != CODE_VERSION:
                problem = f"computed by other code (code version {meta.get('code_version')} != {CODE_VERSION})"
            elif meta.get("key") != key or meta.get("kind") != kind:
                problem = "parameters changed"
            elif meta.get("params") != json.loads(json.dumps(to_jsonable(params))):
                problem = "parameters changed"
            elif meta.get("content_sha256") != _file_sha256(npz_path):
                problem = "array file does not match its content hash (corrupted or modified)"
            else:
                with np.load(npz_path, allow_pickle=False) as data:
                    arrays = {name: data[name] for name in data.files}
                if sorted(arrays) != sorted(meta.get("arrays", [])):
                    problem = "array names differ from the metadata"
                else:
                    return Artifact(arrays=arrays, metadata=meta, path=npz_path, from_cache=True)
        except (OSError, ValueError, KeyError, json.JSONDecodeError) as err:
            problem = f"unreadable ({type(err).__name__}: {err})"
        warnings.warn(f"Recomputing {kind} artifact {npz_path.name}: {problem}.", StaleArtifactWarning,
                      stacklevel=3)
        return None

    def save(self, kind: str, params: Any, arrays: Mapping[str, np.ndarray],
             extra_metadata: Mapping[str, Any] | None = None) -> Artifact:
        npz_path, json_path, key = self.paths(kind, params)
        self.root.mkdir(parents=True, exist_ok=True)
        arrays = {name: np.asarray(a) for name, a in arrays.items()}
        for name, a in arrays.items():
            if a.dtype == object:
                raise TypeError(f"Artifact array {name!r} has dtype object; only numeric arrays are stored.")
        fd, tmp_npz = tempfile.mkstemp(dir=self.root, suffix=".npz.tmp")
        os.close(fd)
        try:
            with open(tmp_npz, "wb") as fh:
                np.savez(fh, **arrays)
            meta = {
                "kind": kind,
                "key": key,
                "format_version": FORMAT_VERSION,
                "code_version": CODE_VERSION,
                "params": to_jsonable(params),
                "arrays": sorted(arrays),
                "shapes": {name: list(a.shape) for name, a in arrays.items()},
                "content_sha256": _file_sha256(Path(tmp_npz)),
                "library_versions": _library_versions(),
                "created_unix": time.time(),
                **(to_jsonable(dict(extra_metadata)) if extra_metadata else {}),
            }
            fd, tmp_json = tempfile.mkstemp(dir=self.root, suffix=".json.tmp")
            with os.fdopen(fd, "w") as fh:
                json.dump(meta, fh, indent=1, sort_keys=True)
            os.replace(tmp_npz, npz_path)
            os.replace(tmp_json, json_path)
        finally:
            if os.path.exists(tmp_npz):
                os.remove(tmp_npz)
        return Artifact(arrays=arrays, metadata=meta, path=npz_path, from_cache=False)

    def load_or_compute(self, kind: str, params: Any, compute: Callable[[], Mapping[str, np.ndarray]],
                        extra_metadata: Mapping[str, Any] | None = None) -> Artifact:
        """The cached artifact if valid, else ``compute()`` saved and returned."""
        cached = self.load(kind, params)
        if cached is not None:
            return cached
        return self.save(kind, params, compute(), extra_metadata)
