"""The planning problem object and the planning-model protocol: a second planning model defined here (a Dubins
vehicle drifting in a known steady current) is planned by the sequential planner; malformed problems and models are
refused with messages naming what is wrong; the old argument list of ``plan_rtt`` still plans the same plan."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.hj.dynamics import ControlAffineDynamics
from stp_env.hj.sets import Box, ProductSet
from stp_env.kinematics import dubins_step
from stp_env.planning.brs import check_split_dynamics
from stp_env.planning.model import (
    PLANNING_MODEL_MEMBERS,
    DubinsPlanning,
    PlanningModel,
    as_planning_model,
    dubins_control_between,
    dubins_step64,
)
from stp_env.planning.problem import PlanningProblem
from stp_env.planning.single import saturated_control
from stp_env.planning.stp import plan_rtt, plan_to_arrays
from stp_env.planning.verify import flight_faults

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)
GRID = hj.Grid.from_bounds((-1.5, -1.5, -np.pi), (1.5, 1.5, np.pi), (31, 31, 16), periodic=2)  # coarse: fast
START, TARGET = (-1.0, 0.0, 0.0), (1.0, 0.0)
CURRENT = (0.15, 0.0)


# --- a second planning model, in one place: a Dubins vehicle in a known steady current -------------------------------

@dataclasses.dataclass(frozen=True, kw_only=True)
class CurrentDynamics(ControlAffineDynamics):
    """``d/dt (p_x, p_y, theta) = (v cos theta + c_x, v sin theta + c_y, omega)``: no disturbance."""

    v_min: float
    v_max: float
    omega_max: float
    current: tuple[float, float]

    @property
    def state_dim(self) -> int:
        return 3

    @property
    def control_space(self) -> ProductSet:
        return ProductSet((Box((self.v_min, -self.omega_max), (self.v_max, self.omega_max)),))

    @property
    def disturbance_space(self) -> ProductSet:
        return ProductSet(())

    def open_loop(self, x):
        return (self.current[0], self.current[1], 0.0)

    def control_jacobian(self, x):
        return ((jnp.cos(x[2]), 0.0), (jnp.sin(x[2]), 0.0), (0.0, 1.0))

    def disturbance_jacobian(self, x):
        return ((), (), ())


@dataclasses.dataclass(frozen=True)
class CurrentPlanning:
    """The planning model of :class:`CurrentDynamics`: exact motion is the Dubins arc plus the drift."""

    dynamics: CurrentDynamics
    wind: float = 0.0
    heading_split: bool = True

    @property
    def speed_bounds(self):
        return (self.dynamics.v_min, self.dynamics.v_max)

    @property
    def omega_max(self):
        return self.dynamics.omega_max

    def control(self, x, p):
        return saturated_control(self.dynamics, x, p)

    def step(self, x, u, wind, dt):
        return dubins_step(x, u[0], u[1], wind + jnp.asarray(self.dynamics.current, x.dtype), dt)

    def step64(self, states, controls, dt):
        v, omega = controls[:, 0], controls[:, 1]
        half = 0.5 * omega * dt
        chord = v * dt * np.sinc(half / np.pi)
        mid = states[:, 2] + half
        cx, cy = self.dynamics.current
        return np.stack([states[:, 0] + chord * np.cos(mid) + cx * dt, states[:, 1] + chord * np.sin(mid) + cy * dt,
                         states[:, 2] + omega * dt], axis=1)

    def control_between(self, x0, x1, dt):
        drift = np.asarray(self.dynamics.current, np.float64) * dt
        return dubins_control_between(x0, np.array([x1[0] - drift[0], x1[1] - drift[1], x1[2]]), dt)


def _current_model(current=CURRENT):
    return CurrentPlanning(CurrentDynamics(v_min=0.5, v_max=0.6, omega_max=0.5, current=current))


def _problem(model, **fields):
    base = dict(grid=GRID, model=model, starts=[START], targets=[TARGET], target_radii=0.25, stas=[0.0],
                tracking_bound=0.05, collision_radius=0.2, horizon=4.0)
    return PlanningProblem(**{**base, **fields})


@pytest.mark.slow
def test_a_second_planning_model_is_planned_by_the_sequential_planner(tmp_path):
    model = _current_model()
    assert isinstance(model, PlanningModel) and as_planning_model(model) is model
    calls = []
    plan = plan_rtt(_problem(model), progress=False, checkpoint=tmp_path / "ck.npz",
                    on_vehicle=lambda rank, index, single: calls.append(index))
    single = plan.vehicles[0].plan
    assert calls == [0]
    # Drifting toward the target at 0.15 m/s the vehicle covers the 1.8 m to the shrunk target's edge (radius
    # 0.25 - r_e) at 0.6 + 0.15 m/s; the planner aims one cell (at the slowest speed) before the STA.
    dx = GRID.spacing[0]
    margin = dx / 0.5
    shrunk = 0.25 - 0.05
    assert single.t_ldt == pytest.approx(-(2.0 - shrunk) / 0.75 - margin, abs=dx / 0.75 + 0.05)
    assert single.arrival_time <= 0.05
    # The stored samples are flights of the model (its exact step with the drift), not of the plain Dubins vehicle.
    flight = dict(dt=0.05, planning_v=(0.5, 0.6), planning_omega_max=0.5)
    times, states, controls = single.times, single.states, single.controls
    assert flight_faults(times, states, controls, single.t_ldt, model=model, **flight) == []
    # Flown as plain Dubins motion, the same controls fall behind by the drift: 0.15 m/s over the flight.
    end = int(np.searchsorted(times, single.arrival_time))
    x = states[:1].astype(np.float64)
    for k in range(end):
        x = dubins_step64(x, controls[k:k + 1, 0], controls[k:k + 1, 1], 0.05)
    lag = states[end, :2] - x[0, :2]
    np.testing.assert_allclose(lag, np.asarray(CURRENT) * (times[end] - times[0]), atol=2e-3)
    # The checkpoint holds the vehicle; resuming checks its samples against the model's motion and plans nothing.
    again = plan_rtt(_problem(model), progress=False, checkpoint=tmp_path / "ck.npz",
                     on_vehicle=lambda rank, index, single: calls.append(index))
    assert calls == [0]
    assert plan_to_arrays(again)["states"].tobytes() == plan_to_arrays(plan)["states"].tobytes()


def test_a_model_is_refused_by_the_member_it_lacks():
    # The members named in refusals are the protocol's.
    assert {name for name in vars(PlanningModel) if not name.startswith("_")} == set(PLANNING_MODEL_MEMBERS)
    assert not isinstance(object(), PlanningModel) and isinstance(DubinsPlanning(VEHICLE), PlanningModel)

    class NoStep:
        dynamics = PLANNER_DYN = DubinsWind(v_min=0.5, v_max=0.6, omega_max=0.5, wind=0.0)
        speed_bounds, omega_max, wind, heading_split = (0.5, 0.6), 0.5, 0.0, True

        def control(self, x, p):
            return saturated_control(self.PLANNER_DYN, x, p)

        def step64(self, states, controls, dt):
            return states

        def control_between(self, x0, x1, dt):
            return 0.0, 0.0

    with pytest.raises(TypeError, match="NoStep is not a planning model: it lacks step "):
        as_planning_model(NoStep())
    with pytest.raises(TypeError, match="lacks step"):
        _problem(NoStep())
    with pytest.raises(TypeError, match="lacks step"):
        check_split_dynamics(NoStep())
    with pytest.raises(TypeError, match="lacks dynamics, speed_bounds, omega_max, wind, heading_split, control, step, "
                                        "step64, control_between"):
        as_planning_model(object())
    # A model whose heading does not split is refused by the split solver (the unsplit one takes it).
    with pytest.raises(ValueError, match="heading-split BRS needs control_mode='min' and no heading disturbance"):
        check_split_dynamics(dataclasses.replace(_current_model(), heading_split=False))
    with pytest.raises(ValueError, match=r"heading_disturbance=0\.1"):
        check_split_dynamics(DubinsWind(heading_disturbance=0.1))
    assert isinstance(check_split_dynamics(VEHICLE), DubinsPlanning)


@pytest.mark.parametrize("change, error, match", [
    ({"targets": [TARGET, TARGET]}, ValueError, "one entry per vehicle; got 1 starts, 2 targets"),
    ({"starts": [(0.0, 0.0)]}, ValueError, r"starts must have shape \(n, 3\); got \(1, 2\)"),
    ({"starts": []}, ValueError, r"starts must have shape \(n, 3\)"),
    ({"stas": [0.0, 1.0]}, ValueError, r"stas of shape \(2,\)"),
    ({"stas": [math.nan]}, ValueError, "stas must be finite"),
    ({"target_radii": -0.25}, ValueError, "target radii must be finite and > 0"),
    ({"target_radii": [0.25, 0.25]}, ValueError, r"one radius per vehicle \(1\); got shape \(2,\)"),
    ({"tracking_bound": -0.05}, ValueError, "tracking_bound must be a finite number >= 0"),
    ({"collision_radius": math.inf}, ValueError, "collision_radius must be a finite number >= 0"),
    ({"tracking_bound": 0.3}, ValueError, "not smaller than its target radius"),
    ({"horizon": 0.0}, ValueError, "horizon must be a finite number > 0"),
    ({"time_step": -0.05}, ValueError, "time_step must be a finite number > 0"),
    ({"arrival_margin": -1.0}, ValueError, "arrival_margin must be a finite number >= 0"),
    ({"priorities": [1]}, ValueError, "permutation of 0..0"),
    ({"kbar": 2}, ValueError, "got kbar without buffer_radius, obstacle_profiles"),
    ({"kbar": 2, "buffer_radius": 0.5}, ValueError, "got kbar, buffer_radius without obstacle_profiles"),
    ({"buffer_radius": 0.5, "obstacle_profiles": {}}, ValueError, "got buffer_radius, obstacle_profiles without kbar"),
    ({"kbar": -1, "buffer_radius": 0.5, "obstacle_profiles": {}}, ValueError, "kbar must be a whole number"),
    ({"kbar": 1, "buffer_radius": 0.0, "obstacle_profiles": {}}, ValueError,
     "buffer_radius must be a finite number > 0"),
    ({"static_obstacle": np.ones((31, 30))}, ValueError, r"position plane, shape \(31, 31\); got \(31, 30\)"),
    ({"solver": "fast"}, ValueError, "solver must be one of"),
    ({"hold_slices": 1.5}, ValueError, "hold_slices must be a whole number"),
    ({"max_slice_dt": 0.0}, ValueError, "max_slice_dt must be a positive number"),
    ({"disk_tolerance": -1.0}, ValueError, "disk_tolerance must be a finite number"),
    ({"grid": hj.Grid.from_bounds((-1.5, -1.5), (1.5, 1.5), (31, 31))}, ValueError, "must be 3-D"),
])
def test_a_malformed_problem_is_refused_naming_what_is_wrong(change, error, match):
    with pytest.raises(error, match=match):
        _problem(VEHICLE, **change)


def test_a_problem_is_frozen_and_holds_checked_read_only_arrays():
    problem = _problem(DubinsWind(v_min=0.5, v_max=0.6, omega_max=0.5, wind=0.0), target_radii=[0.25])
    assert isinstance(problem.model, DubinsPlanning)
    assert problem.planning_v == (0.5, 0.6) and problem.planning_omega_max == 0.5
    assert problem.priorities == (0,) and problem.order == [0] and not problem.intruder_aware
    assert problem.starts.shape == (1, 3) and problem.starts.dtype == np.float64
    with pytest.raises(dataclasses.FrozenInstanceError):
        problem.horizon = 1.0
    with pytest.raises(ValueError, match="read-only"):
        problem.starts[0, 0] = 5.0


def test_plan_rtt_takes_a_problem_only():
    """The argument list of release 0.1 is refused with the way to build the problem."""
    args = (GRID, VEHICLE, (0.5, 0.6), 0.5, 0.05, 0.2, [START], [TARGET], 0.25, [0.0])
    problem = PlanningProblem.dubins(*args, horizon=6.0)
    with pytest.raises(TypeError, match=r"PlanningProblem\.dubins\(grid, vehicle"):
        plan_rtt(*args[:1], progress=False)
    with pytest.raises(TypeError, match="unexpected keyword argument 'horizon'"):
        plan_rtt(problem, horizon=6.0)
    with pytest.raises(TypeError, match=r"plans a stp_env\.planning\.problem\.PlanningProblem; got dict\."):
        plan_rtt({"grid": GRID})
