"""Robust trajectory tracking (SPP paper eqs. 24-26): the bound, and the tracker in closed loop.

Scaled-down vehicle (speeds ~1) so that the error grid is small; the closed loop runs in the world frame against
random references and random or worst-case wind, and against a fully adversarial reference.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.angles import wrap_angle
from stp_env.dynamics import DubinsWind
from stp_env.reach.tracking import TrackingConfig, compute_tracking_bound

VEHICLE = DubinsWind(v_min=0.0, v_max=1.0, omega_max=2.0, wind=0.1)


def config(**kw):
    base = dict(vehicle=VEHICLE, planning_v=(0.4, 0.5), planning_omega_max=1.0, half_width=1.0,
                grid_points=(41, 41, 40), max_horizon=30.0, certify=False)
    base.update(kw)
    return TrackingConfig(**base)


@pytest.fixture(scope="module")
def bound():
    return compute_tracking_bound(config(), progress=False)


@pytest.mark.slow
def test_bound_positive_below_cap_and_grows_with_wind(bound):
    assert 0 < bound.bound < 0.5 * bound.config.cap
    assert bound.min_value <= bound.bound + 1e-6
    windier = compute_tracking_bound(config(vehicle=DubinsWind(v_min=0.0, v_max=1.0, omega_max=2.0, wind=0.2)),
                                     progress=False)
    assert windier.bound > bound.bound


def test_planning_set_must_lie_inside_control_set():
    with pytest.raises(ValueError, match="must lie inside"):
        config(planning_v=(0.4, 1.5))
    with pytest.raises(ValueError, match="must lie inside"):
        config(planning_omega_max=3.0)


def _rot(theta, v):
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _error(xv, xr):
    p = _rot(-xv[2], xr[:2] - xv[:2])
    return jnp.array([p[0], p[1], wrap_angle(xr[2] - xv[2])])


def _f(x, u, w):
    return jnp.array([u[0] * jnp.cos(x[2]) + w[0], u[0] * jnp.sin(x[2]) + w[1], u[1]])


@functools.partial(jax.jit, static_argnames=("mode", "n_steps"))
def _track(key, value, mode, n_steps, dt=0.005):
    """Max position error over a run. mode: 'random' (random reference, random wind), 'worst_wind' (random
    reference, HJ worst-case wind), 'adversarial' (HJ worst-case reference and wind)."""
    cfg = config()
    grid, dyn = cfg.grid, cfg.error_dynamics
    grads = hj.interpolation.gradient_field(grid, -value)  # the solver's W = -V
    lo, hi = cfg.planning_v

    def inputs(key, xv, xr, u_ref):
        e = _error(xv, xr)
        p = hj.interpolation.interpolate_gradient(grid, grads, e)
        ex, pp = (e[0], e[1], e[2]), (p[0], p[1], p[2])
        u = jnp.stack(dyn.optimal_control(ex, pp))
        d = jnp.stack(dyn.optimal_disturbance(ex, pp))  # (v_r, omega_r, w_x, w_y), wind in vehicle frame
        if mode == "random":
            ang = jax.random.uniform(key, (), minval=-jnp.pi, maxval=jnp.pi)
            w = VEHICLE.wind * jnp.sqrt(jax.random.uniform(jax.random.fold_in(key, 1))) * jnp.array(
                [jnp.cos(ang), jnp.sin(ang)])
        else:
            # The error dynamics see -(vehicle wind) rotated into the vehicle frame.
            w = -_rot(xv[2], d[2:4])
        ur = d[:2] if mode == "adversarial" else u_ref
        return u, ur, w

    def step(carry, k):
        xv, xr, u_ref, emax, key = carry
        key, k1, k2 = jax.random.split(key, 3)
        # Reference controls change every 0.5 s (random modes).
        new_ref = jnp.array([jax.random.uniform(k1, (), minval=lo, maxval=hi),
                             jax.random.uniform(k2, (), minval=-cfg.planning_omega_max,
                                                maxval=cfg.planning_omega_max)])
        u_ref = jnp.where(k % 100 == 0, new_ref, u_ref)
        u, ur, w = inputs(key, xv, xr, u_ref)
        xv_m, xr_m = xv + 0.5 * dt * _f(xv, u, w), xr + 0.5 * dt * _f(xr, ur, jnp.zeros(2))
        u, ur, w = inputs(key, xv_m, xr_m, u_ref)
        xv, xr = xv + dt * _f(xv_m, u, w), xr + dt * _f(xr_m, ur, jnp.zeros(2))
        emax = jnp.maximum(emax, jnp.linalg.norm(xv[:2] - xr[:2]))
        return (xv, xr, u_ref, emax, key), None

    x0 = jnp.array([0.0, 0.0, 0.3])
    carry = (x0, x0, jnp.array([lo, 0.0]), 0.0, key)
    (_, _, _, emax, _), _ = jax.lax.scan(step, carry, jnp.arange(n_steps))
    return emax


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["random", "worst_wind", "adversarial"])
def test_tracker_keeps_error_within_bound(bound, mode):
    value = jnp.asarray(bound.value, jnp.float32)
    keys = jax.random.split(jax.random.key(7), 16)
    emax = np.asarray(jax.vmap(lambda k: _track(k, value, mode, 4000))(keys))  # 20 s each
    dx = bound.config.grid.spacing[0]
    # Half a cell of slack: the controller reads an interpolated gradient of a grid value function.
    assert emax.max() <= bound.bound + 0.5 * dx, (mode, emax.max(), bound.bound)
    if mode == "adversarial":
        # The worst case pushes the error to a sizeable fraction of the bound (the bound is not vacuous).
        assert emax.max() >= 0.5 * bound.bound


@pytest.mark.slow
def test_default_bound_matches_the_beacls_figure_and_a_coarser_solve(tmp_path):
    # BEACLS paper Section III: U = [0, 25] m/s x |omega| <= 2, U^p = [11, 13] m/s x |omega| <= 1.2, wind 6 m/s
    # gives "about 5 m". The bound is read after the game's transient (see the module docstring), which adds a few
    # tenths of a metre of grid-dependent creep. Accept 5 m +/- 1.5 m on both grids.
    # The default grid (1/3 m cells) is a 5-minute solve on 2 cores: it ships (stp_env/data/artifacts, read by every
    # other test and a first `stp-env evaluate`), and `stp-env data artifacts --recompute` checks that the
    # shipped copy is what this code computes. Here the same game is solved from scratch on 2/3 m cells (measured:
    # 6.08 m against 5.34 m shipped; 6.30 m on 1/2 m cells, whose solve creeps on to 88 s) and the shipped bound
    # must agree with it to within two of its cells: a shipped bound of another game (the tracking bound was once
    # 2.5x too small at 11 m/s) fails here; a copy computed by other code fails tests/test_artifacts.py.
    import dataclasses

    from stp_env.artifacts import SHIPPED_DIR, ArtifactStore

    default = TrackingConfig()
    shipped = ArtifactStore(tmp_path / "empty", shipped=SHIPPED_DIR).load("tracking_bound", default)
    assert shipped is not None, "the default tracking bound does not ship: run stp-env data artifacts"
    shipped_bound = compute_tracking_bound(default, store=ArtifactStore(tmp_path / "empty", shipped=SHIPPED_DIR),
                                           progress=False)
    assert shipped_bound.converged and 3.5 <= shipped_bound.bound <= 6.5, shipped_bound.bound
    coarse_cfg = dataclasses.replace(default, grid_points=(31, 31, 30), certify=False)
    coarse = compute_tracking_bound(coarse_cfg, store=ArtifactStore(tmp_path / "coarse", shipped=None), progress=False)
    assert coarse.converged
    assert 3.5 <= coarse.bound <= 6.5, coarse.bound
    dx = coarse_cfg.grid.spacing[0]
    assert abs(coarse.bound - shipped_bound.bound) <= 2 * dx, (coarse.bound, shipped_bound.bound)
