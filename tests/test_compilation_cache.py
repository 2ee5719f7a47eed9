"""The persistent compilation cache (stp_env/compilation_cache.py): on by default for every process that imports
stp_env, under the artifact cache directory, keyed by the program, off on request, never in a folder others can
write. Each check runs fresh processes (the cache is per process state in JAX)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

# A child process: imports stp_env (before or after JAX), compiles one program, reports what the cache did.
CHILD = r"""
import json, sys
first = sys.argv[1]
factor = float(sys.argv[2])
if first == "jax":
    import jax
import stp_env
import jax
import jax.numpy as jnp
from jax import monitoring
hits = []
monitoring.register_event_listener(lambda event, **kw: hits.append(event) if event.endswith("cache_hits") else None)
y = jax.jit(lambda x: jnp.sin(x) * factor + jnp.cumsum(x))(jnp.arange(7.0))
from stp_env import compilation_cache
from jax._src import lru_cache
print(json.dumps({"hits": len(hits), "y": float(y.sum()), "dir": str(compilation_cache.directory()),
                  "jax_dir": jax.config.jax_compilation_cache_dir,
                  "atomic": bool(getattr(lru_cache.LRUCache.put, "_atomic", False))}))
"""


def _env(cache: Path, **extra) -> dict:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT", "STP_ENV_COMPILATION"))}
    env.update(STP_ENV_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu",
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")])))
    env.update(extra)
    return env


def _run(env: dict, first: str = "stp_env", factor: float = 2.0) -> tuple[dict, str]:
    out = subprocess.run([sys.executable, "-c", CHILD, first, str(factor)], env=env, capture_output=True, text=True,
                         check=True, timeout=300)
    return json.loads(out.stdout.strip().splitlines()[-1]), out.stderr


def _entries(folder: Path) -> set[str]:
    return {p.name for p in folder.glob("*")} if folder.is_dir() else set()


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    first, _ = _run(_env(tmp_path))
    assert first["dir"] == str(tmp_path / "xla") and first["hits"] == 0
    written = _entries(tmp_path / "xla")
    assert written, "the first process wrote no compiled program"
    second, _ = _run(_env(tmp_path))
    assert second["hits"] >= 1 and second["y"] == first["y"]
    assert _entries(tmp_path / "xla") == written  # nothing compiled again


def test_another_program_is_another_entry_never_a_stale_one(tmp_path):
    first, _ = _run(_env(tmp_path), factor=2.0)
    written = _entries(tmp_path / "xla")
    changed, _ = _run(_env(tmp_path), factor=3.0)  # the code changed: another constant in the program
    x = np.arange(7.0)
    assert changed["y"] == pytest.approx(float(np.sum(np.sin(x) * 3.0 + np.cumsum(x))), rel=1e-6)
    assert first["y"] == pytest.approx(float(np.sum(np.sin(x) * 2.0 + np.cumsum(x))), rel=1e-6)
    assert _entries(tmp_path / "xla") > written  # compiled and written, not loaded


def test_jax_imported_first_still_uses_the_cache(tmp_path):
    _run(_env(tmp_path), first="jax")
    second, _ = _run(_env(tmp_path), first="jax")
    assert second["hits"] >= 1 and second["jax_dir"] == str(tmp_path / "xla")


@pytest.mark.parametrize("value", ["0", "off"])
def test_the_environment_variable_turns_it_off(tmp_path, value):
    # an inherited JAX setting (a parent process that imported stp_env) is turned off too
    env = _env(tmp_path, STP_ENV_COMPILATION_CACHE=value, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "inherited"))
    out, _ = _run(env)
    assert out["dir"] == "None" and out["jax_dir"] is None
    assert not _entries(tmp_path / "xla") and not _entries(tmp_path / "inherited")


def test_configure_turns_it_off_and_on_at_run_time(tmp_path, monkeypatch):
    import jax

    from stp_env import compilation_cache

    before = jax.config.jax_compilation_cache_dir
    try:
        compilation_cache.disable()
        assert compilation_cache.directory() is None and jax.config.jax_compilation_cache_dir is None
        assert compilation_cache.configure(directory=tmp_path / "here") == tmp_path / "here"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "here")
    finally:
        compilation_cache.configure(directory=before) if before else compilation_cache.disable()


def test_a_folder_others_can_write_is_not_used(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    out, err = _run(_env(tmp_path, STP_ENV_COMPILATION_CACHE_DIR=str(shared)))
    assert out["dir"] == "None" and "others can write it" in err
    assert not _entries(shared)


def test_a_new_folder_is_private(tmp_path):
    _run(_env(tmp_path))
    assert (tmp_path / "xla").stat().st_mode & 0o077 == 0


def test_the_folder_is_in_the_artifact_cache_directory(tmp_path, monkeypatch):
    from stp_env import artifacts, compilation_cache

    monkeypatch.delenv("STP_ENV_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("STP_ENV_CACHE_DIR", str(tmp_path))
    assert compilation_cache.default_dir() == artifacts.default_cache_dir() / "xla"
    monkeypatch.delenv("STP_ENV_CACHE_DIR")
    assert compilation_cache.artifact_cache_dir() == artifacts.default_cache_dir()


def test_a_folder_over_its_limit_is_pruned_least_recently_used_first(tmp_path):
    import time as _time

    from stp_env import compilation_cache

    folder = tmp_path / "xla"
    folder.mkdir()
    now = _time.time()
    for i in range(10):  # ten 1 kB entries, entry 0 the least recently used
        path = folder / f"entry{i}-cache"
        path.write_bytes(b"x" * 1000)
        os.utime(path, (now - 1000 + i, now - 1000 + i))
    assert compilation_cache.prune(folder, 20_000) == 0  # under the limit: nothing
    assert compilation_cache.prune(folder, 5_000) == 6  # down to 0.8 of the limit: 4 kB left
    assert sorted(p.name for p in folder.iterdir()) == [f"entry{i}-cache" for i in range(6, 10)]
    assert compilation_cache.prune(folder, -1) == 0


def test_turning_it_on_prunes_the_folder(tmp_path):
    folder = tmp_path / "xla"
    folder.mkdir(mode=0o700)
    (folder / "old-cache").write_bytes(b"x" * 5000)
    _run(_env(tmp_path, STP_ENV_COMPILATION_CACHE_MAX_GB=str(4000 / 1e9)))
    assert not (folder / "old-cache").exists()  # pruned at the start; what the process compiled is written after


def test_the_size_limit_is_read_from_the_environment(monkeypatch):
    from stp_env import compilation_cache

    monkeypatch.delenv(compilation_cache.MAX_GB_ENV_VAR, raising=False)
    assert compilation_cache.max_size_bytes() == int(compilation_cache.DEFAULT_MAX_GB * 1e9)
    monkeypatch.setenv(compilation_cache.MAX_GB_ENV_VAR, "0.5")
    assert compilation_cache.max_size_bytes() == 500_000_000
    monkeypatch.setenv(compilation_cache.MAX_GB_ENV_VAR, "-1")
    assert compilation_cache.max_size_bytes() == -1
    monkeypatch.setenv(compilation_cache.MAX_GB_ENV_VAR, "lots")
    with pytest.raises(ValueError, match="size in GB"):
        compilation_cache.max_size_bytes()


@pytest.mark.parametrize("first", ["stp_env", "jax"])
def test_entries_are_written_whole(tmp_path, first):
    """Whichever is imported first, JAX's file cache writes an entry to a temporary file and renames it into place:
    a worker reading an entry another is writing never gets a truncated executable (two test workers crashed
    deserialising one). Nothing temporary is left behind."""
    out, _ = _run(_env(tmp_path), first=first)
    assert out["atomic"]
    written = _entries(tmp_path / "xla")
    assert written and not any(name.endswith(".tmp") for name in written)
