"""Deprecated: what this module held (``make_params``, ``params_for``, ``load_artifacts``, ``load_plan``,
``with_plan``, ``with_buffer``, ``load_buffer``, ``SHIPPED_PLANS``, ...) is :mod:`stp_env.assembly`, the layer above
the core that makes ``EnvParams`` from a scenario, its plan and the reachability artifacts. Its names are found
there on first use, with a ``DeprecationWarning`` naming the new place."""

import warnings as _warnings


def __getattr__(name):
    # Deprecated alias (tests/test_architecture.py: ALLOWED_UPWARD): the core imports the layer above it only here.
    from stp_env import assembly

    if name.startswith("__") or not hasattr(assembly, name):
        raise AttributeError(f"module 'stp_env.sim.build' has no attribute {name!r}")
    _warnings.warn(f"stp_env.sim.build.{name} moved to stp_env.assembly.{name}.", DeprecationWarning, stacklevel=2)
    return getattr(assembly, name)
