"""The planner's moving-disk obstacles read by time bucket are the obstacles of the whole fleet, bit for bit."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.planning.obstacles import disk_params, moving_disks, time_buckets

GRID = hj.Grid.from_bounds((0.0, 0.0, -np.pi), (2000.0, 2000.0, np.pi), (41, 41, 8), periodic=2)
LAGS = np.array([-5.2, -2.0, 0.0, 1.0, 2.5])
RADII = np.array([60.0, 80.0, 100.0, 70.0, 50.0])


def _fleet(n=12, seed=0):
    """``n`` vehicles with short, staggered flight windows, each in its own part of the plane (so that each one is
    the nearest obstacle somewhere, and leaving out a present one changes the values)."""
    rng = np.random.default_rng(seed)
    fleet = []
    for j in range(n):
        t0 = -300.0 + 40.0 * j + rng.uniform(0, 10)
        ts = t0 + np.arange(0.0, 30.0, 0.5)
        c = np.array([200.0 + 500.0 * (j % 4), 200.0 + 500.0 * (j // 4)])
        xy = c + np.stack([np.linspace(0, 100, len(ts)), rng.uniform(-20, 20, len(ts))], -1)
        fleet.append((ts, xy, ts[0], ts[-1]))
    return fleet


def _query_times(span, buckets):
    rows, t0, dt = buckets
    edges = t0 + dt * np.arange(rows.shape[0] + 1)
    flight_edges = np.concatenate([[tr[2], tr[3]] for tr in _fleet()])[:, None] - LAGS[None, :]
    around = np.concatenate([edges, flight_edges.ravel()])[:, None] + np.array([-1e-3, 0.0, 1e-3])[None, :]
    rng = np.random.default_rng(1)
    return np.concatenate([around.ravel(), rng.uniform(span[0] - 100, span[1] + 100, 300),
                           [span[0] - 1e4, span[1] + 1e4]])


@pytest.mark.slow
def test_bucketed_disks_equal_the_whole_fleet_bit_for_bit():
    fleet, span = _fleet(), (-400.0, 300.0)
    whole = disk_params(GRID, fleet, LAGS, RADII, n_slots=16)
    culled = disk_params(GRID, fleet, LAGS, RADII, n_slots=16, span=span)
    assert "bucket_rows" in culled and "bucket_rows" not in whole
    rows = np.asarray(culled["bucket_rows"])
    assert rows.shape[1] < 12, rows.shape  # the lists are shorter than the fleet (else nothing is tested)
    f = jax.jit(moving_disks)
    times = _query_times(span, (rows, float(culled["bucket_t0"]), float(culled["bucket_dt"])))
    present = 0
    for t in times.astype(np.float32):
        g_whole, g_culled = np.asarray(f(jnp.float32(t), whole)), np.asarray(f(jnp.float32(t), culled))
        np.testing.assert_array_equal(g_culled, g_whole, err_msg=f"t = {t}")
        present += bool(np.isfinite(g_whole).any())
    assert present > 100  # most query times see disks: the comparison is not between two empty planes


def test_a_bucket_lists_every_vehicle_with_a_disk_present_in_it_and_not_the_others():
    fleet = _fleet()
    start = np.array([tr[2] for tr in fleet])
    end = np.array([tr[3] for tr in fleet])
    lags = np.broadcast_to(LAGS, (len(fleet), len(LAGS)))
    rows, t0, dt = time_buckets(start, end, lags, (-400.0, 300.0))
    for t in np.linspace(-420.0, 320.0, 2001):
        b = int(np.clip(np.floor((t - t0) / dt), 0, rows.shape[0] - 1))
        listed = set(rows[b][rows[b] < len(fleet)].tolist())
        tq = t + LAGS
        present = {j for j in range(len(fleet)) if np.any((tq >= start[j]) & (tq <= end[j]))}
        assert present <= listed, (t, present - listed)
        # No vehicle is listed that is absent from the bucket's whole interval widened by the margin (1 s).
        lo, hi = t0 + dt * b, t0 + dt * (b + 1)
        if 0 < b < rows.shape[0] - 1:
            for j in listed:
                assert start[j] - LAGS.max() <= hi + 1.0 and end[j] - LAGS.min() >= lo - 1.0


def test_buckets_are_left_out_when_they_would_list_most_of_the_fleet():
    fleet = [(np.arange(0.0, 100.0), np.zeros((100, 2)) + 100.0 * j, 0.0, 99.0) for j in range(5)]
    params = disk_params(GRID, fleet, LAGS, RADII, n_slots=5, span=(-50.0, 150.0))
    assert "bucket_rows" not in params  # all five fly at once: a list of 8 would be no saving


def test_time_buckets_rejects_an_empty_span():
    with pytest.raises(ValueError, match="span"):
        time_buckets(np.zeros(1), np.ones(1), np.zeros((1, 1)), (5.0, 5.0))


@pytest.mark.slow
def test_moving_disks_are_the_per_disk_signed_distance():
    """Against the definition, disk by disk in float64: ``min_{j, l present} ||p - p_j(t + lambda_l)|| - r_l``."""
    fleet = _fleet()
    params = disk_params(GRID, fleet, LAGS, RADII, n_slots=16, span=(-400.0, 300.0))
    xs, ys = GRID.coordinate_vector(0), GRID.coordinate_vector(1)
    px, py = np.meshgrid(np.asarray(xs, np.float64), np.asarray(ys, np.float64), indexing="ij")
    for t in (-290.0, -250.0, -170.0, -41.3, 100.0, 150.0):
        want = np.full(px.shape, np.inf)
        for ts, xy, start, end in fleet:
            for lag, r in zip(LAGS, RADII):
                if start <= t + lag <= end:
                    cx, cy = np.interp(t + lag, ts, xy[:, 0]), np.interp(t + lag, ts, xy[:, 1])
                    want = np.minimum(want, np.hypot(px - cx, py - cy) - r)
        got = np.asarray(moving_disks(jnp.float32(t), params))
        assert np.isfinite(want).any(), t
        np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
        np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], atol=0.05)


class _Enough(Exception):
    """Stops the planner at the second vehicle's obstacles."""


def _windows_seen_by_the_second_vehicle(monkeypatch, hold_slices):
    """Plans ``tiny``'s first vehicle and returns the flight windows its successor's obstacles are built from, with
    the first vehicle's latest departure and arrival."""
    import stp_env.planning.stp as stp
    from stp_env.scenarios import make

    seen, first = [], []
    original = stp.planning_obstacles

    def capture(grid, trajectories, *args, **kwargs):
        if trajectories:
            seen.extend((float(t[2]), float(t[3])) for t in trajectories)
            raise _Enough
        return original(grid, trajectories, *args, **kwargs)

    monkeypatch.setattr(stp, "planning_obstacles", capture)
    with pytest.raises(_Enough):
        stp.plan_scenario(make("tiny"), tracking_bound=5.337635040283203, progress=False, hold_slices=hold_slices,
                          on_vehicle=lambda rank, i, single: first.append((single.t_ldt, single.arrival_time)))
    return seen[0], first[0]


@pytest.mark.slow
def test_held_disks_stay_whole_slices_longer_on_both_sides(monkeypatch):
    (start0, end0), (t_ldt, arrival) = _windows_seen_by_the_second_vehicle(monkeypatch, 0)
    assert (start0, end0) == pytest.approx((t_ldt, arrival))  # lag-0 disks only: the flight itself
    (start2, end2), again = _windows_seen_by_the_second_vehicle(monkeypatch, 2)
    assert again == (t_ldt, arrival)  # the first vehicle has no obstacle: the same plan
    assert start0 - start2 > 0 and start0 - start2 == pytest.approx(end2 - end0)


@pytest.mark.parametrize("bad", [-1, 1.5, True, "1"])
def test_hold_slices_must_be_a_whole_number(bad):
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    with pytest.raises(ValueError, match="hold_slices"):
        plan_scenario(make("tiny"), tracking_bound=5.337635040283203, progress=False, hold_slices=bad)
