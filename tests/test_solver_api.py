"""The solver's API: results, time stepping, restarts, obstacles, convergence loop and input checks."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import DubinsWind, SingleIntegrator

GRID = hj.Grid.from_bounds((-2.0, -2.0), (2.0, 2.0), (41, 41))  # dx = 0.1
DX = GRID.spacing[0]
HOLO = SingleIntegrator(dim=2, speed=1.0)
VERY_HIGH = hj.SolverSettings.with_accuracy("very_high")
TARGET = hj.shapes.ball(GRID, (-0.5, 0.0), 0.4)

GRID1 = hj.Grid.from_bounds((-1.0,), (1.0,), (41,))  # dx = 0.05
X1 = GRID1.coordinate_vector(0)


def moving_disk(t, p):
    """Time-varying obstacle: a disk moving along x (module level, so that it is hashable and reused)."""
    return jnp.sqrt((p["x"] - p["cx"] - p["vx"] * t) ** 2 + (p["y"] - p["cy"]) ** 2) - p["rho"]


def _moving_disk_params(grid):
    x, y = grid.broadcast_states()
    return {"x": x, "y": y, "cx": jnp.float32(1.0), "cy": jnp.float32(0.2), "vx": jnp.float32(1.0),
            "rho": jnp.float32(0.3)}


def shifted_interval(t, p):
    """1-D obstacle ``|x - c(t)| <= 0.1`` with ``c(t) = c0 + t``."""
    return jnp.abs(p["x"] - p["c0"] - t) - 0.1


# ------------------------------------------------------------------------------------ result structure
@pytest.mark.slow
def test_result_structure_and_cfl_step():
    times = [0.0, -0.3, -0.5]
    res = hj.solve(VERY_HIGH, HOLO, GRID, times, TARGET, progress=False)
    assert res.values.shape == (3, *GRID.shape)
    assert res.values.dtype == jnp.float32
    np.testing.assert_array_equal(res.times, times)
    # Local Lax-Friedrichs bound of a unit-speed holonomic point: alpha_i = 1, dt = cfl / (2 / dx).
    assert res.dt == pytest.approx(0.75 / (2 / DX))
    assert hj.cfl_time_step(VERY_HIGH, HOLO, GRID)[0] == pytest.approx(res.dt)
    # Each interval is split on its own: ceil(0.3 / dt) + ceil(0.2 / dt) steps.
    assert res.n_steps == math.ceil(0.3 / res.dt) + math.ceil(0.2 / res.dt - 1e-9)
    assert res.time_to_reach is None
    np.testing.assert_array_equal(np.asarray(res.values[0]), np.asarray(TARGET))
    # The reachable set grows with the horizon here (the values need not decrease everywhere: dissipation lifts
    # the kink at the bottom of the cone, measured +0.038 at its apex over the first 0.3 s).
    sets = np.asarray(res.values) <= 0
    assert np.all(sets[1:] >= sets[:-1])
    assert sets[2].sum() > sets[1].sum() > sets[0].sum()


@pytest.mark.slow
def test_cfl_time_step_local_and_global_for_dubins():
    grid = hj.Grid.from_bounds((-1.0, -1.0, -math.pi), (1.0, 1.0, math.pi), (11, 11, 16), periodic=2)
    dyn = DubinsWind(v_min=0.2, v_max=1.0, omega_max=0.5, wind=0.25)
    dx, dy, dth = grid.spacing
    th = grid.coordinate_vector(2)
    # alpha = (|cos| v_max + w, |sin| v_max + w, omega_max) (the speed box is [v_min, v_max]).
    local = np.max((np.abs(np.cos(th)) + 0.25) / dx + (np.abs(np.sin(th)) + 0.25) / dy + 0.5 / dth)
    dt, alpha = hj.cfl_time_step(hj.SolverSettings(cfl=0.5), dyn, grid)
    assert dt == pytest.approx(0.5 / local, rel=1e-5)
    np.testing.assert_allclose(alpha, [1.25, 1.25, 0.5], rtol=1e-5)
    dt_global, _ = hj.cfl_time_step(hj.SolverSettings(cfl=0.5, dissipation="global"), dyn, grid)
    assert dt_global == pytest.approx(0.5 / (1.25 / dx + 1.25 / dy + 0.5 / dth), rel=1e-5)
    assert dt_global <= dt
    # No motion at all: an infinite step (one step per interval, which changes nothing).
    still = SingleIntegrator(dim=1, speed=0.0)
    assert hj.cfl_time_step(VERY_HIGH, still, GRID1)[0] == math.inf
    res = hj.solve(VERY_HIGH, still, GRID1, [0.0, -3.0], jnp.asarray(X1, jnp.float32), progress=False)
    assert res.n_steps == 1
    # Only the RK3 combination's round-off: (1/3) v + (2/3) v.
    np.testing.assert_allclose(np.asarray(res.values[-1]), np.asarray(res.values[0]), atol=1e-6)


# ------------------------------------------------------------------------------------ restarts
@pytest.mark.slow
@pytest.mark.parametrize("obstacle", [False, True], ids=["free", "moving_obstacle"])
@pytest.mark.parametrize("tube", [False, True], ids=["set", "tube"])
def test_solve_in_one_go_equals_restarted_solve(tube, obstacle):
    """[0, -T] in one go against [0, -T/2] continued from its values over [-T/2, -T], and against
    times = [0, -T/2, -T].

    The solver splits each interval into full CFL steps plus one shorter remainder step. When T/2 is a whole
    number of steps, all three step plans coincide and only float32 round-off of the step times may differ
    (the moving obstacle is evaluated at ``t_start + k dt``). Otherwise the restarted solve takes one more,
    differently placed step: the results then differ by a (small) change of time discretisation, at most a few
    thousandths of a cell (measured 3e-4 dx without and 6e-3 dx with the moving obstacle, whose projection is
    applied at different times)."""
    kw = {"obstacle": _moving_disk_params(GRID), "obstacle_fn": moving_disk} if obstacle else {}
    dt = hj.cfl_time_step(VERY_HIGH, HOLO, GRID)[0]
    for T, tol in ((20 * dt, 1e-6), (0.77, (0.02 if obstacle else 0.005) * DX)):
        one = hj.solve(VERY_HIGH, HOLO, GRID, [0.0, -T], TARGET, tube=tube, progress=False, **kw)
        first = hj.solve(VERY_HIGH, HOLO, GRID, [0.0, -T / 2], TARGET, tube=tube, progress=False, **kw)
        second = hj.solve(VERY_HIGH, HOLO, GRID, [-T / 2, -T], TARGET, tube=tube, progress=False,
                          initial_values=first.values[-1], **kw)
        three = hj.solve(VERY_HIGH, HOLO, GRID, [0.0, -T / 2, -T], TARGET, tube=tube, progress=False, **kw)
        assert float(jnp.abs(one.values[-1] - second.values[-1]).max()) <= tol
        # Requesting an intermediate time is exactly a restart at that time.
        np.testing.assert_array_equal(np.asarray(three.values[1]), np.asarray(first.values[-1]))
        np.testing.assert_array_equal(np.asarray(three.values[2]), np.asarray(second.values[-1]))
        assert three.n_steps == first.n_steps + second.n_steps


def test_steps_per_chunk_does_not_change_results():
    a = hj.solve(VERY_HIGH, HOLO, GRID, [0.0, -0.5], TARGET, tube=True, progress=False)
    b = hj.solve(hj.SolverSettings(steps_per_chunk=3), HOLO, GRID, [0.0, -0.5], TARGET, tube=True,
                 progress=False)
    np.testing.assert_array_equal(np.asarray(a.values), np.asarray(b.values))
    assert a.n_steps == b.n_steps


# ------------------------------------------------------------------------------------ obstacles
@pytest.mark.slow
def test_static_obstacle_blocks_the_way_in_1d():
    """Target around x = 0.8, a wall on [0.2, 0.4]: in 1-D nothing to the left of the wall can reach the
    target, although everything reaches it without the wall."""
    target = jnp.asarray(np.abs(X1 - 0.8) - 0.1, jnp.float32)
    wall = jnp.asarray(np.abs(X1 - 0.3) - 0.1, jnp.float32)
    dyn = SingleIntegrator(dim=1, speed=1.0)
    free = hj.solve(VERY_HIGH, dyn, GRID1, [0.0, -2.5], target, tube=True, progress=False)
    res = hj.solve(VERY_HIGH, dyn, GRID1, [0.0, -2.5], target, tube=True, obstacle=wall, progress=False)
    v, v_free = np.asarray(res.values[-1]), np.asarray(free.values[-1])
    assert np.all(v_free <= 0)
    assert np.all(v[X1 <= 0.2] > 0)
    assert np.all(v[X1 >= 0.4 + 1e-9] <= 0)
    # The obstacle constraint holds at every output time, including the first: V >= -g.
    assert np.all(np.asarray(res.values) >= -np.asarray(wall)[None] - 1e-6)
    assert np.all(np.asarray(res.values[0]) == np.maximum(np.asarray(target), -np.asarray(wall)))


@pytest.mark.slow
def test_obstacle_fn_uses_absolute_time():
    """The obstacle ``|x - (c0 + t)| <= 0.1`` is applied at the requested times, not at times since the start."""
    params = {"x": jnp.asarray(X1, jnp.float32), "c0": jnp.float32(0.0)}
    target = jnp.asarray(np.abs(X1 + 0.9) - 0.05, jnp.float32)
    dyn = SingleIntegrator(dim=1, speed=0.0, drift=(0.0,))
    for t0 in (0.0, 0.5, -0.5):
        res = hj.solve(VERY_HIGH, dyn, GRID1, [t0, t0 - 0.1], target, obstacle=params,
                       obstacle_fn=shifted_interval, progress=False)
        expected = np.maximum(np.asarray(target), -(np.abs(X1 - t0) - 0.1))
        np.testing.assert_allclose(np.asarray(res.values[0]), expected, atol=1e-6)
        # The dynamics are still: after the interval, the obstacle has moved with t.
        expected_end = np.maximum(expected, -(np.abs(X1 - (t0 - 0.1)) - 0.1))
        np.testing.assert_allclose(np.asarray(res.values[-1]), expected_end, atol=1e-6)
    # A time-invariant obstacle_fn equals the static obstacle array.
    wall = jnp.asarray(np.abs(X1 - 0.3) - 0.1, jnp.float32)
    a = hj.solve(VERY_HIGH, SingleIntegrator(dim=1, speed=1.0), GRID1, [0.0, -1.0], target, tube=True,
                 obstacle=wall, progress=False)
    b = hj.solve(VERY_HIGH, SingleIntegrator(dim=1, speed=1.0), GRID1, [0.0, -1.0], target, tube=True,
                 obstacle=wall, obstacle_fn=hj.static_obstacle, progress=False)
    np.testing.assert_array_equal(np.asarray(a.values), np.asarray(b.values))


# ------------------------------------------------------------------------------------ time to reach
@pytest.mark.slow
def test_time_to_reach_output():
    res = hj.solve(VERY_HIGH, HOLO, GRID, [0.0, -1.0], TARGET, tube=True, time_to_reach=True, progress=False)
    ttr = np.asarray(res.time_to_reach)
    assert ttr.shape == GRID.shape
    assert np.all(ttr[np.asarray(TARGET) <= 0] == 0)
    finite = np.isfinite(ttr)
    np.testing.assert_array_equal(finite, np.asarray(res.values[-1]) <= 0)
    # Unit speed from a disk of radius 0.4: TTR = distance to the disk, to a small fraction of a cell.
    x, y = (np.asarray(a, np.float64) for a in GRID.broadcast_states())
    dist = np.broadcast_to(np.hypot(x + 0.5, y) - 0.4, GRID.shape)
    band = finite & (dist > 2 * DX) & (dist < 0.9)
    assert band.sum() > 50
    assert np.abs(ttr - dist)[band].max() <= 0.05 * DX  # measured 0.0034 dx


# ------------------------------------------------------------------------------------ convergence loop
@pytest.mark.slow
def test_solve_until_converged_with_walls():
    """Target |x| <= 0.2 between walls |x| >= 0.6: the tube stops growing at the walls (after 0.4 s).

    Exact: V = max(-0.2, |x| - 0.6) between the walls. WENO5 is not monotone: at the convex kink |x| = 0.4 that
    the wall constraint creates, it pushes the plateau below min l = -0.2 (to -0.2055 by 0.75 s, -0.209 by 3 s,
    -0.218 by 5 s; ``hj_reachability`` gives the same numbers), so an unbanded check with tol = 1e-4 never
    converges (changes ~4e-4 per 0.25 s). Restricting the check to |V| <= band, as documented, converges; the
    first-order scheme is monotone and converges without a band."""
    target = jnp.asarray(np.abs(X1) - 0.2, jnp.float32)
    walls = jnp.asarray(0.6 - np.abs(X1), jnp.float32)
    exact = np.maximum(-0.2, np.abs(X1) - 0.6)
    dyn = SingleIntegrator(dim=1, speed=1.0)
    out = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, obstacle=walls, check_interval=0.25,
                                   max_horizon=5.0, tol=1e-4, band=0.1, progress=False)
    assert out.converged
    assert 0.5 <= out.horizon <= 1.5
    assert len(out.changes) == round(out.horizon / 0.25) and out.changes[-1] <= 1e-4
    v = np.asarray(out.values)
    assert np.all(v[np.abs(X1) < 0.6 - 1e-9] <= 0)
    assert np.all(v[np.abs(X1) >= 0.6] >= 0)
    near = np.abs(exact) <= 0.1
    assert np.abs(v - exact)[near].max() <= 0.01 * GRID1.spacing[0]
    # The same as one solve over the same horizon, up to the different step plan (see the restart test;
    # measured 0.0013 dx).
    ref = hj.solve(VERY_HIGH, dyn, GRID1, [0.0, -out.horizon], target, tube=True, obstacle=walls, progress=False)
    assert float(jnp.abs(ref.values[-1] - out.values).max()) <= 0.01 * GRID1.spacing[0]

    low = hj.solve_until_converged(hj.SolverSettings.with_accuracy("low"), dyn, GRID1, target, obstacle=walls,
                                   check_interval=0.25, max_horizon=5.0, tol=1e-4, progress=False)
    assert low.converged and low.horizon <= 2.0
    np.testing.assert_allclose(np.asarray(low.values), exact, atol=1e-4)

    with pytest.warns(RuntimeWarning, match="not converged after 0.3"):
        never = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, check_interval=0.1, max_horizon=0.3,
                                         tol=1e-4, progress=False)
    assert not never.converged and never.horizon == pytest.approx(0.3) and len(never.changes) == 3
    assert never.rate == pytest.approx(never.changes[-1] / 0.1)


def test_convergence_never_passes_on_an_empty_comparison_set():
    """A band that every node's value has left compares nothing: that must not count as convergence.

    Target ``|x| + 2`` (no zero level) in a tube that keeps growing: every value exceeds the band of 1 from the
    start, so the old rule (the largest change over an empty set is 0) reported convergence on the first check
    while the values were still changing by 0.25 per check."""
    dyn = SingleIntegrator(dim=1, speed=1.0)
    target = jnp.asarray(np.abs(X1) + 2.0, jnp.float32)
    with pytest.warns(RuntimeWarning, match="not converged"):
        out = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, check_interval=0.25, max_horizon=0.5,
                                       tol=1e-3, band=1.0, progress=False)
    assert not out.converged
    assert out.compared == (0, 0) and all(math.isinf(c) for c in out.changes)
    # Over the whole grid the same solve is visibly still moving, which is what the band hid.
    loose = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, check_interval=0.25, max_horizon=0.5,
                                     tol=1e-3, progress=False, warn=False)
    assert not loose.converged and min(loose.changes) > 0.2


def test_convergence_watches_what_users_consume():
    """A watched quantity that still moves keeps the loop going although the compared band has settled; a
    relative tolerance scales with the watched quantity.

    The walls problem of the test above: the band ``|V| <= 0.1`` settles within 1 s, but WENO5 keeps pushing the
    plateau below ``min l = -0.2`` by 3e-4 to 1e-3 per 0.5 s (the plateau lies outside the band)."""
    dyn = SingleIntegrator(dim=1, speed=1.0)
    target = jnp.asarray(np.abs(X1) - 0.2, jnp.float32)
    walls = jnp.asarray(0.6 - np.abs(X1), jnp.float32)
    kwargs = dict(obstacle=walls, check_interval=0.5, max_horizon=3.0, band=0.1, progress=False)
    banded = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, tol=1e-4, **kwargs)
    assert banded.converged and banded.horizon <= 1.0
    watched = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, tol=1e-4, watch=jnp.min, warn=False,
                                       **kwargs)
    assert not watched.converged
    plateau = [w[0] for w in watched.watched]
    assert plateau[-1] < plateau[0] < -0.2
    relative = hj.solve_until_converged(VERY_HIGH, dyn, GRID1, target, tol=0.0, rtol=0.01, watch=jnp.min,
                                        **kwargs)
    assert relative.converged and relative.horizon <= 1.0


def test_progress_bar_runs():
    res = hj.solve(VERY_HIGH, SingleIntegrator(dim=1, speed=1.0), GRID1, [0.0, -0.1],
                   jnp.asarray(np.abs(X1) - 0.2, jnp.float32), progress=True)
    assert res.values.shape == (2, 41)


@pytest.mark.slow
def test_float64_solve_in_subprocess_matches_float32():
    """float64 needs x64 at start-up, so it runs in a fresh interpreter."""
    code = textwrap.dedent("""
        import jax
        jax.config.update("jax_enable_x64", True)
        jax.config.update("jax_platforms", "cpu")
        import jax.numpy as jnp, numpy as np
        from stp_env import hj
        from stp_env.dynamics import SingleIntegrator
        g = hj.Grid.from_bounds((-1.0,), (1.0,), (41,))
        x = g.coordinate_vector(0)
        dyn = SingleIntegrator(dim=1, speed=1.0)
        st = hj.SolverSettings.with_accuracy("very_high")
        a = hj.solve(st, dyn, g, [0.0, -0.4], np.abs(x) - 0.2, dtype=jnp.float64, progress=False)
        b = hj.solve(st, dyn, g, [0.0, -0.4], np.abs(x) - 0.2, dtype=jnp.float32, progress=False)
        assert a.values.dtype == jnp.float64 and b.values.dtype == jnp.float32
        print(float(jnp.abs(a.values[-1] - b.values[-1].astype(jnp.float64)).max()))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert float(out.stdout.strip().splitlines()[-1]) < 1e-5


# ------------------------------------------------------------------------------------ bad input
def _solve(**kw):
    args = {"settings": VERY_HIGH, "dynamics": HOLO, "grid": GRID, "times": [0.0, -0.1], "target": TARGET}
    args.update(kw)
    return hj.solve(args.pop("settings"), args.pop("dynamics"), args.pop("grid"), args.pop("times"),
                    args.pop("target"), progress=False, **args)


def _with_nan(a, where=(3, 4)):
    a = np.array(a)
    a[where] = np.nan
    return a


@pytest.mark.parametrize(
    ("kwargs", "error", "pattern"),
    [
        ({"target": np.zeros((41, 40))}, ValueError, r"target has shape \(41, 40\), but the grid has shape \(41, 41\)"),
        ({"target": _with_nan(np.ones((41, 41)))}, ValueError, "target contains NaN at 1 grid point.*finite or"),
        ({"times": [0.0, -0.2, -0.1]}, ValueError, "strictly decreasing .* or strictly increasing"),
        ({"times": [0.0, 0.0]}, ValueError, "strictly decreasing .* or strictly increasing"),
        ({"times": [0.0, 1.0, 0.5]}, ValueError, "strictly decreasing .* or strictly increasing"),
        ({"times": [0.0]}, ValueError, "at least 2 times"),
        ({"times": [[0.0, -1.0]]}, ValueError, "1-D sequence"),
        ({"times": [0.0, float("nan")]}, ValueError, "times must be finite"),
        ({"times": [0.0, -float("inf")]}, ValueError, "times must be finite"),
        ({"dynamics": SingleIntegrator(dim=3)}, ValueError, "dynamics has 3 states but the grid has 2 dimensions"),
        ({"dynamics": DubinsWind()}, ValueError, "dynamics has 3 states but the grid has 2 dimensions"),
        ({"dtype": jnp.float64}, ValueError, r"float64 needs jax.config.update\('jax_enable_x64', True\)"),
        ({"dtype": jnp.int32}, ValueError, "dtype must be float32 or float64"),
        ({"dtype": jnp.float16}, ValueError, "dtype must be float32 or float64"),
        ({"settings": "very_high"}, TypeError, "settings must be a SolverSettings"),
        ({"grid": (41, 41)}, TypeError, "grid must be a stp_env.hj.Grid"),
        ({"dynamics": lambda x, u: x}, TypeError, "dynamics must be a ControlAffineDynamics"),
        ({"obstacle": np.zeros((40, 41))}, ValueError, r"obstacle has shape \(40, 41\)"),
        ({"obstacle": _with_nan(np.ones((41, 41)))}, ValueError, "obstacle contains NaN"),
        ({"initial_values": np.zeros((41,))}, ValueError, r"initial_values has shape \(41,\)"),
        ({"initial_values": _with_nan(np.ones((41, 41)))}, ValueError, "initial_values contains NaN"),
        ({"obstacle": {"x": jnp.zeros((3,)), "cx": 0.0, "y": 0.0, "cy": 0.0, "vx": 0.0, "rho": 1.0},
          "obstacle_fn": moving_disk}, ValueError, r"obstacle_fn returns shape \(3,\), but the grid has shape"),
    ],
    ids=lambda v: v if isinstance(v, str) else None,
)
def test_bad_solve_inputs_raise_clear_errors(kwargs, error, pattern):
    with pytest.raises(error, match=pattern):
        _solve(**kwargs)


def test_bad_grid_bounds():
    with pytest.raises(ValueError, match=r"non-positive extent.*hi must exceed lo"):
        hj.Grid.from_bounds((0.0, 1.0), (1.0, 1.0), (5, 5))
    with pytest.raises(ValueError, match="non-positive extent"):
        hj.Grid.from_bounds((0.0,), (-1.0,), (5,))


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"scheme": "weno3"}, r"Unknown scheme 'weno3'; allowed: \['eno2', 'upwind1', 'weno5'\]"),
        ({"integrator": "rk4"}, r"Unknown integrator 'rk4'; allowed: \['euler', 'rk2', 'rk3'\]"),
        ({"dissipation": "none"}, r"Unknown dissipation 'none'; allowed: \('local', 'global'\)"),
        ({"boundary": "periodic"}, r"Unknown boundary 'periodic'; allowed: .*extrapolate_away_from_zero"),
        ({"tube_mode": "max"}, r"Unknown tube_mode 'max'; allowed: \('min_with_target', 'freeze'\)"),
        ({"cfl": 0.0}, r"cfl must be a number in \(0, 1\]; got 0.0"),
        ({"cfl": -0.5}, r"cfl must be a number in \(0, 1\]"),
        ({"cfl": 1.5}, r"cfl must be a number in \(0, 1\]"),
        ({"cfl": float("nan")}, r"cfl must be a number in \(0, 1\]"),
        ({"cfl": float("inf")}, r"cfl must be a number in \(0, 1\]"),
        ({"cfl": "0.5"}, r"cfl must be a number in \(0, 1\]"),
        ({"cfl": True}, r"cfl must be a number in \(0, 1\]"),
        ({"weno_eps": 0.0}, "weno_eps must be positive"),
        ({"steps_per_chunk": 0}, "steps_per_chunk must be >= 1"),
    ],
)
def test_bad_settings_raise_clear_errors(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        hj.SolverSettings(**kwargs)


def test_cfl_accepts_numpy_scalars_and_one():
    assert hj.SolverSettings(cfl=np.float32(0.5)) == hj.SolverSettings(cfl=0.5)
    assert hj.SolverSettings(cfl=1).cfl == 1.0
    assert isinstance(hj.SolverSettings(cfl=np.float64(0.25)).cfl, float)


def test_presets_and_unknown_preset():
    for level, (scheme, integrator) in hj.ACCURACY_PRESETS.items():
        s = hj.SolverSettings.with_accuracy(level, cfl=0.5)
        assert (s.scheme, s.integrator, s.cfl) == (scheme, integrator, 0.5)
    assert hj.SolverSettings.with_accuracy("low") == hj.SolverSettings(scheme="upwind1", integrator="euler")
    with pytest.raises(ValueError, match=r"Unknown accuracy preset 'ultra'; allowed: \['low', 'medium', 'high', "
                                         r"'very_high'\]"):
        hj.SolverSettings.with_accuracy("ultra")
    # The preset fixes scheme and integrator; overriding them is refused with a message, not silently applied.
    with pytest.raises(ValueError, match=r"fixes scheme and integrator; got \['scheme'\]"):
        hj.SolverSettings.with_accuracy("low", scheme="weno5")


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"check_interval": 0.0}, "check_interval > 0"),
        ({"check_interval": 2.0, "max_horizon": 1.0}, "max_horizon >= check_interval"),
        ({"tol": 0.0}, "tol \\+ rtol > 0"),
        ({"tol": -1.0}, "tol >= 0"),
    ],
)
def test_bad_convergence_loop_arguments(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        hj.solve_until_converged(VERY_HIGH, HOLO, GRID, TARGET, progress=False, **kwargs)


def test_bad_dynamics_roles():
    with pytest.raises(ValueError, match="control_mode must be 'min' or 'max'; got 'minimize'"):
        SingleIntegrator(dim=2, control_mode="minimize")
    with pytest.raises(ValueError, match="disturbance_mode must be 'min' or 'max'"):
        DubinsWind().with_modes(disturbance_mode="avoid")
