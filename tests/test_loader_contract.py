"""The loader contract (``stp_env/loaders.py``, ``docs/threat-model.md``): every reader of a file that a user or
another machine can hand over gives a valid result or one line naming the file, never a traceback or a hang.

* The threat model's table has one row per kind of file the package reads, and every reader of a file in the
  package goes through ``stp_env/loaders.py`` (a new loader without a row, or one reading files by itself, fails).
* Property tests per loader: valid files mutated (truncated, overwritten, JSON values of other types, deep nesting,
  arrays of other dtypes and shapes, pickles, headers that lie), files over the size cap, and special files (a FIFO,
  a directory, a device) in place of a file.
* The cases of the second hardening pass, each against the code that had it: deep nesting in every JSON loader, a
  study file that is JSON but not an object, a missions field beyond the csv module's limit, k̄ of 10**30 in an
  events record and on the command line, checkpoints with the right key and bad contents (or truncated, empty,
  mistyped), seeds that wrapped around or were not integers, a FIFO in the cache, a silent wait on a cache lock.

Nothing here compiles a JAX program except the checkpoint test (one small planning run, marked slow).
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import io
import json
import math
import os
import re
import shutil
import tempfile
import threading
import time
import warnings
import zipfile
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from _cli import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stp_env import loaders
from stp_env.artifacts import ArtifactStore, StaleArtifactWarning

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "stp_env"
SHIPPED_INTRUDER = Path(str(resources.files("stp_env") / "data" / "intruders" / "town-kbar2.npz"))
DEEP = "[" * 100_000
CHECKPOINT_TEMPLATE = {"policy": [np.zeros((2, 3), np.float32)], "key": np.zeros(2, np.uint32)}
"""A training run's state as the JAX trainer's checkpoints hold one (any pytree of arrays)."""

PROPERTY = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def within(seconds: float, fn, *fifos):
    """``fn()`` in a thread, which must answer within ``seconds`` (a loader waiting on a FIFO fails the test; the
    FIFOs are then opened from the other end, so that the waiting thread returns). A signal would not do: with JAX
    loaded, a process-wide alarm may be delivered to another thread and never interrupt the blocked one."""
    result = {}

    def target():
        try:
            result["value"] = fn()
        except BaseException as err:  # re-raised in the test's thread
            result["error"] = err

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        for path in fifos:
            for flags in (os.O_RDONLY | os.O_NONBLOCK, os.O_WRONLY | os.O_NONBLOCK):
                with contextlib.suppress(OSError):
                    os.close(os.open(path, flags))
        thread.join(10)
        pytest.fail(f"no answer within {seconds} s (a wait on {[str(p) for p in fifos]})")
    if "error" in result:
        raise result["error"]
    return result.get("value")


def one_line_naming(err: BaseException, path) -> None:
    message = str(err)
    assert "\n" not in message and str(path) in message, message


# ------------------------------------------------------------------------------------------------ valid files
def _event(**changes):
    record = {"config": {"scenario": "tiny-intruder", "kbar": 2, "intruder": "greedy", "vehicle_policy": "nominal"},
              "seed": 1, "index": 0, "n_steps": 100, "plan_samples": 100, "batch_size": 1, "recorded": True,
              "npz_prefix": "0/"}
    record.update(changes)
    return record


COUNTEREXAMPLE = {"format": 1, "package_version": "0.1.0",
                  "spec": {"target": "tracking", "scenario": "town", "kbar": None, "wind_model": "worst", "dt": 0.1,
                           "control_dt": 0.02, "options": {"horizon": 4.0}},
                  "search": {}, "seed": 0, "z": [0.25, 0.5, 0.75, 1.0], "value": 1.5, "summary": {}}


def _single(t0=0.0, m=3):
    from stp_env.planning.plan import SinglePlan

    return SinglePlan(t_ldt=t0, sta=5.0, times=t0 + 0.1 * np.arange(m), states=np.tile([1.0, 2.0, 0.5], (m, 1)),
                      controls=np.ones((m, 2)), arrival_time=math.inf, n_steps=4)


def _missions_text(rows=3) -> str:
    from stp_env.survivability.records import FIELDS

    lines = [",".join(FIELDS)] + [f"50,50,{i},S,G,0,-1,1,9,1.0,0.25" for i in range(rows)]
    return "\n".join(lines) + "\n"


def _write_valid(kind: str, path: Path) -> None:
    """A valid file of ``kind`` at ``path`` (the artifact kinds: the cache entry ``thing`` in ``path.parent``)."""
    if kind in ("artifact-metadata", "artifact-arrays"):
        ArtifactStore(path.parent, shipped=None).save("thing", {"n": 1}, {"x": np.arange(3.0), "y": np.eye(2)})
    elif kind == "events":
        path.write_text(json.dumps([_event(), _event(index=3)]))
    elif kind == "event-states":
        np.savez(path, **{"0/x": np.zeros(3), "0/status": np.arange(4), "1/x": np.ones(2)})
    elif kind == "counterexample":
        path.write_text(json.dumps(COUNTEREXAMPLE))
    elif kind == "learned-policy":
        shutil.copyfile(SHIPPED_INTRUDER, path)
    elif kind == "plan-checkpoint":
        from stp_env.planning import checkpoint

        checkpoint.save(path, "the-key", [(1, _single()), (0, _single(1.0, 4))])
    elif kind == "study-metadata":
        path.write_text(json.dumps({"fingerprint": {"seed": 0, "policies": ["S"], "n_partial": [50]},
                                    "n_instances": 2}))
    elif kind == "study-missions":
        # a study's own file (new format, with the study.json that proves whose rows they are), so that the
        # mutations reach the rows' fingerprint and digest checks
        from stp_env.survivability.config import StudyConfig
        from stp_env.survivability.records import write_missions, write_study_metadata

        config = StudyConfig(n_instances=3, n_partial=(50,), n_unknown=(50,), policies=("S",))
        write_study_metadata(config, path.parent)
        write_missions(config, path, [{"n_partial": 50, "n_unknown": 50, "instance": i, "policy": "S", "outcome": "G",
                                       "reveals": 0, "omega_switch": -1, "n_dp": 1, "windows": 9, "instance_s": 1.0,
                                       "mission_s": 0.25} for i in range(3)])
    elif kind == "jax-checkpoint":
        from stp_env.rl.jax_train import save_runner

        save_runner(CHECKPOINT_TEMPLATE, path, fingerprint_="fp", iteration=1, timesteps=10,
                    logs={"progress": [{"timesteps": 10}], "evaluations": []})
    elif kind == "job-piece":
        from stp_env.execution import write_piece

        assert write_piece(path.parent, 3, {"ep/x": np.arange(4.0), "seconds": np.float64(1.5)}, "ab" * 16) == path
    else:  # pragma: no cover
        raise AssertionError(kind)


def _target(kind: str, directory: Path) -> Path:
    """The file of ``kind`` a property test mutates."""
    if kind in ("artifact-metadata", "artifact-arrays"):
        npz, meta, _ = ArtifactStore(directory).paths("thing", {"n": 1})
        return meta if kind == "artifact-metadata" else npz
    return directory / {"events": "events.json", "event-states": "events.npz", "counterexample": "cx.json",
                        "learned-policy": "policy.npz", "plan-checkpoint": "ck.npz", "study-metadata": "study.json",
                        "study-missions": "missions.csv", "job-piece": "piece-000003.npz",
                        "jax-checkpoint": "runner.npz"}[kind]


def _load(kind: str, path: Path):
    """Runs the loader of ``kind`` on ``path``: its result, or the ``ValueError`` it raised (the cache: ``None``
    and its warnings)."""
    if kind in ("artifact-metadata", "artifact-arrays"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            art = ArtifactStore(path.parent, shipped=None).load("thing", {"n": 1})
        stale = [w for w in caught if issubclass(w.category, StaleArtifactWarning)]
        assert art is not None or stale, "a bad cache entry must be reported"
        for w in stale:
            assert "\n" not in str(w.message) and path.name in str(w.message), str(w.message)
        return art
    if kind == "events":
        from stp_env.evaluation.events import load_events

        return load_events(path)
    if kind == "event-states":
        from stp_env.evaluation.events import load_event_state

        return load_event_state(path, {"npz_prefix": "0/"})
    if kind == "counterexample":
        from stp_env.falsify.counterexample import load

        return load(path)
    if kind == "learned-policy":
        from stp_env.policies.learned import load_mlp

        return load_mlp(path)
    if kind == "plan-checkpoint":
        from stp_env.planning import checkpoint

        return checkpoint.load(path, "the-key")
    if kind == "study-metadata":
        from stp_env.survivability.records import read_study_metadata

        return read_study_metadata(path)
    if kind == "study-missions":
        from stp_env.survivability.records import read_missions

        return read_missions(path)
    if kind == "job-piece":
        from stp_env.execution import read_piece

        return read_piece(path)
    if kind == "jax-checkpoint":
        from stp_env.rl.jax_train import load_runner

        return load_runner(path, CHECKPOINT_TEMPLATE, "fp")
    raise AssertionError(kind)  # pragma: no cover


def _check_contract(kind: str, path: Path) -> None:
    """The contract: a result, or one line naming the file; nothing else, and no wait."""
    try:
        within(30, lambda: _load(kind, path), path)
    except ValueError as err:
        assert kind not in ("artifact-metadata", "artifact-arrays"), f"the cache raised: {err}"
        one_line_naming(err, path)


KINDS = sorted(loaders.LOADERS)
JSON_KINDS = {"artifact-metadata", "events", "counterexample", "study-metadata"}
NPZ_KINDS = {"artifact-arrays", "event-states", "learned-policy", "plan-checkpoint", "job-piece", "jax-checkpoint"}


def test_valid_files_load():
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            directory = Path(tmp) / kind
            directory.mkdir()
            path = _target(kind, directory)
            _write_valid(kind, path)
            result = _load(kind, path)
            assert result is not None and (kind != "artifact-arrays" or result.from_cache), kind


# ------------------------------------------------------------------------------------------------ mutations
json_leaves = (st.none() | st.booleans() | st.integers(-(2**80), 2**80) | st.floats(allow_nan=True)
               | st.text(max_size=12))
json_values = st.recursive(json_leaves, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=6), c,
                                                                                            max_size=3),
                           max_leaves=6)


@st.composite
def json_mutation(draw):
    """Replaces one value somewhere in a JSON document by another of any type (or the whole document by deep
    nesting)."""
    if draw(st.integers(0, 9)) == 0:
        depth = draw(st.sampled_from([65, 1000, 100_000]))
        return lambda doc: "[" * depth + "]" * depth
    replacement = draw(json_values)
    steps = draw(st.lists(st.integers(0, 50), max_size=4))

    def apply(text):
        doc = json.loads(text)
        if not isinstance(doc, (dict, list)) or not doc:
            return json.dumps(replacement)
        parent = doc
        for step in steps:
            keys = list(parent) if isinstance(parent, dict) else list(range(len(parent)))
            key = keys[step % len(keys)]
            child = parent[key]
            if isinstance(child, (dict, list)) and child and step % 3:
                parent = child
                continue
            parent[key] = replacement
            return json.dumps(doc)
        keys = list(parent) if isinstance(parent, dict) else list(range(len(parent)))
        parent[keys[0]] = replacement
        return json.dumps(doc)

    return lambda text_bytes: apply(text_bytes.decode())


ARRAYS = st.sampled_from([np.zeros(0), np.full((2, 3), np.nan), np.arange(5, dtype=np.int8), np.ones(3, bool),
                          np.asarray("text"), np.ones((2, 2), np.complex64), np.full(4, 1e300),
                          np.asarray([{"a": 1}], dtype=object), np.zeros((1, 1, 1, 1)), np.asarray(7),
                          np.asarray([2**62], np.uint64), np.asarray([b"x"])])


@st.composite
def npz_mutation(draw):
    """Drops, replaces or adds an array (any dtype, object arrays included), or makes a member's header promise
    more data than the member holds."""
    op = draw(st.sampled_from(["drop", "replace", "add", "lie", "not-npy"]))
    which = draw(st.integers(0, 100))
    array = draw(ARRAYS)

    def apply(data: bytes) -> bytes:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {k: archive[k] for k in archive.files}
        names = sorted(arrays)
        name = names[which % len(names)] if names else "x"
        out = io.BytesIO()
        if op in ("lie", "not-npy"):
            with zipfile.ZipFile(out, "w") as zf:
                for k, v in arrays.items():
                    buf = io.BytesIO()
                    np.lib.format.write_array(buf, v, allow_pickle=False)
                    raw = buf.getvalue()
                    if k == name and op == "lie":  # the header says 10**12 elements; a few bytes follow
                        header = {"descr": "<f8", "fortran_order": False, "shape": (10**12,)}
                        buf = io.BytesIO()
                        np.lib.format.write_array_header_1_0(buf, header)
                        raw = buf.getvalue() + b"\0" * 16
                    zf.writestr(k + (".txt" if k == name and op == "not-npy" else ".npy"), raw)
            return out.getvalue()
        if op == "drop":
            arrays.pop(name, None)
        elif op == "replace":
            arrays[name] = array
        else:
            arrays[f"extra{which}"] = array
        np.savez(out, **arrays)
        return out.getvalue()

    return apply


@st.composite
def byte_mutation(draw):
    """Truncates the file, overwrites a slice with random bytes, or empties it."""
    op = draw(st.sampled_from(["truncate", "overwrite", "empty"]))
    where = draw(st.floats(0.0, 1.0))
    junk = draw(st.binary(min_size=1, max_size=64))

    def apply(data: bytes) -> bytes:
        k = int(where * len(data))
        if op == "truncate":
            return data[:k]
        if op == "empty":
            return b""
        return data[:k] + junk + data[k + len(junk):]

    return apply


@st.composite
def csv_mutation(draw):
    """A line of junk, a field beyond the csv module's limit, a NUL byte, bytes that are not UTF-8, or another
    header."""
    op = draw(st.sampled_from(["junk", "huge", "nul", "latin1", "header", "long-line"]))
    junk = draw(st.text(max_size=40))

    def apply(data: bytes) -> bytes:
        text = data.decode()
        if op == "junk":
            return (text + junk + "\n").encode("utf-8", "surrogatepass")
        if op == "huge":
            return (text + "50,50,9," + "x" * 200_000 + ",G,0,-1,1,9,1.0,0.25\n").encode()
        if op == "nul":
            return (text + "50,50,9,S\0,G,0,-1,1,9,1.0,0.25\n").encode()
        if op == "latin1":
            return data + "50,50,9,S,Gé,0,-1,1,9,1.0,0.25\n".encode("latin-1")
        if op == "long-line":
            return data + b"y" * (loaders.MAX_CSV_LINE + 10)
        return ("a,b,c\n" + text).encode()

    return apply


def special_files():
    """Things that are not a regular file, put where a file of a loader belongs."""
    return st.sampled_from(["fifo", "directory", "device", "missing-target"])


def _make_special(path: Path, what: str) -> None:
    path.unlink(missing_ok=True)
    if what == "fifo":
        os.mkfifo(path)
    elif what == "directory":
        path.mkdir()
    elif what == "device":
        path.symlink_to("/dev/zero")
    else:
        path.symlink_to(path.parent / "nowhere")


def _mutations(kind: str):
    options = [byte_mutation()]
    if kind in JSON_KINDS:
        options.append(json_mutation())
    if kind in NPZ_KINDS:
        options.append(npz_mutation())
    if kind == "study-missions":
        options.append(csv_mutation())
    return st.one_of(*options)


@pytest.mark.parametrize("kind", KINDS)
def test_every_loader_gives_a_result_or_one_line_naming_the_file(kind):
    @PROPERTY
    @given(mutation=_mutations(kind) | special_files())
    def check(mutation):
        with tempfile.TemporaryDirectory() as tmp:
            path = _target(kind, Path(tmp))
            _write_valid(kind, path)
            if isinstance(mutation, str):
                if not hasattr(os, "mkfifo"):
                    return
                _make_special(path, mutation)
            else:
                new = mutation(path.read_bytes())
                path.write_bytes(new.encode("utf-8", "surrogatepass") if isinstance(new, str) else new)
                if kind == "artifact-arrays":  # a forged entry: the metadata's hash matches the edited arrays
                    meta = path.with_suffix(".json")
                    meta.write_text(json.dumps({**json.loads(meta.read_text()),
                                                "content_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}))
            _check_contract(kind, path)

    check()


@pytest.mark.parametrize("kind", KINDS)
def test_a_file_over_its_size_cap_is_refused_before_it_is_read(kind, monkeypatch, tmp_path):
    path = _target(kind, tmp_path)
    _write_valid(kind, path)
    size = path.stat().st_size
    spec = loaders.LOADERS[kind]
    monkeypatch.setitem(loaders.LOADERS, kind, loaders.Loader(spec.what, size - 1, spec.max_array_bytes))
    if kind.startswith("artifact"):
        with pytest.warns(StaleArtifactWarning, match=rf"{re.escape(path.name)}.*more than"):
            assert ArtifactStore(tmp_path, shipped=None).load("thing", {"n": 1}) is None
        return
    with pytest.raises(ValueError, match="more than") as err:
        _load(kind, path)
    one_line_naming(err.value, path)


@pytest.mark.parametrize("kind", sorted(NPZ_KINDS))
def test_arrays_over_the_cap_are_refused_before_they_are_allocated(kind, monkeypatch, tmp_path):
    path = _target(kind, tmp_path)
    _write_valid(kind, path)
    spec = loaders.LOADERS[kind]
    monkeypatch.setitem(loaders.LOADERS, kind, loaders.Loader(spec.what, spec.max_bytes, 64))
    if kind.startswith("artifact"):
        with pytest.warns(StaleArtifactWarning, match="more than"):
            assert ArtifactStore(tmp_path, shipped=None).load("thing", {"n": 1}) is None
        return
    with pytest.raises(ValueError, match="more than") as err:
        _load(kind, path)
    one_line_naming(err.value, path)


def test_json_depth_counts_brackets_outside_strings():
    assert loaders.json_depth('{"a": "[[[[", "b": [1, {"c": "\\"]["}]}') == 3
    assert loaders.json_depth(DEEP) == 100_000
    assert loaders.json_depth("5") == 0


# ------------------------------------------------------------------------------------------------ the table
def _table_kinds() -> list[str]:
    text = (ROOT / "docs" / "threat-model.md").read_text()
    kinds = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) >= 3 and (m := re.match(r"`([a-z-]+)`", cells[0])):
            kinds.append(m.group(1))
    return kinds


READERS = {"read_json", "read_npz", "read_text", "read_bytes", "read_csv_rows", "open_regular", "check_regular"}
RAW_READS = {("np", "load"), ("numpy", "load"), ("json", "load"), ("json", "loads"), ("csv", "reader"),
             ("csv", "DictReader"), ("zipfile", "ZipFile"), ("pickle", "load"), ("pickle", "loads")}
ALLOWED_RAW = {
    ("artifacts.py", "_code_version", "read_text"): "the package's own source (the code version)",
    ("artifacts.py", "_identity_problem", "loads"): "a round trip of parameters through JSON",
    ("survivability/config.py", "fingerprint", "loads"): "a round trip of the configuration through JSON",
    ("planning/stp.py", "shipped_plan", "load"): "a plan shipped in the package (trusted)",
    ("evaluation/report.py", "source_hash", "read_bytes"): "the package's own source (its hash)",
    ("resources.py", "available_memory", "open"): "the kernel's memory report (/proc/meminfo), not a user's file",
    ("resources.py", "_read_int", "read_text"): "the kernel's cgroup memory limit (/sys/fs/cgroup), not a user's file",
}


def _calls():
    """``(module, enclosing function, callee name, call node)`` of every call in the package."""
    for path in sorted(PACKAGE.rglob("*.py")):
        module = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        stack = [(tree, "<module>")]
        while stack:
            node, where = stack.pop()
            for child in ast.iter_child_nodes(node):
                name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else where
                if isinstance(child, ast.Call):
                    yield module, name, child
                stack.append((child, name))


def test_the_threat_model_table_covers_every_loader_and_every_reader_uses_one():
    """One row per kind of file (``LOADERS``); every kind is read somewhere through ``stp_env/loaders.py``; and no
    module reads a file by itself (``np.load``, ``json.loads``, ``csv.reader``, ``open`` for reading, ...) except
    the listed reads of the package's own files."""
    rows = _table_kinds()
    assert len(rows) == len(set(rows)), rows
    assert set(rows) == set(loaders.LOADERS), (sorted(set(rows) ^ set(loaders.LOADERS)))
    used, raw = set(), []
    for module, function, call in _calls():
        func = call.func
        callee = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
        base = func.value.id if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) else None
        if module != "loaders.py" and callee in READERS and (isinstance(func, ast.Name) or base == "loaders"):
            kind = call.args[1] if len(call.args) > 1 else next((k.value for k in call.keywords if k.arg == "kind"),
                                                               None)
            assert isinstance(kind, ast.Constant) and kind.value in loaders.LOADERS, (module, function, callee)
            used.add(kind.value)
            continue
        reads = (base, callee) in RAW_READS or callee in ("read_text", "read_bytes") or (
            callee == "open" and base != "os" and _reads(call))
        if module != "loaders.py" and reads and (module, function, callee) not in ALLOWED_RAW:
            raw.append(f"stp_env/{module}:{call.lineno} ({function}: {callee})")
    assert used == set(loaders.LOADERS), sorted(set(loaders.LOADERS) - used)
    assert not raw, f"files read outside stp_env/loaders.py: {raw}"


def _reads(call: ast.Call) -> bool:
    """Whether an ``open(path, mode)`` or ``path.open(mode)`` call opens for reading (no mode, or a mode without
    w, a or x)."""
    at = 0 if isinstance(call.func, ast.Attribute) else 1
    mode = call.args[at] if len(call.args) > at else next((k.value for k in call.keywords if k.arg == "mode"), None)
    if mode is None:
        return True
    return isinstance(mode, ast.Constant) and not set(str(mode.value)) & set("wax")


# ------------------------------------------------------------------------------------------------ the cases
def test_deep_nesting_in_every_json_loader_is_one_line(tmp_path):
    """``[`` x 100,000 was a ``RecursionError`` in the cache's metadata (every run), events files, counterexamples,
    learned-policy metadata and the survivability study's ``study.json``."""
    from stp_env.evaluation.events import load_events
    from stp_env.falsify.counterexample import load
    from stp_env.policies.learned import load_mlp

    store = ArtifactStore(tmp_path / "cache", shipped=None)
    store.save("thing", {"n": 1}, {"x": np.arange(3.0)})
    _, meta, _ = store.paths("thing", {"n": 1})
    meta.write_text(DEEP)
    with pytest.warns(StaleArtifactWarning, match="nested"):
        art = store.load_or_compute("thing", {"n": 1}, lambda: {"x": np.arange(3.0)})
    assert not art.from_cache and store.load("thing", {"n": 1}).from_cache  # recomputed, then read again

    for loader, name in ((load_events, "events.json"), (load, "counterexample.json")):
        path = tmp_path / name
        path.write_text(DEEP)
        with pytest.raises(ValueError, match="nested") as err:
            loader(path)
        one_line_naming(err.value, path)

    with np.load(SHIPPED_INTRUDER) as data:
        arrays = {k: data[k] for k in data.files}
    policy = tmp_path / "policy.npz"
    np.savez(policy, **{**arrays, "metadata": np.asarray(DEEP)})
    with pytest.raises(ValueError, match="nested") as err:
        load_mlp(policy)
    one_line_naming(err.value, policy)

    events = tmp_path / "events.json"
    code, _, stderr = run_cli(["render", "--events", str(events), "--out", str(tmp_path / "x.gif")])
    assert code == 2 and stderr.count("\n") == 1 and str(events) in stderr and "Traceback" not in stderr


@pytest.fixture
def no_study_work(monkeypatch):
    """Fails the test if the study starts computing."""
    import stp_env.survivability.study as study

    def forbidden(*args, **kwargs):
        raise AssertionError("the study started before its files were checked")

    monkeypatch.setattr(study, "build_graph", forbidden)
    monkeypatch.setattr(study, "run_instance", forbidden)


@pytest.mark.parametrize("content, needle", [(DEEP, "nested"), ("[1, 2]", "not a survivability study file"),
                                             ('"text"', "not a survivability study file"),
                                             ('{"fingerprint": 5}', "not a survivability study file")])
def test_a_bad_study_json_is_one_line_and_changes_nothing(tmp_path, no_study_work, content, needle):
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.study import run_study

    meta = tmp_path / "study.json"
    meta.write_text(content)
    with pytest.raises(ValueError, match=needle) as err:
        run_study(StudyConfig(n_instances=1, n_partial=(0,), n_unknown=(0,)), tmp_path, progress=False)
    one_line_naming(err.value, meta)
    assert meta.read_text() == content and sorted(p.name for p in tmp_path.iterdir()) == ["study.json"]


def test_a_missions_field_beyond_the_csv_limit_is_one_line_and_changes_nothing(tmp_path, no_study_work):
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.records import read_missions
    from stp_env.survivability.study import run_study

    missions = tmp_path / "missions.csv"
    text = _missions_text() + "50,50,7," + "x" * 200_000 + ",G,0,-1,1,9,1.0,0.25\n"
    missions.write_text(text)
    with pytest.raises(ValueError, match="field larger than field limit") as err:
        read_missions(missions)
    one_line_naming(err.value, missions)
    with pytest.raises(ValueError):
        run_study(StudyConfig(n_instances=1, n_partial=(50,), n_unknown=(50,)), tmp_path, progress=False)
    assert missions.read_text() == text and not (tmp_path / "study.json").exists()
    code, _, stderr = run_cli(["survivability", "--out", str(tmp_path), "--report-only", "--no-figures"])
    assert code == 2 and stderr.count("\n") == 1 and str(missions) in stderr, stderr


@pytest.fixture
def no_work(monkeypatch):
    """Fails the test if a plan, an evaluation, a search or a replay starts."""
    import stp_env.evaluation as evaluation
    import stp_env.falsify.counterexample as counterexample
    import stp_env.planning.stp as stp
    from stp_env.evaluation import pipeline, runner

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the input was checked")

    for module in (evaluation, runner, pipeline):
        for name in ("build_params", "evaluate", "replay", "run"):
            if hasattr(module, name):
                monkeypatch.setattr(module, name, forbidden)
    monkeypatch.setattr(stp, "plan_scenario", forbidden)
    monkeypatch.setattr(counterexample, "build_attack", forbidden)
    monkeypatch.setattr(counterexample, "search", forbidden)


def test_a_kbar_of_10_to_the_30_is_refused_in_events_and_on_the_command_line(tmp_path, no_work):
    from stp_env.evaluation.events import load_events

    events = tmp_path / "events.json"
    events.write_text(json.dumps([_event(config={"scenario": "tiny-intruder", "kbar": 10**30})]))
    with pytest.raises(ValueError, match="kbar") as err:
        load_events(events)
    one_line_naming(err.value, events)
    for argv in (["plan", "--kbar", str(10**30), "--out", str(tmp_path / "p.png")],
                 ["evaluate", "--kbar", str(10**30), "--out", str(tmp_path / "ev")],
                 ["falsify", "--kbar", str(10**30), "--out", str(tmp_path / "f")]):
        code, _, stderr = run_cli(argv)
        assert code == 2 and "--kbar" in stderr and "Traceback" not in stderr, (argv, stderr)
    with pytest.raises(ValueError, match="kbar"):
        from stp_env.scenarios import make

        make("tiny", kbar=10**30)


def test_bad_checkpoint_files_are_one_line_naming_the_file(tmp_path):
    """Truncated, empty and mistyped checkpoints were ``EOFError``, ``BadZipFile`` or ``IndexError`` without the
    file's name."""
    from stp_env.planning import checkpoint

    good = tmp_path / "good.npz"
    checkpoint.save(good, "the-key", [(1, _single()), (0, _single(1.0, 4))], file_format=1)
    data = good.read_bytes()
    with np.load(good) as f:
        arrays = {k: f[k] for k in f.files}
    cases = {"truncated": data[: len(data) // 2], "empty": b"", "header-only": data[:40]}
    for name, content in cases.items():
        (tmp_path / f"{name}.npz").write_bytes(content)
    for name, changes in {"lengths-float": {"lengths": np.asarray([1.5, 2.0])},
                          "lengths-long": {"lengths": np.asarray([3, 99])},
                          "lengths-short": {"lengths": np.asarray([3])},
                          "index-2d": {"index": np.zeros((2, 2), np.int64)},
                          "key-number": {"key": np.asarray(5)},
                          "times-int": {"times": np.zeros((2, 4), np.int64)}}.items():
        np.savez(tmp_path / f"{name}.npz", **{**arrays, **changes})
    for path in sorted(tmp_path.glob("*.npz")):
        if path == good:
            continue
        with pytest.raises(ValueError) as err:
            checkpoint.load(path, "the-key")
        one_line_naming(err.value, path)


@pytest.fixture(scope="module")
def planned_checkpoint(tmp_path_factory):
    """A finished checkpoint of a small planning problem (the one of ``tests/test_planning_resume.py``)."""
    import test_planning_resume as resume

    directory = tmp_path_factory.mktemp("checkpoint")
    resume._plan(directory)
    return directory / "ck.npz"


def _corrupt(name, arrays):
    from stp_env.planning.plan import unpack_trajectories

    arrays = dict(arrays)
    if "packed_trajectories" in arrays:  # work on the padded form
        arrays.update(unpack_trajectories(arrays))
        arrays.pop("packed_trajectories")
        arrays["format"] = np.asarray(1)
    if name == "nan-controls":
        arrays["controls"] = arrays["controls"].copy()
        arrays["controls"][0, 2, 0] = np.nan
    elif name == "moved-5km":
        arrays["states"] = arrays["states"] + np.asarray([5000.0, 0.0, 0.0])
    elif name == "controls-1e6":
        arrays["controls"] = arrays["controls"] * 1e6
    elif name == "nan-t_ldt":
        arrays["t_ldt"] = arrays["t_ldt"].copy()
        arrays["t_ldt"][1] = np.nan
    elif name == "bad-lengths":
        arrays["lengths"] = arrays["lengths"] + arrays["times"].shape[1]
    elif name == "short-lengths":
        arrays["lengths"] = np.minimum(arrays["lengths"], 1)
    return arrays


@pytest.mark.slow
@pytest.mark.parametrize("name", ["nan-controls", "moved-5km", "controls-1e6", "nan-t_ldt", "bad-lengths",
                                  "short-lengths"])
def test_a_checkpoint_with_the_right_key_and_bad_contents_is_refused_before_resuming(planned_checkpoint, tmp_path,
                                                                                      monkeypatch, name):
    """Such a checkpoint resumed silently into a plan full of NaN: its plans are now checked as a finished plan's
    (``trajectory_faults``) before anything is planned against them."""
    import test_planning_resume as resume

    import stp_env.planning.stp as stp

    with np.load(planned_checkpoint) as f:
        arrays = {k: f[k] for k in f.files}
    bad = tmp_path / "ck.npz"
    np.savez(bad, **_corrupt(name, arrays))
    monkeypatch.setattr(stp, "plan_single", lambda *a, **k: pytest.fail("planned against a bad checkpoint"))
    with pytest.raises(ValueError) as err:
        resume._plan(tmp_path)
    one_line_naming(err.value, bad)
    shutil.copyfile(planned_checkpoint, bad)  # the genuine file resumes (nothing left to plan)
    assert len(resume._plan(tmp_path).vehicles) == 3


# ---- seeds
def test_falsify_seeds_do_not_wrap_and_bad_ones_are_refused(monkeypatch, tmp_path):
    import jax

    import stp_env.falsify.counterexample as counterexample
    from stp_env.falsify.search import SearchConfig

    keys = []

    class Stop(Exception):
        pass

    class Attack:
        dim = 2

        def objective(self, z):  # pragma: no cover - never called
            return z.sum()

    def fake_search(objective, dim, key, config, progress=None, seeds=None):
        keys.append(np.asarray(jax.random.key_data(key)).tolist())
        raise Stop

    monkeypatch.setattr(counterexample, "build_attack", lambda *a, **k: Attack())
    monkeypatch.setattr(counterexample, "search", fake_search)
    spec = counterexample.AttackSpec(target="tracking")
    for seed in (0, 2**32):
        with pytest.raises(Stop):
            counterexample.run(spec, SearchConfig(budget=10, population=5, restarts=1, batch=5), seed, progress=False)
    assert keys[0] != keys[1]
    for seed in (-1, 2**70, 1.5, "1", True):
        with pytest.raises(ValueError, match="seed"):
            counterexample.run(spec, SearchConfig(budget=10, population=5, restarts=1, batch=5), seed, progress=False)
    monkeypatch.setattr(counterexample, "run", lambda *a, **k: pytest.fail("searched with a bad seed"))
    for seed in ("-1", str(2**63), str(2**70), "1.5"):
        code, _, stderr = run_cli(["falsify", "--seed", seed, "--out", str(tmp_path / "f")])
        assert code == 2 and "--seed" in stderr, stderr


def test_coobservation_seeds_do_not_wrap_and_bad_ones_are_refused(monkeypatch, tmp_path):
    import jax

    from stp_env.coobservation import cli, evaluation, threat

    keys = []

    class Stop(Exception):
        pass

    def fake_rollout(key, *args, **kwargs):
        keys.append(np.asarray(jax.random.key_data(key)).tolist())
        raise Stop

    monkeypatch.setattr(threat, "rollout", fake_rollout)
    monkeypatch.setattr(threat, "steps_for", lambda params: 10)
    for seed in (0, 2**32):
        with pytest.raises(Stop):
            evaluation.run(None, {"s": None}, {"a": None}, 4, t_window=(0.0, 1.0), batch=4, seed=seed,
                           progress=False)
    assert keys[0] != keys[1]
    for seed in (-1, 2**70, 1.5, True):
        with pytest.raises(ValueError, match="seed"):
            evaluation.run(None, {"s": None}, {"a": None}, 4, t_window=(0.0, 1.0), batch=4, seed=seed,
                           progress=False)
    monkeypatch.setattr(cli, "run", lambda args: pytest.fail("evaluated with a bad seed"))
    for seed in ("-1", str(2**63), "1.5"):
        code, _, stderr = run_cli(["coobservation", "--seed", seed, "--out", str(tmp_path / "c")])
        assert code == 2 and "--seed" in stderr, stderr


# ---- the cache: FIFOs and locks
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("which", ["npz", "json", "both", "lock"])
def test_a_fifo_in_the_cache_is_recomputed_not_waited_on(tmp_path, which):
    store = ArtifactStore(tmp_path, shipped=None)
    store.save("thing", {"n": 1}, {"x": np.arange(3.0)})
    npz, meta, _ = store.paths("thing", {"n": 1})
    targets = {"npz": [npz], "json": [meta], "both": [npz, meta], "lock": [npz, npz.with_suffix(".lock")]}[which]
    for path in targets:
        path.unlink(missing_ok=True)
        os.mkfifo(path)
    with pytest.warns(StaleArtifactWarning):
        art = within(30, lambda: store.load_or_compute("thing", {"n": 1}, lambda: {"x": np.arange(3.0)}), *targets)
    assert not art.from_cache
    assert store.load("thing", {"n": 1}).from_cache


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("what", ["directory", "fifo", "link", "wrong-size"])
@pytest.mark.parametrize("which", ["npz", "json", "lock"])
def test_a_cache_entry_of_the_wrong_kind_is_moved_aside_once_and_the_next_run_loads(tmp_path, which, what):
    """A directory (or FIFO, link, file cut short) where an entry belongs: the run that meets it recomputes with one
    warning, moves it aside (kept, never read again) and saves the artifact; the next run loads it quietly."""
    store = ArtifactStore(tmp_path, shipped=None)
    store.save("thing", {"n": 1}, {"x": np.arange(3.0)})
    npz, meta, _ = store.paths("thing", {"n": 1})
    path = {"npz": npz, "json": meta, "lock": npz.with_suffix(".lock")}[which]
    if which == "lock":
        npz.unlink()                                        # the artifact must be computed, under the lock
    path.unlink(missing_ok=True)
    if what == "directory":
        path.mkdir()
        (path / "inside").write_text("x")
    elif what == "fifo":
        os.mkfifo(path)
    elif what == "link":
        (tmp_path / "elsewhere").write_text("{}")
        path.symlink_to(tmp_path / "elsewhere")
    else:
        path.write_bytes(b"PK")
    with pytest.warns(StaleArtifactWarning) as caught:
        art = within(30, lambda: store.load_or_compute("thing", {"n": 1}, lambda: {"x": np.arange(3.0)}), path)
    assert not art.from_cache and np.array_equal(art.arrays["x"], np.arange(3.0))
    assert all("\n" not in str(w.message) for w in caught)
    assert all(p.is_file() and not p.is_symlink() for p in (npz, meta))
    if what != "wrong-size":                                # a regular file is replaced in place
        assert len(list(tmp_path.glob(path.name + ".rejected-*"))) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = store.load_or_compute("thing", {"n": 1}, lambda: pytest.fail("recomputed twice"))
    assert again.from_cache


@pytest.mark.skipif(os.name != "posix", reason="advisory locks are POSIX")
def test_a_process_waiting_on_a_cache_lock_says_so(tmp_path, capfd):
    import fcntl

    store = ArtifactStore(tmp_path, shipped=None)
    npz, _, _ = store.paths("thing", {"n": 1})
    tmp_path.mkdir(exist_ok=True)
    holder = open(npz.with_suffix(".lock"), "a")  # held across the thread
    fcntl.flock(holder.fileno(), fcntl.LOCK_EX)

    def release():
        time.sleep(1.0)
        fcntl.flock(holder.fileno(), fcntl.LOCK_UN)
        holder.close()

    thread = threading.Thread(target=release)
    thread.start()
    art = within(30, lambda: store.load_or_compute("thing", {"n": 1}, lambda: {"x": np.arange(3.0)}))
    thread.join()
    assert not art.from_cache
    err = capfd.readouterr().err
    assert "waiting" in err and str(npz.with_suffix(".lock")) in err, err


def _straight_problem():
    """One vehicle flying straight east at 5 m/s, 0.1 s samples, into a target of radius 1 m at (10, 0)."""
    from stp_env.planning.plan import SinglePlan

    times = -2.0 + 0.1 * np.arange(25)
    states = np.stack([5.0 * (times + 2.0), np.zeros(25), np.zeros(25)], axis=1)
    single = SinglePlan(t_ldt=-2.0, sta=1.0, times=times, states=states, controls=np.tile([5.0, 0.0], (25, 1)),
                        arrival_time=float(times[19]), n_steps=3)
    problem = {"starts": [(0.0, 0.0, 0.0)], "targets": [(10.0, 0.0)], "target_radii": [1.0], "stas": [1.0],
               "priorities": [0], "tracking_bound": 0.1, "time_step": 0.1, "planning_v": (4.0, 6.0),
               "planning_omega_max": 1.0}
    return single, problem


@pytest.mark.parametrize("change, needle", [
    ({}, None),
    ({"controls": lambda p: np.where(np.arange(25)[:, None] == 3, np.nan, p.controls)}, "non-finite"),
    ({"states": lambda p: p.states + np.asarray([5000.0, 0.0, 0.0])}, "from the start"),
    ({"controls": lambda p: p.controls * 1e6}, r"outside U\^p"),
    ({"t_ldt": lambda p: math.nan}, "non-finite"),
    ({"times": lambda p: p.times[:1], "states": lambda p: p.states[:1], "controls": lambda p: p.controls[:1]},
     "arrival recorded"),
    ({"sta": lambda p: 2.0}, "STA"),
])
def test_check_plans_runs_the_finished_plan_checks(change, needle):
    import dataclasses

    from stp_env.planning import checkpoint

    single, problem = _straight_problem()
    single = dataclasses.replace(single, **{k: f(single) for k, f in change.items()})
    if needle is None:
        checkpoint.check_plans("ck.npz", [(0, single)], **problem)
        return
    with pytest.raises(ValueError, match=needle) as err:
        checkpoint.check_plans("ck.npz", [(0, single)], **problem)
    one_line_naming(err.value, "ck.npz")
