"""Simulation backends by name: which engine moves the vehicles.

* ``"jax"``: the papers' Dubins plant in the jitted core (exact zero-order-hold step; fast, batches with vmap).
* ``"pymunk"``: the same Dubins motion, stepped by the pymunk physics engine as kinematic bodies
  (:class:`~stp_env.sim.vehicle_models.rigid_body.PymunkKinematic`); agrees with ``"jax"`` to float32 rounding.
* ``"pymunk-dynamic"`` (or ``"pymunk-dynamic:param=value,..."`` with fields of
  :class:`~stp_env.sim.vehicle_models.rigid_body.RigidBodyConfig`): rigid bodies with mass, inertia, drag,
  actuator lag and wind as an aerodynamic force
  (:class:`~stp_env.sim.vehicle_models.rigid_body.PymunkRigidBody`): the model-mismatch plant.

The pymunk backends run on the host (one callback per inner control step); see docs/model_mismatch.md.
"""

from __future__ import annotations

import dataclasses

from stp_env.sim.config import EnvConfig
from stp_env.sim.vehicle_models import Dubins, VehicleModel

BACKENDS = ("jax", "pymunk", "pymunk-dynamic")


def vehicle_model(spec: str) -> VehicleModel:
    """The vehicle model of backend ``spec`` (one of :data:`BACKENDS`, the last with optional ``:param=value,...``).
    ``ValueError`` naming ``backend`` otherwise."""
    if not isinstance(spec, str):
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got {spec!r}.")
    name, colon, rest = spec.partition(":")
    if name not in BACKENDS:
        raise ValueError(f"backend {name!r} is not known; allowed: {', '.join(BACKENDS)}.")
    if colon and name != "pymunk-dynamic":
        raise ValueError(f"backend {spec!r}: only pymunk-dynamic takes parameters.")
    if name == "jax":
        return Dubins()
    from stp_env.sim.vehicle_models.rigid_body import PymunkKinematic, PymunkRigidBody, RigidBodyConfig

    if name == "pymunk":
        return PymunkKinematic()
    allowed = [f.name for f in dataclasses.fields(RigidBodyConfig)]
    values = {}
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, _, text = (s.strip() for s in item.partition("="))
        if key not in allowed or not text:
            raise ValueError(f"backend {spec!r}: {item!r} is not param=value with param one of {', '.join(allowed)}.")
        try:
            values[key] = float(text)
        except ValueError:
            raise ValueError(f"backend {spec!r}: {key} must be a number; got {text!r}.") from None
    return PymunkRigidBody(RigidBodyConfig(**values))


def with_backend(config: EnvConfig, backend: str | None) -> EnvConfig:
    """``config`` with the vehicle model of ``backend`` (``None``: unchanged). A config that already names another
    plant than the default Dubins one keeps it only with ``backend=None``."""
    if backend is None:
        return config
    model = vehicle_model(backend)
    if config.vehicle_model != Dubins() and config.vehicle_model != model:
        raise ValueError(f"backend {backend!r} and config.vehicle_model ({type(config.vehicle_model).__name__}) "
                         "both choose the plant; pass one of them.")
    return config.with_overrides(vehicle_model=model)


__all__ = ["BACKENDS", "vehicle_model", "with_backend"]
