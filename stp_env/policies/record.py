"""The record every intruder is: its policy and what running it takes (a module of its own, so that the scripted
intruders and the learned intruders' loader both build records without importing each other)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from stp_env.sim.types import SPAWN_MODES


@dataclasses.dataclass(frozen=True)
class Intruder:
    """An intruder policy and what running it takes: the record every entry of :data:`INTRUDERS` is, and what a
    plug-in module may define instead of a bare function (:func:`resolve_intruder`), so that the environment, the
    evaluator and the falsifier treat it as they treat the registered ones.

    Attributes:
        policy: the jittable ``(key, state, params) -> (2,)`` actions in ``[-1, 1]``.
        tables: the names of the tables the policy reads beyond the scenario's own (``"buffer"``: ``V^B``,
            ``params.tables.buffer_values``; any other: a table registered with
            :func:`stp_env.requirements.register_table`, read with :func:`stp_env.sim.tables.extra_table`):
            whoever runs it loads them (:func:`stp_env.requirements.with_required_tables`), and an unknown name is
            refused there, before anything runs.
        spawn: where it appears when the configuration leaves it open (``SPAWN_MODES`` of
            :mod:`stp_env.sim.types`: ``"outside"``, ``"boundary"`` on a vehicle's avoid boundary, ``"mixed"``).
        description: one line, for listings.

    The record is called like its policy (the simulator takes it wherever it takes a policy); it is hashable, so
    it is a static argument of the compiled rollouts like a function.
    """

    policy: Callable
    tables: tuple[str, ...] = ()
    spawn: str = "outside"
    description: str = ""

    def __post_init__(self) -> None:
        if not callable(self.policy) or isinstance(self.policy, Intruder):
            raise ValueError(f"an intruder's policy is a function (key, state, params) -> (2,); got "
                             f"{type(self.policy).__name__}.")
        tables = self.tables
        if isinstance(tables, str) or not isinstance(tables, (tuple, list)) or not all(
                isinstance(name, str) and name for name in tables):
            raise ValueError(f"tables must be a tuple of table names (e.g. ('buffer',)); got {tables!r}.")
        object.__setattr__(self, "tables", tuple(dict.fromkeys(tables)))  # hashable, each name once, in order
        if self.spawn not in SPAWN_MODES:
            raise ValueError(f"spawn must be one of {', '.join(SPAWN_MODES)}; got {self.spawn!r}.")
        if not isinstance(self.description, str):
            raise ValueError(f"description must be a string; got {type(self.description).__name__}.")

    def __call__(self, key, state, params):
        return self.policy(key, state, params)

    @property
    def __name__(self) -> str:
        return getattr(self.policy, "__name__", "intruder")
