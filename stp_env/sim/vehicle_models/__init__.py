"""The simulated vehicles' plant (:class:`~stp_env.sim.vehicle_models.base.VehicleModel`), apart from the HJ
model the reachability sets and plans are computed with (:mod:`stp_env.dynamics`).

The simulator holds the model in :class:`~stp_env.sim.types.EnvParams` (``vehicles.model``, static) and asks it
for everything that depends on the plant: the state size, the action size and the action-to-control mapping,
the motion over a step, the pose ``(x, y, heading)`` it is sensed and drawn by, and how the papers' controllers
(which command the HJ model's ``(v, omega)``) become the plant's actions. :class:`Dubins` (intruder paper eq. 43,
the papers' vehicle) is the default; a new plant is one new module with a ``VehicleModel`` subclass, passed as
``EnvConfig(vehicle_model=...)``. The intruder flies the papers' Dubins model.
"""

from stp_env.sim.vehicle_models.base import VehicleModel
from stp_env.sim.vehicle_models.dubins import Dubins

__all__ = ["Dubins", "VehicleModel"]
