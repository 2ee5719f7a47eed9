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

from stp_env.arguments import parse_spec
from stp_env.sim.config import EnvConfig
from stp_env.sim.vehicle_models import Dubins, VehicleModel

BACKENDS = ("jax", "pymunk", "pymunk-dynamic")


def vehicle_model(spec: str) -> VehicleModel:
    """The vehicle model of backend ``spec`` (one of :data:`BACKENDS`, the last with optional ``:param=value,...``).
    ``ValueError`` naming ``backend`` otherwise."""
    if not isinstance(spec, str):
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got {spec!r}.")

    def fields(name):
        if name != "pymunk-dynamic":
            return ()
        from stp_env.sim.vehicle_models.rigid_body import RigidBodyConfig

        return [f.name for f in dataclasses.fields(RigidBodyConfig)]

    name, values = parse_spec(spec, "backend", BACKENDS, fields)
    if name == "jax":
        return Dubins()
    from stp_env.sim.vehicle_models.rigid_body import PymunkKinematic, PymunkRigidBody, RigidBodyConfig

    if name == "pymunk":
        return PymunkKinematic()
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
