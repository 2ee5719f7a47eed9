"""Robust trajectory tracking (RTT): the tracking-error bound and the tracking controller.

SPP paper Section IV-C, eqs. (24)-(26). The tracking error ``e`` is the state of a virtual reference (moving with
the reduced planning controls ``U^p`` and no wind) relative to the vehicle, in the vehicle's body frame
(:func:`stp_env.dynamics.tracking_error_dynamics`). The reference and the wind play against the vehicle.

We compute the infinite-horizon value ``V(e) = sup_T`` of the largest future position error under optimal
play, ``V(e) = inf_kappa sup_{u_r, d} sup_{s >= 0} l(e(s))`` with ``l(e) = min(||e_p||, cap)``; every sub-level
set ``{V <= c}`` is robustly controlled-invariant (the set ``Omega`` of eqs. 24-26 for the error bound ``E = {||e_p||
<= c}``), and the smallest bound that tracking *from zero error* can guarantee is ``V(0)``. It is solved as the
tube of the negated problem (``W = -V``, ``W <- min(W, -l)`` every step, the vehicle maximising ``W``) until the
value stops changing.

Stopping rule (``docs/numerics.md``). The loop watches what users consume: ``V(0)``, the smallest invariant level
``min V``, and ``V`` on the sub-level set ``{V <= V(0)}`` (never empty: it holds the minimum). It stops when none of
them changed by more than ``rtol * V(0)`` over one ``check_interval``. The value never stops changing entirely: with
a max-over-time cost the Lax-Friedrichs dissipation acts like a small noise and ``V(0)`` keeps creeping up at a rate
that falls with grid refinement (``TrackingBound.rate`` reports it), while the game's own transient at 11 m/s wind
lasts tens of seconds (the vehicle out-runs the reference by 1 m/s into a headwind). The refinement study in
``BENCHMARKS.md`` shows that finer grids give *smaller* bounds at every horizon, so the default grid sits on the
conservative side of the trend; the falsifier (:mod:`stp_env.falsify.tracking`) attacks the result in closed loop.

The cap keeps the value bounded at the inflow boundary; the result is only trusted if the sub-level set
``{V <= V(0)}`` stays a few cells inside the capped zone (:func:`compute_tracking_bound` checks it, and
:func:`default_tracking_bound` grows the box until it does).

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
        check_interval, max_horizon: stopping rule: simulated seconds per check, and at most [s].
        rtol: stop once ``V(0)``, ``min V`` and ``V`` on ``{V <= V(0)}`` change by at most ``rtol * V(0)`` per
            check (the residual creep, see the module docstring).
        cap_clearance_cells: the sub-level set ``{V <= V(0)}`` must stay this many cells inside the cap.
    """

    vehicle: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    planning_v: tuple[float, float] = (11.0, 13.0)
    planning_omega_max: float = 1.2
    half_width: float = 10.0
    cap_fraction: float = 0.9
    grid_points: tuple[int, int, int] = (61, 61, 60)
    accuracy: str = "very_high"
    check_interval: float = 1.0
    max_horizon: float = 120.0
    rtol: float = 0.0025
    cap_clearance_cells: float = 3.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.half_width) and self.half_width > 0):
            raise ValueError(f"half_width must be positive; got {self.half_width}.")
        if not 0 < self.cap_fraction < 1:
            raise ValueError(f"cap_fraction must lie in (0, 1); got {self.cap_fraction}.")
        if len(self.grid_points) != 3 or min(self.grid_points) < 5:
            raise ValueError(f"grid_points must be 3 counts >= 5; got {self.grid_points}.")
        if not (self.check_interval > 0 and self.max_horizon >= self.check_interval and 0 < self.rtol < 1):
            raise ValueError(f"need check_interval > 0, max_horizon >= check_interval and 0 < rtol < 1; got "
                             f"{self.check_interval}, {self.max_horizon}, {self.rtol}.")
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
        converged: whether the stopping rule fired within ``max_horizon``.
        horizon: simulated seconds solved.
        n_steps: solver time steps.
        rate: the residual creep of the watched quantities at the end [m/s] (see the module docstring).
        history: ``V(0)`` after each check interval [m].
    """

    config: TrackingConfig
    value: np.ndarray
    bound: float
    min_value: float
    converged: bool
    horizon: float
    n_steps: int
    rate: float = math.nan
    history: tuple[float, ...] = ()

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
    """Solves SPP eqs. (24)-(26) to convergence (cached in ``store`` when given).

    Raises ``ValueError`` if the cost cap binds: the sub-level set ``{V <= V(0)}`` comes within
    ``cap_clearance_cells`` cells of ``||e_p|| = cap`` (the box is too small, or no bound exists: ``U^p`` plus the
    wind outruns ``U``)."""
    config = TrackingConfig() if config is None else config

    def compute():
        grid = config.grid
        x = grid.broadcast_states()
        cost = jnp.broadcast_to(jnp.minimum(jnp.sqrt(x[0] ** 2 + x[1] ** 2), config.cap), grid.shape)
        settings = hj.SolverSettings.with_accuracy(config.accuracy)
        zero = jnp.zeros(3)

        def at_zero(w):
            return -hj.interpolation.interpolate(grid, w, zero)

        def region(old, new):  # the sub-level sets up to the bound, in V = -W: never empty (they hold the minimum)
            return (-new <= at_zero(new)) | (-old <= at_zero(old))

        def watch(w):
            return jnp.stack([at_zero(w), -jnp.max(w)])

        res = hj.solve_until_converged(settings, config.error_dynamics, grid, -cost, tube=True,
                                       check_interval=config.check_interval, max_horizon=config.max_horizon,
                                       tol=0.0, rtol=config.rtol, region=jax.jit(region), watch=jax.jit(watch),
                                       progress=progress)
        return {
            "value": -np.asarray(res.values),
            "converged": np.asarray(res.converged),
            "horizon": np.asarray(res.horizon),
            "n_steps": np.asarray(res.n_steps),
            "rate": np.asarray(res.rate),
            "history": np.asarray([w[0] for w in res.watched], np.float64),
        }

    if store is None:
        arrays = compute()
    else:
        arrays = store.load_or_compute("tracking_bound", config, compute).arrays
    value = np.asarray(arrays["value"])
    grid = config.grid
    bound = float(hj.interpolation.interpolate(grid, jnp.asarray(value), jnp.zeros(3)))
    x = np.asarray(grid.broadcast_states()[0]), np.asarray(grid.broadcast_states()[1])
    radius = np.broadcast_to(np.hypot(x[0], x[1]), grid.shape)
    reach = float(radius[value <= bound].max(initial=0.0))
    clearance = config.cap - reach
    if clearance < config.cap_clearance_cells * max(grid.spacing[:2]):
        raise ValueError(
            f"The tracking-error bound ({bound:.2f} m) reaches the cost cap ({config.cap:.2f} m): its sub-level set "
            f"extends to {reach:.2f} m, within {config.cap_clearance_cells:g} cells of the cap. The error box "
            f"(half_width={config.half_width} m) is too small for these bounds, or no bound exists (U^p plus the "
            "wind outruns U). Increase half_width.")
    converged = bool(arrays["converged"])
    rate = float(arrays["rate"]) if "rate" in arrays else math.nan
    if not converged:
        import warnings

        warnings.warn(f"The tracking-error bound ({bound:.3f} m) did not converge within {config.max_horizon:g} s "
                      f"of horizon (still rising {rate:.4f} m/s).", RuntimeWarning, stacklevel=2)
    return TrackingBound(config=config, value=value, bound=bound, min_value=float(value.min()),
                         converged=converged, horizon=float(arrays["horizon"]),
                         n_steps=int(arrays["n_steps"]), rate=rate,
                         history=tuple(float(v) for v in np.asarray(arrays.get("history", ()))))


def default_tracking_config(vehicle: DubinsWind, planning_v=(11.0, 13.0), planning_omega_max: float = 1.2,
                            half_width: float | None = None) -> TrackingConfig:
    """The tracking parameters used throughout, so that every user shares one cached artifact: the error box
    starts from the vehicle's top ground speed (10 m for the papers' 25 m/s vehicle in 6 m/s wind; see
    :func:`default_tracking_bound`, which grows it while the cap binds)."""
    if half_width is None:
        half_width = float(np.float32(10.0 * (vehicle.v_max + vehicle.wind) / 31.0))
    return TrackingConfig(vehicle=vehicle, planning_v=tuple(planning_v), planning_omega_max=planning_omega_max,
                          half_width=half_width)


BOX_GROWTH = 1.5


def default_tracking_bound(vehicle: DubinsWind, planning_v=(11.0, 13.0), planning_omega_max: float = 1.2, *,
                           store: ArtifactStore | None = None, progress: bool = True,
                           max_growths: int = 6) -> TrackingBound:
    """:func:`compute_tracking_bound` on :func:`default_tracking_config`, growing the error box by
    :data:`BOX_GROWTH` while the cost cap binds (strong wind needs a larger box: about 35 m of error at 11 m/s).
    The grid keeps its number of points, so a larger box is a coarser grid: on the conservative side."""
    cfg = default_tracking_config(vehicle, planning_v, planning_omega_max)
    for attempt in range(max_growths + 1):
        try:
            return compute_tracking_bound(cfg, store=store, progress=progress)
        except ValueError as err:
            if "reaches the cost cap" not in str(err) or attempt == max_growths:
                raise
            cfg = dataclasses.replace(cfg, half_width=float(np.float32(BOX_GROWTH * cfg.half_width)))
    raise AssertionError("unreachable")
