"""The record of a survivability study: its ``missions*.csv`` files, its ``study.json`` and the provenance of every
row (the survivability study's record format, :data:`RECORD_FORMAT`).

Every row of a missions file proves which study wrote it: it carries the study's fingerprint (:func:`study_id`) and a
SHA-256 digest of that fingerprint and of the row's values, its key ``(N_p, N_u, instance, policy)`` among them
(:func:`row_digest`). A study resumes from, and reports, only the rows that are its own: its fingerprint, a key of
its scenarios, policies and instances that no earlier row had, the digest recomputed and equal. Any other row (of
another study, edited, of an older format without the fingerprint, beyond the study's instances) is left out with one
warning per file, and the missions it stood for are flown again. Every file is read under the loader contract
(:mod:`stp_env.loaders`) and written atomically.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import os
import uuid
import warnings
from collections import Counter
from pathlib import Path

from stp_env.arguments import INT32_MAX
from stp_env.files import atomic_open, write_text
from stp_env.loaders import read_csv_rows, read_json
from stp_env.survivability.config import StudyConfig

FIELDS = ("n_partial", "n_unknown", "instance", "policy", "outcome", "reveals", "omega_switch", "n_dp", "windows",
          "instance_s", "mission_s")
"""A mission's columns (the rows :func:`read_missions` and :func:`read_study` return)."""
RECORD_FIELDS = (*FIELDS, "study", "digest")
"""The columns of a missions file: a mission's :data:`FIELDS`, the fingerprint of the study that flew it
(:func:`study_id`) and the digest of both (:func:`row_digest`)."""
RECORD_FORMAT = "stp-env survivability mission v1"
"""What every row digest starts from (another format of the record gives other digests)."""


def study_id(fingerprint: dict) -> str:
    """SHA-256 hex digest of a study's fingerprint (:meth:`StudyConfig.fingerprint`, or the one ``study.json``
    holds): what every row of the study's missions files carries. Fields that are ``None`` do not count, as
    :func:`_same_config` counts a field added since a study was written, and unset, as absent."""
    text = json.dumps(_without_none(fingerprint), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _without_none(value):
    if isinstance(value, dict):
        return {k: _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_without_none(v) for v in value]
    return value


def row_digest(study: str, values) -> str:
    """SHA-256 hex digest of one mission row: :data:`RECORD_FORMAT`, the study's id (:func:`study_id`) and the
    row's values (:data:`FIELDS`, in order) as the file holds them, each with its length (so that no two rows hash
    the same text)."""
    h = hashlib.sha256(f"{RECORD_FORMAT}\n{study}\n".encode())
    for value in values:
        data = str(value).encode()
        h.update(b"%d:%b\n" % (len(data), data))
    return h.hexdigest()


def _text(value) -> str:
    """A value as a missions file holds it (a float by its shortest exact text)."""
    return repr(value) if isinstance(value, float) else str(value)


def stamp_rows(study: str, rows) -> list[dict[str, str]]:
    """Missions (dicts of :data:`FIELDS`) as the rows of a missions file of study ``study`` (:func:`study_id`):
    their values as text, the study's id and each row's digest (:data:`RECORD_FIELDS`)."""
    out = []
    for row in rows:
        values = [_text(row[name]) for name in FIELDS]
        out.append({**dict(zip(FIELDS, values)), "study": study, "digest": row_digest(study, values)})
    return out


@dataclasses.dataclass(frozen=True)
class Provenance:
    """What a row of a missions file must match to be used: the study's id (:func:`study_id`), its scenarios
    ``(N_p, N_u)``, its policies and its number of instances (rows of instances ``0 .. n_instances - 1`` only)."""

    study: str
    scenarios: frozenset
    policies: tuple[str, ...]
    n_instances: int

    @classmethod
    def of(cls, config: StudyConfig) -> Provenance:
        """The provenance of the rows the study ``config`` writes."""
        return cls(study_id(config.fingerprint()), frozenset(config.scenarios), tuple(config.policies),
                   config.n_instances)

    @classmethod
    def from_metadata(cls, meta: dict, path) -> Provenance:
        """The provenance of the study whose ``study.json`` (at ``path``, already read by
        :func:`read_study_metadata`) is ``meta``; a one-line ``ValueError`` naming the file when it does not say
        the study's scenarios, policies and number of instances."""
        fp, n = meta["fingerprint"], meta.get("n_instances")

        def integers(value) -> bool:
            return isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)

        policies = fp.get("policies")
        if not (integers(fp.get("n_partial")) and integers(fp.get("n_unknown")) and isinstance(policies, list)
                and all(isinstance(p, str) for p in policies) and isinstance(n, int) and not isinstance(n, bool)
                and 1 <= n <= INT32_MAX):
            raise ValueError(f"{path}: not a survivability study file (its fingerprint does not give n_partial, "
                             "n_unknown and policies, or n_instances is not a positive integer); remove it or "
                             "choose another --out.")
        return cls(study_id(fp), frozenset((p, u) for p in fp["n_partial"] for u in fp["n_unknown"]),
                   tuple(policies), n)


@dataclasses.dataclass
class _Checked:
    """One missions file, checked against a :class:`Provenance`: the rows used (parsed, and as the file holds
    them), and how many rows were left out for each reason (:data:`_REASONS`)."""

    path: Path
    rows: list[dict] = dataclasses.field(default_factory=list)
    texts: list[dict] = dataclasses.field(default_factory=list)
    refused: Counter = dataclasses.field(default_factory=Counter)
    foreign: set = dataclasses.field(default_factory=set)

    def problem(self, provenance: Provenance | None) -> str | None:
        """Why rows of the file were left out, on one line (``None``: every row is used)."""
        if not self.refused:
            return None
        n = sum(self.refused.values())
        parts = []
        for reason, count in self.refused.items():
            what = _REASONS[reason]
            if reason == "foreign":
                shown = ", ".join(sorted({_shown(f) for f in self.foreign})[:3])
                what = f"{what} (fingerprint {shown}, this study's {provenance.study[:12]})"
            elif reason == "instance":
                what = f"{what} {provenance.n_instances}"
            parts.append(f"{count} {what}")
        return (f"{self.path}: {n} row{'s' if n > 1 else ''} not used, {'; '.join(parts)}; the study's own "
                "missions among them are flown again")


def _shown(study: str) -> str:
    """The start of a study id as a warning shows it (what is not a hex digit, a newline say, as ``?``)."""
    return "".join(c if c in "0123456789abcdef" else "?" for c in study[:12])


_REASONS = {
    "unproven": "that no study.json beside the file says whose they are",
    "older": "of an older format, without their study's fingerprint and digest",
    "foreign": "from another study",
    "unreadable": "whose values do not parse",
    "digest": "whose values do not match their digest (edited after they were written)",
    "scenario": "for a scenario or policy that this study does not fly",
    "instance": "for instances beyond this study's",
    "duplicate": "repeating a mission read before",
}
"""Why a row of a missions file is not used, as a warning says it."""

_INT_COLUMNS = ("n_partial", "n_unknown", "instance", "reveals", "omega_switch", "n_dp", "windows")
_WARNED: set[tuple[str, str]] = set()


def _check_missions(path: Path, provenance: Provenance | None, seen: set) -> _Checked:
    """Read one missions file under the loader contract and keep the rows of the study ``provenance`` (``None``:
    none can be proven) whose mission is not in ``seen`` (updated with those kept). A file that is not a missions
    file at all is a one-line ``ValueError`` naming it."""
    checked = _Checked(path)
    if not path.exists() and not path.is_symlink():
        return checked
    raw = read_csv_rows(path, "study-missions", RECORD_FIELDS, older=(FIELDS,), drop_torn_tail=True)
    for row in raw:
        reason = _refusal(row, provenance, seen, checked)
        if reason is not None:
            checked.refused[reason] += 1
    return checked


def _refusal(row: dict[str, str], provenance: Provenance | None, seen: set, checked: _Checked) -> str | None:
    """Why ``row`` (text, as read) is not used, or ``None`` after adding it to ``checked`` and its key to ``seen``."""
    if "digest" not in row:
        return "older"
    if provenance is None:
        return "unproven"
    if row["study"] != provenance.study:
        checked.foreign.add(row["study"])
        return "foreign"
    try:
        ints = {k: int(row[k]) for k in _INT_COLUMNS}
        floats = {k: float(row[k]) for k in ("instance_s", "mission_s")}
    except ValueError:
        return "unreadable"
    if not (all(abs(v) <= INT32_MAX for v in ints.values()) and all(math.isfinite(v) for v in floats.values())):
        return "unreadable"
    if row["digest"] != row_digest(provenance.study, [row[k] for k in FIELDS]):
        return "digest"
    key = (ints["n_partial"], ints["n_unknown"], ints["instance"], row["policy"])
    if key[:2] not in provenance.scenarios or key[3] not in provenance.policies:
        return "scenario"
    if not 0 <= key[2] < provenance.n_instances:
        return "instance"
    if key in seen:
        return "duplicate"
    seen.add(key)
    checked.rows.append({**{k: row[k] for k in FIELDS}, **ints, **floats})
    checked.texts.append({k: row[k] for k in RECORD_FIELDS})
    return None


def _warn(message: str | None, path: Path) -> None:
    """One ``RuntimeWarning`` per file and problem in a process (a study and its report read the files again)."""
    if message is not None and (str(path), message) not in _WARNED:
        _WARNED.add((str(path), message))
        warnings.warn(message, RuntimeWarning, stacklevel=3)


def _folder_provenance(out: Path) -> Provenance | None:
    """The provenance of the study in ``out``, from its ``study.json`` (``None`` when there is none)."""
    meta_path = out / "study.json"
    if not (meta_path.exists() or meta_path.is_symlink()):
        return None
    return Provenance.from_metadata(read_study_metadata(meta_path), meta_path)


def _missions_files(out: Path) -> list[Path]:
    return sorted(out.glob("missions*.csv"))


def read_study(out, config: StudyConfig | None = None) -> list[dict]:
    """Every mission of the study ``config`` in directory ``out`` (``missions.csv`` and the workers'
    ``missions-*.csv``); ``config=None``: of the study that ``out/study.json`` describes. Only the rows that are the
    study's own are returned (the module's docstring); the others are left out with one ``RuntimeWarning`` per
    file that names it and says why. Every file is read under the loader contract (:func:`read_missions`)."""
    out = Path(out)
    provenance = Provenance.of(config) if config is not None else _folder_provenance(out)
    rows, seen = [], set()
    for path in _missions_files(out):
        checked = _check_missions(path, provenance, seen)
        _warn(checked.problem(provenance), path)
        rows += checked.rows
    return rows


def read_missions(path: Path, config: StudyConfig | None = None) -> list[dict]:
    """The missions of one missions file that are the study ``config``'s own (``config=None``: of the study that
    ``study.json`` beside the file describes), as dicts of :data:`FIELDS`; every other row is left out with one
    ``RuntimeWarning`` naming the file and saying why (a trailing line cut short by an interrupted write is left out
    silently). Read under the loader contract (:func:`stp_env.loaders.read_csv_rows`: a regular file of at most
    1 GiB, lines of at most 1 MiB, the header :data:`RECORD_FIELDS`, or :data:`FIELDS` of the older format whose
    rows are all left out): a file that is not one is a one-line ``ValueError`` naming it, never a traceback or a
    wait."""
    path = Path(path)
    provenance = Provenance.of(config) if config is not None else _folder_provenance(path.parent)
    checked = _check_missions(path, provenance, set())
    _warn(checked.problem(provenance), path)
    return checked.rows


def read_study_metadata(path: Path) -> dict:
    """``study.json`` of a study directory: a JSON object with a ``fingerprint`` object (the loader contract,
    :func:`stp_env.loaders.read_json`: a regular file of at most 16 MiB, JSON nested at most 64 levels). Anything
    else is a one-line ``ValueError`` naming the file."""
    meta = read_json(path, "study-metadata")
    if not isinstance(meta, dict) or not isinstance(meta.get("fingerprint"), dict):
        what = f"a JSON {type(meta).__name__}" if not isinstance(meta, dict) else "an object without a fingerprint"
        raise ValueError(f"{path}: not a survivability study file ({what}, expected an object with a 'fingerprint' "
                         "object); remove it or choose another --out.")
    return meta


def check_study_metadata(config: StudyConfig, out) -> None:
    """A one-line ``ValueError`` when ``out/study.json`` exists and is not a study file of ``config``'s
    fingerprint (another configuration's study is never resumed or reported as this one)."""
    meta_path = Path(out) / "study.json"
    if meta_path.exists() or meta_path.is_symlink():
        old = read_study_metadata(meta_path)
        if not _same_config(old["fingerprint"], config.fingerprint()):
            raise ValueError(f"{out} holds a study with a different configuration; choose another --out "
                             f"(or the same options as {meta_path}).")


def write_study_metadata(config: StudyConfig, out) -> Path:
    """``out/study.json`` of the study ``config`` (its fingerprint and number of instances), atomically."""
    path = Path(out) / "study.json"
    _atomic_write(path, json.dumps({"fingerprint": config.fingerprint(), "n_instances": config.n_instances},
                                   indent=1))
    return path


def write_missions(config: StudyConfig, path, rows) -> Path:
    """A missions file of the study ``config`` holding ``rows`` (dicts of :data:`FIELDS`, stamped by
    :func:`stamp_rows`), atomically: what :func:`run_study` writes, for missions flown by other means."""
    path = Path(path)
    _repair(path, stamp_rows(study_id(config.fingerprint()), rows))
    return path


def completed(rows, policies) -> set[tuple[int, int, int]]:
    """(n_partial, n_unknown, instance) with a row for every policy."""
    seen: dict[tuple[int, int, int], set] = {}
    for r in rows:
        seen.setdefault((r["n_partial"], r["n_unknown"], r["instance"]), set()).add(r["policy"])
    return {key for key, pols in seen.items() if set(policies) <= pols}


def _same_config(old, new) -> bool:
    """Equal fingerprints, up to fields added since ``old`` was written that are unset (``None``) in ``new``."""
    if isinstance(old, dict) and isinstance(new, dict):
        extra = set(new) - set(old)
        return (set(old) <= set(new) and all(new[k] is None for k in extra)
                and all(_same_config(old[k], new[k]) for k in old))
    return old == new


def _repair(path: Path, rows) -> None:
    """Rewrite a missions file with ``rows`` only (rows of :data:`RECORD_FIELDS`, as text) and the header."""
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, RECORD_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def _keep_aside(path: Path) -> str:
    """Keep the file ``path`` as it is under ``NAME.rejected-<hex>`` (a second name: the study then rewrites
    ``path``; the kept file is never read again); what the warning adds about it."""
    aside = path.with_name(f"{path.name}.rejected-{uuid.uuid4().hex[:8]}")
    try:
        os.link(path, aside)
    except OSError:
        return "; the file is rewritten without them"
    return f"; the file is rewritten without them (as it was: {aside.name})"


def _atomic_write(path: Path, text: str) -> None:
    write_text(text, path)
