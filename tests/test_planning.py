"""Single-vehicle reach-avoid planning and robust-tracking STP on small crossing problems."""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.planning.problem import PlanningProblem
from stp_env.planning.single import InfeasiblePlanError, TubeExcursionWarning, departure_in_tube, plan_single
from stp_env.planning.stp import plan_rtt

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=1.0, wind=0.1)
PLANNER = DubinsWind(v_min=0.5, v_max=0.6, omega_max=0.5, wind=0.0)
GRID = hj.Grid.from_bounds((-1.5, -1.5, -np.pi), (1.5, 1.5, np.pi), (61, 61, 40), periodic=2)


@pytest.mark.slow
def test_straight_path_latest_departure_time():
    # Pointing at the target: the time to reach is (distance - r) / v_max (docs/numerics.md), so t_LDT = -that.
    start, target, r = (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2
    plan = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=5.0, time_step=0.05)
    exact = -(2.0 - r) / PLANNER.v_max
    dx = GRID.spacing[0]
    assert plan.t_ldt == pytest.approx(exact, abs=dx / PLANNER.v_max)
    # the rollout is exact, so it arrives when the exact path does, shifted by the value's error, at a sample
    assert plan.arrival_time <= 0.05 + (plan.t_ldt - exact) + 1e-6
    assert np.all(np.abs(plan.flight()[1][:, 1]) < dx)  # stays on the line
    assert np.all((plan.controls[:, 0] >= 0.5 - 1e-6) & (plan.controls[:, 0] <= 0.6 + 1e-6))


def test_infeasible_horizon_raises():
    with pytest.raises(InfeasiblePlanError, match="cannot reach the target"):
        plan_single(GRID, PLANNER, (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2, sta=0.0, horizon=1.0)
    with pytest.raises(ValueError, match="outside the planning grid"):
        plan_single(GRID, PLANNER, (-3.0, 0.0, 0.0), (1.0, 0.0), 0.2, sta=0.0, horizon=1.0)


def _min_separation(pa, pb):
    """Smallest distance between two nominal trajectories while both are in the air."""
    (ta, sa), (tb, sb) = pa.flight(), pb.flight()
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    if lo > hi:
        return np.inf
    ts = np.linspace(lo, hi, 400)
    xa = np.stack([np.interp(ts, ta, sa[:, k]) for k in range(2)], -1)
    xb = np.stack([np.interp(ts, tb, sb[:, k]) for k in range(2)], -1)
    return float(np.linalg.norm(xa - xb, axis=1).min())


@pytest.mark.slow
def test_crossing_vehicles_keep_the_induced_obstacle_apart():
    # Two vehicles crossing at right angles with the same STA: the lower-priority one must leave earlier or
    # detour, and its nominal trajectory stays outside the higher-priority disk R_c + 2 r_e.
    rc, r_e = 0.2, 0.05
    problem = PlanningProblem.dubins(GRID, VEHICLE, (0.5, 0.6), 0.5, r_e, rc,
                                     starts=[(-1.2, 0.0, 0.0), (0.0, -1.2, np.pi / 2)],
                                     targets=[(1.2, 0.0), (0.0, 1.2)], target_radius=0.25, stas=[0.0, 0.0],
                                     horizon=8.0)
    plan = plan_rtt(problem, progress=False)
    first, second = (v.plan for v in plan.vehicles)
    dx = GRID.spacing[0]
    assert first.arrival_time <= 0.05 and second.arrival_time <= 0.05
    # Highest priority: no obstacle, straight line; the planner aims one cell (at the slowest planning speed)
    # before the STA (plan_rtt's arrival_margin).
    margin = dx / 0.5
    assert first.t_ldt == pytest.approx(-(2.4 - 0.2) / 0.6 - margin, abs=dx / 0.6)
    # The lower-priority vehicle pays for the crossing with an earlier departure.
    assert second.t_ldt < first.t_ldt - 0.1
    # Half a cell of slack: the obstacle is resolved on the grid.
    assert _min_separation(first, second) >= rc + 2 * r_e - 0.5 * dx


def test_bad_inputs():
    with pytest.raises(ValueError, match="permutation"):
        PlanningProblem.dubins(GRID, VEHICLE, (0.5, 0.6), 0.5, 0.05, 0.2, [(-1, 0, 0), (0, -1, 0)], [(1, 0), (0, 1)],
                               0.25, [0.0, 0.0], priorities=[0, 0], horizon=5.0)
    with pytest.raises(ValueError, match="not smaller than its target radius"):
        PlanningProblem.dubins(GRID, VEHICLE, (0.5, 0.6), 0.5, 0.3, 0.2, [(-1, 0, 0)], [(1, 0)], 0.25, [0.0],
                               horizon=5.0)
    with pytest.raises(ValueError, match="got kbar without buffer_radius, obstacle_profiles"):
        PlanningProblem.dubins(GRID, VEHICLE, (0.5, 0.6), 0.5, 0.05, 0.2, [(-1, 0, 0)], [(1, 0)], 0.25, [0.0],
                               horizon=5.0, kbar=2)


@pytest.mark.slow
def test_plan_scenario_tiny_arrives_and_separates():
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    scenario = make("tiny")
    r_e = 4.13  # the default robust-tracking bound (tests/test_reach_tracking.py measures it)
    plan = plan_scenario(scenario, tracking_bound=r_e, progress=False)
    dx = scenario.grid().spacing[0]
    for v, spec in zip(plan.vehicles, scenario.vehicles):
        # Arrives by its STA, up to one trajectory sample.
        assert v.plan.arrival_time <= spec.sta + scenario.time_step
        assert v.plan.t_ldt < spec.sta
    a, b = (v.plan for v in plan.vehicles)
    assert _min_separation(a, b) >= scenario.collision_radius + 2 * r_e - 0.5 * dx
    # A horizon long enough for the first vehicle but not for the second, which detours around the first (about
    # 2.3 s longer): the error names the vehicle and the reason.
    margin = dx / scenario.planning_v[0]  # plan_rtt's arrival margin
    need = [v.plan.sta - margin - v.plan.t_ldt for v in plan.vehicles]
    assert need[1] > need[0] + 1.0
    with pytest.raises(InfeasiblePlanError, match=r"vehicle 1 \(priority 1\): no feasible departure for its STA"):
        plan_scenario(scenario, tracking_bound=r_e, horizon=0.5 * (need[0] + need[1]), progress=False)


@pytest.mark.slow
def test_intruder_aware_plan_keeps_the_buffer(tmp_path):
    from stp_env.artifacts import ArtifactStore
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    # STA spacing 90 s: the second vehicle must be in the air while the first still flies.
    scenario = make("tiny-intruder", sta_spacing=90)
    plan = plan_scenario(scenario, tracking_bound=4.13, store=ArtifactStore(tmp_path), progress=False)
    first, second = (v.plan for v in plan.vehicles)
    assert second.t_ldt < first.arrival_time  # they do share the airspace
    buffer_radius = plan.vehicles[1].obstacle_radii[0]
    assert buffer_radius > 500.0  # k̄ = 2 at 6 m/s wind: about 760 m
    dx = scenario.grid().spacing[0]
    assert _min_separation(first, second) >= buffer_radius - 0.5 * dx
    for v, spec in zip(plan.vehicles, scenario.vehicles):
        assert v.plan.arrival_time <= spec.sta + scenario.time_step


def test_shipped_tiny_plan_regenerates_bit_for_bit(tmp_path):
    import contextlib
    import io
    import json

    from stp_env.cli import main
    from stp_env.loaders import read_npz
    from stp_env.planning.stp import plan_to_arrays, shipped_plan

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["data", "plans", "--names", "tiny", "--out", str(tmp_path / "plans"), "--no-progress"]) == 0
    line = json.loads(out.getvalue())
    assert line["scenario"] == "tiny" and line["file"] == str(tmp_path / "plans" / "tiny.npz")
    fresh = read_npz(tmp_path / "plans" / "tiny.npz", "plan-checkpoint")
    shipped = plan_to_arrays(shipped_plan("tiny"))
    assert sorted(fresh) == sorted(shipped)
    for key in fresh:
        assert np.asarray(fresh[key]).tobytes() == np.asarray(shipped[key]).tobytes(), key
    with pytest.raises(ValueError, match="No shipped plan"):
        shipped_plan("nope")


@pytest.mark.slow
def test_replanning_changes_only_the_affected_vehicle():
    from stp_env.planning.replan import replan
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    scenario = make("tiny")
    plan = plan_scenario(scenario, tracking_bound=4.13, progress=False)
    # Vehicle 1 (second priority) was pushed off its path by an intruder: at t = -60 s it is 300 m east of its
    # nominal position, heading north-east.
    t_bar = -60.0
    nominal = plan.vehicles[1].plan
    p = np.array([np.interp(t_bar, nominal.times, nominal.states[:, k]) for k in range(2)])
    displaced = (float(p[0] + 300.0), float(p[1]), np.pi / 4)
    new = replan(plan, scenario, {1: displaced}, t_bar)
    assert new.vehicles[0] is plan.vehicles[0]  # untouched
    moved = new.vehicles[1].plan
    assert moved.t_ldt == pytest.approx(t_bar)
    np.testing.assert_allclose(moved.states[0], displaced, atol=1e-5)
    # The new STA is no earlier than a straight flight at the top planning speed allows, and the plan meets it.
    target = np.asarray(scenario.vehicles[1].target)
    straight = (np.hypot(*(target - np.asarray(displaced[:2]))) - scenario.vehicles[1].target_radius) / 13.0
    assert moved.sta >= t_bar + straight - 1e-6
    assert moved.arrival_time <= moved.sta + scenario.time_step
    dx = scenario.grid().spacing[0]
    assert _min_separation(plan.vehicles[0].plan, moved) >= scenario.collision_radius + 2 * 4.13 - 0.5 * dx
    with pytest.raises(ValueError, match="out of range"):
        replan(plan, scenario, {5: displaced}, t_bar)


@pytest.mark.slow
def test_early_stop_gives_the_full_solve_t_ldt_with_fewer_steps():
    # The time-to-reach of a node never changes once finite, so stopping the backward solve once the start is
    # inside the tube gives the same t_LDT (up to float32 rounding of the segment offsets) and the same trajectory.
    start, target, r = (-1.0, 0.3, 0.5), (1.0, -0.2), 0.2
    full = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=10.0, early_stop=False)
    early = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=10.0)
    assert early.t_ldt == pytest.approx(full.t_ldt, abs=1e-4)
    assert early.n_steps < 0.6 * full.n_steps
    np.testing.assert_allclose(early.states, full.states, atol=1e-3)
    # With depart_at the solve goes on until it has passed the imposed departure time.
    later = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=10.0, depart_at=full.t_ldt - 3.0)
    assert later.times[0] == pytest.approx(full.t_ldt - 3.0)
    assert later.arrival_time <= 0.05


AGILE = DubinsWind(v_min=0.5, v_max=0.6, omega_max=2.0, wind=0.0)


@pytest.mark.slow
def test_a_vehicle_with_time_to_spare_flies_to_its_target():
    # Departing 10 s before its latest departure time, the vehicle is deep inside the tube, where V is flat (the
    # target's depth): the controller of V(t) alone wandered and arrived 0.63 s after the STA (13.95 s of flight
    # for a 3.35 s trip). The goal-directed control (the latest slice containing the state) flies the direct trip.
    start, target, r = (-1.0, 0.3, 0.5), (1.0, -0.2), 0.2
    direct = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=20.0)
    early = plan_single(GRID, PLANNER, start, target, r, sta=0.0, horizon=20.0, depart_at=direct.t_ldt - 10.0)
    assert early.arrival_time - early.t_ldt <= direct.arrival_time - direct.t_ldt + 0.1


@pytest.mark.slow
def test_the_goal_directed_control_is_filtered_by_the_tube_of_its_own_time():
    # A disk sweeps across the straight route, centred on it 1.7 s after an early departure: the goal-directed
    # control (from a later slice, where the disk has gone) would fly into it. The filter keeps each sample in the
    # tube of its own time: the trajectory dodges the disk and still arrives early. The controller of V(t) alone
    # never arrived (it wandered on the flat plateau).
    def sweeper(t, p):
        return jnp.hypot(p["xs"][:, None], p["ys"][None, :] - 0.3 * (t + 13.3)) - 0.3

    axis = jnp.linspace(-1.5, 1.5, 61)
    plan = plan_single(GRID, AGILE, (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2, sta=0.0, horizon=20.0, depart_at=-15.0,
                       obstacle_fn=sweeper, obstacle_params={"xs": axis, "ys": axis})
    t, x = plan.flight()
    assert plan.arrival_time <= plan.t_ldt + 1.5 * 1.8 / AGILE.v_max   # 1.8 m to the target's edge
    assert np.hypot(x[:, 0], x[:, 1] - 0.3 * (t + 13.3)).min() >= 0.3 - 0.5 * GRID.spacing[0]


@pytest.mark.slow
def test_a_trajectory_that_leaves_the_tube_is_reported():
    # A disk appears on the target 3 s after an early departure, just before the direct trip would arrive: the
    # trajectory enters the target as the disk appears (the tube's values are sampled in time), i.e. inside an
    # obstacle. The check must see it: the tube value along the flight exceeds a cell.
    def cover(t, p):
        d = jnp.hypot(p["xs"][:, None] - 1.0, p["ys"][None, :]) - 0.3
        return jnp.where((t >= -12.0) & (t <= -5.0), d, jnp.inf)

    axis = jnp.linspace(-1.5, 1.5, 61)
    with pytest.warns(TubeExcursionWarning, match="leaves the reach-avoid tube"):
        plan_single(GRID, AGILE, (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2, sta=0.0, horizon=20.0, depart_at=-15.0,
                    obstacle_fn=cover, obstacle_params={"xs": axis, "ys": axis})


def test_departure_in_tube_keeps_a_consistent_time_and_falls_back_to_a_slice_inside():
    ts, tol = np.array([-3.0, -2.0, -1.0, 0.0]), 0.1
    # The start's value at t_ldt (linear between slices) is within the tolerance: t_ldt stands.
    assert departure_in_tube(ts, np.array([-1.0, -0.5, 0.0, 1.0]), -1.05, tol) == -1.05
    assert departure_in_tube(ts, np.array([-1.0, -0.5, 0.05, 1.0]), -1.0, tol) == -1.0
    # Outside by more than the tolerance: the latest slice at or before t_ldt with the start inside.
    assert departure_in_tube(ts, np.array([-1.0, 0.5, 0.5, -1.0]), -1.5, tol) == -3.0
    assert departure_in_tube(ts, np.array([-1.0, -0.2, 0.5, -1.0]), -1.0, tol) == -2.0
    # None inside before it: -inf (plan_single then reports the vehicle infeasible).
    assert departure_in_tube(ts, np.array([0.5, 0.5, 0.5, -1.0]), -1.5, tol) == -np.inf
    assert departure_in_tube(ts, np.zeros(4), -np.inf, tol) == -np.inf
    with pytest.raises(ValueError, match="ascending"):
        departure_in_tube(ts[::-1], np.zeros(4), -1.0, tol)
    with pytest.raises(ValueError, match="one value per slice"):
        departure_in_tube(ts, np.zeros(3), -1.0, tol)
    with pytest.raises(ValueError, match="tolerance"):
        departure_in_tube(ts, np.zeros(4), -1.0, np.nan)


def _shared_origin_departure(solver, monkeypatch=None):
    """A vehicle whose start a higher-priority vehicle leaves at t0 = -3.75 s (its disk, radius 0.4, moving off the
    start at 0.6 m/s), planned for an STA at 0: its clearance from that disk over its flight, and its plan."""
    from stp_env.planning import single
    from stp_env.planning.obstacles import planning_obstacles

    start, t0, rho = np.array([-1.025, 0.025, 0.08]), -3.75, 0.4
    ts = t0 + 0.05 * np.arange(200)
    xs = np.stack([np.full_like(ts, start[0]), start[1] + 0.6 * (ts - t0)], -1)
    obstacles = planning_obstacles(GRID, [(ts, xs, t0, ts[-1])], [0.0], [rho], None, n_slots=1, n_samples=len(ts))
    if monkeypatch is not None:  # the departure taken from the interpolated time-to-reach alone
        monkeypatch.setattr(single, "departure_in_tube", lambda times, values, t_ldt, tolerance: t_ldt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TubeExcursionWarning)
        plan = plan_single(GRID, PLANNER, start, (1.0, 0.0), 0.2, sta=0.0, horizon=8.0, slice_dt=0.25,
                           solver=solver, **obstacles)
    t, x = plan.flight()
    present = t >= t0
    gap = np.hypot(x[present, 0] - np.interp(t[present], ts, xs[:, 0]),
                   x[present, 1] - np.interp(t[present], ts, xs[:, 1])) - rho
    return float(gap.min()), plan


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["split", "hj"])
def test_a_start_that_another_vehicle_has_just_left_departs_outside_its_disk(solver, monkeypatch):
    # The nodes around the start enter the tube (first entry, going backward) on either side of the disk's stay
    # on the start: their interpolated time-to-reach is a time at which the start is inside the disk (measured on
    # the bay area: a vehicle departing 0.03 s after another from the same city, 170 m inside its disk). The
    # departure is checked against the tube's slices and moved to the latest slice with the start inside.
    gap, plan = _shared_origin_departure(solver)
    assert gap >= -0.5 * GRID.spacing[0]
    assert plan.arrival_time <= 0.0
    assert plan.t_ldt == pytest.approx(-4.5, abs=1e-6)  # a slice (0.25 s apart) before the disk appears at -3.75 s
    # The mutant, departing at the interpolated time-to-reach, starts inside the disk by more than three cells.
    bad, plan = _shared_origin_departure(solver, monkeypatch)
    assert bad < -3 * GRID.spacing[0]
    assert plan.t_ldt > -4.5


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["split", "hj"])
def test_the_backward_solve_stops_only_at_a_slice_with_the_start_inside(solver):
    # A disk sits on the start over [-3.6, -3.1] s; unobstructed, the start enters the tube at -3.0 s, between
    # the slices at -2.67 and -3.33 s, and the slice at -3.33 s has the disk on it. A solve stopped at the first
    # slice where the time-to-reach is finite has no slice with the start inside at or before -3.0 s (measured:
    # the plan was then infeasible). Solving on, the slice at -4.0 s has it. The departure check is conservative
    # here: -3.0 s was free (the disk had gone), but the slices, 0.67 s apart, cannot show it.
    def cover(t, p):
        d = jnp.hypot(p["xs"][:, None] + 1.0, p["ys"][None, :]) - 0.2
        return jnp.where((t >= -3.6) & (t <= -3.1), d, jnp.inf)

    axis = jnp.linspace(-1.5, 1.5, 61)
    plan = plan_single(GRID, PLANNER, (-1.0, 0.0, 0.0), (1.0, 0.0), 0.2, sta=0.0, horizon=8.0, slice_dt=0.7,
                       solver=solver, obstacle_fn=cover, obstacle_params={"xs": axis, "ys": axis})
    assert plan.t_ldt == pytest.approx(-4.0)
    assert plan.arrival_time <= 0.0
    t, x = plan.flight()
    on = (t >= -3.6) & (t <= -3.1)
    assert np.hypot(x[on, 0] + 1.0, x[on, 1]).min() >= 0.2


@pytest.mark.slow
def test_folded_lag_disks_are_a_superset_of_the_lag_profiles():
    # fold_contained_disks drops the lag disks inside the lag-0 disk and widens the flight window instead: the
    # obstacle g (sub-zero set) must contain the original union at every time, before, during and after the flight.
    import jax.numpy as jnp

    from stp_env.planning.obstacles import disk_params, moving_disks
    from stp_env.planning.stp import fold_contained_disks

    grid = hj.Grid.from_bounds((0.0, 0.0, -np.pi), (2000.0, 2000.0, np.pi), (81, 81, 8), periodic=2)
    lags = np.concatenate([[0.0], np.linspace(-10.0, 10.0, 41), [12.0]])
    radii = np.concatenate([[700.0], 400.0 + 10.0 * np.abs(np.linspace(-10.0, 10.0, 41)), [650.0]])
    kept_lags, kept_radii, before, after = fold_contained_disks(lags, radii, speed=13.0)
    assert kept_lags[0] == 0.0 and kept_radii[0] == 700.0
    assert 12.0 in kept_lags and len(kept_lags) < len(lags)  # 650 + 13 * 12 > 700: kept
    assert (before, after) == (10.0, 10.0)
    ts = np.arange(0.0, 100.0, 0.5)
    heading = np.cumsum(np.full_like(ts, 0.01))
    xy = np.stack([300.0 + np.cumsum(13.0 * 0.5 * np.cos(heading)), 500.0 + np.cumsum(13.0 * 0.5 * np.sin(heading)),
                   heading], -1)
    full = disk_params(grid, [(ts, xy, ts[0], ts[-1])], lags, radii)
    folded = disk_params(grid, [(ts, xy, ts[0] - before, ts[-1] + after)], kept_lags, kept_radii)
    for t in (-15.0, -8.0, -0.3, 0.0, 33.3, 99.5, 104.0, 111.0):
        g_full, g_folded = moving_disks(jnp.float32(t), full), moving_disks(jnp.float32(t), folded)
        assert np.all(np.asarray(g_folded) <= np.asarray(g_full) + 1e-3), t


TOWN_KBARS = (1, 2, 3)


@pytest.fixture(scope="module")
def town_plans():
    from stp_env.planning.stp import shipped_plan_for
    from stp_env.scenarios import make

    return {k: (make("town", kbar=k), shipped_plan_for("town", k)) for k in TOWN_KBARS}


def _pair_distances(plan, ts):
    """Distances ``(T, N, N)`` between vehicles' nominal positions at ``ts`` (``inf`` unless both are flying) and
    the number of vehicles flying at each time."""
    pos = []
    for v in plan.vehicles:
        times, st = v.plan.flight()
        p = np.stack([np.interp(ts, times, st[:, k]) for k in range(2)], -1)
        p[(ts < times[0]) | (ts > times[-1])] = np.nan
        pos.append(p)
    pos = np.stack(pos, 1)
    d = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=-1)
    d[np.isnan(d)] = np.inf
    d[:, np.arange(len(pos[0])), np.arange(len(pos[0]))] = np.inf
    return d, np.sum(np.isfinite(pos[..., 0]), axis=1)


@pytest.mark.parametrize("kbar", TOWN_KBARS)
def test_shipped_town_plans_keep_the_buffer_and_share_the_airspace(town_plans, kbar):
    # Intruder-aware planning (intruder paper Algorithm 3, eq. 34): every pair of nominal trajectories stays at
    # least the buffer radius of eqs. (21), (48) apart while both fly (half a cell of grid slack), every vehicle
    # arrives by its STA, and vehicles do share the airspace: at some time a vehicle has another one within two
    # buffer radii, so an intruder could press more than one if the plan did not keep the buffer.
    scenario, plan = town_plans[kbar]
    assert plan.kbar == kbar and len(plan.vehicles) == scenario.n_vehicles
    buffer_radius = plan.vehicles[0].obstacle_radii[0]
    dx = scenario.grid().spacing[0]
    t0 = min(v.plan.t_ldt for v in plan.vehicles)
    t1 = max(v.plan.arrival_time for v in plan.vehicles)
    d, flying = _pair_distances(plan, np.arange(t0, t1, 0.25))
    assert d.min() >= buffer_radius - 0.5 * dx
    assert d.min() <= 2.0 * buffer_radius
    assert flying.max() >= 3
    for v, spec in zip(plan.vehicles, scenario.vehicles):
        assert v.plan.arrival_time <= spec.sta + scenario.time_step
        assert v.priority == spec.priority
        np.testing.assert_allclose(v.plan.states[0, :2], spec.start[:2])
        end = v.plan.flight()[1][-1]
        assert np.hypot(end[0] - spec.target[0], end[1] - spec.target[1]) <= spec.target_radius


def test_shipped_town_buffer_radii_shrink_with_kbar(town_plans):
    # t_BRD = t_IAT / k̄: a larger k̄ allows a smaller relative buffer region (eqs. 22, 46-47).
    radii = [town_plans[k][1].vehicles[0].obstacle_radii[0] for k in TOWN_KBARS]
    assert radii[0] > radii[1] > radii[2] > 2 * 245.0  # beyond the separation region (d^A ~ 246 m, eq. 20)


@pytest.mark.slow
def test_late_extraction_departs_earlier(monkeypatch):
    """A nominal trajectory that comes out later than its STA (the sampled controller can lose time in a narrow
    channel; seen on a city case) is extracted again from an earlier departure."""
    import dataclasses

    import stp_env.planning.stp as stp
    from stp_env.scenarios import make

    real = stp.plan_single
    calls = []

    def late_first(*args, depart_at=None, **kwargs):
        out = real(*args, depart_at=depart_at, **kwargs)
        calls.append((depart_at, out.t_ldt))
        if depart_at is None:  # pretend the first extraction arrives 5 s after the STA
            return dataclasses.replace(out, arrival_time=args[5] + 5.0 + 3.0)
        return out

    monkeypatch.setattr(stp, "plan_single", late_first)
    scenario = make("tiny")
    plan = stp.plan_scenario(scenario, tracking_bound=4.13, progress=False)
    assert len(calls) == 4  # two vehicles, one retry each
    for (first_depart, first_ldt), (retry_depart, _), v in zip(calls[::2], calls[1::2], plan.vehicles):
        assert first_depart is None and retry_depart < first_ldt - 5.0
        assert v.plan.t_ldt == pytest.approx(retry_depart) and v.plan.arrival_time <= v.plan.sta
