"""Closed-loop (state-feedback, time-varying) dynamics in the solver: :class:`stp_env.hj.FeedbackDynamics`.

Closed form: a holonomic point under the rotating feedback ``u = omega(t) (-y, x)`` (``omega`` a table over time,
passed as ``dynamics_params``) and a disturbance ``||d|| <= a``. The flow is a rotation by
``Theta(t) = int_0^t omega``; the disturbance adds a ball of radius ``a t`` (a rotation maps the ball onto itself),
so the forward reachable set of a disk ``|x - c| <= r`` is the disk of radius ``r + a t`` around
``R(Theta(t)) c`` (SPP paper eqs. 14-17 with this package's sign convention: covering every disturbance forward
is ``"max"``); with the disturbance minimising, it shrinks to radius ``r - a t``.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.hj.sets import Ball, Box, ProductSet
from stp_env.hj.solver import _advance

GRID = hj.Grid.from_bounds((-1.5, -1.5), (1.5, 1.5), (61, 61))  # dx = 0.05
DX = GRID.spacing[0]


@dataclasses.dataclass(frozen=True, kw_only=True)
class Holonomic(hj.ControlAffineDynamics):
    """``dx/dt = u + d``, ``u`` in a box, ``||d|| <= wind``."""

    u_max: float = 2.0
    wind: float = 0.2

    @property
    def state_dim(self):
        return 2

    @property
    def control_space(self):
        return ProductSet((Box((-self.u_max, -self.u_max), (self.u_max, self.u_max)),))

    @property
    def disturbance_space(self):
        return ProductSet((Ball((0.0, 0.0), self.wind),))

    def open_loop(self, x):
        return (0.0, 0.0)

    def control_jacobian(self, x):
        return ((1.0, 0.0), (0.0, 1.0))

    def disturbance_jacobian(self, x):
        return ((1.0, 0.0), (0.0, 1.0))


def rotation_feedback(t, x, params):
    """``u = omega(t) (-y, x)`` with ``omega`` linear between ``params["times"]``."""
    w = jnp.interp(t, params["times"], params["omega"])
    return (-w * x[1], w * x[0])


@dataclasses.dataclass
class UnhashableFeedback:
    """A mutable dataclass: equality without a hash."""

    def __call__(self, t, x, params):
        return (0.0 * x[0], 0.0 * x[1])


def _theta(times, omega, t):
    ts = np.linspace(0.0, t, 2001)
    return float(np.trapezoid(np.interp(ts, times, omega), ts))


def _front_radius(values, center):
    """Zero crossings of ``values`` along 16 rays from ``center`` (linear between samples)."""
    out = []
    for ang in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        s = np.linspace(0.0, 0.9, 400)
        pts = np.stack([center[0] + s * np.cos(ang), center[1] + s * np.sin(ang)], -1)
        v = np.asarray([float(hj.interpolation.interpolate(GRID, values, jnp.asarray(p))) for p in pts[::8]])
        ss = s[::8]
        k = int(np.nonzero(v > 0)[0][0])
        out.append(ss[k - 1] + (ss[k] - ss[k - 1]) * (-v[k - 1]) / (v[k] - v[k - 1]))
    return np.asarray(out)


@pytest.mark.slow
@pytest.mark.parametrize(("mode", "sign"), [("max", 1.0), ("min", -1.0)])
def test_rotating_feedback_frs_is_rotated_grown_disk(mode, sign):
    c0, r, a, T = np.array([0.8, 0.0]), 0.35, 0.2, 1.0
    table = {"times": jnp.asarray([0.0, 0.5, 1.0]), "omega": jnp.asarray([0.5, 1.5, 1.0])}
    dyn = hj.FeedbackDynamics(base=Holonomic(wind=a), feedback=rotation_feedback, disturbance_mode=mode)
    init = hj.shapes.ball(GRID, tuple(c0), r)
    res = hj.solve(hj.SolverSettings.with_accuracy("very_high"), dyn, GRID, [0.0, 0.5, T], init,
                   dynamics_params=table, progress=False)
    for k, t in enumerate((0.5, T)):
        th = _theta(np.asarray(table["times"]), np.asarray(table["omega"]), t)
        centre = np.array([np.cos(th) * c0[0] - np.sin(th) * c0[1], np.sin(th) * c0[0] + np.cos(th) * c0[1]])
        radius = _front_radius(res.values[k + 1], centre)
        # measured: |error| <= 0.015 dx growing ("max"), 0.08 dx shrinking ("min")
        assert np.all(np.abs(radius - (r + sign * a * t)) <= 0.15 * DX), (mode, t, (radius - r - sign * a * t) / DX)
    # The set has left its start (0.85 from the rotated centre, radius 0.55): the feedback moved it.
    assert float(hj.interpolation.interpolate(GRID, res.values[-1], jnp.asarray(c0))) > 0.2


def test_new_tables_reuse_the_compiled_loop():
    dyn = hj.FeedbackDynamics(base=Holonomic(), feedback=rotation_feedback)
    init = hj.shapes.ball(GRID, (0.8, 0.0), 0.3)
    settings = hj.SolverSettings.with_accuracy("low")
    outs = []
    for omega in ([1.0, 1.0, 1.0], [-1.0, 0.0, 1.0]):
        table = {"times": jnp.asarray([0.0, 0.5, 1.0]), "omega": jnp.asarray(omega)}
        res = hj.solve(settings, dyn, GRID, [0.0, 0.2], init, dynamics_params=table, progress=False)
        if not outs:
            size = _advance._cache_size()
        outs.append(res.values[-1])
    assert _advance._cache_size() == size  # the second table did not compile a new loop
    assert float(jnp.max(jnp.abs(outs[0] - outs[1]))) > 0.05  # ... and was used


def test_feedback_dynamics_input_checks():
    with pytest.raises(TypeError, match="hashable"):
        hj.FeedbackDynamics(base=Holonomic(), feedback=UnhashableFeedback())
    with pytest.raises(TypeError, match="open-loop"):
        inner = hj.FeedbackDynamics(base=Holonomic(), feedback=rotation_feedback)
        hj.FeedbackDynamics(base=inner, feedback=rotation_feedback)
    dyn = hj.FeedbackDynamics(base=Holonomic(), feedback=rotation_feedback)
    with pytest.raises(TypeError, match="time-varying"):
        dyn.hamiltonian((0.0, 0.0), (1.0, 0.0))
    # The closed-loop field is the base field at the feedback control.
    table = {"times": jnp.asarray([0.0, 1.0]), "omega": jnp.asarray([2.0, 2.0])}
    f = dyn.closed_loop(0.3, (0.5, 0.25), table, d=(0.1, 0.0))
    np.testing.assert_allclose([float(f[0]), float(f[1])], [-0.5 + 0.1, 1.0], atol=1e-6)
