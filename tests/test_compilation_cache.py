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
print(json.dumps({"hits": len(hits), "y": float(y.sum()), "dir": str(compilation_cache.directory()),
                  "jax_dir": jax.config.jax_compilation_cache_dir,
                  "max_size": jax.config.jax_compilation_cache_max_size}))
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


def test_jax_deletes_the_least_recently_used_entries_past_the_limit(tmp_path):
    """The limit is JAX's own (``jax_compilation_cache_max_size``): JAX deletes the least recently used entries
    before a write would pass it. Entries without JAX's access-time file (written without a limit, as earlier
    versions of the package did) are dated by their modification time first, or JAX's eviction would fail on them
    and write nothing more."""
    import time as _time

    folder = tmp_path / "xla"
    folder.mkdir(mode=0o700)
    now = _time.time()
    for i, name in enumerate(("old1-cache", "old2-cache")):  # old1 the least recently used
        (folder / name).write_bytes(b"x" * 5000)
        os.utime(folder / name, (now - 1000 + i, now - 1000 + i))
    limit = 11_000
    out, err = _run(_env(tmp_path, STP_ENV_COMPILATION_CACHE_MAX_GB=str(limit / 1e9)))
    assert out["max_size"] == limit
    entries = sorted(folder.glob("*-cache"))
    assert not (folder / "old1-cache").exists(), err  # evicted first
    assert any(not p.name.startswith("old") for p in entries), err  # what the process compiled was written
    assert sum(p.stat().st_size for p in entries) <= limit
    assert all(p.with_name(p.name[:-len("-cache")] + "-atime").exists() for p in entries)


def test_undated_entries_are_dated_and_kept(tmp_path):
    from stp_env import compilation_cache

    folder = tmp_path / "xla"
    folder.mkdir(mode=0o700)
    (folder / "old-cache").write_bytes(b"x" * 10)
    (folder / "new-cache").write_bytes(b"y" * 10)
    (folder / "new-atime").write_bytes((7).to_bytes(8, "little"))
    os.utime(folder / "old-cache", ns=(1_000_000_000, 2_000_000_000))
    assert compilation_cache.private_cache_dir(folder) == folder
    assert int.from_bytes((folder / "old-atime").read_bytes(), "little") == 2_000_000_000
    assert int.from_bytes((folder / "new-atime").read_bytes(), "little") == 7  # JAX's own date is left alone
    assert (folder / "old-cache").read_bytes() == b"x" * 10


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


@pytest.mark.parametrize("gb, expected", [(None, 2_000_000_000), ("0.5", 500_000_000), ("-1", sys.maxsize)])
def test_jax_is_given_the_limit_so_that_it_locks_the_folder(tmp_path, gb, expected):
    """JAX's size limit comes from ``STP_ENV_COMPILATION_CACHE_MAX_GB`` (default 2 GB; ``-1``, no limit, as a limit
    no folder reaches: JAX's own ``-1`` would write entries in place without its lock), whichever of stp_env and JAX
    is imported first; JAX locks the folder and dates every entry. The dates are the proof of the lock: JAX writes an
    ``-atime`` file only with a size limit, and only holding the folder's lock (the lock file itself is not: filelock
    3.0 deletes it on release)."""
    for first in ("stp_env", "jax"):
        env = _env(tmp_path / first, **({} if gb is None else {"STP_ENV_COMPILATION_CACHE_MAX_GB": gb}))
        out, _ = _run(env, first=first)
        assert out["max_size"] == expected
        folder = tmp_path / first / "xla"
        entries = list(folder.glob("*-cache"))
        assert entries
        assert all(p.with_name(p.name[:-len("-cache")] + "-atime").exists() for p in entries)


def test_a_limit_jax_was_given_is_kept_unless_ours_is_set(tmp_path):
    out, _ = _run(_env(tmp_path, JAX_COMPILATION_CACHE_MAX_SIZE="123456789"))
    assert out["max_size"] == 123456789
    out, _ = _run(_env(tmp_path, JAX_COMPILATION_CACHE_MAX_SIZE="123456789", STP_ENV_COMPILATION_CACHE_MAX_GB="0.5"))
    assert out["max_size"] == 500_000_000


def test_importing_the_package_installs_no_import_hook(tmp_path):
    """``import stp_env`` registers its Gymnasium environments and sets JAX's cache through JAX's own settings: it
    adds no import hook to ``sys.meta_path`` (an earlier version patched JAX's file cache from one), before or after
    JAX is imported and compiles."""
    code = ("import json, sys\nbefore = list(sys.meta_path)\nimport stp_env\nafter_import = list(sys.meta_path)\n"
            "import jax, jax.numpy as jnp\njax.jit(lambda x: x + 1)(jnp.arange(3)).block_until_ready()\n"
            "print(json.dumps({'import': after_import == before, 'compile': sys.meta_path == before}))")
    out = subprocess.run([sys.executable, "-c", code], env=_env(tmp_path), capture_output=True, text=True,
                         check=True, timeout=300)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"import": True, "compile": True}
