"""Relative buffer region V^B (eqs. 22-23, 46-47), t_BRD and the planner's disk radii."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stp_env.dynamics import DubinsWind
from stp_env.reach.avoid import AvoidRegionConfig, compute_avoid_region
from stp_env.reach.buffer import (
    BufferConfig,
    brd_time,
    buffer_radii,
    compute_relative_buffer,
    disk_conservatism,
    position_radius,
)

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)
AVOID = AvoidRegionConfig(vehicle=VEHICLE, intruder=VEHICLE, collision_radius=1.0, t_iat=2.0, half_width=4.0,
                          certify=False,
                          grid_points=(41, 41, 40), n_slices=5)


@pytest.fixture(scope="module")
def avoid():
    return compute_avoid_region(AVOID, progress=False)


@pytest.fixture(scope="module")
def buffers(avoid):
    return {k: compute_relative_buffer(BufferConfig(avoid=AVOID, kbar=k, grid_points=(41, 41, 40)), avoid,
                                       progress=False) for k in (1, 2, 4)}


def test_brd_time():
    assert brd_time(10.0, 3) == pytest.approx(10 / 3)
    assert brd_time(10.0, 1) == 10.0
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="k̄ must be an integer >= 1"):
            brd_time(10.0, bad)


@pytest.mark.slow
def test_buffer_shrinks_as_kbar_grows(buffers):
    radii = [buffers[k].radius for k in (1, 2, 4)]
    assert radii[0] > radii[1] > radii[2]


def test_buffer_radius_between_closed_form_bounds(avoid, buffers):
    # V^B contains V^A(t_BRD) (zero duration) and is reached at most at the closing speed (all players
    # cooperate): r_A(t_BRD) <= r_VB <= r_A(t_BRD) + closing * t_BRD, up to a cell.
    for buf in buffers.values():
        t_brd = buf.config.t_brd
        slab = avoid.values[int(np.argmin(np.abs(avoid.taus - t_brd)))]
        r_a = position_radius(avoid.grid, slab)
        dx = buf.config.grid.spacing[0]
        assert buf.radius >= r_a - dx
        assert buf.radius <= r_a + buf.config.closing_speed * t_brd + dx


def test_cooperative_closing_in_straight_line(avoid, buffers):
    # Head-on along +x with opposite headings (theta = pi), everyone closing at full speed: the front of V^B
    # lies at least closing_speed * t_BRD beyond the front of V^A(t_BRD) on that line, minus a cell.
    buf = buffers[2]
    grid = buf.config.grid
    k_theta = int(np.argmin(np.abs(np.abs(grid.coordinate_vector(2)) - math.pi)))
    xs = grid.coordinate_vector(0)
    j0 = int(np.argmin(np.abs(grid.coordinate_vector(1))))
    front_vb = xs[buf.values[:, j0, k_theta] <= 0].max()
    ag = avoid.grid
    slab = avoid.values[int(np.argmin(np.abs(avoid.taus - buf.config.t_brd)))]
    ka = int(np.argmin(np.abs(np.abs(ag.coordinate_vector(2)) - math.pi)))
    front_va = ag.coordinate_vector(0)[slab[:, int(np.argmin(np.abs(ag.coordinate_vector(1)))), ka] <= 0].max()
    assert front_vb >= front_va + buf.config.closing_speed * buf.config.t_brd - 1.5 * grid.spacing[0]


def test_radii_and_conservatism(avoid, buffers):
    d_a = avoid.detection_range()
    rs = [buffer_radii(k, 0.1, d_a, buffers[k].radius, AVOID.t_iat) for k in (1, 2, 4)]
    assert rs[0].buffer > rs[1].buffer > rs[2].buffer
    assert all(r.separation == pytest.approx(0.1 + d_a) for r in rs)
    for buf in buffers.values():
        ratio = disk_conservatism(buf.config.grid, buf.values, buf.radius)
        assert ratio >= 0.97  # a disk through the farthest point covers the footprint (node-count area)


def test_bad_buffer_config():
    with pytest.raises(ValueError, match="k̄"):
        BufferConfig(avoid=AVOID, kbar=0)
    with pytest.raises(ValueError, match="Radii"):
        buffer_radii(2, -1.0, 1.0, 1.0, 2.0)


@pytest.mark.slow
def test_other_priority_frame_is_an_involution_with_the_same_radius(buffers):
    from stp_env.reach.buffer import swap_relative_frame

    buf = buffers[2]
    grid = buf.config.grid
    other = np.asarray(swap_relative_frame(grid, buf.values))
    back = np.asarray(swap_relative_frame(grid, other))
    inside = buf.values <= 0
    # Interpolation smears by about a cell: compare the sets away from their boundary.
    dx = grid.spacing[0]
    assert np.all(back[buf.values <= -2 * dx] <= 0)
    assert np.all(back[buf.values >= 2 * dx] > 0)
    assert abs(position_radius(grid, other) - buf.radius) <= 1.5 * dx
    assert inside.sum() > 0
