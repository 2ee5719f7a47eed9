"""The falsifier's targets: what an attack is, and the registry that names them.

An **attack** is a frozen dataclass whose first field is ``base`` (the :class:`~stp_env.sim.types.EnvParams` it
runs in) and whose other fields are its options (``stp-env falsify --option NAME=VALUE``), with:

* ``name`` (a class attribute): the target's name, ``AttackSpec.target``;
* ``dim`` (int), ``bound`` (float) and ``margin(value) -> float`` (negative: the bound is broken);
* ``objective(z)``: a jittable function of ``z`` in ``[0, 1]^dim``, larger is worse for the system;
* ``details(z) -> dict``: what the simulator says about the attack at ``z`` (JSON-ready, for the summary line);
* ``draw(ax, ax2, z)``: the figure of the attack at ``z`` on two matplotlib axes (paths; a quantity over time);
* optionally ``seeds() -> (S, dim)``: the game's own worst strategies, where the search starts, and
  ``tables_for(options) -> tuple[str, ...]`` (a classmethod): the names of the tables beyond the scenario's that
  the environment must carry (``"buffer"``: ``V^B``; any table of :data:`stp_env.requirements.TABLES`).

A new target is one module with such a class decorated by :func:`register`; the command line, the search, the
counterexample files (saved, loaded, replayed) and the figure then take it by name. The three targets of the
project (``tracking``, ``avoidance``, ``kbar``) are listed in :data:`BUILT_IN` and imported on first use, so that
the command line's parser does not pay for JAX.

A counterexample file names its target; loading one never imports code: the target must be built in or registered
in this process.
"""

from __future__ import annotations

import importlib

BUILT_IN: dict[str, str] = {
    "tracking": "stp_env.falsify.tracking:TrackingAttack",
    "avoidance": "stp_env.falsify.avoidance:AvoidanceAttack",
    "kbar": "stp_env.falsify.kbar:KbarAttack",
}
"""The project's targets: name -> ``module:class`` (imported on first use)."""

_REGISTERED: dict[str, type] = {}

REQUIRED = ("dim", "bound", "margin", "objective", "details", "draw")
"""What every attack class defines (:func:`register` checks)."""


def register(cls: type) -> type:
    """Class decorator: list the attack class ``cls`` under ``cls.name`` (module docstring). A name is registered
    once (a built-in name cannot be taken)."""
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"an attack class needs a name of letters, digits, '-' and '_'; got {name!r}.")
    missing = [attr for attr in REQUIRED if not hasattr(cls, attr)]
    if missing:
        raise ValueError(f"attack {name!r} lacks {', '.join(missing)} (stp_env.falsify.targets).")
    if name in BUILT_IN and BUILT_IN[name] != f"{cls.__module__}:{cls.__qualname__}":
        raise ValueError(f"{name!r} is a built-in target.")
    if name in _REGISTERED and _REGISTERED[name] is not cls:
        raise ValueError(f"a target named {name!r} is already registered.")
    _REGISTERED[name] = cls
    return cls


def names() -> tuple[str, ...]:
    """Every target's name: the built-in ones, then those registered in this process."""
    return (*BUILT_IN, *(n for n in _REGISTERED if n not in BUILT_IN))


def attack_class(name: str) -> type:
    """The attack class of target ``name``; ``ValueError`` for an unknown one."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in BUILT_IN:
        module, _, attribute = BUILT_IN[name].partition(":")
        return getattr(importlib.import_module(module), attribute)  # its module registers it on import
    raise ValueError(f"unknown target {name!r}; allowed: {', '.join(names())} (register a new one with "
                     "stp_env.falsify.targets.register).")


def required_tables(name: str, options: dict) -> tuple[str, ...]:
    """The tables beyond the scenario's that target ``name`` with ``options`` reads (its ``tables_for``; none when
    it defines none), which :func:`stp_env.falsify.counterexample.environment` loads
    (:func:`stp_env.requirements.with_required_tables`)."""
    tables_for = getattr(attack_class(name), "tables_for", None)
    return tuple(tables_for(options)) if tables_for is not None else ()
