"""Induced-obstacle profiles (eqs. 24-31, 49-57) and the static-obstacle augmentation V^S (eqs. 32-33)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.reach.buffer import position_radius
from stp_env.reach.obstacles import (
    disk_frs,
    intruder_obstacle_profiles,
    static_inflation_radius,
    static_obstacle_augmentation,
)

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)


def test_profiles_shapes_and_monotonicity():
    prof = intruder_obstacle_profiles(VEHICLE, 0.1, 1.0, t_iat=2.0, kbar=2)
    vbar = 1.1
    assert prof["case1A"].radii[-1] == pytest.approx(1.1)  # lag 0: r_M + R_c
    assert prof["case1A"].radii[0] == pytest.approx(1.1 + vbar * 2.0)
    assert prof["case2A"].radii[0] == pytest.approx(1.1)
    assert prof["case2A"].radii[-1] == pytest.approx(1.1 + vbar * 2.0)
    # Case 1B peaks at lag -t_BRD with 2 (t_IAT - t_BRD) + t_BRD = 3 s of travel.
    k = int(np.argmax(prof["case1B"].radii))
    assert prof["case1B"].lags[k] == pytest.approx(-1.0, abs=0.06)
    assert prof["case1B"].radii.max() == pytest.approx(1.1 + vbar * 3.0, abs=vbar * 0.06)
    # Larger k̄ (shorter t_BRD) makes the case-B obstacles larger (the intruder reaches Q_j sooner).
    prof4 = intruder_obstacle_profiles(VEHICLE, 0.1, 1.0, t_iat=2.0, kbar=4)
    assert prof4["case2B"].radii.max() > prof["case2B"].radii.max()
    with pytest.raises(ValueError, match="k̄"):
        intruder_obstacle_profiles(VEHICLE, 0.1, 1.0, t_iat=2.0, kbar=0)


def test_signed_distance_of_profile():
    prof = intruder_obstacle_profiles(VEHICLE, 0.0, 1.0, t_iat=2.0, kbar=1, n_lags=3)["case2A"]
    centres = jnp.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]])
    # Lags 0, 1, 2 s -> radii 1, 2.1, 3.2.
    assert float(prof.signed_distance(centres, jnp.array([0.0, 3.0]))) == pytest.approx(2.0)
    assert float(prof.signed_distance(centres, jnp.array([10.0, 3.0]))) == pytest.approx(-0.2, abs=1e-5)


@pytest.mark.slow
def test_disk_frs_is_bounded_by_the_radius_rule():
    grid = hj.Grid.from_bounds((-4.0, -4.0, -np.pi), (4.0, 4.0, np.pi), (41, 41, 40), periodic=2)
    duration = 2.0
    values = np.asarray(disk_frs(grid, VEHICLE, radius=0.6, duration=duration))
    r = position_radius(grid, values)
    bound = 0.6 + (VEHICLE.v_max + VEHICLE.wind) * duration
    dx = grid.spacing[0]
    # All headings, v_min = 0: the disk bound is nearly tight (the FRS reaches it straight ahead).
    assert bound - 2 * dx <= r <= bound + dx


@pytest.mark.slow
def test_static_augmentation_within_inflation_radius():
    grid = hj.Grid.from_bounds((-6.0, -6.0, -np.pi), (6.0, 6.0, np.pi), (49, 49, 40), periodic=2)
    building = hj.shapes.rectangle(grid, (-1.0, -0.5), (1.0, 0.5), dims=(0, 1))
    t_iat = 2.0
    vs = np.asarray(static_obstacle_augmentation(grid, building, VEHICLE, collision_radius=0.5, t_iat=t_iat))
    radius = static_inflation_radius(VEHICLE, 0.5, t_iat)
    inflated = np.asarray(building) - radius
    dx = grid.spacing[0]
    # Conservative: V^S inside the inflated set (one cell of slack); and nearly tight straight off a face.
    assert np.all(inflated[vs <= 0] <= dx)
    xs = grid.coordinate_vector(0)
    j0 = int(np.argmin(np.abs(grid.coordinate_vector(1))))
    k0 = int(np.argmin(np.abs(grid.coordinate_vector(2) - np.pi)))  # heading -x, toward the building from +x
    reach_x = xs[vs[:, j0, k0] <= 0].max()
    assert reach_x >= 1.0 + radius - 2 * dx
