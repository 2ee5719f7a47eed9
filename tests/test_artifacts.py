"""Artifact store: bit-exact round trips; stale, tampered or corrupted files are recomputed with a warning."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from stp_env import artifacts
from stp_env.artifacts import ArtifactStore, StaleArtifactWarning
from stp_env.dynamics import DubinsWind


@dataclasses.dataclass(frozen=True)
class Params:
    vehicle: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    n: int = 5


def _compute_counter():
    calls = []

    def compute(seed=0):
        calls.append(1)
        rng = np.random.default_rng(seed)
        return {"values": rng.normal(size=(7, 5, 3)).astype(np.float32), "n_steps": np.asarray(12)}

    return calls, compute


def test_round_trip_is_bit_exact_and_cached(tmp_path):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    first = store.load_or_compute("demo", Params(), compute)
    assert not first.from_cache and len(calls) == 1
    second = store.load_or_compute("demo", Params(), compute)
    assert second.from_cache and len(calls) == 1
    for name in first.arrays:
        assert first.arrays[name].dtype == second.arrays[name].dtype
        assert first.arrays[name].tobytes() == second.arrays[name].tobytes()
    meta = json.loads(first.path.with_suffix(".json").read_text())
    assert meta["format_version"] == artifacts.FORMAT_VERSION
    assert meta["params"]["vehicle"]["wind"] == 6.0
    assert set(meta["library_versions"]) >= {"jax", "numpy", "stp_env"}


def test_changed_parameter_recomputes(tmp_path):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    store.load_or_compute("demo", Params(), compute)
    store.load_or_compute("demo", Params(vehicle=DubinsWind(wind=11.0)), compute)
    assert len(calls) == 2


def test_tampered_array_file_recomputes_with_warning(tmp_path):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    art = store.load_or_compute("demo", Params(), compute)
    data = bytearray(art.path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    art.path.write_bytes(bytes(data))
    with pytest.warns(StaleArtifactWarning, match="content hash"):
        again = store.load_or_compute("demo", Params(), compute)
    assert not again.from_cache and len(calls) == 2
    assert store.load("demo", Params()) is not None  # rewritten cleanly


def test_truncated_file_and_bad_json_recompute(tmp_path):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    art = store.load_or_compute("demo", Params(), compute)
    art.path.write_bytes(art.path.read_bytes()[:50])
    with pytest.warns(StaleArtifactWarning):
        store.load_or_compute("demo", Params(), compute)
    art.path.with_suffix(".json").write_text("{not json")
    with pytest.warns(StaleArtifactWarning, match="unreadable"):
        store.load_or_compute("demo", Params(), compute)
    assert len(calls) == 3


def test_format_version_mismatch_recomputes(tmp_path, monkeypatch):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    art = store.load_or_compute("demo", Params(), compute)
    meta_path = art.path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["format_version"] = artifacts.FORMAT_VERSION + 1
    meta_path.write_text(json.dumps(meta))
    with pytest.warns(StaleArtifactWarning, match="format version"):
        store.load_or_compute("demo", Params(), compute)
    assert len(calls) == 2


def test_artifacts_of_other_code_are_recomputed(tmp_path, monkeypatch):
    """An artifact computed by another version of the numerics code is not reused (same parameters)."""
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    art = store.load_or_compute("demo", Params(), compute)
    assert json.loads(art.path.with_suffix(".json").read_text())["code_version"] == artifacts.CODE_VERSION
    monkeypatch.setattr(artifacts, "CODE_VERSION", "0123456789abcdef")
    again = store.load_or_compute("demo", Params(), compute)  # another key: computed, not loaded
    assert len(calls) == 2
    assert again.path != art.path
    # and metadata claiming other code under the current key is refused
    meta_path = again.path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["code_version"] = "fedcba9876543210"
    meta_path.write_text(json.dumps(meta))
    with pytest.warns(StaleArtifactWarning, match="other code"):
        store.load_or_compute("demo", Params(), compute)
    assert len(calls) == 3


def test_reachability_tables_keep_their_key_when_only_the_planner_changes(tmp_path, monkeypatch):
    """A tracking bound is keyed by the reachability code alone: another planner (``CODE_VERSION``) finds it, other
    reachability code does not; a plan is keyed by the whole numerics code."""
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    first = store.load_or_compute("tracking_bound", Params(), compute)
    plan = store.load_or_compute("plan", Params(), compute)
    assert len(calls) == 2
    monkeypatch.setattr(artifacts, "CODE_VERSION", "0123456789abcdef")
    assert store.load_or_compute("tracking_bound", Params(), compute).path == first.path and len(calls) == 2
    assert store.load_or_compute("plan", Params(), compute).path != plan.path and len(calls) == 3
    monkeypatch.setattr(artifacts, "REACHABILITY_CODE_VERSION", "fedcba9876543210")
    assert store.load_or_compute("tracking_bound", Params(), compute).path != first.path and len(calls) == 4


def test_the_reachability_code_version_covers_what_the_reachability_code_imports():
    """Every ``stp_env`` module that ``stp_env.reach`` (or the solver and dynamics it uses) imports is hashed into
    :data:`REACHABILITY_CODE_VERSION` but ``artifacts`` itself (the store, not the numerics) and ``files`` where a
    figure module imports it (it writes the figure atomically and computes nothing)."""
    import ast
    from pathlib import Path

    root = Path(artifacts.__file__).parent
    hashed = set(artifacts._REACHABILITY)
    files = [f for name in hashed for f in ((root / name).rglob("*.py") if (root / name).is_dir() else [root / name])]
    for file in files:
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("stp_env"):
                parts = node.module.split(".")[1:] or [a.name for a in node.names]
                top = parts[0]
                if top == "artifacts" or (top == "files" and file.name == "plots.py"):
                    continue
                assert top in hashed or f"{top}.py" in hashed, (file.name, node.module)


def test_edited_metadata_params_detected(tmp_path):
    store = ArtifactStore(tmp_path)
    calls, compute = _compute_counter()
    art = store.load_or_compute("demo", Params(), compute)
    meta_path = art.path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["params"]["n"] = 6
    meta_path.write_text(json.dumps(meta))
    with pytest.warns(StaleArtifactWarning, match="parameters changed"):
        store.load_or_compute("demo", Params(), compute)
    assert len(calls) == 2


def test_cache_dir_environment_override(tmp_path, monkeypatch):
    monkeypatch.setenv(artifacts.CACHE_ENV_VAR, str(tmp_path / "custom"))
    assert ArtifactStore().root == tmp_path / "custom"


def test_object_arrays_refused(tmp_path):
    store = ArtifactStore(tmp_path)
    with pytest.raises(TypeError, match="object"):
        store.save("demo", Params(), {"bad": np.array([{"a": 1}], dtype=object)})


def test_code_version_ignores_prose_but_not_code():
    """Editing a docstring or a comment keeps cached artifacts; editing code (even a string constant) does not."""
    from stp_env.artifacts import code_fingerprint

    base = 'def f(x):\n    """Doc."""\n    y = "a"  # note\n    return x + 1\n'
    prose = 'def f(x):\n    """Other doc."""\n    y = "a"\n    return x + 1\n'
    assert code_fingerprint(base) == code_fingerprint(prose)
    assert code_fingerprint(base) != code_fingerprint('def f(x):\n    """Doc."""\n    y = "a"\n    return x + 2\n')
    assert code_fingerprint(base) != code_fingerprint('def f(x):\n    """Doc."""\n    y = "b"\n    return x + 1\n')


def _slow_compute_in_child(root, marker_dir, params):
    import os
    import time as _time

    def compute():
        (Path(marker_dir) / f"computed-{os.getpid()}").write_text("")
        _time.sleep(1.0)
        return {"x": np.arange(4.0)}

    ArtifactStore(root).load_or_compute("lock_probe", params, compute)


@pytest.mark.slow
def test_concurrent_processes_compute_an_artifact_once(tmp_path):
    """Two processes asking for the same missing artifact at once (parallel test workers, two CLI runs): one
    computes it, the other waits for the lock and loads it. Without the lock both would compute."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    markers = tmp_path / "markers"
    markers.mkdir()
    procs = [ctx.Process(target=_slow_compute_in_child, args=(str(tmp_path / "cache"), str(markers), {"p": 1}))
             for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert len(list(markers.iterdir())) == 1
    art = ArtifactStore(tmp_path / "cache").load("lock_probe", {"p": 1})
    assert art is not None and np.array_equal(art.arrays["x"], np.arange(4.0))


# ------------------------------------------------------------------------------------- shipped artifacts
def test_a_valid_shipped_copy_is_used_and_an_invalid_one_is_not(tmp_path):
    """The shipped layer is consulted only when the cache has no file, and only a copy that passes every check of
    a cache entry is used: a tampered or stale shipped copy means a computation, not a silently reused result."""
    calls, compute = _compute_counter()
    shipped = tmp_path / "shipped"
    made = ArtifactStore(shipped, shipped=None).load_or_compute("demo", Params(), compute)
    assert len(calls) == 1
    store = ArtifactStore(tmp_path / "cache", shipped=shipped)
    hit = store.load_or_compute("demo", Params(), compute)
    assert len(calls) == 1 and hit.from_cache and hit.path == made.path
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").iterdir())  # nothing written
    assert ArtifactStore(tmp_path / "off", shipped=None).load("demo", Params()) is None   # the layer can be off
    store.load_or_compute("demo", Params(n=6), compute)   # other parameters: the shipped copy does not serve
    assert len(calls) == 2
    data = made.path.read_bytes()
    made.path.write_bytes(data[:-8] + b"\0" * 8)           # tampered shipped copy: computed into the cache
    fresh = ArtifactStore(tmp_path / "cache2", shipped=shipped).load_or_compute("demo", Params(), compute)
    assert len(calls) == 3 and not fresh.from_cache and fresh.path.parent == tmp_path / "cache2"


def test_the_shipped_artifacts_are_current_and_serve_the_default_scenario(tmp_path):
    """Every file in ``stp_env/data/artifacts`` was computed by this code (an edit to the numerical code makes it
    stale: run ``stp-env data artifacts``), and the default scenario's tracking bound is read from it by
    a store with an empty cache, without computing."""
    from stp_env.reach import tracking
    from stp_env.scenarios import make

    metas = sorted(artifacts.SHIPPED_DIR.glob("*.json"))
    assert metas, "no shipped artifacts"
    for path in metas:
        meta = json.loads(path.read_text())
        current = artifacts.code_version(meta["kind"])
        assert meta["code_version"] == current, (
            f"{path.name} is stale (computed by code {meta['code_version']}, this is {current}): "
            "run stp-env data artifacts")
        assert meta["content_sha256"] == artifacts._file_sha256(path.with_suffix(".npz")), path.name
    town = make("town")
    store = ArtifactStore(tmp_path / "empty-cache")
    cfg = tracking.default_tracking_config(town.vehicle, tuple(town.planning_v), town.planning_omega_max)
    art = store.load("tracking_bound", cfg)
    assert art is not None and art.path.parent == artifacts.SHIPPED_DIR
    bound = tracking.default_tracking_bound(town.vehicle, tuple(town.planning_v), town.planning_omega_max,
                                            store=store, progress=False)
    assert bound.converged and 3.5 <= bound.bound <= 6.5
    assert not (tmp_path / "empty-cache").exists() or not any((tmp_path / "empty-cache").iterdir())


def test_the_recompute_check_of_the_shipped_copies_can_fail(tmp_path):
    """``stp-env data artifacts --recompute`` compares freshly computed arrays with the shipped copies: a changed
    value, a missing array, another shape or another NaN pattern each make it report a difference."""
    from stp_env.data_tools import ship_artifacts as ship

    base = {"value": np.linspace(0.0, 1.0, 12).reshape(3, 4), "n_steps": np.array(7)}

    def write(name, **arrays):
        path = tmp_path / f"{name}.npz"
        np.savez(path, **arrays)
        return path

    ref = write("ref", **base)
    assert ship.compare(write("same", **base), ref, atol=1e-3)["same"]
    nudged = dict(base, value=base["value"] + 5e-4)
    assert ship.compare(write("nudged", **nudged), ref, atol=1e-3)["same"]        # within atol
    moved = dict(base, value=base["value"] + 2e-3)
    assert not ship.compare(write("moved", **moved), ref, atol=1e-3)["same"]
    assert not ship.compare(write("missing", value=base["value"]), ref, atol=1e-3)["same"]
    assert not ship.compare(write("shape", **dict(base, value=base["value"].ravel())), ref, atol=1e-3)["same"]
    holed = base["value"].copy()
    holed[0, 0] = np.nan
    report = ship.compare(write("nan", **dict(base, value=holed)), ref, atol=1e-3)
    assert not report["same"] and report["max_abs_diff"]["value"] == float("inf")
