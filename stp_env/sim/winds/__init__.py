"""Wind models, one module each, registered by name (:data:`WIND_MODELS`).

A wind model is a small frozen dataclass (:class:`~stp_env.sim.winds.base.WindModel`) whose fields are its
parameters; it gives every agent a wind in the disk of its bound (``d_r`` for vehicles, ``d_I`` for the intruder;
intruder paper eq. 43) and a heading-rate disturbance in ``[-d_theta, d_theta]`` where the vehicle model has one
(SPP eq. 28). The simulator holds the model in :class:`~stp_env.sim.types.EnvParams` (static: part of the
compiled program) and asks it for the winds of each step.

Adding a model is one new module in this package: a subclass of ``WindModel`` decorated with :func:`register`;
every module here is imported when the registry is first read, and the configuration (``EnvConfig.wind_model``)
and the command line (``--wind-model``) list what is registered. A model is named by a spec string,
``"name"`` or ``"name:param=value,param=value"`` (``"gusts:time_constant=3"``), or given as an instance.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil

from stp_env import catalog
from stp_env.arguments import parse_spec
from stp_env.sim.winds.base import WindModel

WIND_MODELS: dict[str, type[WindModel]] = {}
_loaded = False


def register(cls: type[WindModel]) -> type[WindModel]:
    """Class decorator: registers a :class:`WindModel` subclass under its ``name``."""
    if not (isinstance(cls, type) and issubclass(cls, WindModel)) or not cls.name:
        raise ValueError(f"only WindModel subclasses with a name can be registered; got {cls!r}.")
    if cls.name in WIND_MODELS and WIND_MODELS[cls.name] is not cls:
        raise ValueError(f"a wind model named {cls.name!r} is already registered.")
    WIND_MODELS[cls.name] = cls
    return cls


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name != "base":
            importlib.import_module(f"{__name__}.{info.name}")


def names() -> tuple[str, ...]:
    """The registered wind models, in registration order (the papers' ``uniform`` first), then the installed
    plug-ins' (:mod:`stp_env.catalog`, imported when one is named)."""
    _load()
    ordered = tuple(sorted(WIND_MODELS, key=lambda name: (WIND_MODELS[name].order, name)))
    return catalog.names("wind_models", ordered)


def _load_plugin(name: str) -> None:
    """Registers the installed plug-in ``name`` (a :class:`WindModel` subclass) when no model has that name."""
    if name in WIND_MODELS or name not in catalog.plugins("wind_models"):
        return
    cls = catalog.load_plugin("wind_models", name)
    if name not in WIND_MODELS:  # its module may have registered it on import
        if not (isinstance(cls, type) and issubclass(cls, WindModel)) or cls.name != name:
            raise ValueError(f"wind model plug-in {name!r} must be a WindModel subclass named {name!r}; got {cls!r}.")
        register(cls)


def describe() -> str:
    """One line per registered model: its name, parameters and help (for the command line)."""
    _load()
    lines = []
    for name in names():
        cls = WIND_MODELS.get(name)
        if cls is None:  # an installed plug-in, not imported
            lines.append(f"{name}: a plug-in")
            continue
        params = ", ".join(f"{f.name}={f.default}" for f in dataclasses.fields(cls))
        lines.append(f"{name}{f' ({params})' if params else ''}: {cls.help}")
    return "; ".join(lines)


def make(spec) -> WindModel:
    """The wind model named by ``spec`` (``"name"`` or ``"name:param=value,..."``; numbers are floats) or
    ``spec`` itself if it is a :class:`WindModel`. ``ValueError`` naming ``wind_model`` otherwise."""
    if isinstance(spec, WindModel):
        return spec
    if not isinstance(spec, str):
        raise ValueError(f"wind_model must be a name ({', '.join(names())}) or a WindModel; got {spec!r}.")
    _load()
    _load_plugin(spec.partition(":")[0].strip())
    name, kwargs = parse_spec(spec, "wind_model", names(),
                              lambda n: [f.name for f in dataclasses.fields(WIND_MODELS[n])])
    return WIND_MODELS[name](**kwargs)


__all__ = ["WIND_MODELS", "WindModel", "describe", "make", "names", "register"]
