"""Arguments that ask for a share of the machine (CPU devices, threads, memory for a batch or a grid, runs of a
sweep), bounded by the machine the program runs on and refused before any work.

A count that the program would honour by starting threads, splitting the CPU or allocating memory in proportion
to it is checked here first, against what this machine has: a count beyond it used to start (a thread pool of
``2**63`` threads, 65,536 CPU devices, a batch of ``2**31 - 1`` episodes) and then hang, or fail minutes later
naming nothing. The bounds, and the measurements behind them (a 2-core machine with 24 GB of memory, busy with
another job):

* **CPU devices** (:func:`max_cpu_devices`): ``max(64, 4 x cores)``. Starting JAX's CPU backend took about 2 s for
  1 to 1,024 devices and 11 s for 4,096 (a process asked for 65,536 grew to 19 GB and had not started after five
  minutes); every program shared among the devices is compiled once per device count,
  which grew by about 30 ms per device (a trivial batch: 2 s at 64 devices, 22 s at 1,024). One device per core is
  the setting that pays (:func:`stp_env.cpu_threads.set_cpu_devices`); 64 leaves room for an events file recorded
  on a larger machine to replay here.
* **XLA's CPU threads** (:func:`max_cpu_threads`): ``max(64, 4 x cores)``. The first computation took 1.3 s with
  64 threads, 1.5 s with 1,024, 2.9 s with 2,048, 12 s with 4,096 and did not finish in 60 s with 8,192.
* **Memory** (:func:`available_memory`): what the system reports as available (``MemAvailable``, within the
  process's cgroup limit). A batch of episodes needs at least :data:`EPISODE_BYTES` per episode, a run's results
  :data:`RESULT_BYTES` per episode, and a grid of the reachability solver :data:`SOLVER_BYTES_PER_POINT` per point
  (:func:`check_memory`, :func:`check_grid`).
* **Sweeps**: at most :data:`MAX_SWEEP_RUNS` training runs.

Every check raises a one-line ``ValueError`` naming the argument, the value and the machine's limit. This module
imports nothing heavy (no JAX, no NumPy), so that the command line can use it while parsing.
"""

from __future__ import annotations

import os
from pathlib import Path

from stp_env.arguments import check_int

PER_CORE = 4
"""CPU devices or threads per core allowed above the floor :data:`MIN_CPU_CAP`."""

MIN_CPU_CAP = 64
"""The CPU device and thread counts allowed on any machine, however few cores it has."""

EPISODE_BYTES = 64 * 1024
"""The least memory one episode of a batch takes [bytes]: a town episode of ``stp-env evaluate`` took 0.55 MB (peak
memory at a batch of 400 against 50), the tiny scenario's state alone 234 bytes; a floor well under both."""

RESULT_BYTES = 200
"""The least memory the results of one episode take [bytes]: an evaluation keeps every episode's final state (234
bytes for the tiny scenario's 2 vehicles, 669 for the town's 7)."""

SOLVER_BYTES_PER_POINT = 48
"""The least memory the reachability solver takes per grid point [bytes]: one compiled step of the avoid-region
solve (float32, 3 dimensions, ``very_high``) held 51 bytes per point (39 of temporaries, 8 of arguments, 4 of
output; XLA's memory analysis at 21^3 and 41^3 points), before any stored time slice."""

MAX_N_ENVS = 1 << 20
"""The most environments of a batched training VecEnv (``train-intruder --n-envs``, a sweep grid's ``n_envs``)."""

MAX_SWEEP_RUNS = 10_000
"""The most training runs one sweep (seeds times grid points) may ask for. Each run trains for minutes at least;
a larger product is a slip in a ``--grid``. Checking every run's configuration takes 0.16 ms a run."""

_GB = 1e9


def available_cores() -> int:
    """How many cores this process may run on (its CPU affinity where the system reports one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - systems without affinity (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def max_cpu_devices() -> int:
    """The most CPU devices JAX's backend may be split into here: ``max(64, 4 x cores)``."""
    return max(MIN_CPU_CAP, PER_CORE * available_cores())


def max_cpu_threads() -> int:
    """The most threads XLA's CPU runtime may be given here: ``max(64, 4 x cores)``."""
    return max(MIN_CPU_CAP, PER_CORE * available_cores())


def cpu_limit_reason() -> str:
    """``"on this machine (N cores: 4 per core, at least 64)"``, what the CPU limits depend on."""
    cores = available_cores()
    return f"on this machine ({cores} core{'s' if cores != 1 else ''}: {PER_CORE} per core, at least {MIN_CPU_CAP})"


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text(encoding="ascii").strip()
        return int(text)
    except (OSError, ValueError):
        return None


def _cgroup_room() -> int | None:
    """The memory the process's cgroup (v2, else v1) may still take [bytes]; ``None`` without a limit."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is not None and usage is not None and limit < 1 << 60:  # "max" or a huge value: no limit
            return max(0, limit - usage)
    return None


def available_memory() -> int | None:
    """The memory available to this process now [bytes]: ``MemAvailable`` of ``/proc/meminfo`` (else the free
    physical pages), within the cgroup's limit; ``None`` where the system reports neither."""
    found = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        found = None
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):  # pragma: no cover - systems without sysconf
            found = None
    room = _cgroup_room()
    if room is not None:
        found = room if found is None else min(found, room)
    return found


def _size(n: float) -> str:
    """``n`` bytes in GB (MB below 0.1 GB), three figures or whole GB."""
    if n >= 100 * _GB:
        return f"{n / _GB:,.0f} GB"
    return f"{n / _GB:.3g} GB" if n >= 0.1 * _GB else f"{n / 1e6:.3g} MB"


def _label(name: str, value) -> str:
    from stp_env.arguments import show

    return f"{name} {show(value)}" if name else show(value)


def check_count(name: str, value, *, limit: int, why: str) -> int:
    """``value`` as an ``int`` if it is an integer in ``[1, limit]``; a one-line ``ValueError`` otherwise,
    ``"<name> <value>: at most <limit> <why>"`` for a count over the limit (``why``: what the limit comes from,
    e.g. :func:`cpu_limit_reason`)."""
    n = check_int(value, name or "the count", 1, None)
    if n > limit:
        raise ValueError(f"{_label(name, value)}: at most {limit:,} {why}.")
    return n


def check_memory(name: str, value, *, unit_bytes: int, unit: str, lo: int = 1) -> int:
    """``value`` as an ``int`` if it is an integer ``>= lo`` and that many things (``unit``) of at least
    ``unit_bytes`` each fit in the memory available now (:func:`available_memory`; not checked where the system
    reports none); a one-line ``ValueError`` naming ``name``, the memory needed and the memory available otherwise."""
    n = check_int(value, name or "the count", lo, None)
    need = n * unit_bytes
    have = available_memory()
    if have is not None and need > have:
        most = max(lo, have // unit_bytes)
        raise ValueError(f"{_label(name, value)}: needs at least {_size(need)} ({unit_bytes:,} bytes per {unit}); "
                         f"this machine has {_size(have)} available (at most about {most:,} {unit}s).")
    return n


def check_grid(name: str, shape, *, bytes_per_point: int = SOLVER_BYTES_PER_POINT) -> int:
    """The number of points of a grid of ``shape`` if they fit in the memory available now at ``bytes_per_point``
    (default: the solver's, :data:`SOLVER_BYTES_PER_POINT`); a one-line ``ValueError`` naming ``name`` otherwise."""
    points = 1
    for n in shape:
        points *= int(n)
    have = available_memory()
    need = points * bytes_per_point
    if have is not None and need > have:
        dims = " x ".join(str(int(n)) for n in shape)
        raise ValueError(f"{name}: a grid of {dims} = {points:,} points needs at least {_size(need)} "
                         f"({bytes_per_point} bytes per point); this machine has {_size(have)} available (at most "
                         f"about {have // bytes_per_point:,} points).")
    return points


def check_sweep(runs: int, what: str) -> int:
    """``runs`` if at most :data:`MAX_SWEEP_RUNS`; a one-line ``ValueError`` saying ``what`` makes them otherwise."""
    if runs > MAX_SWEEP_RUNS:
        raise ValueError(f"{what} make {runs:,} training runs; a sweep runs at most {MAX_SWEEP_RUNS:,}.")
    return runs


__all__ = ["EPISODE_BYTES", "MAX_N_ENVS", "MAX_SWEEP_RUNS", "MIN_CPU_CAP", "PER_CORE", "RESULT_BYTES",
           "SOLVER_BYTES_PER_POINT", "available_cores", "available_memory", "check_count", "check_grid",
           "check_memory", "check_sweep", "cpu_limit_reason", "max_cpu_devices", "max_cpu_threads"]
