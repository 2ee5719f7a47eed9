"""Avoid region ``V^A(tau, t_IAT)`` of a vehicle against an intruder (intruder paper Section IV-A).

``V^A(tau, t_IAT)`` (eq. 13) is the set of relative states ``x_Ii`` (intruder relative to vehicle ``i``, in the
vehicle's body frame, eq. 44) from which the intruder, helped by both winds, can force the pair into the danger
zone ``L^A = {||p_Ii|| <= R_c}`` within ``t_IAT - tau``, whatever vehicle ``i`` does. It is the backward reachable
*tube* of ``L^A`` with Hamiltonian (14): the vehicle's control maximises, the intruder's control and both winds
minimise (:class:`stp_env.dynamics.RelativeDubins` with its default roles).

The minimum detection range ``d^A`` (eq. 16) is the largest distance of a relative state in
``V^A(0, t_IAT)``.

Numerics (docs/numerics.md): local Lax-Friedrichs and WENO5 by default; the box must contain the set with margin
(checked: :attr:`AvoidRegion.boundary_margin` must be positive). The exact sanity check ``R_c + (v_I,max +
wind_i + wind_I - v_i,max) t_IAT`` for the extent straight behind the vehicle at equal heading is available as
:meth:`AvoidRegionConfig.behind_extent`.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.artifacts import ArtifactStore
from stp_env.dynamics import DubinsWind, RelativeDubins
from stp_env.reach import closed_loop
from stp_env.reach.closed_loop import CERTIFIED_CONTROL_DT
from stp_env.reach.fall_rate import FALL_RATE_BAND, avoid_value_fall_rate


@dataclasses.dataclass(frozen=True, kw_only=True)
class AvoidRegionConfig:
    """Parameters of the avoid region. Defaults: the intruder paper's Section V (eq. 43 bounds, wind 6 m/s,
    ``t_IAT = 10 s``, ``R_c = 100 m``).

    Attributes:
        vehicle: the STP vehicle's dynamics bounds (and its wind bound).
        intruder: the intruder's dynamics bounds (and its wind bound).
        collision_radius: ``R_c`` [m].
        t_iat: ``t_IAT``, the longest time the intruder stays [s].
        half_width: the relative-position box is ``[-half_width, half_width]^2`` [m].
        grid_points: grid points in ``(p_x, p_y, theta)``.
        n_slices: number of stored time slices ``tau_k`` evenly spaced in ``[0, t_IAT]``.
        accuracy: solver preset (see :meth:`stp_env.hj.SolverSettings.with_accuracy`).
        certify: certify the table in closed loop (module docstring); ``False``: no certificate, and the
            simulator refuses the table's margin unless told to run uncertified (coarse tables in tests and studies
            in which no intruder appears).
        certify_taus, certify_bearings, certify_headings: the closed-loop certification's starts (module docstring):
            on the zero level of ``V^A(tau_0)`` at this many times ``tau_0`` in ``[0, t_IAT)``, bearings and relative
            headings.
        certify_refine: that many of the worst starts are refined by a local search.
        certify_allowance: [m] added to the largest loss found (:attr:`AvoidRegion.table_error`).
    """

    vehicle: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    intruder: DubinsWind = dataclasses.field(default_factory=DubinsWind)
    collision_radius: float = 100.0
    t_iat: float = 10.0
    half_width: float = 320.0
    grid_points: tuple[int, int, int] = (61, 61, 61)
    n_slices: int = 11
    accuracy: str = "very_high"
    certify: bool = True
    certify_taus: int = 20
    certify_bearings: int = 32
    certify_headings: int = 32
    certify_refine: int = 8
    certify_allowance: float = 0.1

    def __post_init__(self) -> None:
        for name in ("collision_radius", "t_iat", "half_width"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number; got {value!r}.")
        if self.half_width <= self.collision_radius:
            raise ValueError(f"half_width ({self.half_width} m) must exceed the collision radius "
                             f"({self.collision_radius} m), or the danger zone does not fit in the grid.")
        if len(self.grid_points) != 3 or min(self.grid_points) < 5:
            raise ValueError(f"grid_points must be 3 counts >= 5; got {self.grid_points}.")
        if self.n_slices < 2:
            raise ValueError(f"n_slices must be >= 2; got {self.n_slices}.")
        hj.SolverSettings.with_accuracy(self.accuracy)  # validates the preset name
        if not isinstance(self.certify, bool):
            raise ValueError(f"certify must be True or False; got {self.certify!r}.")
        for name in ("certify_taus", "certify_bearings", "certify_headings", "certify_refine"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1; got {value!r}.")
        if not (isinstance(self.certify_allowance, (int, float)) and math.isfinite(self.certify_allowance)
                and self.certify_allowance >= 0):
            raise ValueError(f"certify_allowance must be a finite number >= 0 [m]; got {self.certify_allowance!r}.")

    @property
    def relative_dynamics(self) -> RelativeDubins:
        """Eq. (44) with the vehicle's control maximising and the intruder and winds minimising (eq. 14)."""
        return RelativeDubins(
            v_min=self.vehicle.v_min, v_max=self.vehicle.v_max, omega_max=self.vehicle.omega_max,
            other_v_min=self.intruder.v_min, other_v_max=self.intruder.v_max,
            other_omega_max=self.intruder.omega_max, wind=self.vehicle.wind + self.intruder.wind,
            own_heading_disturbance=self.vehicle.heading_disturbance,
            other_heading_disturbance=self.intruder.heading_disturbance,
            control_mode="max", disturbance_mode="min",
        )

    @property
    def grid(self) -> hj.Grid:
        w = self.half_width
        return hj.Grid.from_bounds((-w, -w, -math.pi), (w, w, math.pi), self.grid_points, periodic=2)

    @property
    def game(self) -> AvoidGame:
        return AvoidGame(grid=self.grid, dynamics=self.relative_dynamics, t_iat=float(self.t_iat),
                         collision_radius=float(self.collision_radius))

    def behind_extent(self) -> float:
        """Exact extent of ``V^A(0, t_IAT)`` straight behind the vehicle at equal heading: the intruder closes
        at ``v_I,max + wind_i + wind_I - v_i,max`` (if positive) for ``t_IAT`` (docs/numerics.md)."""
        closing = self.intruder.v_max + self.vehicle.wind + self.intruder.wind - self.vehicle.v_max
        return self.collision_radius + max(closing, 0.0) * self.t_iat


@dataclasses.dataclass(frozen=True)
class AvoidRegion:
    """Computed avoid region.

    Attributes:
        config: the parameters that shaped it.
        taus: ``tau_k`` ascending in ``[0, t_IAT]`` [s].
        values: ``V^A(tau_k, t_IAT)`` on ``config.grid``, shape ``(n_slices, *grid.shape)``; the set is
            ``{V <= 0}``.
        n_steps: solver time steps.
        fall_rate: [m/s] the largest rate at which the interpolated value can fall near its zero level, under any
            input and wind (:func:`stp_env.reach.fall_rate.avoid_value_fall_rate`): the simulator's avoid check,
            sampled every ``control_dt``, needs a margin of ``control_dt * fall_rate``.
        table_error: [m] how far above the table's zero level the avoidance must start for ``u^A`` to keep the
            intruder out of ``R_c`` in closed loop: the largest loss of the game flown from the zero level
            (:func:`certify_zero_level`) plus ``config.certify_allowance``. The simulator's avoid margin adds it.
            ``nan`` when the table is not certified (``config.certify`` false).
        certificate: the certification's numbers (:func:`certify_zero_level`): ``loss`` (largest ``R_c - min
            distance`` from the zero level [m]), ``tau0``, ``bearing``, ``heading`` of that start, and ``starts``.
    """

    config: AvoidRegionConfig
    taus: np.ndarray
    values: np.ndarray
    n_steps: int
    fall_rate: float
    table_error: float = 0.0
    certificate: dict = dataclasses.field(default_factory=dict)

    @property
    def grid(self) -> hj.Grid:
        return self.config.grid

    @property
    def boundary_margin(self) -> float:
        """Minimum of ``V^A(0)`` on the non-periodic faces: positive when the set does not touch the box."""
        return self.grid.boundary_faces_min(self.values[0])

    def detection_range(self, n_rays: int = 720) -> float:
        """``d^A`` (eq. 16): the largest ``||p||`` over ``V^A(0, t_IAT)``.

        Evaluated on the projection ``min_theta V`` along ``n_rays`` rays from the origin, sampled every tenth
        of a cell with bilinear interpolation, so the answer is resolved below one grid cell."""
        grid = self.grid
        proj = jnp.asarray(np.asarray(self.values[0]).min(axis=2))
        plane = hj.Grid.from_bounds(grid.lo[:2], grid.hi[:2], grid.shape[:2])
        step = 0.1 * min(plane.spacing)
        radii = np.arange(0.0, grid.hi[0], step)
        angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
        pts = np.stack([np.outer(np.cos(angles), radii), np.outer(np.sin(angles), radii)], -1)
        vals = np.asarray(jax.vmap(jax.vmap(lambda s: hj.interpolation.interpolate(plane, proj, s)))(
            jnp.asarray(pts, proj.dtype)))
        inside = vals <= 0
        if not inside.any():
            return 0.0
        return float(np.max(np.where(inside, radii[None, :], 0.0)))


@dataclasses.dataclass(frozen=True)
class AvoidGame:
    """What flying the avoid game needs besides its table: the table's grid, the relative dynamics with the roles
    of eq. (14), ``t_IAT`` [s] and ``R_c`` [m] (hashable: compiled programs are cached by it)."""

    grid: hj.Grid
    dynamics: RelativeDubins
    t_iat: float
    collision_radius: float


def _level_radius(grid: hj.Grid, taus, values, tau, direction, rel_heading, level):
    """The distance along the unit ``direction`` at which the table's ``V^A(tau)`` crosses ``level`` (just
    outside), by bisection between the vehicle and the table's edge on that bearing."""
    r_hi0 = 0.999 * min(-grid.lo[0], grid.hi[0], -grid.lo[1], grid.hi[1])

    def inside(r):
        x = jnp.stack([r * direction[0], r * direction[1], rel_heading])
        return avoid_table_value(grid, taus, values, tau, x) <= level

    def bisect(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        return jnp.where(inside(mid), mid, lo), jnp.where(inside(mid), hi, mid)

    _, hi = jax.lax.fori_loop(0, 40, bisect, (jnp.zeros((), jnp.float32), jnp.asarray(r_hi0, jnp.float32)))
    return hi


_ZERO_LEVEL_PROGRAMS: dict = {}
SWEEP_CHUNKS = 8
CERTIFY_STEPS = SWEEP_CHUNKS + 4 + 1
"""The steps :func:`certify_zero_level` reports: the sweep's chunks, the local search's rounds, the final flights."""


def _zero_level_program(game: AvoidGame, h: float, hold: int):
    """Compiled ``(taus, values, starts (M, 3) of (tau_0, bearing, heading), level) -> loss per start`` [m]."""
    key = (game, float(h), int(hold))
    if key in _ZERO_LEVEL_PROGRAMS:
        return _ZERO_LEVEL_PROGRAMS[key]
    grid, dyn = game.grid, game.dynamics
    t_iat, r_c = float(game.t_iat), float(game.collision_radius)
    n_max = round(t_iat / h)

    def run(taus, values, starts, level):
        def gradient(t, x):
            return hj.interpolation.gradient_slices(grid, taus, values, t, x)

        def one(start):
            tau0, bearing, heading = start[0], start[1], start[2]
            direction = jnp.stack([jnp.cos(bearing), jnp.sin(bearing)])
            r = _level_radius(grid, taus, values, tau0, direction, heading, level)
            x0 = jnp.stack([r * direction[0], r * direction[1], heading])
            xs, _, _ = closed_loop.rollout(dyn, gradient, gradient, x0, h=h, n_steps=n_max, hold=hold, t0=tau0)
            # the intruder leaves after t_IAT: only the periods before count
            live = tau0 + h * jnp.arange(n_max) < t_iat - 1e-6
            dist = jnp.where(live, jnp.hypot(xs[:, 0], xs[:, 1]), jnp.inf)
            return r_c - jnp.minimum(jnp.min(dist), jnp.hypot(x0[0], x0[1]))

        return jax.vmap(one)(starts)

    _ZERO_LEVEL_PROGRAMS[key] = jax.jit(run)
    return _ZERO_LEVEL_PROGRAMS[key]


def certify_zero_level(game: AvoidGame, taus, values, *, n_taus: int = 20, n_bearings: int = 32,
                       n_headings: int = 32, n_refine: int = 8, level: float = 0.0,
                       control_dts=CERTIFIED_CONTROL_DT, decision_dt: float = 0.1, on_step=None) -> dict:
    """Fly the avoid game in closed loop from the table's level ``level`` (module docstring, "Certification"):
    ``u^A`` against the game's own optimal pursuit and worst combined wind, all three read from the table's
    gradient, the vehicle's control re-read every inner period ``h`` in ``control_dts``, the intruder's every period
    and also held for a decision step ``decision_dt`` (as the simulator holds an intruder's action); from starts on
    the level of ``V^A(tau_0)`` at ``n_taus`` times ``tau_0`` in ``[0, t_IAT)``, ``n_bearings`` bearings and
    ``n_headings`` relative headings (a sweep at the coarsest period), the ``n_refine`` worst refined by a local
    search and then flown at every period and hold.

    Returns ``{"loss": largest R_c - min distance [m], "tau0", "bearing", "heading": its start, "starts": count}``.
    A vehicle whose avoidance starts ``loss`` above ``level`` or higher keeps the intruder out of ``R_c`` against
    these strategies. ``on_step``: called with a short description after each of the :data:`CERTIFY_STEPS` steps
    (progress)."""
    taus = jnp.asarray(taus, jnp.float32)
    values = jnp.asarray(values, jnp.float32)
    t_iat = float(game.t_iat)
    tau0 = np.arange(n_taus) * (t_iat / n_taus)
    bearing = (np.arange(n_bearings) + 0.5) * (2 * np.pi / n_bearings) - np.pi
    heading = (np.arange(n_headings) + 0.5) * (2 * np.pi / n_headings) - np.pi
    grid = np.stack(np.meshgrid(tau0, bearing, heading, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    programs = [(h, _zero_level_program(game, h, hold)) for h in control_dts
                for hold in sorted({1, max(1, round(decision_dt / h))})]
    level = jnp.asarray(level, jnp.float32)

    def losses(starts, which):
        starts = jnp.asarray(starts, jnp.float32)
        return np.max([np.asarray(p(taus, values, starts, level), np.float64) for _, p in which], axis=0)

    # sweep and local search at the coarsest period (the cheapest), then the worst starts at every period and hold
    coarse = [(h, p) for h, p in programs if h == max(control_dts)]
    done = on_step if on_step is not None else (lambda _: None)
    chunks = np.array_split(np.arange(len(grid)), SWEEP_CHUNKS)
    parts = []
    for c in chunks:
        if len(c):
            parts.append(losses(grid[c], coarse))
        done("sweep")
    sweep = np.concatenate(parts)
    count = len(grid)
    top = grid[np.argsort(-sweep)[:n_refine]].astype(np.float64)
    step = np.array([t_iat / n_taus, 2 * np.pi / n_bearings, 2 * np.pi / n_headings]) / 2
    offsets = np.stack(np.meshgrid(*[np.array([-1.0, 0.0, 1.0])] * 3, indexing="ij"), -1).reshape(-1, 3)
    for _ in range(4):  # a 3 x 3 x 3 pattern around each, halving
        cand = (top[:, None, :] + offsets[None] * step).reshape(-1, 3)
        cand[:, 0] = np.clip(cand[:, 0], 0.0, t_iat - 1e-3)
        cand[:, 1:] = (cand[:, 1:] + np.pi) % (2 * np.pi) - np.pi
        vals = losses(cand, coarse).reshape(len(top), -1)
        count += cand.shape[0]
        j = np.argmax(vals, axis=1)
        top = cand.reshape(len(top), -1, 3)[np.arange(len(top)), j]
        step = step / 2
        done("local search")
    best = losses(top, programs)
    done("every inner period")
    count += len(top)
    i = int(np.argmax(best))
    loss = max(float(best[i]), float(sweep.max()))
    return {"loss": loss, "tau0": float(top[i, 0]), "bearing": float(top[i, 1]), "heading": float(top[i, 2]),
            "starts": count}


def compute_avoid_region(config: AvoidRegionConfig | None = None, *, store: ArtifactStore | None = None,
                         progress: bool = True) -> AvoidRegion:
    """Solves eqs. (13)-(14): the backward reachable tube of the danger zone over ``[tau, t_IAT]``, then certifies
    it in closed loop from its zero level (:func:`certify_zero_level`). Both are cached in ``store`` when given, as
    two artifacts: the table (``avoid_region``, tens of megabytes) and its certificate (``avoid_certificate``, a few
    numbers, shipped with the package for the scenarios whose plans ship)."""
    config = AvoidRegionConfig() if config is None else config

    def compute():
        grid = config.grid
        target = hj.shapes.cylinder(grid, (0, 1), (0.0, 0.0), config.collision_radius)
        settings = hj.SolverSettings.with_accuracy(config.accuracy)
        taus_desc = np.linspace(config.t_iat, 0.0, config.n_slices)
        result = hj.solve(settings, config.relative_dynamics, grid, taus_desc, target, tube=True,
                          progress=progress)
        taus = taus_desc[::-1].copy()
        values = np.asarray(result.values)[::-1].copy()  # ascending tau: values[0] = V^A(0, t_IAT)
        rate = avoid_value_fall_rate(values, taus, grid, config.vehicle, config.intruder, FALL_RATE_BAND)
        return {"taus": taus, "values": values, "n_steps": np.asarray(result.n_steps), "fall_rate": np.asarray(rate)}

    arrays = compute() if store is None else store.load_or_compute("avoid_region", config, compute).arrays

    def certificate():
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=CERTIFY_STEPS, desc="avoid region: certifying in closed loop (compiling)", unit="step",
                       leave=False)

        def step(what):
            if bar is not None:
                bar.set_description(f"avoid region: certifying in closed loop ({what})")
                bar.update(1)

        try:
            cert = certify_zero_level(config.game, arrays["taus"], arrays["values"], n_taus=config.certify_taus,
                                      n_bearings=config.certify_bearings, n_headings=config.certify_headings,
                                      n_refine=config.certify_refine, on_step=step)
        finally:
            if bar is not None:
                bar.close()
        return {"certificate": np.asarray([cert["loss"], cert["tau0"], cert["bearing"], cert["heading"],
                                           cert["starts"]], np.float64)}

    if config.certify:
        cert_arrays = certificate() if store is None else \
            store.load_or_compute("avoid_certificate", config, certificate).arrays
        cert = np.asarray(cert_arrays["certificate"], np.float64)
        certificate = dict(zip(("loss", "tau0", "bearing", "heading", "starts"), (float(c) for c in cert),
                               strict=True))
        table_error = max(0.0, certificate["loss"]) + config.certify_allowance
    else:
        certificate, table_error = {}, math.nan
    region = AvoidRegion(config=config, taus=np.asarray(arrays["taus"]), values=np.asarray(arrays["values"]),
                         n_steps=int(arrays["n_steps"]), fall_rate=float(arrays["fall_rate"]),
                         table_error=table_error, certificate=certificate)
    if region.boundary_margin <= 0:
        raise ValueError(
            f"The avoid region touches the grid boundary (half_width={config.half_width} m); the set is cut off "
            f"and cannot be trusted. Increase half_width (the set extends at least {config.behind_extent():.0f} m "
            "behind the vehicle)."
        )
    return region


def avoid_table_value(grid: hj.Grid, taus, values, tau, x_rel):
    """``V^A(tau, t_IAT)(x_rel)`` read from a table of slices ``values`` at ascending ``taus`` on ``grid`` (linear
    in ``tau``, multilinear in the state; jittable). The one reader of avoid tables: :func:`make_value_function`
    and the simulator (:mod:`stp_env.sim.tables`) both use it."""
    return hj.interpolation.interpolate_slices(grid, taus, values, tau, x_rel)


def avoid_table_input(dynamics: RelativeDubins, grid: hj.Grid, taus, values, player: str, tau, x_rel):
    """The optimal input of one player of eq. (14) at ``x_rel`` from the interpolated gradient of the table:
    ``player="vehicle"``: ``u^A = (v_i, omega_i)`` (eq. 15, the maximising control); ``"intruder"``: ``(v_I,
    omega_I, w_x, w_y)``, the minimising intruder control and worst combined wind (vehicle's body frame)."""
    if player not in ("vehicle", "intruder"):
        raise ValueError(f"player must be 'vehicle' or 'intruder'; got {player!r}.")
    p = hj.interpolation.gradient_slices(grid, taus, values, tau, x_rel)
    optimum = dynamics.optimal_control if player == "vehicle" else dynamics.optimal_disturbance
    return jnp.stack(optimum((x_rel[0], x_rel[1], x_rel[2]), (p[0], p[1], p[2])))


def make_value_function(region: AvoidRegion):
    """Jittable ``(tau, x_rel) -> V^A(tau, t_IAT)(x_rel)`` (:func:`avoid_table_value` of ``region``)."""
    grid = region.grid
    taus = jnp.asarray(region.taus, jnp.float32)
    stack = jnp.asarray(region.values, jnp.float32)

    def value(tau, x_rel):
        return avoid_table_value(grid, taus, stack, tau, x_rel)

    return value


def _optimal_input(region: AvoidRegion, player: str):
    dyn = region.config.relative_dynamics
    grid = region.grid
    taus = jnp.asarray(region.taus, jnp.float32)
    stack = jnp.asarray(region.values, jnp.float32)

    def u(tau, x_rel):
        return avoid_table_input(dyn, grid, taus, stack, player, tau, x_rel)

    return u


def make_avoidance_controller(region: AvoidRegion):
    """The avoidance control ``u^A`` (eq. 15) as a jittable ``(tau, x_rel) -> (v_i, omega_i)``, ``x_rel`` the
    intruder's state in the vehicle's body frame (eq. 44), ``tau`` the time since the intruder appeared [s]."""
    return _optimal_input(region, "vehicle")


def make_pursuit_controller(region: AvoidRegion):
    """The intruder's optimal pursuit (the minimising player of eq. 14) as a jittable ``(tau, x_rel) ->
    (v_I, omega_I, w_x, w_y)``: intruder speed and turn rate, and the worst combined wind in the vehicle's body
    frame [m/s]."""
    return _optimal_input(region, "intruder")
