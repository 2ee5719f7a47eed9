"""Files written atomically, and the temporary files of writers that died (a low-level module: the standard
library only, used by the artifact cache, the result writers, the planner's checkpoints and the studies).

A writer writes a temporary file beside its target and moves it onto the target (``os.replace``) only when the
whole content is written: a reader sees the old content or the complete new one, never half of it. Temporary files
are named after their writer (``.stp-tmp-<pid>-<host>-*``), so that those of a writer killed mid-write can be told
from those of a live one and removed (:func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import tempfile
import time
from pathlib import Path

TEMP_PREFIX = ".stp-tmp-"
LEGACY_TEMP_SUFFIXES = (".npz.tmp", ".json.tmp")  # temporary files of earlier versions (no writer recorded)
LEGACY_TEMP_AGE_S = 3600.0


def _host() -> str:
    return "".join(c if c.isalnum() else "_" for c in socket.gethostname())[:40] or "host"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def writer_tag() -> str:
    """``"<pid>-<host>-"``: what a temporary file's name records about its writer (see
    :func:`remove_stale_temporaries`)."""
    return f"{os.getpid()}-{_host()}-"


def remove_stale_temporaries(root: Path, prefix: str = TEMP_PREFIX) -> list[Path]:
    """Remove the temporary files (or directories) that writers which are no longer running (killed mid-write)
    left in ``root``: ``<prefix><pid>-<host>-*`` of this host whose process is gone and, for the cache's own
    prefix, unnamed ``*.npz.tmp`` / ``*.json.tmp`` of earlier versions older than an hour. Returns the removed
    paths (errors are ignored: a read-only directory keeps them)."""
    removed = []
    try:
        entries = list(Path(root).iterdir())
    except OSError:
        return removed
    host, now = _host(), time.time()
    for path in entries:
        name = path.name
        stale = False
        if name.startswith(prefix):
            pid, _, rest = name[len(prefix):].partition("-")
            stale = pid.isdigit() and rest.startswith(host + "-") and not _pid_alive(int(pid))
        elif prefix == TEMP_PREFIX and name.endswith(LEGACY_TEMP_SUFFIXES):
            try:
                stale = now - path.stat().st_mtime > LEGACY_TEMP_AGE_S
            except OSError:
                stale = False
        if stale:
            try:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
                removed.append(path)
            except OSError:
                pass
    return removed


def plain_file_mode() -> int:
    """The permissions ``open(path, "w")`` gives a new file (``0o666`` less the process's umask). A temporary file
    from ``tempfile.mkstemp`` is private (``0o600``); results moved into place from one get these instead, so that
    they are as readable as any other file the user writes."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


class WriteError(OSError):
    """An output that could not be written (a full disk, a quota, a read-only or missing directory): one line,
    ``"cannot write <path>: <the system's reason>"``, with the system's ``errno``."""

    def __init__(self, path, err: OSError):
        super().__init__(err.errno, err.strerror or str(err))
        self.path = Path(path)

    def __str__(self) -> str:
        return f"cannot write {self.path}: {self.strerror}"

    def __reduce__(self):
        return type(self), (self.path, OSError(self.errno, self.strerror))


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Open a temporary file beside ``path`` for writing and move it onto ``path`` (``os.replace``) when the block
    ends without an error: ``path`` is either its old content or the complete new one, never half written. The
    file gets the permissions of a plainly written one (:func:`plain_file_mode`).

    An ``OSError`` of the writing (creating, writing, flushing, closing or moving the file; in the block, one that
    names no file, as a write to this one does) is a :class:`WriteError` naming ``path``: a full disk reads
    ``cannot write OUT/x.json: No space left on device``, not a bare ``[Errno 28]``."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=TEMP_PREFIX + writer_tag(), suffix=path.suffix)
    except OSError as err:
        raise WriteError(path, err) from err
    fh = None
    try:
        fh = os.fdopen(fd, mode, **kwargs)
        try:
            yield fh
        except OSError as err:
            if err.filename is not None or isinstance(err, WriteError):
                raise  # another file's error (a read in the block): its own message names that file
            raise WriteError(path, err) from err
        try:
            fh.close()  # flushes: a full disk may only show here
            os.chmod(tmp, plain_file_mode())
            os.replace(tmp, path)
        except OSError as err:
            raise WriteError(path, err) from err
    finally:
        if fh is None:
            os.close(fd)
        elif not fh.closed:
            with contextlib.suppress(OSError):  # the block's own error is the one to report
                fh.close()
        if os.path.exists(tmp):
            os.remove(tmp)


def write_text(text: str, path) -> str:
    """``text`` to ``path``, atomically (:func:`atomic_open`)."""
    with atomic_open(path) as fh:
        fh.write(text)
    return str(path)


def save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig(path, **kwargs)``, atomically (:func:`atomic_open`; the format from the path's suffix, PNG
    without one): an interrupted run leaves the old figure or none, never a truncated one."""
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format=path.suffix[1:].lower() or "png", **kwargs)
    return path


def append_csv_row(path, row: dict) -> None:
    """Append ``row`` to the csv file ``path`` (its keys are the columns; the header first when the file is new);
    :class:`WriteError` naming ``path`` when it cannot be written."""
    import csv

    path = Path(path)
    new = not path.exists()
    try:
        with path.open("a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(row))
            if new:
                writer.writeheader()
            writer.writerow(row)
    except OSError as err:
        raise WriteError(path, err) from err


def move_aside(path) -> Path | None:
    """Rename ``path`` (a file, directory, FIFO or link that a reader refused) to ``NAME.rejected-<hex>`` beside
    it, so that it is never read again and a writer can put the right file in its place; nothing is deleted.
    Returns the new path, or ``None`` when there was nothing to move or the folder is read-only."""
    import uuid

    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        return None
    target = path.with_name(f"{path.name}.rejected-{uuid.uuid4().hex[:8]}")
    try:
        path.rename(target)
    except OSError:
        return None
    return target


def is_regular_file(path) -> bool:
    """Whether ``path`` itself (not what a link points to) is a regular file."""
    import stat

    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False
