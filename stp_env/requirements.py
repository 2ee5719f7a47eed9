"""Which tables a run reads beyond the scenario's own, decided in one place for the environment, the evaluator, the
trainers and the falsifier, and the registry that builds them.

* The policies say what they read, by table name: an intruder's record (:class:`stp_env.policies.record.Intruder`
  ``tables``; any intruder's by :func:`stp_env.policies.intruders.capabilities`, plug-ins included), a vehicle
  policy's entry of :data:`stp_env.policies.vehicles.VEHICLE_POLICY_TABLES`, a learner's observation set's of
  :data:`stp_env.policies.observations.OBSERVATION_TABLES`, a falsifier target's ``tables_for(options)``
  (:func:`stp_env.falsify.targets.required_tables`).
* :func:`required_tables` collects the names (an unknown one is a ``ValueError`` before anything is built or run);
  :func:`with_required_tables` builds each one the run's ``EnvParams`` lack through :data:`TABLES`.
* Built in: ``"buffer"``, the relative buffer region ``V^B(0, t_IAT / k̄)`` of the buffer game (intruder paper
  eqs. 46-47; read by the ``worst`` vehicles, the ``optimal-max-k`` intruder and the ``"game"`` observation),
  computed for the run's k̄ (:func:`stp_env.assembly.load_buffer`) into its own fields
  (``params.tables.buffer_values``, ``buffer_grid``: :func:`stp_env.assembly.with_buffer`).
* Any other table: :func:`register_table` names a builder ``(scenario, *, kbar, store, progress) -> (values,
  grid)`` (``values`` on a :class:`stp_env.hj.grid.Grid`); its table lands in ``params.tables.extra``
  (:class:`stp_env.sim.types.Table`), which a policy reads by name (:func:`stp_env.sim.tables.extra_table`,
  :func:`stp_env.sim.tables.table_value`). An intruder that reads a new table is thus one file, the builder and
  its registration beside ``Intruder(policy, tables=(name,))`` (``tests/test_table_registry.py`` writes one).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from stp_env import assembly
from stp_env.hj.grid import Grid
from stp_env.sim.types import Table


@dataclasses.dataclass(frozen=True)
class TableEntry:
    """How a table is made and put into ``EnvParams``: ``build(scenario, *, kbar, store, progress)`` computes it,
    ``attach(params, built)`` returns the params holding it, ``loaded(params)`` says whether they hold it already."""

    build: Callable
    attach: Callable
    loaded: Callable
    description: str = ""


def _build_buffer(scenario, *, kbar=None, store=None, progress=None):
    return assembly.load_buffer(scenario, kbar, store=store, progress=progress)


def _attach_buffer(params, buffer):
    return assembly.with_buffer(params, buffer)


def _buffer_loaded(params) -> bool:
    return params.tables.buffer_values is not None


TABLES: dict[str, TableEntry] = {
    "buffer": TableEntry(_build_buffer, _attach_buffer, _buffer_loaded,
                         "V^B, the relative buffer region of the buffer game (intruder paper eqs. 46-47) for k̄"),
}
"""Every table a policy may read beyond the scenario's, by name: the built-in ``"buffer"`` and those registered
with :func:`register_table` in this process."""


def _attach_extra(name: str, params, built):
    """``params`` with the table ``name`` built as ``(values, grid)`` in ``params.tables.extra`` (float32, sorted
    by name; a table of that name already there is replaced)."""
    if not (isinstance(built, tuple) and len(built) == 2 and isinstance(built[1], Grid)):
        raise ValueError(f"the builder of table {name!r} must return (values, grid) with grid a "
                         f"stp_env.hj.grid.Grid; got {type(built).__name__}.")
    values, grid = built
    if tuple(np.shape(values)) != tuple(grid.shape):
        raise ValueError(f"table {name!r}: the values have shape {tuple(np.shape(values))}, the grid "
                         f"{tuple(grid.shape)}.")
    table = Table(values=jnp.asarray(values, jnp.float32), name=name, grid=grid)
    others = tuple(t for t in params.tables.extra if t.name != name)
    return params.replace(tables=dict(extra=tuple(sorted((*others, table), key=lambda t: t.name))))


def _extra_loaded(name: str, params) -> bool:
    return any(t.name == name for t in params.tables.extra)


def register_table(name: str, builder: Callable, description: str = "") -> Callable:
    """Register the table ``name``: ``builder(scenario, *, kbar, store, progress) -> (values, grid)`` computes it
    for a scenario (``kbar``: the run's k̄, ``None`` for the scenario's; ``store``: an
    :class:`stp_env.artifacts.ArtifactStore` or ``None``; ``progress``: whether to report), ``values`` of
    ``grid.shape`` on a :class:`stp_env.hj.grid.Grid`. A policy whose record lists ``name`` then finds it in its
    params (:func:`stp_env.sim.tables.extra_table`). A name is registered once (the same builder again is a no-op;
    the built-in ``"buffer"`` cannot be taken). Returns ``builder``."""
    if not isinstance(name, str) or not name or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"a table name is a non-empty string of letters, digits, '-' and '_'; got {name!r}.")
    if not callable(builder):
        raise ValueError(f"table {name!r}: the builder must be callable (scenario, *, kbar, store, progress) -> "
                         f"(values, grid); got {type(builder).__name__}.")
    if not isinstance(description, str):
        raise ValueError(f"table {name!r}: the description must be a string; got {type(description).__name__}.")
    if name in TABLES:
        if TABLES[name].build is builder:
            return builder
        raise ValueError(f"a table named {name!r} is already registered ({TABLES[name].description or 'a plug-in'}); "
                         "pick another name.")
    TABLES[name] = TableEntry(builder, functools.partial(_attach_extra, name), functools.partial(_extra_loaded, name),
                              description)
    return builder


def required_tables(vehicle_policy=None, intruder=None, observation: str | None = None, *,
                    tables=()) -> tuple[str, ...]:
    """The names of the tables a run reads beyond the scenario's own, each once: those of the vehicles' policy (a
    name, a resolved policy or ``None``), of the intruder (a spec, a record, a policy or ``None``: the agent), of a
    learner's ``observation`` set, and ``tables`` (names, e.g. a falsifier target's). ``ValueError`` for a name
    :data:`TABLES` does not hold."""
    from stp_env.policies import VEHICLE_POLICIES
    from stp_env.policies.intruders import capabilities
    from stp_env.policies.observations import OBSERVATION_TABLES
    from stp_env.policies.vehicles import VEHICLE_POLICY_TABLES

    if isinstance(tables, str):
        raise ValueError(f"tables is a tuple of table names; got the string {tables!r}.")
    names = list(tables)
    if observation is not None:
        names += OBSERVATION_TABLES.get(observation, ())
    if isinstance(vehicle_policy, str):
        names += VEHICLE_POLICY_TABLES.get(vehicle_policy, ())
    elif vehicle_policy is not None:
        names += next((read for name, read in VEHICLE_POLICY_TABLES.items()
                       if VEHICLE_POLICIES.get(name) is vehicle_policy), ())
    reader = None if intruder is None else capabilities(intruder)
    if reader is not None:
        names += reader.tables
    unknown = [name for name in dict.fromkeys(names) if name not in TABLES]
    if unknown:
        by = (f" (read by intruder {reader.__name__!r})" if reader is not None and set(unknown) & set(reader.tables)
              else "")
        raise ValueError(f"unknown table(s) {', '.join(map(repr, unknown))}{by}; registered: {', '.join(TABLES)}. "
                         "A table is registered with stp_env.requirements.register_table(name, builder) when the "
                         "module that defines it is imported.")
    return tuple(dict.fromkeys(names))


def missing_tables(params, names) -> tuple[str, ...]:
    """Those of the table ``names`` (each in :data:`TABLES`) that ``params`` lack."""
    return tuple(name for name in required_tables(tables=names) if not TABLES[name].loaded(params))


def with_required_tables(params, scenario, *, vehicle_policy=None, intruder=None, observation: str | None = None,
                         tables=(), kbar: int | None = None, store=None, progress: bool | None = None):
    """``params`` with every table of :func:`required_tables` that it lacks, each built once through
    :data:`TABLES` for ``scenario`` and ``kbar`` (``None``: the scenario's); ``params`` itself when nothing is
    missing. Every name is checked before any table is built."""
    for name in missing_tables(params, required_tables(vehicle_policy, intruder, observation, tables=tables)):
        entry = TABLES[name]
        params = entry.attach(params, entry.build(scenario, kbar=kbar, store=store, progress=progress))
    return params
