"""What one evaluation configuration is (typed), and how names become policies.

A :class:`Configuration` fixes everything that shapes an episode distribution: the scenario and its k̄, the wind
bound and wind model, where the intruder spawns, the intruder and the vehicles' policy. Policies are jittable
functions ``(key, state, params) -> actions`` (:mod:`stp_env.policies`); a learned intruder enters the same way
(see :func:`resolve_intruder`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from stp_env import catalog
from stp_env.arguments import check_kbar
from stp_env.policies import INTRUDERS, vehicle_policy
from stp_env.policies.intruders import (  # noqa: F401  (LEARNED_PREFIX: re-exported)
    LEARNED_PREFIX,
    capabilities,
    resolve_intruder,
)
from stp_env.sim import EnvConfig, winds
from stp_env.sim.backends import vehicle_model as backend_model
from stp_env.sim.types import SPAWN_MODES

SPAWN_CHOICES = ("auto", *SPAWN_MODES)
"""``auto``: the intruder's own default (its :class:`~stp_env.policies.intruders.Intruder` record's ``spawn``):
``boundary`` for ``max-k`` and ``optimal-max-k`` (the strategy of the intruder paper's Figs. 6-7 starts on a
vehicle's avoid boundary), ``outside`` for every other registered intruder and for a bare policy."""
BOUNDARY_INTRUDERS = tuple(name for name, entry in INTRUDERS.items() if entry.spawn == "boundary")
"""The registered intruders that spawn on an avoid boundary by default, as names (a view of :data:`INTRUDERS`'
``spawn``; :func:`stp_env.policies.intruders.capabilities` answers for any intruder, plug-ins included)."""

EPISODE_CHOICES = catalog.EPISODE_CHOICES


resolve_vehicle_policy = vehicle_policy  # the one lookup by name (stp_env.policies.vehicles)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Configuration:
    """One evaluated configuration.

    Attributes:
        scenario: registry name (:func:`stp_env.scenarios.make`).
        kbar: the bound under test, passed to the scenario factory (its plan is planned for it).
        intruder: intruder name or import spec (:func:`resolve_intruder`).
        wind: wind bound ``d_r`` of vehicles and intruder [m/s]; ``None``: the scenario's (a non-default wind
            needs its own reachability artifacts and plan, computed and cached on first use).
        wind_model: a registered wind model (:func:`stp_env.sim.winds.names`), or a spec ``name:param=value``.
        spawn_mode: one of :data:`SPAWN_CHOICES`.
        vehicle_policy: ``"switching"`` (``u*``, eq. 38, with the core's safety filter), ``"nominal"`` (``u^PP``
            only: the safety filter is off and vehicles ignore the intruder; their avoid starts are still counted)
            or ``"worst"`` (the buffer game's worst vehicles until forced, then ``u^A``: the assumption behind
            ``V^B``, under which the k̄ bound can be reached).
        episode: ``"window"`` (around the intruder's appearance window) or ``"full"`` (first departure to the last
            STA), see :class:`stp_env.sim.EnvConfig`.
        backend: the engine that moves the vehicles (:mod:`stp_env.sim.backends`): ``"jax"`` (the papers' Dubins
            model in the jitted core), ``"pymunk"`` (the same motion in the pymunk engine) or
            ``"pymunk-dynamic[:param=value,...]"`` (rigid bodies with mass, drag and actuator lag).
    """

    scenario: str = "town"
    kbar: int = 2
    intruder: str = "hj"
    wind: float | None = None
    wind_model: str = "uniform"
    spawn_mode: str = "auto"
    vehicle_policy: str = "switching"
    episode: str = "window"
    backend: str = "jax"

    def __post_init__(self) -> None:
        for name in ("scenario", "intruder", "wind_model", "spawn_mode", "vehicle_policy", "episode", "backend"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise ValueError(f"{name} must be a non-empty string; got {value!r}.")
        check_kbar(self.kbar, "kbar (the number of vehicles the intruder may force to avoid)")
        if self.wind is not None and (isinstance(self.wind, bool) or not isinstance(self.wind, (int, float))
                                      or not math.isfinite(self.wind)
                                      or self.wind < 0):
            raise ValueError(f"wind must be a finite number >= 0 [m/s]; got {self.wind!r}.")
        winds.make(self.wind_model)  # ValueError naming wind_model and the registered models
        if self.spawn_mode not in SPAWN_CHOICES:
            raise ValueError(f"spawn_mode {self.spawn_mode!r} is not a known spawn mode; allowed: "
                             f"{', '.join(SPAWN_CHOICES)}.")
        if self.episode not in EPISODE_CHOICES:
            raise ValueError(f"episode {self.episode!r} is not known; allowed: {', '.join(EPISODE_CHOICES)}.")
        vehicle_policy(self.vehicle_policy)  # ValueError naming the allowed ones
        backend_model(self.backend)  # ValueError naming the backends

    @property
    def effective_spawn_mode(self) -> str:
        if self.spawn_mode != "auto":
            return self.spawn_mode
        return capabilities(self.intruder).spawn

    @property
    def label(self) -> str:
        wind = "default" if self.wind is None else f"{self.wind:g}"
        return (f"{self.scenario}_k{self.kbar}_{self.intruder.replace(':', '.').replace('/', '.')}_wind{wind}"
                f"_{self.wind_model}_{self.effective_spawn_mode}_"
                f"{self.vehicle_policy.replace(':', '.').replace('/', '.')}"
                + ("" if self.backend == "jax" else f"_{self.backend.replace(':', '.').replace(',', '.')}"))

    def make_scenario(self):
        from stp_env.scenarios import make

        overrides = {"kbar": self.kbar}
        if self.wind is not None:
            overrides["wind"] = float(self.wind)
        try:
            return make(self.scenario, **overrides)
        except TypeError as err:
            raise ValueError(f"scenario {self.scenario!r} does not take {sorted(overrides)}: {err}") from None

    def env_config(self) -> EnvConfig:
        return EnvConfig(wind_model=self.wind_model, spawn_mode=self.effective_spawn_mode,
                         safety_filter=self.vehicle_policy != "nominal", episode=self.episode,
                         vehicle_model=backend_model(self.backend))

    def policies(self) -> tuple[Callable, Callable]:
        return resolve_vehicle_policy(self.vehicle_policy), resolve_intruder(self.intruder)


DEFAULT_SUITE = (
    *(Configuration(scenario="town", kbar=k, intruder="max-k") for k in (1, 2, 3)),
    Configuration(scenario="crossing", kbar=2, intruder="optimal-max-k", vehicle_policy="worst"),
)
"""What ``stp-env evaluate`` runs when no configuration option is given: the default scenario ``town`` (7 vehicles
planned intruder-aware for k̄ = 1, 2, 3, vehicles on ``u*`` with the safety filter, the max-k intruder of the
intruder paper's Figs. 6-7), where no intruder forces more than one vehicle, and one configuration where the bound
binds: the ``crossing`` (two streams of 10 vehicles at the tightest spacing the k̄ = 2 buffer allows) with the
vehicles on the buffer game's worst control (the assumption behind ``V^B``) and the ``optimal-max-k`` intruder,
which forces k̄ = 2 vehicles in some episodes and never more (docs/dense.md)."""


def default_suite(**common) -> list[Configuration]:
    """:data:`DEFAULT_SUITE` with the fields in ``common`` (wind, wind model, spawn mode, episode, backend)
    replaced in every configuration."""
    return [dataclasses.replace(config, **common) for config in DEFAULT_SUITE]
