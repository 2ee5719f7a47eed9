"""The one contract of every reader of a file that a user or another machine can hand over (``docs/threat-model.md``).

Every such reader in the package goes through this module, which checks, before anything is computed from the
file:

* **a regular file only**: a directory, a FIFO, a socket or a device is refused (opened without blocking, so that
  a FIFO in place of a file is refused at once instead of waiting for a writer forever);
* **a size cap** (per kind of file, :data:`LOADERS`), on the file and, for ``.npz`` archives, on the arrays it
  would decompress to (each array's header is read and checked against its member's size before any array is
  allocated: a header that promises a terabyte, or a compressed member that would inflate past the cap, is refused);
* **bounded nesting** for JSON (:data:`MAX_JSON_DEPTH`, checked on the text before it is parsed, so that
  ``[`` x 100,000 is a clear error, not a ``RecursionError``);
* **no code**: ``.npz`` members are read with ``allow_pickle=False`` (object arrays are refused), JSON is parsed as
  data, nothing is imported or evaluated.

A problem is a :class:`LoadError` (a ``ValueError``): one line that names the file and says what is wrong. The
structure, types and ranges of what was read are then checked by each loader (its row in the threat model) before
it computes anything.

This module imports NumPy only (no JAX), so that the command line can use it cheaply.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import re
import stat
import zipfile
from pathlib import Path

import numpy as np

KiB, MiB, GiB = 1 << 10, 1 << 20, 1 << 30

MAX_JSON_DEPTH = 64
"""The deepest nesting of JSON arrays and objects any loader accepts (the package writes at most about 10)."""

MAX_NPZ_MEMBERS = 10_000
"""The most arrays an ``.npz`` file may hold."""


@dataclasses.dataclass(frozen=True)
class Loader:
    """A kind of file read from outside: what it is called in messages and its size caps [bytes]
    (``max_bytes``: the file; ``max_array_bytes``: what an archive's arrays decompress to)."""

    what: str
    max_bytes: int
    max_array_bytes: int = 0


LOADERS: dict[str, Loader] = {
    "artifact-metadata": Loader("artifact cache metadata file", 16 * MiB),
    "artifact-arrays": Loader("artifact cache array file", 16 * GiB, 16 * GiB),
    "events": Loader("events file", 256 * MiB),
    "event-states": Loader("events archive", 16 * GiB, 16 * GiB),
    "counterexample": Loader("counterexample file", 64 * MiB),
    "learned-policy": Loader("learned-policy file", 256 * MiB, 1 * GiB),
    "plan-checkpoint": Loader("planning checkpoint", 16 * GiB, 16 * GiB),
    "study-metadata": Loader("survivability study file", 16 * MiB),
    "study-missions": Loader("survivability missions file", 1 * GiB),
    "job-piece": Loader("job piece file", 16 * GiB, 16 * GiB),
    "jax-checkpoint": Loader("JAX training checkpoint", 16 * GiB, 16 * GiB),
}
"""Every kind of file the package reads from outside, by the name the threat model's table gives it."""


class LoadError(ValueError):
    """A file that cannot be loaded: ``"<path>: <what is wrong>"`` on one line."""

    def __init__(self, path, problem: str):
        self.path = Path(path)
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{path}: {self.problem}")


def loader(kind: str) -> Loader:
    try:
        return LOADERS[kind]
    except KeyError:
        raise ValueError(f"unknown kind of file {kind!r}; known: {', '.join(LOADERS)}.") from None


def _a(what: str) -> str:
    return f"{'an' if what[:1] in 'aeiou' else 'a'} {what}"


def _size(n: int) -> str:
    for unit, size in (("GiB", GiB), ("MiB", MiB), ("KiB", KiB)):
        if n >= size:
            return f"{n / size:g} {unit}"
    return f"{n} bytes"


_FILE_TYPES = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def _not_regular(mode: int) -> str | None:
    if stat.S_ISREG(mode):
        return None
    for test, name in _FILE_TYPES:
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path, kind: str) -> os.stat_result:
    """``os.stat(path)`` if ``path`` is a regular file within the size cap of ``kind``; :class:`LoadError`
    otherwise (``FileNotFoundError`` is reported as ``no such <what>``)."""
    spec = loader(kind)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise LoadError(path, f"no such {spec.what}.") from None
    except OSError as err:
        raise LoadError(path, f"cannot read the {spec.what} ({err.strerror or err}).") from None
    _check_stat(path, st, spec)
    return st


def _check_stat(path, st: os.stat_result, spec: Loader) -> None:
    other = _not_regular(st.st_mode)
    if other is not None:
        raise LoadError(path, f"is {other}, not a regular file; {_a(spec.what)} must be a regular file.")
    if st.st_size > spec.max_bytes:
        raise LoadError(path, f"is {_size(st.st_size)}, more than {_a(spec.what)} may be ({_size(spec.max_bytes)}).")


def open_regular(path, kind: str):
    """``path`` opened for binary reading, if it is a regular file within the size cap of ``kind``
    (:class:`LoadError` otherwise). Opened with ``O_NONBLOCK`` and checked again on the open descriptor, so that a
    FIFO (or a file swapped for one) never blocks."""
    spec = loader(kind)
    check_regular(path, kind)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise LoadError(path, f"no such {spec.what}.") from None
    except OSError as err:
        raise LoadError(path, f"cannot read the {spec.what} ({err.strerror or err}).") from None
    try:
        _check_stat(path, os.fstat(fd), spec)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path, kind: str) -> bytes:
    """The contents of a regular file of ``kind`` (:func:`open_regular`), at most its size cap."""
    spec = loader(kind)
    with open_regular(path, kind) as fh:
        try:
            data = fh.read(spec.max_bytes + 1)
        except OSError as err:
            raise LoadError(path, f"cannot read the {spec.what} ({err.strerror or err}).") from None
    if len(data) > spec.max_bytes:
        raise LoadError(path, f"is more than {_a(spec.what)} may be ({_size(spec.max_bytes)}).")
    return data


def read_text(path, kind: str) -> str:
    """:func:`read_bytes` decoded as UTF-8."""
    data = read_bytes(path, kind)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise LoadError(path, f"not {_a(loader(kind).what)}: not UTF-8 text (byte {err.start}).") from None


_JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_CHUNK = 1 << 24


def json_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON ``text`` (brackets inside strings do not count), found
    without parsing it (linear time, no recursion)."""
    brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text)).encode("ascii")
    depth = deepest = 0
    for start in range(0, len(brackets), _CHUNK):  # in chunks: a file of brackets needs no 8 bytes per bracket
        codes = np.frombuffer(brackets, np.uint8, count=min(_CHUNK, len(brackets) - start), offset=start)
        levels = depth + np.cumsum(np.where((codes == ord("[")) | (codes == ord("{")), 1, -1).astype(np.int32),
                                   dtype=np.int64)
        deepest, depth = max(deepest, int(levels.max())), int(levels[-1])
    return deepest


def parse_json(text: str, path, what: str, max_depth: int = MAX_JSON_DEPTH):
    """``json.loads(text)`` with the nesting bounded by ``max_depth``; :class:`LoadError` naming ``path`` (the
    file the text came from) for invalid or too deeply nested JSON."""
    depth = json_depth(text)
    if depth > max_depth:
        raise LoadError(path, f"not {_a(what)}: JSON nested {depth} levels deep (at most {max_depth}).")
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - json_depth refuses what would recurse this deep
        raise LoadError(path, f"not {_a(what)}: JSON nested too deeply.") from None
    except ValueError as err:  # JSONDecodeError, and integers longer than Python converts
        raise LoadError(path, f"not {_a(what)} (invalid JSON: {err}).") from None


def read_json(path, kind: str, max_depth: int = MAX_JSON_DEPTH):
    """The JSON value in a regular file of ``kind`` (size capped, nesting bounded: :func:`parse_json`)."""
    return parse_json(read_text(path, kind), path, loader(kind).what, max_depth)


def _array_header(fp, path, what: str, name: str):
    """``(shape, fortran_order, dtype)`` of the ``.npy`` member ``name`` (versions 1.0 and 2.0)."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fp)
        if version == (1, 0):
            return fmt.read_array_header_1_0(fp)
        if version == (2, 0):
            return fmt.read_array_header_2_0(fp)
    except (ValueError, EOFError, OSError, zipfile.BadZipFile, SyntaxError, TypeError) as err:
        raise LoadError(path, f"not {_a(what)}: array {name!r} has no valid .npy header ({err}).") from None
    raise LoadError(path, f"not {_a(what)}: array {name!r} is in .npy format {version}, which is not read.")


def read_npz(path, kind: str) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` archive of ``kind``: a regular file within its size cap, at most
    :data:`MAX_NPZ_MEMBERS` members, every member a ``.npy`` array of a numeric, boolean or string dtype (never an
    object array: nothing is unpickled) whose header agrees with the member's size, all of them decompressing to at
    most the cap on arrays. Every problem is a :class:`LoadError` naming the file."""
    spec = loader(kind)
    what = spec.what
    arrays: dict[str, np.ndarray] = {}
    with open_regular(path, kind) as fh:
        try:
            archive = zipfile.ZipFile(fh)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
            raise LoadError(path, f"not {_a(what)}: not an .npz archive ({err}).") from None
        with archive:
            members = archive.infolist()
            if len(members) > MAX_NPZ_MEMBERS:
                raise LoadError(path, f"not {_a(what)}: {len(members)} members (at most {MAX_NPZ_MEMBERS}).")
            total = 0
            for info in members:
                name = info.filename
                if not name.endswith(".npy") or info.is_dir():
                    raise LoadError(path, f"not {_a(what)}: member {name!r} is not a .npy array.")
                key = name[:-4]
                if key in arrays:
                    raise LoadError(path, f"not {_a(what)}: array {key!r} appears twice.")
                total += info.file_size
                if info.file_size > spec.max_array_bytes or total > spec.max_array_bytes:
                    raise LoadError(path, f"its arrays would take more than {_a(what)} may "
                                          f"({_size(spec.max_array_bytes)}).")
                try:
                    with archive.open(info) as member:
                        shape, _, dtype = _array_header(member, path, what, key)
                        if dtype.hasobject or dtype.kind not in "biufcUS":
                            raise LoadError(path, f"not {_a(what)}: array {key!r} has dtype {dtype}; only numeric "
                                                  "and string arrays are read (nothing is unpickled).")
                        if any(d < 0 for d in shape):
                            raise LoadError(path, f"not {_a(what)}: array {key!r} has shape {shape}.")
                        nbytes = math.prod(shape) * dtype.itemsize
                        header = member.tell()
                        if header + nbytes != info.file_size:
                            raise LoadError(path, f"not {_a(what)}: array {key!r} of shape {shape} and dtype {dtype} "
                                                  f"does not fit its {info.file_size}-byte member (truncated or "
                                                  "edited).")
                    with archive.open(info) as member:
                        arrays[key] = np.lib.format.read_array(member, allow_pickle=False)
                except LoadError:
                    raise
                except (ValueError, EOFError, OSError, zipfile.BadZipFile, KeyError, RuntimeError,
                        NotImplementedError) as err:  # bad CRC, truncated data, unsupported compression
                    raise LoadError(path, f"not {_a(what)}: array {key!r} is unreadable "
                                          f"({type(err).__name__}: {err}).") from None
    return arrays


MAX_CSV_LINE = 1 * MiB
"""The longest line a CSV file may have [characters]."""


def read_csv_rows(path, kind: str, fields, *, older=(), drop_torn_tail: bool = False) -> list[dict[str, str]]:
    """The rows of a CSV file of ``kind`` with the header ``fields``, as dicts of strings; a row that does not
    have exactly those fields (e.g. a line torn by an interrupted write) is left out. :class:`LoadError` for a file
    that is not UTF-8 CSV (a line longer than :data:`MAX_CSV_LINE`, a field beyond the csv module's limit, a NUL
    byte) or whose header is not ``fields``.

    ``older``: headers of earlier formats that are read too; the rows of such a file are keyed by its own header's
    fields (the caller tells the format by the keys). ``drop_torn_tail``: also leave out a last line without its line
    ending (cut short by an interrupted write, even where it still has the right number of fields)."""
    import io

    what = loader(kind).what
    fields = tuple(fields)
    headers = [fields, *(tuple(h) for h in older)]
    with open_regular(path, kind) as fh:
        text = io.TextIOWrapper(fh, encoding="utf-8", newline="")

        def lines():  # bounded lines: the csv module would read a line of any length into memory first
            number = 0
            while line := text.readline(MAX_CSV_LINE + 1):
                number += 1
                if len(line) > MAX_CSV_LINE:
                    raise LoadError(path, f"not {_a(what)}: line {number} is longer than {_size(MAX_CSV_LINE)}.")
                if drop_torn_tail and not line.endswith("\n"):
                    return  # the last line (a line without its ending is always the last one)
                yield line

        reader = csv.reader(lines())
        rows = []
        try:
            header = next(reader, None)
            if header is None:
                return []
            if tuple(header) not in headers:
                raise LoadError(path, f"not {_a(what)}: its header is not {','.join(fields)}.")
            names = tuple(header)
            for row in reader:
                if len(row) == len(names):
                    rows.append(dict(zip(names, row)))
        except csv.Error as err:
            raise LoadError(path, f"not {_a(what)}: line {reader.line_num}: {err}.") from None
        except UnicodeDecodeError as err:
            raise LoadError(path, f"not {_a(what)}: not UTF-8 text (byte {err.start}).") from None
        except OSError as err:
            raise LoadError(path, f"cannot read the {what} ({err.strerror or err}).") from None
    return rows
