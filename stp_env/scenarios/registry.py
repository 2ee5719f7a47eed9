"""The scenario registry: ``register(name)`` (a decorator for a factory), ``make(name, **overrides)``, ``names()``.

The mechanism only; the scenarios themselves are data in :mod:`stp_env.scenarios.catalog` (one module each, and a
line in :data:`stp_env.catalog.SCENARIOS`, the names ``--help`` lists without importing them): every module of
that package is imported the first time a name is looked up. A scenario defined elsewhere registers the same way
(``@register("name")`` on its factory) once its module is imported, or as an installed plug-in (the entry-point
group ``stp_env.scenarios``, :mod:`stp_env.catalog`), imported when its name is looked up.

``make(name, **overrides)``: overrides whose names are keyword parameters of the scenario's factory (for example
``wind``, ``sta_spacing``, ``n_vehicles``, ``seed``, ``kbar`` for ``city``) are passed to the factory, which rebuilds
what depends on them; the others must be :class:`~stp_env.scenarios.config.Scenario` fields and replace them
afterwards (:meth:`~stp_env.scenarios.config.Scenario.with_overrides`); anything else is an error that lists both.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from collections.abc import Callable

from stp_env import catalog
from stp_env.scenarios.config import Scenario

CATALOG = "stp_env.scenarios.catalog"

ScenarioFactory = Callable[..., Scenario]

_REGISTRY: dict[str, ScenarioFactory] = {}


def register(name: str) -> Callable[[ScenarioFactory], ScenarioFactory]:
    """Decorator: registers a factory (keyword-only parameters, each with a default) under ``name``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"scenario names must be non-empty strings; got {name!r}.")

    def decorator(factory: ScenarioFactory) -> ScenarioFactory:
        if name in _REGISTRY:
            raise ValueError(f"a scenario named {name!r} is already registered.")
        for p in inspect.signature(factory).parameters.values():
            if p.kind is not inspect.Parameter.KEYWORD_ONLY or p.default is inspect.Parameter.empty:
                raise ValueError(f"scenario factory {factory.__name__!r}: parameter {p.name!r} must be keyword-only "
                                 "with a default, so that make(name) works without arguments.")
        _REGISTRY[name] = factory
        return factory

    return decorator


_catalog_loaded = False


def load_catalog() -> None:
    """Imports every module of :data:`CATALOG` (once), which registers the scenarios they define."""
    global _catalog_loaded
    if _catalog_loaded:
        return
    _catalog_loaded = True
    package = importlib.import_module(CATALOG)
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        importlib.import_module(f"{CATALOG}.{info.name}")


def names() -> tuple[str, ...]:
    """The registered scenario names and the installed plug-ins', sorted."""
    load_catalog()
    return tuple(sorted(set(_REGISTRY) | set(catalog.plugins("scenarios"))))


def factory_parameters(name: str) -> tuple[str, ...]:
    """The keyword parameters of scenario ``name``'s factory."""
    return tuple(inspect.signature(_factory(name)).parameters)


def _factory(name: str) -> ScenarioFactory:
    load_catalog()
    if name not in _REGISTRY and isinstance(name, str):
        factory = catalog.load_plugin("scenarios", name)
        if factory is not None and name not in _REGISTRY:  # its module may have registered it on import
            register(name)(factory)
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; registered scenarios: {', '.join(names())}.") from None


def make(name: str, **overrides) -> Scenario:
    """Builds the registered scenario ``name``.

    Overrides matching the factory's parameters go to the factory; the rest must be ``Scenario`` fields and replace
    them afterwards. Raises ``ValueError`` for an unknown name or an override that matches neither.
    """
    factory = _factory(name)
    params = set(inspect.signature(factory).parameters)
    fields = set(Scenario.field_names())
    unknown = sorted(set(overrides) - params - fields)
    if unknown:
        raise ValueError(f"unknown override(s) {unknown} for scenario {name!r}; allowed: factory parameters "
                         f"[{', '.join(sorted(params)) or 'none'}] and "
                         f"Scenario fields [{', '.join(Scenario.field_names())}].")
    scenario = factory(**{k: v for k, v in overrides.items() if k in params})
    rest = {k: v for k, v in overrides.items() if k not in params}
    return scenario.with_overrides(**rest) if rest else scenario
