"""stp-env: provably safe multi-UAV sequential trajectory planning under wind and an adversarial intruder.

``stp_env.parallel_env(...)`` and ``stp_env.env(...)`` are the PettingZoo environment (:mod:`stp_env.env`, whose
docstring is the user's manual), imported on first use. The single-agent views are registered with Gymnasium
(``gymnasium.make("stp_env/Intruder-v0")``, :mod:`stp_env.registration`). Importing the package turns on JAX's
persistent compilation cache (:mod:`stp_env.compilation_cache`: programs compile once per machine;
``STP_ENV_COMPILATION_CACHE=0`` turns it off). :func:`set_cpu_threads` (:mod:`stp_env.cpu_threads`) sizes XLA's CPU
thread pools before JAX starts: one thread makes a loop over one environment faster; :func:`set_cpu_devices`
splits the CPU into one device per core, among which batches of episodes are shared.
"""

from __future__ import annotations

import warnings as _warnings

from stp_env.cpu_threads import set_cpu_devices, set_cpu_threads
from stp_env.version import __version__

__all__ = ["__version__", "env", "parallel_env", "set_cpu_devices", "set_cpu_threads"]

try:
    from stp_env import compilation_cache as _compilation_cache

    _compilation_cache.configure()
except Exception as _err:  # the package must import even where the cache cannot be set up
    _warnings.warn(f"stp_env: the persistent compilation cache is off ({type(_err).__name__}: {_err}).",
                   stacklevel=2)


try:
    from stp_env.registration import register_envs as _register_envs

    _register_envs()  # gymnasium.make("stp_env/Intruder-v0") (stp_env/registration.py)
except ImportError:  # pragma: no cover - gymnasium is a dependency
    pass


def parallel_env(*args, **kwargs):
    """:func:`stp_env.env.parallel_env` (the PettingZoo ParallelEnv; arguments in :mod:`stp_env.env`)."""
    from stp_env.env import parallel_env as make

    return make(*args, **kwargs)


def __getattr__(name):
    # ``stp_env.env`` is the module :mod:`stp_env.env`, which is also callable: ``stp_env.env(...)`` is its
    # :func:`stp_env.env.env` (a package attribute named ``env`` would be replaced by the submodule on its import).
    if name == "env":
        import importlib

        return importlib.import_module("stp_env.env")
    raise AttributeError(f"module 'stp_env' has no attribute {name!r}")
