"""Exact reachability regions between two observations (Dubins in wind, from the HJ solver) on a small grid: the
backward field agrees with the time reversal of the forward one, the region lies inside the ellipse of the same
speed bound (up to a cell), and a vehicle that cannot turn on the spot has a visibly smaller region."""

from __future__ import annotations

import numpy as np

from stp_env.artifacts import ArtifactStore
from stp_env.coobservation import exact


def test_exact_region_inside_the_ellipse_and_smaller_when_turning_costs(tmp_path):
    cfg = exact.ExactRegionConfig(v_min=0.5, v_max=1.0, omega_max=0.5, wind=0.1, radius=0.5, horizon=4.0,
                                  spacing=0.2, n_headings=16, accuracy="low")
    regions = exact.compute(cfg, store=ArtifactStore(tmp_path), check_reversal=True, progress=False)
    assert regions.reversal_error < 0.25  # [s], a first-order scheme on a coarse grid
    q1, q2 = np.zeros(2), np.array([1.5, 0.0])
    r = exact.area_ratio(regions, q1, q2, 3.0, spacing=0.05)
    assert r["outside_ellipse"] <= 2 * cfg.spacing * 2 * np.pi * 3.0  # a band of about a cell around the ellipse
    assert 0.2 < r["ratio"] < 0.9  # turning at 0.5 rad/s with v >= 0.5 costs area
    # the points the region holds are reachable: the observation disks themselves (waiting inside them)
    s = regions.sum_times(q1, q2, np.array([[0.0, 0.0], [1.5, 0.0], [0.75, 0.0]]))
    assert np.all(np.asarray(s) <= 3.0)
    # and a point beyond the speed bound is not
    far = regions.sum_times(q1, q2, np.array([[0.75, 2.5]]))
    assert float(np.asarray(far)[0]) > 3.0
