"""The papers' vehicle: Dubins kinematics in wind (intruder paper eq. 43, SPP eq. 28), exact under zero-order
hold (:func:`stp_env.sim.physics.dubins_step`)."""

from __future__ import annotations

import dataclasses

from stp_env.sim.physics import action_to_control, control_to_action, dubins_step
from stp_env.sim.vehicle_models.base import VehicleModel


@dataclasses.dataclass(frozen=True)
class Dubins(VehicleModel):
    """State ``(x, y, theta)``; action ``[-1, 1]^2`` mapped linearly to ``v in [v_min, v_max]`` and ``omega in
    [-omega_max, omega_max]``; the heading-rate disturbance adds to ``omega``."""

    name = "dubins"

    def action_to_control(self, action, bounds):
        return action_to_control(action, bounds)

    def step(self, x, control, wind, heading_disturbance, dt):
        v, omega = control
        return dubins_step(x, v, omega + heading_disturbance, wind, dt)

    def pose(self, x):
        return x

    def from_pose(self, pose):
        return pose

    def command_to_action(self, x, v, omega, bounds):
        del x
        return control_to_action(v, omega, bounds)
