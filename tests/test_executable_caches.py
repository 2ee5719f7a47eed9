"""One rule for every folder that holds compiled programs (stp_env/compilation_cache.py, ``private_cache_dir``): JAX
loads and runs what it finds there, so the package's compilation cache, a folder JAX was given in the environment and
a survivability study's ``OUT/jax-cache`` are all created private and refused (a warning, the setting not applied)
when another user owns them or others can write them. A size limit that is not a size deletes nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from _cli import run_cli

ROOT = Path(__file__).resolve().parents[1]

# A child process that imports stp_env only (no JAX): what the compilation cache was set to.
CHILD = r"""
import json, os
import stp_env
from stp_env import compilation_cache
print(json.dumps({"dir": str(compilation_cache.directory()), "jax_dir": os.environ.get("JAX_COMPILATION_CACHE_DIR")}))
"""


def _child(tmp_path: Path, **extra) -> tuple[dict, str]:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT", "STP_ENV_COMPILATION"))}
    env.update(STP_ENV_CACHE_DIR=str(tmp_path / "cache"), JAX_PLATFORMS="cpu",
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")])), **extra)
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, check=True,
                         timeout=300)
    return json.loads(out.stdout.strip().splitlines()[-1]), out.stderr


def _folder(tmp_path: Path, mode: int, owner: int | None = None) -> Path:
    folder = tmp_path / "shared"
    folder.mkdir()
    folder.chmod(mode)
    if owner is not None:
        os.chown(folder, owner, -1)
    return folder


@pytest.fixture
def jax_settings():
    """Restores the process's compilation cache (this module's state and JAX's settings) after the test."""
    import jax

    from stp_env import compilation_cache

    before = (jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)
    yield
    if compilation_cache.directory() != (None if before[0] is None else Path(before[0])):
        compilation_cache.configure(directory=before[0]) if before[0] else compilation_cache.disable()
    jax.config.update("jax_compilation_cache_dir", before[0])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])


def _study_cli(out: Path, monkeypatch) -> tuple[int, str]:
    """``stp-env survivability --out OUT`` up to its compilation cache: the study and its report are stubs."""
    from stp_env.survivability import report, study

    monkeypatch.setattr(study, "run_study", lambda *args, **kwargs: out / "missions.csv")
    monkeypatch.setattr(report, "build_report", lambda *args, **kwargs: {"timing": {}, "findings": {}})
    code, _, err = run_cli(["survivability", "--out", str(out), "--partial", "4", "--unknown", "4", "--no-figures",
                            "--no-progress"])
    return code, err


CASES = [pytest.param(0o777, None, "others can write it", id="world-writable"),
         pytest.param(0o1777, None, "others can write it", id="world-writable-sticky"),
         pytest.param(0o770, None, "others can write it", id="group-writable"),
         pytest.param(0o700, 65534, "belongs to another user", id="another-user",
                      marks=pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0,
                                               reason="only root can give a folder to another user"))]


@pytest.mark.parametrize("mode, owner, why", CASES)
def test_every_executable_cache_refuses_a_folder_others_can_write(tmp_path, monkeypatch, jax_settings, mode, owner,
                                                                  why):
    """The package's compilation cache and the study's ``OUT/jax-cache`` refuse the same folders with a warning
    that names the folder and why, and JAX's setting stays as it was; a private folder is used."""
    import jax

    from stp_env import compilation_cache

    shared = _folder(tmp_path, mode, owner)
    with pytest.warns(UserWarning, match=why) as caught:
        assert compilation_cache.configure(directory=shared) is None
    assert str(shared) in str(caught[0].message)
    assert jax.config.jax_compilation_cache_dir != str(shared) and compilation_cache.directory() is None

    before = jax.config.jax_compilation_cache_dir
    out = tmp_path / "study"
    out.mkdir()
    cache = _folder(out, mode, owner).rename(out / "jax-cache")
    with pytest.warns(UserWarning, match=why) as caught:
        code, err = _study_cli(out, monkeypatch)
    assert code == 0, err
    assert any(str(cache) in str(w.message) and "study's compilation cache" in str(w.message) for w in caught)
    assert jax.config.jax_compilation_cache_dir == before
    assert cache.stat().st_mode & 0o7777 == mode                      # refused, not changed

    private = tmp_path / "private"
    private.mkdir()
    code, err = _study_cli(private, monkeypatch)
    assert code == 0, err
    assert jax.config.jax_compilation_cache_dir == str(private / "jax-cache")
    assert (private / "jax-cache").stat().st_mode & 0o077 == 0          # created private


def test_a_folder_jax_was_given_in_the_environment_is_checked_too(tmp_path):
    """``JAX_COMPILATION_CACHE_DIR`` (set by a parent process or the user) that others can write is not used: the
    process compiles without a cache, and says so."""
    shared = _folder(tmp_path, 0o777)
    out, err = _child(tmp_path, JAX_COMPILATION_CACHE_DIR=str(shared))
    assert out == {"dir": "None", "jax_dir": None}
    assert "others can write it" in err and str(shared) in err


@pytest.mark.parametrize("value", ["0", "-0", "-2", "nan", "inf", "lots"])
def test_a_size_limit_that_is_not_a_size_deletes_nothing(tmp_path, monkeypatch, jax_settings, value):
    """``STP_ENV_COMPILATION_CACHE_MAX_GB`` must be a finite number of GB above 0 (or ``-1``: no limit); any other
    value is one line naming the variable, the cache is off, and no entry is deleted (``0`` deleted every entry at
    every start)."""
    from stp_env import compilation_cache

    folder = tmp_path / "xla"
    folder.mkdir(mode=0o700)
    entry = folder / "old-cache"
    entry.write_bytes(b"x" * 5000)
    monkeypatch.setenv(compilation_cache.MAX_GB_ENV_VAR, value)
    with pytest.raises(ValueError, match=compilation_cache.MAX_GB_ENV_VAR) as err:
        compilation_cache.max_size_bytes()
    assert "\n" not in str(err.value)
    with pytest.warns(UserWarning, match=compilation_cache.MAX_GB_ENV_VAR):
        assert compilation_cache.configure(directory=folder) is None
    assert entry.exists() and compilation_cache.directory() is None
    monkeypatch.setenv(compilation_cache.MAX_GB_ENV_VAR, "-1")
    assert compilation_cache.max_size_bytes() == -1


def test_a_zero_size_limit_at_import_deletes_nothing(tmp_path):
    """The same at the import of stp_env, where the cache is turned on: one warning naming the variable, the
    entries kept."""
    folder = tmp_path / "cache" / "xla"
    folder.mkdir(parents=True, mode=0o700)
    entry = folder / "old-cache"
    entry.write_bytes(b"x" * 5000)
    out, err = _child(tmp_path, STP_ENV_COMPILATION_CACHE_MAX_GB="0")
    assert out["dir"] == "None" and entry.exists()
    lines = [line for line in err.splitlines() if "STP_ENV_COMPILATION_CACHE_MAX_GB" in line]
    assert len(lines) == 1, err
