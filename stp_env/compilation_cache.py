"""Compile once per machine: JAX's persistent compilation cache, on by default.

The simulator's programs take tens of seconds each to compile (``docs/numerics.md``, "Compiling the simulator"),
and JAX keeps compiled programs in memory only: every new process (a second ``parallel_env()``, each ``stp-env``
command, each test worker) would compile them again. Importing :mod:`stp_env` therefore turns on JAX's persistent
compilation cache, in the ``xla`` folder of the artifact cache directory (``$STP_ENV_CACHE_DIR`` if set, else the
user cache directory of ``platformdirs``: the same rule as :func:`stp_env.artifacts.default_cache_dir`), so that a
program compiled once on a machine is loaded from disk afterwards.

**What keys an entry.** JAX names every entry by a hash of the program itself (its StableHLO, so any change to the
code that changes the program gives a new entry), the compile options (the simulator's optimisation level of
:mod:`stp_env.sim.jit` included), the XLA flags, the devices and the JAX and jaxlib versions. An upgrade of JAX or an
edit to the code can therefore never load a program compiled for something else; it compiles and adds a new entry.
Programs that call back into Python (the pymunk backend, ``jax.debug.print``) are never written. Every other
program is written, however fast it compiled (:data:`MIN_COMPILE_TIME_S`).

**Its size.** About :data:`DEFAULT_MAX_GB` GB at most (``STP_ENV_COMPILATION_CACHE_MAX_GB`` changes it, ``-1``: no
limit): a process that turns the cache on first deletes the least recently used programs of a folder above the
limit (:func:`prune`); the folder can exceed it by what processes compile until the next one starts. Any other value
that is not a finite number of GB above 0 (``0``, ``-2``, ``nan``, ``inf``, text) is refused: a one-line warning names
the variable, the cache is off in that process and nothing is deleted (a limit of 0 would delete every program at
every start).

**Turning it off.** ``STP_ENV_COMPILATION_CACHE=0`` (or ``off``, ``false``, ``no``) in the environment before the
import, or :func:`configure` ``(enabled=False)`` (:func:`disable`) at run time; ``STP_ENV_COMPILATION_CACHE_DIR``
moves it. Turned off, JAX's persistent cache is off in the process, whatever folder it had. A cache directory that
JAX was already given (``JAX_COMPILATION_CACHE_DIR``, or ``jax.config.update("jax_compilation_cache_dir", ...)``
before importing :mod:`stp_env`) is otherwise used as it is, once it passes the check below. Deleting the folder
clears the cache (JAX writes entries in place: one cut short by a killed process is warned about and compiled again
until then).

**Trust.** A compiled program is machine code: whoever can write the cache folder can make this process run code
(as whoever can write its ``site-packages``). Every folder that holds compiled programs goes through one check,
:func:`private_cache_dir`: this cache's folder, a local folder JAX was given before (``JAX_COMPILATION_CACHE_DIR``)
and a survivability study's ``OUT/jax-cache``. The folder is created private (mode ``0o700``), and a folder owned by
another user or writable by others (sticky bit or not) is not used (a warning says so). See
``docs/threat-model.md``.

**How it is set.** When :mod:`stp_env` is imported before JAX (the usual case: every submodule imports the package
first), the settings go into this process's environment (``JAX_COMPILATION_CACHE_DIR`` and the threshold
variables), where JAX reads them at its import; child processes inherit them. When JAX was imported first, they are
set with ``jax.config.update``.
"""

from __future__ import annotations

import math
import os
import stat
import sys
import time
import warnings
from pathlib import Path

ENV_VAR = "STP_ENV_COMPILATION_CACHE"
"""``0``, ``off``, ``false`` or ``no`` turns the persistent compilation cache off (anything else leaves it on)."""
DIR_ENV_VAR = "STP_ENV_COMPILATION_CACHE_DIR"
"""Where the compiled programs go instead of ``<artifact cache>/xla``."""
MAX_GB_ENV_VAR = "STP_ENV_COMPILATION_CACHE_MAX_GB"
"""The cache's size limit in GB (default :data:`DEFAULT_MAX_GB`): a finite number above 0, or ``-1``: no limit."""
DEFAULT_MAX_GB = 2.0
"""Beyond this, the least recently used programs are deleted when a process turns the cache on (:func:`prune`). A
simulator rollout is tens of MB compiled, the environment's reset and step well under a MB (BENCHMARKS.md, "The test
suite with the compilation cache" and "First step of ``parallel_env()`` in a fresh process")."""
PRUNE_TO = 0.8
"""A folder over its limit is pruned to this fraction of it (so that it is not pruned again at every start)."""
MIN_COMPILE_TIME_S = 0.0
"""Programs that compiled faster than this are not written. JAX's default is 1 s; building a scenario's parameters
compiles about a hundred small programs (eager array operations, tens of ms each), which load from the cache faster
than they compile (BENCHMARKS.md, "First step of ``parallel_env()`` in a fresh process")."""

_JAX_DIR = "JAX_COMPILATION_CACHE_DIR"
_JAX_MIN_TIME = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
_OFF = {"0", "off", "false", "no"}
_state: dict[str, object] = {"directory": None, "set_by_us": False}


def artifact_cache_dir() -> Path:
    """The artifact cache directory (:func:`stp_env.artifacts.default_cache_dir`, read here without importing the
    artifact module, which hashes the package's source when imported)."""
    root = os.environ.get("STP_ENV_CACHE_DIR")
    if root:
        return Path(root).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("stp-env", appauthor=False))


def default_dir() -> Path:
    """``$STP_ENV_COMPILATION_CACHE_DIR``, else ``<artifact cache dir>/xla``."""
    explicit = os.environ.get(DIR_ENV_VAR)
    return Path(explicit).expanduser() if explicit else artifact_cache_dir() / "xla"


def enabled_by_environment() -> bool:
    """``False`` when ``$STP_ENV_COMPILATION_CACHE`` turns the cache off."""
    return os.environ.get(ENV_VAR, "").strip().lower() not in _OFF


def _private_dir(path: Path) -> str | None:
    """``path`` created if missing (mode ``0o700``); the reason it must not hold executable code, or ``None``."""
    try:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
        st = path.stat()
    except OSError as err:
        return f"it cannot be created or read ({err})"
    if not stat.S_ISDIR(st.st_mode):
        return "it is not a directory"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return "it belongs to another user"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return "others can write it"
    return None


def private_cache_dir(path: str | os.PathLike, what: str = "the compilation cache",
                      advice: str | None = None) -> Path | None:
    """``path`` when it may hold compiled programs, created private (mode ``0o700``) if missing; else ``None``, with a
    warning that names it and says why (it cannot be created, is not a directory, belongs to another user, or others
    can write it). The one check of every folder that holds executables (JAX loads and runs what it finds there).

    ``what``: the cache, as the warning names it; ``advice``: what the warning suggests instead (default: a private
    ``$STP_ENV_COMPILATION_CACHE_DIR``, or turning the cache off)."""
    path = Path(path)
    problem = _private_dir(path)
    if problem is None:
        return path
    if advice is None:
        advice = f"Set {DIR_ENV_VAR} to a private folder, or {ENV_VAR}=0 to silence this."
    warnings.warn(f"not using {path} as {what}: {problem}; programs are compiled in every process. {advice}",
                  stacklevel=3)
    return None


def max_size_bytes() -> int:
    """The size limit in bytes (``-1``: none), from ``$STP_ENV_COMPILATION_CACHE_MAX_GB``: a finite number of GB
    above 0, or ``-1``. Any other value is a one-line ``ValueError`` naming the variable (``0`` would delete every
    program at every start)."""
    text = os.environ.get(MAX_GB_ENV_VAR, "").strip()
    try:
        gb = float(text) if text else DEFAULT_MAX_GB
    except ValueError:
        gb = math.nan
    if gb == -1:
        return -1
    if not (math.isfinite(gb) and gb > 0):
        raise ValueError(f"{MAX_GB_ENV_VAR}={text!r}: a size in GB above 0 (or -1: no limit) was expected.")
    return max(1, int(gb * 1e9))


def prune(folder: str | os.PathLike, max_bytes: int) -> int:
    """Delete the least recently used files of ``folder`` (by the later of their access and modification times)
    until it holds at most :data:`PRUNE_TO` of ``max_bytes``, if it holds more than ``max_bytes``; the number of
    files deleted. Done once per process when the cache is turned on: cheap (one directory listing), and it never
    blocks a compile. (JAX's own limit, ``jax_compilation_cache_max_size``, scans the folder at every write, which
    with the thousands of small programs of a test run costs more than it saves.) A file that another process is
    reading stays readable to it; one deleted before another process opens it is compiled again there."""
    if max_bytes < 0:
        return 0
    entries = []
    with os.scandir(folder) as it:
        for entry in it:
            if entry.is_file(follow_symlinks=False):
                st = entry.stat(follow_symlinks=False)
                entries.append((max(st.st_atime, st.st_mtime), st.st_size, entry.path))
    total = sum(size for _, size, _ in entries)
    if total <= max_bytes:
        return 0
    deleted = 0
    for _, size, path in sorted(entries):
        if total <= PRUNE_TO * max_bytes:
            break
        try:
            os.unlink(path)
        except OSError:
            continue
        total -= size
        deleted += 1
    return deleted


def _jax_imported() -> bool:
    return "jax" in sys.modules


def _reset_jax_cache() -> None:
    """Make JAX read the settings again at its next compile (it decides once per process whether to use a cache)."""
    from jax._src import compilation_cache as cc

    cc.reset_cache()


_LRU_MODULE = "jax._src.lru_cache"


def _atomic_puts(module) -> None:
    """Make the file cache of ``module`` (``jax._src.lru_cache``) write each entry atomically.

    Without a size limit (JAX's default, and this module's: it prunes by itself) JAX writes an entry in place and
    takes no lock, so a process that reads the entry while another writes it gets a truncated executable; test
    workers crashed deserialising one (a segmentation fault in XLA, in a program two workers compiled at once). The
    entry is written to a temporary file in the same folder and renamed into place (atomic on POSIX), so a reader
    finds no entry or the whole one. With JAX's own size limit it locks the folder and is left as it is."""
    cls = getattr(module, "LRUCache", None)
    suffix = getattr(module, "_CACHE_SUFFIX", None)
    if cls is None or suffix is None or getattr(cls.put, "_atomic", False):
        return
    original = cls.put

    def put(self, key: str, value: bytes) -> None:
        if getattr(self, "eviction_enabled", True) or not key:
            return original(self, key, value)
        path = Path(str(self.path)) / f"{key}{suffix}"
        if path.exists():
            return None
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{time.monotonic_ns()}.tmp")
        try:
            tmp.write_bytes(value)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return None

    put._atomic = True
    cls.put = put


class _PatchOnImport:
    """A ``sys.meta_path`` finder that applies :func:`_atomic_puts` when JAX loads its cache module (importing the
    package does not import JAX)."""

    def find_spec(self, name, path=None, target=None):
        if name != _LRU_MODULE:
            return None
        sys.meta_path.remove(self)
        import importlib.util

        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        load = spec.loader.exec_module

        def exec_module(module):
            load(module)
            _atomic_puts(module)

        spec.loader.exec_module = exec_module
        return spec


def _make_writes_atomic() -> None:
    if _LRU_MODULE in sys.modules:
        _atomic_puts(sys.modules[_LRU_MODULE])
    elif not any(isinstance(f, _PatchOnImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _PatchOnImport())


def _apply(directory: str | None) -> None:
    """Point JAX's persistent cache at ``directory`` (``None``: off), in the environment or in JAX's config."""
    if _jax_imported():
        import jax

        jax.config.update("jax_compilation_cache_dir", directory)
        if directory is not None:
            jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
        _reset_jax_cache()
    else:
        if directory is None:
            os.environ.pop(_JAX_DIR, None)
        else:
            os.environ[_JAX_DIR] = directory
            os.environ.setdefault(_JAX_MIN_TIME, str(MIN_COMPILE_TIME_S))
    if directory is not None:
        _make_writes_atomic()
    _state["directory"] = directory
    _state["set_by_us"] = True


def _user_directory() -> str | None:
    """A cache directory that JAX was given by someone else than this module, or ``None``."""
    if _state["set_by_us"]:
        return None
    if _jax_imported():
        import jax

        value = jax.config.jax_compilation_cache_dir
        if value:
            return str(value)
    return os.environ.get(_JAX_DIR) or None


def configure(enabled: bool | None = None, directory: str | os.PathLike | None = None) -> Path | None:
    """Turn the persistent compilation cache on or off; the folder it uses (``None``: off).

    ``enabled=None`` follows ``$STP_ENV_COMPILATION_CACHE`` (on unless it says off); ``directory=None`` is
    :func:`default_dir`. Turning it on at run time takes effect at the next compile. A directory that JAX was
    given before :mod:`stp_env` was imported is kept when ``directory`` is ``None``.
    """
    if enabled is None:
        enabled = enabled_by_environment()
    if not enabled:
        _apply(None)
        return None
    user = _user_directory() if directory is None else None
    if user is not None:
        # A local folder is checked as this module's own is (a remote one, "gs://...", is JAX's to reach).
        if "://" not in user and private_cache_dir(user, what="JAX's compilation cache") is None:
            _apply(None)
            return None
        _state["directory"] = user
        return Path(user)
    path = Path(directory).expanduser() if directory is not None else default_dir()
    try:
        limit = max_size_bytes()
    except ValueError as err:  # refused before the folder is touched: nothing is deleted
        warnings.warn(f"not using the compilation cache: {err}", stacklevel=2)
        _apply(None)
        return None
    if private_cache_dir(path) is None:
        _apply(None)
        return None
    try:
        prune(path, limit)
    except OSError as err:  # a folder that cannot be listed is not used
        warnings.warn(f"not using {path} as the compilation cache: it cannot be read ({err}).", stacklevel=2)
        _apply(None)
        return None
    _apply(str(path))
    return path


def disable() -> None:
    """Turn the persistent compilation cache off for this process (:func:`configure` ``(enabled=False)``)."""
    configure(enabled=False)


def directory() -> Path | None:
    """The folder in use (``None``: off)."""
    value = _state["directory"]
    return None if value is None else Path(str(value))
