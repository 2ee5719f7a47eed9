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
``min V``, and ``V`` on the sub-level set ``{V <= V(0)}`` (never empty: it holds the minimum). The rule fires when
none of them changed by more than ``rtol * V(0)`` over one ``check_interval``. The value never stops changing
entirely: with a max-over-time cost the Lax-Friedrichs dissipation acts like a small noise and ``V(0)`` keeps creeping
up at a rate that falls with grid refinement (``TrackingBound.rate`` reports it), while the game's own transient at
11 m/s wind lasts tens of seconds (the vehicle out-runs the reference by 1 m/s into a headwind). The refinement study
in ``BENCHMARKS.md`` shows that finer grids give *smaller* values at every horizon, so the grid's error in ``V``
is on the conservative side.

Certification. A small rate is not enough: at 11 m/s the rule fired at 40 s of horizon (35.39 m, still rising
0.06 m/s), and the tracker of that value, flown against the game's own worst reference and wind, reached 36.62 m.
What the bound promises is a property of the closed loop the simulator flies, so the solve stops only once that
closed loop keeps it: after the rule fires, every ``certify_every`` seconds of horizon :func:`certify` flies the
tracker ``kappa`` of the current value against the game's own worst strategies (the reference control and the wind
that the value's gradient says grow the error most, re-read at every inner period, and also held per plan sample),
at each inner period of ``certify_control_dts``, from zero error and small perturbations of it, with the exact Dubins
motion of the simulator (:mod:`stp_env.reach.closed_loop`). The bound is certified when every rollout stays
``certify_allowance_cells`` position cells below ``V`` at its start; the solve continues otherwise (the value keeps
rising, the closed loop does not: at 11 m/s it levels off near 36.7 m whatever the horizon). Where the value stops
closing on the closed loop (the excess fell by less than a tenth of the allowance over :data:`STALL_CHECKS` checks:
without wind the value settles at 0.24 m, less than a cell, while the sampled closed loop reaches about 0.33 m), the
bound is raised to the closed loop plus the allowance (``TrackingBound.raised``). The allowance covers attacks that
search around the game's strategies (``stp-env falsify``, whose tracking attack starts from them).

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
from stp_env.reach import closed_loop
from stp_env.reach.closed_loop import CERTIFIED_CONTROL_DT


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
        certify: certify the bound in closed loop (module docstring) and solve on until it is certified; ``False``
            stops where the stopping rule fires, and the bound is not certified (the simulator refuses it unless
            told to run uncertified: for coarse tables in tests and studies that do not rest on the bound).
        certify_allowance_cells: closed-loop certification (module docstring): the game's own worst strategies,
            flown against the tracker at the inner control periods ``certify_control_dts``, must keep the error this
            many position cells below the value of their start.
        certify_control_dts: the tracker's inner periods the certification flies [s]
            (:data:`stp_env.reach.closed_loop.CERTIFIED_CONTROL_DT`).
        certify_plan_dt: the sample period of the references the certification also flies (a plan's sample holds
            its control; the strongest reference switches at every inner period, which is flown too) [s].
        certify_duration: seconds each certification rollout lasts.
        certify_starts: rollouts per check: from zero error, and from small perturbations of it.
        certify_every: seconds of horizon solved between two certification checks.
    """

    vehicle: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    planning_v: tuple[float, float] = (11.0, 13.0)
    planning_omega_max: float = 1.2
    half_width: float = 10.0
    cap_fraction: float = 0.9
    grid_points: tuple[int, int, int] = (61, 61, 60)
    accuracy: str = "very_high"
    check_interval: float = 1.0
    max_horizon: float = 300.0
    rtol: float = 0.0025
    cap_clearance_cells: float = 3.0
    certify: bool = True
    certify_allowance_cells: float = 0.5
    certify_control_dts: tuple[float, ...] = CERTIFIED_CONTROL_DT
    certify_plan_dt: float = 0.1
    certify_duration: float = 90.0
    certify_starts: int = 16
    certify_every: float = 5.0

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
        if not isinstance(self.certify, bool):
            raise ValueError(f"certify must be True or False; got {self.certify!r}.")
        if not (self.certify_allowance_cells >= 0 and self.certify_duration > 0 and self.certify_every > 0
                and self.certify_plan_dt > 0 and len(self.certify_control_dts) > 0
                and all(0 < h <= self.certify_plan_dt for h in self.certify_control_dts)
                and isinstance(self.certify_starts, int) and self.certify_starts >= 1):
            raise ValueError("need certify_allowance_cells >= 0, certify_duration > 0, certify_every > 0, "
                             "0 < certify_control_dts <= certify_plan_dt and certify_starts >= 1; got "
                             f"{self.certify_allowance_cells}, {self.certify_duration}, {self.certify_every}, "
                             f"{self.certify_control_dts}, {self.certify_plan_dt}, {self.certify_starts}.")
        object.__setattr__(self, "certify_control_dts", tuple(float(h) for h in self.certify_control_dts))
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

    @property
    def certify_allowance(self) -> float:
        """[m] the certification margin: ``certify_allowance_cells`` position cells."""
        return self.certify_allowance_cells * max(self.grid.spacing[:2])


@dataclasses.dataclass(frozen=True)
class TrackingBound:
    """Result of :func:`compute_tracking_bound`.

    Attributes:
        config: parameters.
        value: ``V(e)`` on ``config.grid`` (largest future position error under optimal tracking) [m].
        bound: ``V(0)``, the tracking-error bound from zero initial error [m].
        min_value: ``min_e V(e)`` (the smallest invariant level) [m].
        converged: whether the solve stopped before ``max_horizon``: the stopping rule fired and, when
            ``config.certify``, the closed-loop certification passed.
        certified: whether the closed-loop certification passed (the simulator runs only certified bounds unless
            told otherwise).
        horizon: simulated seconds solved.
        n_steps: solver time steps.
        rate: the residual creep of the watched quantities at the end [m/s] (see the module docstring).
        history: ``V(0)`` after each check interval [m].
        closed_loop_excess: the certification's largest ``max_t ||e(t)|| - V(e_0)`` [m] (negative: below the value).
        closed_loop_worst: the largest error of the certification's rollouts from zero error [m].
        raised: how far the bound was raised above ``V(0)`` to the closed loop (module docstring, "Certification";
            0 when the value itself came to hold it) [m]: ``bound = V(0) + raised``.
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
    closed_loop_excess: float = math.nan
    closed_loop_worst: float = math.nan
    certified: bool = False
    raised: float = 0.0

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


STALL_CHECKS = 3
"""Certification checks over which the excess must fall by a tenth of the allowance, else the bound is raised."""

_CERTIFY_PROGRAMS: dict = {}


def _certify_program(grid: hj.Grid, dynamics: RelativeDubins, h: float, n_steps: int, hold: int):
    """Compiled (once per shape) ``(tracker gradients, attacker gradients, starts) -> largest error per start``."""
    key = (grid, dynamics, float(h), int(n_steps), int(hold))
    if key not in _CERTIFY_PROGRAMS:
        lo, hi = jnp.asarray(grid.lo, jnp.float32), jnp.asarray(grid.hi, jnp.float32)

        def reader(fields):
            def gradient(t, x):
                del t
                xc = jnp.clip(x, lo, hi)
                return jnp.stack([hj.interpolation.interpolate(grid, fields[i], xc) for i in range(3)])
            return gradient

        def run(tracker, attacker, starts):
            def one(x0):
                xs, _, _ = closed_loop.rollout(dynamics, reader(tracker), reader(attacker), x0, h=h, n_steps=n_steps,
                                            hold=hold)
                return jnp.max(jnp.hypot(xs[:, 0], xs[:, 1]))
            return jax.vmap(one)(starts)

        _CERTIFY_PROGRAMS[key] = jax.jit(run)
    return _CERTIFY_PROGRAMS[key]


@dataclasses.dataclass(frozen=True)
class Certificate:
    """Outcome of :func:`certify`.

    Attributes:
        excess: the largest ``max_t ||e(t)|| - V(e_0)`` over the rollouts [m]: negative when every rollout stayed
            below the value of its start (the bound from zero error is ``V(0)``).
        worst_error: the largest error of a rollout from zero error [m].
        allowance: the margin the certification asks for, ``excess <= -allowance`` [m].
        by_control_dt: the largest excess at each inner period [m].
    """

    excess: float
    worst_error: float
    allowance: float
    by_control_dt: dict

    @property
    def certified(self) -> bool:
        return self.excess <= -self.allowance


def certify(config: TrackingConfig, value, attacker_value=None) -> Certificate:
    """Fly the tracking game in closed loop (module docstring, "Certification"): the tracker ``kappa`` of ``value``
    against the game's own worst reference and wind (those of ``attacker_value``, default ``value``), the reference
    switching at every inner period and holding each plan sample's control, at every inner period of
    ``config.certify_control_dts``, from zero error and ``certify_starts - 1`` perturbations of it (a tenth of a cell).
    """
    grid = config.grid
    value = np.asarray(value)
    attacker_value = value if attacker_value is None else np.asarray(attacker_value)
    tracker = hj.interpolation.gradient_field(grid, jnp.asarray(-value, jnp.float32))
    attacker = hj.interpolation.gradient_field(grid, jnp.asarray(-attacker_value, jnp.float32))
    rng = np.random.default_rng(0)
    starts = np.zeros((config.certify_starts, 3), np.float32)
    spacing = np.asarray(grid.spacing, np.float64)
    starts[1:] = rng.normal(0.0, 0.1, (config.certify_starts - 1, 3)) * spacing
    v_start = np.asarray(jax.vmap(lambda x: hj.interpolation.interpolate(grid, jnp.asarray(value, jnp.float32), x))(
        jnp.asarray(starts)), np.float64)
    excess, worst, by_h = -math.inf, 0.0, {}
    for h in config.certify_control_dts:
        n_steps = round(config.certify_duration / h)
        for hold in sorted({1, max(1, round(config.certify_plan_dt / h))}):
            program = _certify_program(grid, config.error_dynamics, h, n_steps, hold)
            errors = np.asarray(program(tracker, attacker, jnp.asarray(starts)), np.float64)
            e = float(np.max(errors - v_start))
            by_h[h] = max(by_h.get(h, -math.inf), e)
            excess = max(excess, e)
            worst = max(worst, float(errors[0]))
    return Certificate(excess=excess, worst_error=worst, allowance=config.certify_allowance, by_control_dt=by_h)


def _cap_clearance(config: TrackingConfig, value, raised: float = 0.0) -> tuple[float, float, float]:
    """``(clearance beyond the required cells [m], the bound V(0) + raised, the largest ||e_p|| on {V <= bound})``:
    negative when the sub-level set of the bound comes within ``cap_clearance_cells`` cells of the cost cap."""
    grid = config.grid
    value = np.asarray(value)
    bound = float(hj.interpolation.interpolate(grid, jnp.asarray(value), jnp.zeros(3))) + raised
    x = grid.broadcast_states()
    radius = np.broadcast_to(np.hypot(np.asarray(x[0]), np.asarray(x[1])), grid.shape)
    reach = float(radius[value <= bound].max(initial=0.0))
    return config.cap - reach - config.cap_clearance_cells * max(grid.spacing[:2]), bound, reach


def compute_tracking_bound(config: TrackingConfig | None = None, *, store: ArtifactStore | None = None,
                           progress: bool = True) -> TrackingBound:
    """Solves SPP eqs. (24)-(26) until the stopping rule fires and the closed-loop certification passes (module
    docstring; cached in ``store`` when given).

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

        bound_at = jax.jit(at_zero)
        res = hj.solve_until_converged(settings, config.error_dynamics, grid, -cost, tube=True,
                                       check_interval=config.check_interval, max_horizon=config.max_horizon,
                                       tol=0.0, rtol=config.rtol, region=jax.jit(region), watch=jax.jit(watch),
                                       warn=False, progress=progress)
        w, horizon, n_steps = res.values, res.horizon, res.n_steps
        history = [float(v[0]) for v in res.watched]
        rate = res.rate
        rule_fired = bool(res.converged)
        cert, checks, raised = None, [], 0.0
        bar = None
        certifying = rule_fired and config.certify and _cap_clearance(config, -np.asarray(w))[0] >= 0
        if certifying and progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=None, desc="tracking bound: certifying in closed loop", unit="check", leave=False)
        try:
            while certifying and _cap_clearance(config, -np.asarray(w))[0] >= 0:  # (a binding cap raises below)
                cert = certify(config, -np.asarray(w))
                checks.append((horizon, history[-1], cert.excess, cert.worst_error))
                if bar is not None:
                    bar.set_postfix_str(f"horizon {horizon:.0f} s, V(0) {history[-1]:.3f} m, "
                                        f"excess {cert.excess:+.3f} m")
                    bar.update(1)
                if cert.certified or horizon + config.certify_every > config.max_horizon + 1e-9:
                    break
                if len(checks) > STALL_CHECKS and checks[-1 - STALL_CHECKS][2] - cert.excess < 0.1 * cert.allowance:
                    # the value no longer closes on the closed loop: raise the bound to it (module docstring)
                    raised = cert.excess + cert.allowance
                    break
                for _ in range(max(1, round(config.certify_every / config.check_interval))):
                    step = hj.solve(settings, config.error_dynamics, grid, [0.0, -config.check_interval], -cost,
                                    initial_values=w, tube=True, progress=False)
                    new = step.values[-1]
                    v_old, v_new = float(bound_at(w)), float(bound_at(new))
                    rate = (v_new - v_old) / config.check_interval
                    w = new
                    horizon += config.check_interval
                    n_steps += step.n_steps
                    history.append(v_new)
        finally:
            if bar is not None:
                bar.close()
        certified = cert is not None and (cert.certified or raised > 0)
        return {
            "value": -np.asarray(w),
            "converged": np.asarray(certified if config.certify else rule_fired),
            "certified": np.asarray(certified),
            "rule_fired": np.asarray(rule_fired),
            "horizon": np.asarray(horizon),
            "n_steps": np.asarray(n_steps),
            "rate": np.asarray(rate),
            "history": np.asarray(history, np.float64),
            "certificate": np.asarray([np.nan] * 4 if cert is None else
                                      [cert.excess, cert.worst_error, cert.allowance, len(checks)], np.float64),
            "checks": np.asarray(checks, np.float64).reshape(-1, 4),
            "raised": np.asarray(raised, np.float64),
        }

    if store is None:
        arrays = compute()
    else:
        arrays = store.load_or_compute("tracking_bound", config, compute).arrays
    value = np.asarray(arrays["value"])
    raised = float(arrays["raised"])
    excess, bound, reach = _cap_clearance(config, value, raised)
    if excess < 0:
        raise ValueError(
            f"The tracking-error bound ({bound:.2f} m) reaches the cost cap ({config.cap:.2f} m): its sub-level set "
            f"extends to {reach:.2f} m, within {config.cap_clearance_cells:g} cells of the cap. The error box "
            f"(half_width={config.half_width} m) is too small for these bounds, or no bound exists (U^p plus the "
            "wind outruns U). Increase half_width.")
    converged = bool(arrays["converged"])
    rate = float(arrays["rate"]) if "rate" in arrays else math.nan
    certificate = np.asarray(arrays["certificate"], np.float64)
    if not converged or (config.certify and not bool(arrays["certified"])):
        import warnings

        reason = ("the stopping rule did not fire" if not bool(arrays["rule_fired"]) else
                  f"the closed-loop certification did not pass (the game's worst strategies came "
                  f"{certificate[0]:+.3f} m from the value of their start; {-certificate[2]:.3f} m needed)")
        warnings.warn(f"The tracking-error bound ({bound:.3f} m) is not certified within {config.max_horizon:g} s of "
                      f"horizon: {reason}; still rising {rate:.4f} m/s.", RuntimeWarning, stacklevel=2)
    return TrackingBound(config=config, value=value, bound=bound, min_value=float(value.min()),
                         converged=converged, horizon=float(arrays["horizon"]),
                         n_steps=int(arrays["n_steps"]), rate=rate,
                         history=tuple(float(v) for v in np.asarray(arrays.get("history", ()))),
                         closed_loop_excess=float(certificate[0]), closed_loop_worst=float(certificate[1]),
                         certified=bool(arrays["certified"]), raised=raised)


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
