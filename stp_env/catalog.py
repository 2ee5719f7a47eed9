"""The names the command line lists, as plain tables that import nothing heavy (``stp-env --help`` runs without
JAX), and the plug-ins that installed distributions add to them.

Built-in names are the tables below (``tests/test_cli_kit.py`` checks that they are the registries' names): a new
scenario, intruder, vehicle policy or wind model is its module (or entry) plus its name here, as Gymnasium's ids are
a ``register`` line beside the environment's module. A scenario module without its line still registers and runs;
``--help`` does not list it. A plug-in joins through an entry point of its distribution's metadata (Python packaging's
``[project.entry-points."<group>"]``, the mechanism Gymnasium and pytest use): ``name = "package.module:object"``
in one of :data:`GROUPS`. The command line lists a plug-in by its name from the metadata alone (its module is not
imported for ``--help``); the registry imports it when the name is looked up:

* ``stp_env.scenarios``: a scenario factory (keyword-only parameters with defaults), as ``@register`` takes it;
* ``stp_env.intruders``: a jittable intruder policy ``(key, state, params) -> (2,)`` or its record
  (:class:`stp_env.policies.record.Policy`);
* ``stp_env.vehicle_policies``: a jittable vehicle policy ``(key, state, params) -> (N, action_dim)``;
* ``stp_env.wind_models``: a :class:`stp_env.sim.winds.base.WindModel` subclass.

Entry points are installed code, loaded only for a name the user gave (the command line or their own code): a
name read from a data file (saved events, counterexamples) never loads one.
"""

from __future__ import annotations

import functools
from importlib import metadata
from typing import NamedTuple

GROUPS = {"scenarios": "stp_env.scenarios", "intruders": "stp_env.intruders",
          "vehicle_policies": "stp_env.vehicle_policies", "wind_models": "stp_env.wind_models"}
"""Entry-point group of each kind of plug-in."""

SCENARIOS = {
    "bay-area": "bay_area", "city": "city", "city-intruder": "city_intruder", "corridor": "corridor",
    "crossing": "crossing", "fig6": "fig6", "four-vehicle": "four_vehicle", "pinwheel": "pinwheel", "tiny": "tiny",
    "tiny-intruder": "tiny", "town": "town",
}
"""Built-in scenario -> its module in :mod:`stp_env.scenarios.catalog`."""

INTRUDERS = ("hover", "random", "bezier2", "bezier3", "greedy", "hj", "max-k", "optimal-max-k")
"""Built-in scripted intruders (:data:`stp_env.policies.INTRUDERS`), in its order."""

VEHICLE_POLICIES = ("switching", "nominal", "worst")
"""Built-in vehicle policies (:data:`stp_env.policies.VEHICLE_POLICIES`), in its order."""


class WindEntry(NamedTuple):
    help: str
    params: dict


WIND_MODELS = {
    "uniform": WindEntry("a new wind in the disk every step (the papers)", {}),
    "constant": WindEntry("one per episode", {}),
    "gusts": WindEntry("Ornstein-Uhlenbeck with correlation time time_constant [s]", {"time_constant": 5.0}),
    "worst": WindEntry("the HJ games' worst-case wind", {}),
    "tailwind": WindEntry("full strength along each agent's heading (the fastest ground speed)", {}),
    "converging": WindEntry("the buffer game's helping winds by line of sight (unforced vehicles and intruder blow "
                            "toward each other)", {}),
}
"""Built-in wind models (:mod:`stp_env.sim.winds`), in the order the registry lists them: help and parameters with
their defaults."""

SPAWN_MODES = ("outside", "boundary", "mixed")
"""Where the intruder appears (:data:`stp_env.sim.types.SPAWN_MODES`)."""

EPISODE_CHOICES = ("window", "full")
"""The evaluated episode (:data:`stp_env.evaluation.config.EPISODE_CHOICES`)."""


@functools.cache
def plugins(kind: str) -> dict[str, metadata.EntryPoint]:
    """The plug-ins of ``kind`` (a key of :data:`GROUPS`) that installed distributions declare, by name (the first
    declaration of a name wins, as importlib lists them)."""
    found: dict[str, metadata.EntryPoint] = {}
    for entry in metadata.entry_points(group=GROUPS[kind]):
        found.setdefault(entry.name, entry)
    return found


def names(kind: str, builtin) -> tuple[str, ...]:
    """``builtin`` names, then the plug-ins of ``kind`` that do not shadow one (sorted)."""
    builtin = tuple(builtin)
    return builtin + tuple(sorted(n for n in plugins(kind) if n not in builtin))


def load_plugin(kind: str, name: str):
    """The object of plug-in ``name`` of ``kind`` (its module imported); ``None`` when no distribution declares it.
    For names the user gave only (never for names read from a file)."""
    entry = plugins(kind).get(name)
    return None if entry is None else entry.load()
