"""How many threads XLA's CPU runtime gives a program: every core for batches, one for a loop over one environment.

On a CPU, XLA runs a compiled program as a sequence of small kernels (one per fusion) and hands the kernels that are
ready at the same time to a pool of threads, one thread per core by default. For a batch of a thousand episodes
(``stp-env evaluate``, the falsifier, the vectorised training environments) each kernel has work for every core and
the pool pays. For one environment at a time (the PettingZoo ``env.step`` loop, a SuperSuit worker) the kernels are
tiny (a microsecond or so: seven vehicles, one intruder) and handing them to another core costs more than running
them. On the 2-core machine, with one thread, the adapter's step loop ran 1.06 (town) and 1.2 (city) times as fast
when the machine was otherwise idle and 1.73 and 1.24 times as fast beside a background job on both cores (medians
of three runs each), and the batched core at 1,024 episodes 0.69 (city) to 1.03 (town) times as fast
(``BENCHMARKS.md``, "Environment throughput: XLA's CPU threads"; ``python benchmarks/cpu_threads.py``).

XLA's CPU client reads the size of its pools once, when JAX starts its CPU backend (the first computation), from the
environment variable ``PJRT_NPROC`` (then ``NPROC``; unset: the number of cores the process may run on). Set it
before the first JAX computation:

* ``PJRT_NPROC=1 python my_loop.py`` in the shell, or
* :func:`set_cpu_threads` ``(1)`` first thing in the script (after ``import stp_env``, before any environment or
  array is made); it refuses, with the reason, once the backend has started with another setting.

The setting is the process's; child processes inherit the environment variable. It changes how fast programs run,
never what they compute (the kernels are the same; ``tests/test_cpu_threads.py``).
"""

from __future__ import annotations

import os

from stp_env import resources
from stp_env.resources import check_count, cpu_limit_reason, max_cpu_devices, max_cpu_threads

ENV_VAR = "PJRT_NPROC"
"""The environment variable XLA's CPU client reads for the size of its thread pools."""


_PROBE_OPTION = "jax_cpu_get_local_topology_timeout_minutes"
"""A JAX option that may only change before the backends start (JAX 0.10.2: its validator refuses a new value with a
``RuntimeError`` once they have), read only by multi-process CPU clusters: what :func:`_backend_started` probes."""


def _backend_started() -> bool:
    """Whether JAX has created its backends (after which XLA's thread pools and the device count are fixed).

    JAX has no public function that says so (checked on JAX 0.10.2). Its public configuration does: an option that
    must be set before the backends start (:data:`_PROBE_OPTION`) refuses a new value once they have, by the same
    test JAX uses for ``jax_num_cpu_devices``. The probe sets another value and puts the old one back (a timeout that
    only a multi-process CPU cluster reads, so that a backend started by another thread in between does no harm).
    When the option is missing (another JAX) or refuses otherwise, the answer is the safe one: started."""
    import sys

    if "jax" not in sys.modules:
        return False
    import jax

    try:
        current = getattr(jax.config, _PROBE_OPTION)
    except AttributeError:  # pragma: no cover - another JAX: assume started, the safe answer
        return True
    try:
        jax.config.update(_PROBE_OPTION, int(current) + 1)
    except Exception:  # RuntimeError: started; anything else (another JAX): assume started, the safe answer
        return True
    try:
        jax.config.update(_PROBE_OPTION, current)
    except RuntimeError:  # pragma: no cover - another thread started the backends in between
        return True
    return False


def cpu_threads() -> int | None:
    """The thread count set for XLA's CPU runtime (``PJRT_NPROC``, else ``NPROC``), ``None`` when neither is set
    (every core the process may run on)."""
    for var in (ENV_VAR, "NPROC"):
        value = os.environ.get(var, "").strip()
        if value:
            try:
                return int(value)
            except ValueError:
                continue  # XLA skips a value it cannot parse and reads the next variable
    return None


def set_cpu_threads(n: int | None) -> None:
    """Give XLA's CPU runtime ``n`` threads per program (``None``: every core, XLA's default). Must come before the
    first JAX computation of the process; afterwards only the setting already in effect is accepted.

    Raises ``ValueError`` for a count that is not a positive integer, or is over this machine's limit
    (:func:`stp_env.resources.max_cpu_threads`: a pool of thousands of threads takes minutes to start), and
    ``RuntimeError`` once the backend has started with a different setting (nothing is changed then)."""
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"the CPU thread count must be a positive integer or None (every core); got {n!r}.")
    if n is not None:
        check_count("the CPU thread count", n, limit=max_cpu_threads(), why=cpu_limit_reason())
    if cpu_threads() == n:
        return
    if _backend_started():
        current = cpu_threads()
        raise RuntimeError(
            f"XLA's CPU runtime has already started with {current if current is not None else 'one thread per core'} "
            f"(the first JAX computation fixes it); set the thread count before it: {ENV_VAR}={n or ''} in the "
            "environment, or stp_env.set_cpu_threads(...) before making any environment or array.")
    if n is None:
        os.environ.pop(ENV_VAR, None)
        os.environ.pop("NPROC", None)
    else:
        os.environ[ENV_VAR] = str(n)


def cpu_devices() -> int:
    """How many devices JAX's CPU backend has or will have (:func:`set_cpu_devices`; 1 unless set)."""
    import jax

    n = int(jax.config.jax_num_cpu_devices)
    if n > 0:
        return n
    for flag in os.environ.get("XLA_FLAGS", "").split():
        if flag.startswith("--xla_force_host_platform_device_count="):
            try:
                return int(flag.split("=", 1)[1])
            except ValueError:
                break
    return 1


def available_cores() -> int:
    """How many cores this process may run on (:func:`stp_env.resources.available_cores`)."""
    return resources.available_cores()


DEVICES_ENV_VAR = "STP_ENV_CPU_DEVICES"
"""The environment variable that sets the default ``--cpu-devices`` of the commands that take it (``evaluate``,
``falsify``, ``coobservation``, ``train-intruder``): a positive integer, or ``auto`` (one device per core,
:func:`available_cores`). Unset, each command's own default applies."""


def default_cpu_devices(unset: int | str = "auto") -> int | str:
    """The device count :data:`DEVICES_ENV_VAR` asks for: a positive integer of at most
    :func:`stp_env.resources.max_cpu_devices`, or ``"auto"``; ``unset`` when it is not set. ``ValueError`` naming the
    variable for anything else."""
    value = os.environ.get(DEVICES_ENV_VAR, "").strip()
    if not value:
        return unset
    if value == "auto":
        return "auto"
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"{DEVICES_ENV_VAR} must be a positive integer or 'auto'; got {value!r}.")
    return check_count(DEVICES_ENV_VAR, n, limit=max_cpu_devices(), why=cpu_limit_reason())


def set_cpu_devices(n: int) -> None:
    """Split JAX's CPU backend into ``n`` devices (``jax_num_cpu_devices``); ``n`` = the number of cores is the
    setting for batches of episodes.

    XLA runs one program on one device at a time and, inside it, gives kernels to other cores only when several
    are ready at once: a batched rollout kept about 1.45 of the 2 cores busy. With one device per core the episode
    engine (:func:`stp_env.sim.engine.across_devices`) shares each batch among the devices, which run side by side:
    on the 2-core machine the town rollout at 1,024 episodes went from about 470,000 to 900,000 agent-steps/s and
    10,000 city evaluation episodes from 70.7 s to 36.0 s (``BENCHMARKS.md``, "The batched core on one device per
    core"). Results: each device runs a batch of its share, another compiled program than the whole batch on one
    device, so the episodes agree in their outcomes and may differ in their last bits (``docs/numerics.md``); the
    same device count gives the same bits. A loop over one environment runs on the first device and is unchanged.

    Must come before the first JAX computation (like :func:`set_cpu_threads`); ``ValueError`` for a count that is
    not a positive integer or is over this machine's limit (:func:`stp_env.resources.max_cpu_devices`: every
    program shared among the devices compiles once per device, about 30 ms each), ``RuntimeError`` once the backend
    has started with another count (nothing changed)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"the CPU device count must be a positive integer; got {n!r}.")
    check_count("the CPU device count", n, limit=max_cpu_devices(), why=cpu_limit_reason())
    import jax

    if cpu_devices() == n:
        return
    if _backend_started():
        raise RuntimeError(
            f"JAX's CPU backend has already started with {cpu_devices()} device(s) (the first JAX computation fixes "
            f"it); set the device count before it: stp_env.set_cpu_devices({n}) before making any environment or "
            "array.")
    jax.config.update("jax_num_cpu_devices", n)
