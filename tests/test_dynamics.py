"""Dynamics: closed-form Hamiltonians and optimal inputs against brute force, partial bounds, the relative
dynamics (intruder paper eq. 44) against two simulated vehicles, and input checks.

The reference formulas here are written out independently in numpy float64 from the papers' equations; the
library evaluates in float32, so comparisons allow float32 round-off relative to the size of the terms.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stp_env import hj
from stp_env.dynamics import DubinsWind, RelativeDubins, SingleIntegrator, tracking_error_dynamics

N_ANGLES = 720  # samples of a disk's boundary: the sampled support is short by at most r |q| (1 - cos(pi/720))
BALL_GAP = 1.0 - math.cos(math.pi / N_ANGLES)  # 9.5e-6
F32 = 4e-6  # relative float32 round-off allowance (a few ulps of the larger terms)


# ------------------------------------------------------------------------------- independent references
def f_dubins(x, u, d, heading):
    """Intruder paper eq. 43 (SPP eq. 28 with heading disturbance): (v cos th + dx, v sin th + dy, w + dth)."""
    v, om = u
    dx, dy = d[0], d[1]
    dth = d[2] if heading else 0.0
    return (v * np.cos(x[2]) + dx, v * np.sin(x[2]) + dy, om + dth)


def f_relative(x, u, d, wind, own_heading, other_heading):
    """Intruder paper eq. 44 (second line with v_o, as derived from R(-theta_i)(p_o - p_i)); vehicle i's own
    heading disturbance turns its frame like omega_i."""
    vi, wi = u
    vo, wo = d[0], d[1]
    k = 2
    wx = wy = 0.0
    if wind:
        wx, wy = d[2], d[3]
        k = 4
    dth_i = d[k] if own_heading else 0.0
    k += 1 if own_heading else 0
    dth_o = d[k] if other_heading else 0.0
    turn = wi + dth_i
    return (-vi + turn * x[1] + vo * np.cos(x[2]) + wx,
            -turn * x[0] + vo * np.sin(x[2]) + wy,
            wo + dth_o - turn)


def box_samples(lo, hi, levels=5):
    """A tensor grid over the box, vertices included (a linear function's extremes are at vertices)."""
    axes = [np.linspace(a, b, levels) for a, b in zip(lo, hi)]
    return [m.ravel() for m in np.meshgrid(*axes, indexing="ij")]


def disk_samples(radius, n=N_ANGLES):
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    rr = np.concatenate([radius * np.ones(n), 0.5 * radius * np.ones(n), [0.0]])
    aa = np.concatenate([ang, ang, [0.0]])
    return [rr * np.cos(aa), rr * np.sin(aa)]


def product(*blocks):
    """Cartesian product of sample sets (each a list of equal-length component arrays)."""
    out = None
    for comps in blocks:
        m = len(comps[0])
        if out is None:
            out = [c.copy() for c in comps]
            continue
        n = len(out[0])
        out = [np.repeat(c, m) for c in out] + [np.tile(c, n) for c in comps]
    return out


def dubins_inputs(dyn: DubinsWind):
    u = box_samples((dyn.v_min, -dyn.omega_max), (dyn.v_max, dyn.omega_max))
    blocks = [disk_samples(dyn.wind)]
    if dyn.heading_disturbance > 0:
        blocks.append([np.array([-dyn.heading_disturbance, 0.0, dyn.heading_disturbance])])
    return u, product(*blocks)


def relative_inputs(dyn: RelativeDubins):
    u = box_samples((dyn.v_min, -dyn.omega_max), (dyn.v_max, dyn.omega_max))
    blocks = [box_samples((dyn.other_v_min, -dyn.other_omega_max), (dyn.other_v_max, dyn.other_omega_max), 3)]
    if dyn.wind > 0:
        blocks.append(disk_samples(dyn.wind))
    for bound in (dyn.own_heading_disturbance, dyn.other_heading_disturbance):
        if bound > 0:
            blocks.append([np.array([-bound, bound])])
    return u, product(*blocks)


def reference_f(dyn, x, u, d):
    if isinstance(dyn, DubinsWind):
        return f_dubins(x, u, d, dyn.heading_disturbance > 0)
    return f_relative(x, u, d, dyn.wind > 0, dyn.own_heading_disturbance > 0, dyn.other_heading_disturbance > 0)


def brute_force_hamiltonian(dyn, x, p):
    """opt_u opt_d p . f over sampled inputs, joint table (u rows, d columns); both orders of optimisation."""
    u, d = dubins_inputs(dyn) if isinstance(dyn, DubinsWind) else relative_inputs(dyn)
    uu = [c[:, None] for c in u]
    dd = [c[None, :] for c in d]
    f = reference_f(dyn, x, uu, dd)
    table = sum(pi * np.broadcast_to(fi, (len(u[0]), len(d[0]))) for pi, fi in zip(p, f))
    opt = {"min": np.min, "max": np.max}
    inner_d = opt[dyn.disturbance_mode](table, axis=1)
    h_ud = opt[dyn.control_mode](inner_d)
    h_du = opt[dyn.disturbance_mode](opt[dyn.control_mode](table, axis=0))
    return h_ud, h_du, table, u, d


def bounds_of_f(dyn, x):
    """Crude magnitudes of each f_i (for float32 tolerances)."""
    if isinstance(dyn, DubinsWind):
        return np.array([dyn.v_max + dyn.wind, dyn.v_max + dyn.wind, dyn.omega_max + dyn.heading_disturbance])
    turn = dyn.omega_max + dyn.own_heading_disturbance
    return np.array([dyn.v_max + turn * abs(x[1]) + dyn.other_v_max + dyn.wind,
                     turn * abs(x[0]) + dyn.other_v_max + dyn.wind,
                     turn + dyn.other_omega_max + dyn.other_heading_disturbance])


def ball_radii_times_q(dyn, x, p):
    """r |q| of the wind disk (both models: the wind acts on p_x, p_y); the brute force's possible shortfall is
    this times BALL_GAP."""
    return dyn.wind * math.hypot(p[0], p[1])


DUBINS_CASES = [
    DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=6.0),
    DubinsWind(v_min=5.0, v_max=12.0, omega_max=0.7, wind=2.5, heading_disturbance=0.3),
]
RELATIVE_CASES = [
    RelativeDubins(),
    RelativeDubins(v_min=3.0, v_max=9.0, omega_max=1.2, other_v_min=2.0, other_v_max=15.0, other_omega_max=0.4,
                   wind=4.0, own_heading_disturbance=0.1, other_heading_disturbance=0.15),
    RelativeDubins(v_min=5.0, v_max=5.0, omega_max=1.0, other_v_min=5.0, other_v_max=5.0, other_omega_max=1.0,
                   wind=0.0),  # Air3D: no wind block, degenerate speed boxes
]
MODES = [("min", "max"), ("max", "min"), ("min", "min"), ("max", "max")]


def random_state_and_costate(rng, relative):
    scale = 40.0 if relative else 100.0
    x = (rng.uniform(-scale, scale), rng.uniform(-scale, scale), rng.uniform(-math.pi, math.pi))
    p = rng.normal(size=3)
    kind = rng.integers(0, 5)
    if kind == 1:
        p[0] = p[1] = 0.0  # no position gradient: speed and wind choices are ties
    elif kind == 2:
        p[2] = 0.0  # no heading gradient
    return x, p


@pytest.mark.parametrize("modes", MODES, ids=lambda m: f"u_{m[0]}-d_{m[1]}")
@pytest.mark.parametrize("base", DUBINS_CASES + RELATIVE_CASES,
                         ids=["dubins", "dubins_heading", "relative", "relative_heading", "air3d"])
def test_hamiltonian_and_optimal_inputs_match_brute_force(base, modes):
    dyn = base.with_modes(*modes)
    relative = isinstance(dyn, RelativeDubins)
    rng = np.random.default_rng(1234)
    for _ in range(12):
        x, p = random_state_and_costate(rng, relative)
        xs = tuple(jnp.float32(v) for v in x)
        ps = tuple(jnp.float32(v) for v in p)
        h = float(dyn.hamiltonian(xs, ps))
        h_ud, h_du, _, _, _ = brute_force_hamiltonian(dyn, x, p)
        scale = float(np.abs(p) @ bounds_of_f(dyn, x))
        gap = ball_radii_times_q(dyn, x, p) * BALL_GAP
        assert h_ud == pytest.approx(h_du, abs=1e-9 * scale)  # separable: Isaacs' condition holds
        # The sampled optimum is within the disk sampling gap of the true one, on the side given by the roles.
        assert abs(h - h_ud) <= gap + F32 * scale, (h, h_ud, gap)
        # The closed-form inputs lie in their sets and realise the Hamiltonian.
        u = tuple(float(c) for c in dyn.optimal_control(xs, ps))
        d = tuple(float(c) for c in dyn.optimal_disturbance(xs, ps))
        assert bool(dyn.control_space.contains(u, atol=1e-5))
        assert bool(dyn.disturbance_space.contains(d, atol=1e-5))
        value = float(np.dot(p, reference_f(dyn, x, u, d)))
        assert value == pytest.approx(h, abs=F32 * scale)
        # ... and the library's own f at those inputs agrees with the reference formulas.
        f_lib = np.array([float(c) for c in dyn(xs, u, d)])
        np.testing.assert_allclose(f_lib, reference_f(dyn, x, u, d), atol=F32 * bounds_of_f(dyn, x).max())


@pytest.mark.parametrize("base", DUBINS_CASES + RELATIVE_CASES,
                         ids=["dubins", "dubins_heading", "relative", "relative_heading", "air3d"])
def test_optimal_inputs_are_optimal_against_every_sample(base):
    """Saddle point: with u* fixed, no sampled d does better for the disturbance than d*, and vice versa."""
    dyn = base  # default roles
    rng = np.random.default_rng(99)
    sign_u = 1.0 if dyn.control_mode == "max" else -1.0
    sign_d = 1.0 if dyn.disturbance_mode == "max" else -1.0
    for _ in range(8):
        x, p = random_state_and_costate(rng, isinstance(dyn, RelativeDubins))
        xs, ps = tuple(jnp.float32(v) for v in x), tuple(jnp.float32(v) for v in p)
        u_star = tuple(float(c) for c in dyn.optimal_control(xs, ps))
        d_star = tuple(float(c) for c in dyn.optimal_disturbance(xs, ps))
        _, _, _, us, ds = brute_force_hamiltonian(dyn, x, p)
        scale = float(np.abs(p) @ bounds_of_f(dyn, x))
        star = float(np.dot(p, reference_f(dyn, x, u_star, d_star)))
        vs_d = sum(pi * np.asarray(fi) for pi, fi in zip(p, reference_f(dyn, x, u_star, ds)))
        vs_u = sum(pi * np.asarray(fi) for pi, fi in zip(p, reference_f(dyn, x, us, d_star)))
        assert np.all(sign_d * (vs_d - star) <= F32 * scale)
        assert np.all(sign_u * (vs_u - star) <= F32 * scale)


def test_mode_flip_symmetry_and_single_integrator():
    dyn = RelativeDubins(wind=3.0, own_heading_disturbance=0.1, other_heading_disturbance=0.05)
    flipped = dyn.with_modes(control_mode="min", disturbance_mode="max")
    rng = np.random.default_rng(5)
    for _ in range(5):
        x, p = random_state_and_costate(rng, True)
        xs = tuple(jnp.float32(v) for v in x)
        h = float(dyn.hamiltonian(xs, tuple(jnp.float32(v) for v in p)))
        h_neg = float(flipped.hamiltonian(xs, tuple(jnp.float32(-v) for v in p)))
        assert h == pytest.approx(-h_neg, abs=F32 * float(np.abs(p) @ bounds_of_f(dyn, x)))
    si = SingleIntegrator(dim=3, speed=2.0, drift=(0.5, -1.0, 0.0))
    p = (jnp.float32(0.3), jnp.float32(-0.4), jnp.float32(1.2))
    norm = math.sqrt(0.09 + 0.16 + 1.44)
    assert float(si.hamiltonian((0.0, 0.0, 0.0), p)) == pytest.approx(0.15 + 0.4 - 2.0 * norm, rel=1e-6)
    u = np.array([float(c) for c in si.optimal_control((0.0, 0.0, 0.0), p)])
    np.testing.assert_allclose(u, -2.0 * np.array([0.3, -0.4, 1.2]) / norm, rtol=1e-6)
    assert si.optimal_disturbance((0.0, 0.0, 0.0), p) == ()
    # A zero gradient: the ball's maximiser is its centre (no NaN from 0 / 0).
    u0 = [float(c) for c in si.optimal_control((0.0, 0.0, 0.0), (jnp.float32(0.0),) * 3)]
    assert u0 == [0.0, 0.0, 0.0]


@pytest.mark.slow
def test_grid_evaluation_matches_pointwise():
    """Structure-of-arrays evaluation on broadcast grid states equals evaluation at single states."""
    grid = hj.Grid.from_bounds((-20.0, -10.0, -math.pi), (20.0, 10.0, math.pi), (5, 4, 6), periodic=2)
    dyn = RelativeDubins(wind=3.0, own_heading_disturbance=0.1, other_heading_disturbance=0.05)
    rng = np.random.default_rng(0)
    p = tuple(jnp.asarray(rng.normal(size=grid.shape), jnp.float32) for _ in range(3))
    states = grid.broadcast_states()
    h = np.asarray(jnp.broadcast_to(dyn.hamiltonian(states, p), grid.shape))
    alpha = [np.asarray(jnp.broadcast_to(a, grid.shape)) for a in dyn.partial_bounds(states)]
    full = np.asarray(grid.states())
    for idx in [(0, 0, 0), (4, 3, 5), (2, 1, 3), (1, 2, 0)]:
        xs = tuple(jnp.float32(v) for v in full[idx])
        ps = tuple(pi[idx] for pi in p)
        assert h[idx] == pytest.approx(float(dyn.hamiltonian(xs, ps)), rel=1e-5, abs=1e-4)
        for i in range(3):
            assert alpha[i][idx] == pytest.approx(float(dyn.partial_bounds(xs)[i]), rel=1e-6)


# ------------------------------------------------------------------------------- partial bounds
@pytest.mark.parametrize("dyn", DUBINS_CASES + RELATIVE_CASES,
                         ids=["dubins", "dubins_heading", "relative", "relative_heading", "air3d"])
def test_partial_bounds_cover_and_are_tight(dyn):
    """alpha_i(x) >= |f_i(x, u, d)| for every sampled input, and the sampled maximum nearly attains it
    (products of boxes and balls: the bound is exact)."""
    rng = np.random.default_rng(7)
    u, d = dubins_inputs(dyn) if isinstance(dyn, DubinsWind) else relative_inputs(dyn)
    uu = [c[:, None] for c in u]
    dd = [c[None, :] for c in d]
    for _ in range(10):
        x, _ = random_state_and_costate(rng, isinstance(dyn, RelativeDubins))
        alpha = np.array([float(a) for a in dyn.partial_bounds(tuple(jnp.float32(v) for v in x))])
        f = reference_f(dyn, x, uu, dd)
        tol = F32 * bounds_of_f(dyn, x)
        for i in range(3):
            sampled = float(np.max(np.abs(f[i])))
            assert sampled <= alpha[i] + tol[i], (i, sampled, alpha[i])
            assert sampled >= alpha[i] - dyn.wind * BALL_GAP - tol[i], (i, sampled, alpha[i])


# ------------------------------------------------------------------------------- eq. 44 from two vehicles
def _rk4(state, inputs, h):
    """One RK4 step of a Dubins vehicle in wind: state (px, py, th), inputs (v, om, wx, wy, dth)."""
    v, om, wx, wy, dth = inputs

    def f(s):
        return np.array([v * math.cos(s[2]) + wx, v * math.sin(s[2]) + wy, om + dth])

    k1 = f(state)
    k2 = f(state + 0.5 * h * k1)
    k3 = f(state + 0.5 * h * k2)
    k4 = f(state + h * k3)
    return state + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def _relative(si, so):
    c, s = math.cos(si[2]), math.sin(si[2])
    dx, dy = so[0] - si[0], so[1] - si[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, so[2] - si[2]])


def _two_vehicle_samples(dyn, wind_i, wind_o, heading_i, heading_o, n, seed):
    """Random absolute states and inputs of two Dubins vehicles, the finite-difference time derivative of their
    relative state, and the matching relative state and inputs of ``dyn``. Central differences of RK4 steps,
    h = 1e-4: truncation ~h^2/6 |d^3 r/dt^3| < 1e-7 here, round-off ~1e-16 * 100 / h = 1e-10."""
    rng = np.random.default_rng(seed)
    h = 1e-4
    for _ in range(n):
        si = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-math.pi, math.pi)])
        so = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-math.pi, math.pi)])
        vi, oi = rng.uniform(dyn.v_min, dyn.v_max), rng.uniform(-dyn.omega_max, dyn.omega_max)
        vo = rng.uniform(dyn.other_v_min, dyn.other_v_max)
        oo = rng.uniform(-dyn.other_omega_max, dyn.other_omega_max)
        a_i, a_o = rng.uniform(0, 2 * math.pi, 2)
        wi = rng.uniform(0, wind_i) * np.array([math.cos(a_i), math.sin(a_i)])
        wo = rng.uniform(0, wind_o) * np.array([math.cos(a_o), math.sin(a_o)])
        hi_ = rng.uniform(-heading_i, heading_i)
        ho_ = rng.uniform(-heading_o, heading_o)
        in_i = (vi, oi, wi[0], wi[1], hi_)
        in_o = (vo, oo, wo[0], wo[1], ho_)
        fwd = _relative(_rk4(si, in_i, h), _rk4(so, in_o, h))
        bwd = _relative(_rk4(si, in_i, -h), _rk4(so, in_o, -h))
        fd = (fwd - bwd) / (2 * h)
        x_rel = _relative(si, so)
        c, s = math.cos(si[2]), math.sin(si[2])
        dw = wo - wi
        w_rel = (c * dw[0] + s * dw[1], -s * dw[0] + c * dw[1])
        d = ([vo, oo, *w_rel] + ([hi_] if dyn.own_heading_disturbance > 0 else [])
             + ([ho_] if dyn.other_heading_disturbance > 0 else []))
        yield x_rel, (vi, oi), tuple(d), fd, hi_


def test_relative_dubins_matches_two_simulated_vehicles():
    """d/dt of (R(-theta_i)(p_o - p_i), theta_o - theta_i) for two Dubins vehicles in independent winds equals
    RelativeDubins.__call__ with control (v_i, omega_i) and disturbance (v_o, omega_o, R(-theta_i)(w_o - w_i)),
    and that disturbance lies in the model's set (the combined wind disk). This checks eq. 44 independently,
    including its second line (v_o sin theta, not v_i sin theta as printed)."""
    wind_i, wind_o = 3.0, 5.0
    dyn = RelativeDubins(v_min=4.0, v_max=20.0, omega_max=1.5, other_v_min=2.0, other_v_max=25.0,
                         other_omega_max=0.8, wind=wind_i + wind_o)
    for x_rel, u, d, fd, _ in _two_vehicle_samples(dyn, wind_i, wind_o, 0.0, 0.0, 20, 2024):
        assert bool(dyn.disturbance_space.contains(d, atol=1e-9))
        assert bool(dyn.control_space.contains(u, atol=1e-9))
        np.testing.assert_allclose(reference_f(dyn, x_rel, u, d), fd, rtol=1e-6, atol=1e-6)
        model = np.array([float(v) for v in dyn(tuple(jnp.float32(v) for v in x_rel), u, d)])
        np.testing.assert_allclose(model, fd, rtol=1e-5, atol=F32 * bounds_of_f(dyn, x_rel).max())


HEADING_DYN = RelativeDubins(v_min=4.0, v_max=20.0, omega_max=1.5, other_v_min=2.0, other_v_max=25.0,
                             other_omega_max=0.8, wind=8.0, own_heading_disturbance=0.25,
                             other_heading_disturbance=0.25)


def test_relative_dubins_with_heading_disturbance_matches_two_simulated_vehicles():
    """With heading-rate disturbances theta_i' = omega_i + dth_i, vehicle i's frame turns at omega_i + dth_i:
    the model's own-heading column (p_y, -p_x, -1) must reproduce the simulated derivative exactly."""
    dyn = HEADING_DYN
    for x_rel, u, d, fd, _ in _two_vehicle_samples(dyn, 3.0, 5.0, 0.25, 0.25, 10, 7):
        assert bool(dyn.disturbance_space.contains(d, atol=1e-9))
        np.testing.assert_allclose(reference_f(dyn, x_rel, u, d), fd, rtol=1e-6, atol=1e-6)
        model = np.array([float(v) for v in dyn(tuple(jnp.float32(v) for v in x_rel), u, d)])
        np.testing.assert_allclose(model, fd, rtol=1e-5, atol=F32 * bounds_of_f(dyn, x_rel).max())


def test_dubins_wind_call_matches_simulation():
    dyn = DubinsWind(v_min=1.0, v_max=10.0, omega_max=1.0, wind=2.0, heading_disturbance=0.2)
    s0 = np.array([3.0, -4.0, 2.5])
    inputs = (7.0, -0.6, 1.2, -0.9, 0.1)
    fd = (_rk4(s0, inputs, 1e-3) - _rk4(s0, inputs, -1e-3)) / 2e-3
    model = np.array([float(v) for v in dyn(tuple(jnp.float32(v) for v in s0), inputs[:2], inputs[2:])])
    np.testing.assert_allclose(model, fd, rtol=1e-5, atol=1e-5)
    # Without a disturbance argument the disturbance is zero.
    still = np.array([float(v) for v in dyn(tuple(jnp.float32(v) for v in s0), inputs[:2])])
    np.testing.assert_allclose(still, [7 * math.cos(2.5), 7 * math.sin(2.5), -0.6], rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------------------- sets (Box, Ball)
@given(st.integers(1, 3), st.integers(0, 2**31 - 1))
def test_box_and_ball_support_and_argmax_match_brute_force(k, seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-3, 1, k)
    hi = lo + rng.uniform(0, 4, k)
    box = hj.Box(tuple(lo), tuple(hi))
    center = rng.uniform(-2, 2, k)
    radius = float(rng.uniform(0, 3))
    ball = hj.Ball(tuple(center), radius)
    q = rng.normal(size=k)
    if rng.integers(0, 4) == 0:
        q[0] = 0.0
    qs = tuple(jnp.float32(v) for v in q)
    # Box: vertices attain the maximum of a linear function.
    verts = np.array(np.meshgrid(*[[a, b] for a, b in zip(lo, hi)], indexing="ij")).reshape(k, -1)
    brute = float(np.max(q @ verts))
    assert float(box.support(qs)) == pytest.approx(brute, abs=F32 * (1 + np.abs(q) @ np.abs(verts).max(1)))
    arg = np.array([float(a) for a in box.argmax(qs)])
    assert float(q @ arg) == pytest.approx(brute, abs=1e-5 * (1 + np.abs(q).sum() * np.abs(verts).max()))
    # Ball: directions on a fine sphere sampling (k <= 3).
    if k == 1:
        dirs = np.array([[-1.0, 1.0]])
        gap = 0.0
    elif k == 2:
        ang = np.linspace(0.0, 2 * np.pi, 2000, endpoint=False)
        dirs = np.stack([np.cos(ang), np.sin(ang)])
        gap = 1.0 - math.cos(math.pi / 2000)  # every direction is within half a sample spacing of a sample
    else:
        g = np.random.default_rng(0).normal(size=(k, 20000))
        dirs = g / np.linalg.norm(g, axis=0)
        gap = 1.0 - math.cos(0.25)  # a generous covering radius for 20000 random directions (typically ~0.05)
    pts = center[:, None] + radius * dirs
    brute = float(np.max(q @ pts))
    support = float(ball.support(qs))
    qn = float(np.linalg.norm(q))
    assert brute <= support + F32 * (1 + qn * (np.abs(center).max() + radius) * k)
    assert support <= brute + radius * qn * gap + F32 * (1 + qn * (np.abs(center).max() + radius) * k)
    arg = np.array([float(a) for a in ball.argmax(qs)])
    assert np.linalg.norm(arg - center) <= radius * (1 + 1e-6) + 1e-6
    assert float(q @ arg) == pytest.approx(support, abs=1e-5 * (1 + qn * (np.abs(center).max() + radius)))
    # min is -max of -q.
    prod = hj.ProductSet((box, ball))
    both = qs + qs
    assert float(prod.optimum(both, "min")) == pytest.approx(
        -float(box.support(tuple(-v for v in qs))) - float(ball.support(tuple(-v for v in qs))), rel=1e-6,
        abs=1e-6)


# ------------------------------------------------------------------------------- construction checks
def test_tracking_error_dynamics_accepts_subsets_and_rejects_others():
    vehicle = DubinsWind(v_min=5.0, v_max=20.0, omega_max=1.0, wind=4.0, heading_disturbance=0.1)
    te = tracking_error_dynamics(vehicle, (8.0, 15.0), 0.5)
    assert isinstance(te, RelativeDubins)
    assert (te.v_min, te.v_max, te.omega_max) == (5.0, 20.0, 1.0)
    assert (te.other_v_min, te.other_v_max, te.other_omega_max) == (8.0, 15.0, 0.5)
    # The reference has no wind and no heading disturbance; the vehicle's own turns its frame.
    assert te.wind == 4.0 and te.own_heading_disturbance == 0.1 and te.other_heading_disturbance == 0.0
    assert (te.control_mode, te.disturbance_mode) == ("max", "min")
    tracking_error_dynamics(vehicle, (5.0, 20.0), 1.0)  # U^p = U is allowed
    for v, om in [((4.0, 15.0), 0.5), ((8.0, 21.0), 0.5), ((15.0, 8.0), 0.5), ((8.0, 15.0), 1.5),
                  ((8.0, 15.0), -0.1)]:
        with pytest.raises(ValueError, match=r"U\^p = .* must lie inside\s+U = \[5.0, 20.0\]"):
            tracking_error_dynamics(vehicle, v, om)


@pytest.mark.parametrize(
    ("factory", "pattern"),
    [
        (lambda: DubinsWind(v_min=10.0, v_max=5.0), "speed lower bound 10.0 exceeds upper bound 5.0"),
        (lambda: DubinsWind(v_min=-1.0), "speed must be >= 0"),
        (lambda: DubinsWind(v_max=float("inf")), "speed bounds must be finite"),
        (lambda: DubinsWind(wind=-1.0), "wind must be a finite number >= 0"),
        (lambda: DubinsWind(omega_max=float("nan")), "omega_max must be a finite number >= 0"),
        (lambda: DubinsWind(heading_disturbance=-0.1), "heading_disturbance must be a finite number >= 0"),
        (lambda: RelativeDubins(other_v_min=3.0, other_v_max=2.0), "other speed lower bound"),
        (lambda: RelativeDubins(other_omega_max=-1.0), "other_omega_max must be a finite number >= 0"),
        (lambda: SingleIntegrator(dim=0), "dim must be >= 1"),
        (lambda: SingleIntegrator(dim=2, drift=(1.0,)), "drift must have 2 components"),
        (lambda: SingleIntegrator(speed=-1.0), "speed must be a finite number >= 0"),
        (lambda: DubinsWind(control_mode="reach"), "control_mode must be 'min' or 'max'"),
    ],
)
def test_bad_dynamics_parameters(factory, pattern):
    with pytest.raises(ValueError, match=pattern):
        factory()


def test_dynamics_are_hashable_and_frozen():
    a, b = DubinsWind(wind=3.0), DubinsWind(wind=3.0)
    assert a == b and hash(a) == hash(b)
    assert a.with_modes(control_mode="max") != a
    assert a.with_modes(control_mode="max").with_modes(control_mode="min") == a
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.wind = 1.0  # type: ignore[misc]
    assert a.state_dim == 3 and a.control_space.dim == 2 and a.disturbance_space.dim == 2
    assert DubinsWind(heading_disturbance=0.1).disturbance_space.dim == 3
    assert RelativeDubins(wind=0.0).disturbance_space.dim == 2
    assert RelativeDubins(wind=1.0, own_heading_disturbance=0.1).disturbance_space.dim == 5
    both = RelativeDubins(wind=1.0, own_heading_disturbance=0.1, other_heading_disturbance=0.1)
    assert both.disturbance_space.dim == 6
