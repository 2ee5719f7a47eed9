"""Robust trajectory tracking (RTT): the tracking-error bound and the tracking controller.

SPP paper Section IV-C, eqs. (24)-(26). The tracking error ``e`` is the state of a virtual reference (moving with
the reduced planning controls ``U^p`` and no wind) relative to the vehicle, in the vehicle's body frame
(:func:`stp_env.dynamics.tracking_error_dynamics`). The reference and the wind play against the vehicle.

We compute the infinite-horizon value ``V(e) = sup_T`` of the largest future position error under optimal
play, ``V(e) = inf_kappa sup_{u_r, d} sup_{s >= 0} l(e(s))`` with ``l(e) = min(||e_p||, cap)``; every sub-level
set ``{V <= c}`` is robustly controlled-invariant (the set ``Omega`` of eqs. 24-26 for the error bound ``E = {||e_p||
<= c}``), and the smallest bound that tracking *from zero error* can guarantee is ``V(0)``. It is solved as the
tube of the negated problem (``W = -V``, ``W <- min(W, -l)`` every step, the vehicle maximising ``W``) until the
value stops changing. The cap keeps the value bounded at the inflow boundary (NUMERICS.md); the result is only
trusted if ``V(0)`` is well below the cap, which :func:`compute_tracking_bound` checks.

Stopping rule. With a max-over-time cost, the Lax-Friedrichs dissipation acts like a small noise, and the sup of a
noisy error over an unbounded horizon keeps growing: after the game's transient (a few seconds), ``V(0)`` creeps
up at a rate that falls with grid refinement (measured for the default scenario: about 0.1 m/s on a 41-point
grid of half-width 10-20 m, 0.05 m/s on 61 points). We therefore stop when the largest change of ``V`` over one
second, on the sub-level set ``{V <= band_fraction * cap}``, falls below ``tol`` (the end of the transient), and
validate the bound by closed-loop simulation against random and worst-case references and winds (tests).

The tracking controller (eq. 26) is ``kappa(e) = arg max_u grad W(e) . f(e, u, u_r, d)``, closed form.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.artifacts import ArtifactStore
from stp_env.dynamics import DubinsWind, RelativeDubins, tracking_error_dynamics


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrackingConfig:
    """Robust-trajectory-tracking parameters. Defaults: the BEACLS paper's city study (``U = [0, 25] m/s x
    |omega| <= 2 rad/s``, ``U^p = [11, 13] m/s x |omega| <= 1.2 rad/s``, wind 6 m/s).

    Attributes:
        vehicle: the vehicle (full control set ``U`` and wind bound).
        planning_v: speed interval of the planning set ``U^p`` [m/s].
        planning_omega_max: turn-rate bound of ``U^p`` [rad/s].
        half_width: the error box is ``[-half_width, half_width]^2`` in position [m].
        cap_fraction: ``l(e) = min(||e_p||, cap_fraction * half_width)``.
        grid_points: points in ``(e_x, e_y, e_theta)``.
        accuracy: solver preset.
        check_interval, max_horizon, tol: stopping rule (simulated seconds, metres per interval).
        band_fraction: the stopping rule looks at ``{V <= band_fraction * cap}``.
    """

    vehicle: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    planning_v: tuple[float, float] = (11.0, 13.0)
    planning_omega_max: float = 1.2
    half_width: float = 10.0
    cap_fraction: float = 0.8
    grid_points: tuple[int, int, int] = (61, 61, 60)
    accuracy: str = "very_high"
    check_interval: float = 1.0
    max_horizon: float = 60.0
    tol: float = 0.05
    band_fraction: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.half_width) and self.half_width > 0):
            raise ValueError(f"half_width must be positive; got {self.half_width}.")
        if not 0 < self.cap_fraction < 1:
            raise ValueError(f"cap_fraction must lie in (0, 1); got {self.cap_fraction}.")
        if len(self.grid_points) != 3 or min(self.grid_points) < 5:
            raise ValueError(f"grid_points must be 3 counts >= 5; got {self.grid_points}.")
        hj.SolverSettings.with_accuracy(self.accuracy)
        self.error_dynamics  # noqa: B018  (validates U^p inside U)

    @property
    def error_dynamics(self) -> RelativeDubins:
        return tracking_error_dynamics(self.vehicle, self.planning_v, self.planning_omega_max)

    @property
    def grid(self) -> hj.Grid:
        w = self.half_width
        return hj.Grid.from_bounds((-w, -w, -math.pi), (w, w, math.pi), self.grid_points, periodic=2)

    @property
    def cap(self) -> float:
        return self.cap_fraction * self.half_width


@dataclasses.dataclass(frozen=True)
class TrackingBound:
    """Result of :func:`compute_tracking_bound`.

    Attributes:
        config: parameters.
        value: ``V(e)`` on ``config.grid`` (largest future position error under optimal tracking) [m].
        bound: ``V(0)``, the tracking-error bound from zero initial error [m].
        min_value: ``min_e V(e)`` (the smallest invariant level) [m].
        converged: whether the value stopped changing within ``max_horizon``.
        horizon: simulated seconds solved.
        n_steps: solver time steps.
    """

    config: TrackingConfig
    value: np.ndarray
    bound: float
    min_value: float
    converged: bool
    horizon: float
    n_steps: int

    def controller(self):
        """A jittable ``kappa(e) -> (v, omega)`` (eq. 26) for an error state ``e`` of shape ``(3,)``."""
        return make_tracker(self.config, self.value)


def make_tracker(config: TrackingConfig, value: np.ndarray):
    grid = config.grid
    dyn = config.error_dynamics
    w = jnp.asarray(-np.asarray(value), jnp.float32)  # the solver's W = -V
    grads = hj.interpolation.gradient_field(grid, w)

    def kappa(error_state):
        return hj.interpolation.optimal_control(grid, dyn, grads, error_state)

    return jax.jit(kappa)


def compute_tracking_bound(config: TrackingConfig | None = None, *, store: ArtifactStore | None = None,
                           progress: bool = True) -> TrackingBound:
    """Solves SPP eqs. (24)-(26) to convergence (cached in ``store`` when given)."""
    config = TrackingConfig() if config is None else config

    def compute():
        grid = config.grid
        x = grid.broadcast_states()
        cost = jnp.broadcast_to(jnp.minimum(jnp.sqrt(x[0] ** 2 + x[1] ** 2), config.cap), grid.shape)
        settings = hj.SolverSettings.with_accuracy(config.accuracy)
        res = hj.solve_until_converged(settings, config.error_dynamics, grid, -cost, tube=True,
                                       check_interval=config.check_interval, max_horizon=config.max_horizon,
                                       tol=config.tol, band=config.band_fraction * config.cap,
                                       progress=progress)
        return {
            "value": -np.asarray(res.values),
            "converged": np.asarray(res.converged),
            "horizon": np.asarray(res.horizon),
            "n_steps": np.asarray(res.n_steps),
        }

    if store is None:
        arrays = compute()
    else:
        arrays = store.load_or_compute("tracking_bound", config, compute).arrays
    value = np.asarray(arrays["value"])
    grid = config.grid
    bound = float(hj.interpolation.interpolate(grid, jnp.asarray(value), jnp.zeros(3)))
    if bound >= 0.95 * config.cap:
        raise ValueError(
            f"The tracking-error bound ({bound:.2f} m) reaches the cost cap ({config.cap:.2f} m): the error box "
            f"(half_width={config.half_width} m) is too small for these bounds, or no bound exists (U^p plus the "
            "wind outruns U). Increase half_width."
        )
    return TrackingBound(config=config, value=value, bound=bound, min_value=float(value.min()),
                         converged=bool(arrays["converged"]), horizon=float(arrays["horizon"]),
                         n_steps=int(arrays["n_steps"]))


def default_tracking_config(vehicle: DubinsWind, planning_v=(11.0, 13.0), planning_omega_max: float = 1.2,
                            half_width: float | None = None) -> TrackingConfig:
    """The tracking parameters used throughout, so that every user shares one cached artifact: the error box
    scales with the vehicle's top ground speed (10 m for the papers' 25 m/s vehicle in 6 m/s wind)."""
    if half_width is None:
        half_width = float(np.float32(10.0 * (vehicle.v_max + vehicle.wind) / 31.0))
    return TrackingConfig(vehicle=vehicle, planning_v=tuple(planning_v), planning_omega_max=planning_omega_max,
                          half_width=half_width)


def default_tracking_bound(vehicle: DubinsWind, planning_v=(11.0, 13.0), planning_omega_max: float = 1.2, *,
                           store: ArtifactStore | None = None, progress: bool = True,
                           max_doublings: int = 3) -> TrackingBound:
    """:func:`compute_tracking_bound` on :func:`default_tracking_config`, doubling the error box while the bound
    reaches the cost cap (strong wind needs a larger box: about 16 m of error at 11 m/s)."""
    cfg = default_tracking_config(vehicle, planning_v, planning_omega_max)
    for attempt in range(max_doublings + 1):
        try:
            return compute_tracking_bound(cfg, store=store, progress=progress)
        except ValueError as err:
            if "reaches the cost cap" not in str(err) or attempt == max_doublings:
                raise
            cfg = dataclasses.replace(cfg, half_width=2 * cfg.half_width)
    raise AssertionError("unreachable")
