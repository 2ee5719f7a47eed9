"""Shared test configuration: CPU-only JAX, float32 (no x64), matplotlib's Agg backend and a small, deterministic
hypothesis profile."""

from __future__ import annotations

import gc
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# Figures are written to files, never shown: the library selects no backend, the tests pick the file-only one.
os.environ.setdefault("MPLBACKEND", "Agg")

import jax
import pytest
from hypothesis import HealthCheck, settings

jax.config.update("jax_platforms", "cpu")
# `stp-env evaluate` splits the CPU into one device per core unless told otherwise; the suite calls the command line
# in-process and in child processes and compares with the library on one device, so it pins one device (the tests of
# the default itself, tests/test_cpu_devices.py, set the variable per child process).
os.environ.setdefault("STP_ENV_CPU_DEVICES", "1")

# JAX's persistent compilation cache (stp_env/compilation_cache.py) is on in every worker, in the artifact cache
# directory they share: a program that one worker or test file compiled is loaded by the others (most of the suite's
# time is compiling). Exported so that the tests' child processes use the same folder, with the same size limit
# (with a limit JAX locks the folder, so that no process reads an entry another is writing).
# The suite compiles about 5,000 programs (about 2 GB): with the package's default limit JAX would evict programs that
# later test files load again, so the suite runs with a limit it does not reach (a lock is kept either way).
os.environ.setdefault("STP_ENV_COMPILATION_CACHE_MAX_GB", "16")
from stp_env import compilation_cache  # noqa: E402

if compilation_cache.directory() is not None:
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(compilation_cache.directory()))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(compilation_cache.MIN_COMPILE_TIME_S))
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(jax.config.jax_compilation_cache_max_size))

# JIT compilation makes the first example of a property test slow; deadlines would only measure compilation.
settings.register_profile(
    "stp",
    deadline=None,
    max_examples=40,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("thorough", deadline=None, max_examples=400)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "stp"))

# The README's command runs `-n 2 --dist loadfile -m "not slow"` and the slow tests `-m slow`: every test file runs
# whole on one of two workers, handed out in collection order (`--no-loadscope-reorder` in pyproject.toml keeps that
# order; xdist would otherwise sort the files by their number of tests). A long file handed out last leaves the other
# worker idle at the end, so the longest files go first (longest-processing-time-first), ranked by the larger of a
# file's times in the two runs (a whole run's JUnit report, as benchmarks/suite_split.py reads it); a file not listed
# (under 15 s in both) runs after these, in collection order, so a long new file belongs here. The order only affects
# the wall time, never what runs.
SLOWEST_FILES = ("test_certification.py", "test_gates.py", "test_jax_rl.py", "test_planning.py",
                 "test_planning_methods.py", "test_learned_intruders.py", "test_fleet.py", "test_cpu_devices.py",
                 "test_falsify.py", "test_ray.py", "test_sim.py", "test_vehicle_filter.py", "test_docs.py",
                 "test_coobservation_env.py", "test_four_vehicle.py", "test_coobservation_planning.py",
                 "test_pymunk_backend.py", "test_clients.py", "test_extension_points.py", "test_pinwheel.py",
                 "test_survivability.py", "test_coobservation_attempts.py", "test_planning_resume.py",
                 "test_reach_avoid.py", "test_interpolation.py", "test_replan_env.py", "test_fig6.py", "test_env.py",
                 "test_closed_forms.py", "test_block_reads.py", "test_coobservation_geometry.py",
                 "test_reach_buffer.py", "test_oracle_hj_reachability.py", "test_reach_tracking.py",
                 "test_survivability_batch.py", "test_rl.py", "test_dense.py", "test_solver_api.py",
                 "test_public_jax_api.py", "test_table_registry.py", "test_coobservation_layouts.py",
                 "test_survivability_paper.py", "test_reach_obstacles.py", "test_dynamics.py",
                 "test_piece_provenance.py", "test_feedback_dynamics.py", "test_evaluation.py",
                 "test_coobservation_exact.py", "test_cpu_threads.py", "test_planning_obstacles.py",
                 "test_loader_contract.py", "test_compilation_cache.py", "test_fail_closed.py",
                 "test_plan_disk_check.py", "test_plan_domain.py", "test_progress.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: tests keep their order in a file


# Each compiled XLA program holds its machine code in memory mappings of its own, and a worker keeps every program it
# compiled: measured on the whole suite, a worker passed 20,000 mappings in 5 minutes, on the way to the kernel's
# limit (vm.max_map_count, 65,530 by default), past which LLVM's next allocation fails and the worker dies with a
# segmentation fault while compiling, loading or serialising a program (what crashed late suite runs). Programs are
# rarely shared between test files, and a shared one comes back from the persistent compilation cache, so the
# in-memory caches are dropped after each file.
@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    jax.clear_caches()
    gc.collect()
