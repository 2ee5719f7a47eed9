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

**Its size, and several processes.** JAX's own least-recently-used cache keeps the folder under a size limit:
about :data:`DEFAULT_MAX_GB` GB (``STP_ENV_COMPILATION_CACHE_MAX_GB`` changes it), which this module gives JAX as
``jax_compilation_cache_max_size`` (in the environment, ``JAX_COMPILATION_CACHE_MAX_SIZE``, before JAX is imported).
With a limit, JAX takes a file lock on the folder (``.lockfile``, the ``filelock`` package) around every read and
write of an entry and deletes the least recently used entries before a write would exceed the limit, so processes
that share the folder (two test workers, Ray workers on one machine) never read an entry that another is still
writing. The price: before each write JAX lists the folder and reads every entry's access time, under the lock
(about 0.13 s a write with 3,000 entries on the 2-core machine, busy), and each read of an entry writes its access
time. ``-1`` means no limit: this module then gives JAX a limit no folder reaches (:data:`UNLIMITED_BYTES`)
rather than JAX's own ``-1``, because with ``-1`` JAX writes entries in place without the lock (a worker that read
an entry another was writing crashed deserialising a truncated executable). Any other value that is not a finite
number of GB above 0 (``0``, ``-2``, ``nan``, ``inf``, text) is refused: a one-line warning names the variable,
the cache is off in that process and nothing is deleted. When ``STP_ENV_COMPILATION_CACHE_MAX_GB`` is unset, a size
JAX was given by someone else (``JAX_COMPILATION_CACHE_MAX_SIZE``, or ``jax.config.update`` before importing
:mod:`stp_env`) is kept as it is, JAX's ``-1`` included (in-place writes: safe for one process at a time only).
JAX's eviction needs an access-time file beside each entry; entries without one (written by a process that ran
without a limit, e.g. an earlier version of this package) are given one, dated by the entry's modification time,
when a process checks the folder (:func:`private_cache_dir`), since JAX's eviction fails on them otherwise.

**Turning it off.** ``STP_ENV_COMPILATION_CACHE=0`` (or ``off``, ``false``, ``no``) in the environment before the
import, or :func:`configure` ``(enabled=False)`` (:func:`disable`) at run time; ``STP_ENV_COMPILATION_CACHE_DIR``
moves it. Turned off, JAX's persistent cache is off in the process, whatever folder it had. A cache directory that
JAX was already given (``JAX_COMPILATION_CACHE_DIR``, or ``jax.config.update("jax_compilation_cache_dir", ...)``
before importing :mod:`stp_env`) is otherwise used as it is, once it passes the check below. Deleting the folder
clears the cache (JAX writes entries in place, under its lock: one cut short by a killed process is warned about and
compiled again until then).

**Trust.** A compiled program is machine code: whoever can write the cache folder can make this process run code
(as whoever can write its ``site-packages``). Every folder that holds compiled programs goes through one check,
:func:`private_cache_dir`: this cache's folder, a local folder JAX was given before (``JAX_COMPILATION_CACHE_DIR``)
and a survivability study's ``OUT/jax-cache``. The folder is created private (mode ``0o700``), and a folder owned by
another user or writable by others (sticky bit or not) is not used (a warning says so). See
``docs/threat-model.md``.

**How it is set.** When :mod:`stp_env` is imported before JAX (the usual case: every submodule imports the package
first), the settings go into this process's environment (``JAX_COMPILATION_CACHE_DIR`` and the threshold
variables), where JAX reads them at its import; child processes inherit them. When JAX was imported first, they are
set with ``jax.config.update`` and JAX's cache is reset (``jax.experimental.compilation_cache.compilation_cache
.reset_cache``, public API) so that its next compile reads them. Nothing of JAX is patched.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import stat
import sys
import warnings
from pathlib import Path

ENV_VAR = "STP_ENV_COMPILATION_CACHE"
"""``0``, ``off``, ``false`` or ``no`` turns the persistent compilation cache off (anything else leaves it on)."""
DIR_ENV_VAR = "STP_ENV_COMPILATION_CACHE_DIR"
"""Where the compiled programs go instead of ``<artifact cache>/xla``."""
MAX_GB_ENV_VAR = "STP_ENV_COMPILATION_CACHE_MAX_GB"
"""The cache's size limit in GB (default :data:`DEFAULT_MAX_GB`): a finite number above 0, or ``-1``: no limit."""
DEFAULT_MAX_GB = 2.0
"""Beyond this, JAX deletes the least recently used programs before it writes another. A simulator rollout is tens
of MB compiled, the environment's reset and step well under a MB (BENCHMARKS.md, "The test suite with the compilation
cache" and "First step of ``parallel_env()`` in a fresh process")."""
UNLIMITED_BYTES = sys.maxsize
"""What JAX is given for ``STP_ENV_COMPILATION_CACHE_MAX_GB=-1`` (no limit): a limit no folder reaches, so that JAX
still locks the folder (its own ``-1`` writes in place without the lock)."""
MIN_COMPILE_TIME_S = 0.0
"""Programs that compiled faster than this are not written. JAX's default is 1 s; building a scenario's parameters
compiles about a hundred small programs (eager array operations, tens of ms each), which load from the cache faster
than they compile (BENCHMARKS.md, "First step of ``parallel_env()`` in a fresh process")."""

_JAX_DIR = "JAX_COMPILATION_CACHE_DIR"
_JAX_MIN_TIME = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
_JAX_MAX_SIZE = "JAX_COMPILATION_CACHE_MAX_SIZE"
_OFF = {"0", "off", "false", "no"}
_UNREAD = object()
_state: dict[str, object] = {"directory": None, "set_by_us": False, "given_size": _UNREAD}

# JAX's file cache on disk, as JAX 0.10.2 writes it with a size limit (its private ``lru_cache`` module, read in the
# installed package, never imported here):
# an entry ``<key>-cache``, beside it ``<key>-atime`` (the last access, ``time.time_ns()`` as 8 little-endian bytes),
# and the folder's lock ``.lockfile`` (``filelock.FileLock``). JAX has no public API for this layout; it is used only
# by :func:`_date_undated_entries`. Checked on jax/jaxlib 0.10.2.
_ENTRY_SUFFIX = "-cache"
_ATIME_SUFFIX = "-atime"
_LOCK_NAME = ".lockfile"
_LOCK_TIMEOUT_S = 10.0


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
    A folder that passes has its undated entries dated for JAX's eviction (:func:`_date_undated_entries`).

    ``what``: the cache, as the warning names it; ``advice``: what the warning suggests instead (default: a private
    ``$STP_ENV_COMPILATION_CACHE_DIR``, or turning the cache off)."""
    path = Path(path)
    problem = _private_dir(path)
    if problem is None:
        # a folder that cannot be listed: JAX itself warns when it cannot read or write an entry
        with contextlib.suppress(OSError):
            _date_undated_entries(path)
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


def jax_max_size() -> int:
    """The value this module gives JAX's ``jax_compilation_cache_max_size``: :func:`max_size_bytes`, with ``-1``
    (no limit) as :data:`UNLIMITED_BYTES`, so that JAX keeps locking the folder. ``ValueError`` as
    :func:`max_size_bytes`."""
    limit = max_size_bytes()
    return UNLIMITED_BYTES if limit < 0 else limit


def _date_undated_entries(folder: str | os.PathLike) -> int:
    """Give every entry of ``folder`` that has no access-time file one, dated by the entry's modification time; the
    number dated. JAX's eviction (with a size limit) reads the access time of every entry before each write and fails
    on an entry without one, and would then write nothing more: entries written without a limit (an earlier version of
    this package, a process run with JAX's default) have none. Done under JAX's own lock of the folder, once per
    check of it (one directory listing); skipped when the lock is busy for :data:`_LOCK_TIMEOUT_S` or ``filelock``
    is missing. The layout is JAX's (see ``_ENTRY_SUFFIX``): no public API exposes it."""
    try:
        import filelock
    except ImportError:
        return 0
    folder = Path(folder)
    with os.scandir(folder) as it:
        names = {entry.name for entry in it}
    undated = [name for name in names
               if name.endswith(_ENTRY_SUFFIX) and name[:-len(_ENTRY_SUFFIX)] + _ATIME_SUFFIX not in names]
    if not undated:
        return 0
    dated = 0
    try:
        with filelock.FileLock(str(folder / _LOCK_NAME), timeout=_LOCK_TIMEOUT_S):
            for name in undated:
                entry = folder / name
                atime = folder / (name[:-len(_ENTRY_SUFFIX)] + _ATIME_SUFFIX)
                try:
                    if atime.exists():
                        continue
                    when = entry.stat().st_mtime_ns
                    atime.write_bytes(when.to_bytes(8, "little"))
                except OSError:  # deleted meanwhile (JAX evicted it), or unreadable: JAX's concern
                    continue
                dated += 1
    except filelock.Timeout:
        return 0
    return dated


def _jax_imported() -> bool:
    return "jax" in sys.modules


def _reset_jax_cache() -> None:
    """Make JAX read the settings again at its next compile (it decides once per process whether to use a cache, and
    reads the folder and the size limit then). ``reset_cache`` is public in ``jax.experimental.compilation_cache``
    (checked on JAX 0.10.2)."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    cc.reset_cache()


def _given_jax_max_size() -> int | None:
    """A size limit JAX was given by someone other than this module (``JAX_COMPILATION_CACHE_MAX_SIZE``, or
    ``jax.config.update`` before JAX's cache was first configured here), or ``None``: read once per process, before
    this module sets it."""
    if _state["given_size"] is _UNREAD:
        value = None
        if _jax_imported():
            import jax

            current = int(jax.config.jax_compilation_cache_max_size)
            if current != -1 or _JAX_MAX_SIZE in os.environ:
                value = current
        else:
            text = os.environ.get(_JAX_MAX_SIZE, "").strip()
            try:
                value = int(text) if text else None
            except ValueError:
                value = None  # JAX would refuse it at its import; this module's limit replaces it
        _state["given_size"] = value
    return _state["given_size"]  # type: ignore[return-value]


def _size_for_jax() -> int:
    """JAX's size limit to be: from :data:`MAX_GB_ENV_VAR` when it is set (:func:`jax_max_size`), else one JAX was
    given by someone else (kept as it is), else the default. ``ValueError`` for a bad :data:`MAX_GB_ENV_VAR`."""
    given = _given_jax_max_size()
    if given is not None and not os.environ.get(MAX_GB_ENV_VAR, "").strip():
        return given
    return jax_max_size()


def _set_jax_max_size(max_size: int) -> None:
    """Give JAX's ``jax_compilation_cache_max_size`` the value ``max_size`` (bytes), in the environment or in JAX's
    config."""
    if _jax_imported():
        import jax

        jax.config.update("jax_compilation_cache_max_size", max_size)
        _reset_jax_cache()
    else:
        os.environ[_JAX_MAX_SIZE] = str(max_size)


def _apply(directory: str | None, max_size: int | None = None) -> None:
    """Point JAX's persistent cache at ``directory`` (``None``: off) with the size limit ``max_size`` (bytes), in the
    environment or in JAX's config."""
    if _jax_imported():
        import jax

        jax.config.update("jax_compilation_cache_dir", directory)
        if directory is not None:
            jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
            if max_size is not None:
                jax.config.update("jax_compilation_cache_max_size", max_size)
        _reset_jax_cache()
    else:
        if directory is None:
            os.environ.pop(_JAX_DIR, None)
        else:
            os.environ[_JAX_DIR] = directory
            os.environ.setdefault(_JAX_MIN_TIME, str(MIN_COMPILE_TIME_S))
            if max_size is not None:
                os.environ[_JAX_MAX_SIZE] = str(max_size)
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
    given before :mod:`stp_env` was imported is kept when ``directory`` is ``None``. Either way JAX is given the
    size limit (:func:`jax_max_size`), which makes it lock the folder; a bad :data:`MAX_GB_ENV_VAR`, or no
    ``filelock`` package (JAX's lock), turns the cache off with a warning.
    """
    _given_jax_max_size()  # read before this module sets it
    if enabled is None:
        enabled = enabled_by_environment()
    if not enabled:
        _apply(None)
        return None
    try:
        max_size = _size_for_jax()
    except ValueError as err:  # refused before the folder is touched: nothing is deleted
        warnings.warn(f"not using the compilation cache: {err}", stacklevel=2)
        _apply(None)
        return None
    if max_size != -1 and importlib.util.find_spec("filelock") is None:
        warnings.warn("not using the compilation cache: JAX locks its folder with the filelock package, which is not "
                      "installed (pip install filelock).", stacklevel=2)
        _apply(None)
        return None
    user = _user_directory() if directory is None else None
    if user is not None:
        # A local folder is checked as this module's own is (a remote one, "gs://...", is JAX's to reach).
        if "://" not in user and private_cache_dir(user, what="JAX's compilation cache") is None:
            _apply(None)
            return None
        _set_jax_max_size(max_size)
        _state["directory"] = user
        return Path(user)
    path = Path(directory).expanduser() if directory is not None else default_dir()
    if private_cache_dir(path) is None:
        _apply(None)
        return None
    _apply(str(path), max_size)
    return path


def disable() -> None:
    """Turn the persistent compilation cache off for this process (:func:`configure` ``(enabled=False)``)."""
    configure(enabled=False)


def directory() -> Path | None:
    """The folder in use (``None``: off)."""
    value = _state["directory"]
    return None if value is None else Path(str(value))
