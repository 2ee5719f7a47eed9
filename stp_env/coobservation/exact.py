"""Exact reachability regions between two observations, for a Dubins vehicle in wind, from the project's HJ solver.

A vehicle observed within ``r`` of ``q1`` at ``t1`` (any heading) and within ``r`` of ``q2`` at ``t2`` can have
visited position ``p`` exactly when some heading ``theta`` has

    T_F(p - q1, theta) + T_B(p - q2, theta) <= t2 - t1,

with ``T_F(x, theta)`` the least time to reach state ``(x, theta)`` from the disk ``|x| <= r`` (any heading) and
``T_B(x, theta)`` the least time from ``(x, theta)`` into that disk: the forward reachable set from the first
observation intersected with the backward reachable set of the second, over all split times (the intersection at
one common time is the tube of all splits because a vehicle that arrives early can wait: hover, or circle inside
the disk, which is what the sum of first-arrival times assumes). Control and wind both *help* (``"max"`` in the
forward problem, ``"min"`` in the backward one): the region holds every position the attacker could reach under
some wind, the conservative side for security. Both fields are translation invariant, so one solve on a grid
centred at the origin serves every pair of observations.

Time reversal gives ``T_B(x, theta) = T_F(x, theta + pi)`` (a trajectory run backward is a forward trajectory of
the vehicle turned around, with the wind reversed, still inside its disk), so :func:`compute` solves the forward
problem only; :func:`compute` with ``check_reversal=True`` also solves the backward one and records the largest
difference (a test of the solver set-up).

The ellipse of Def. 3 with ``a = (v_max + wind)(t2 - t1)/2 + r`` contains the region (its speed bound holds in
every direction). :func:`area_ratio` measures how much smaller the region is.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind

FAR = 1e6  # [s] stand-in for "never reached" inside the interpolation


@dataclasses.dataclass(frozen=True, kw_only=True)
class ExactRegionConfig:
    """The vehicle and the numerical grid of :func:`compute`.

    Attributes:
        v_min, v_max, omega_max, wind: the Dubins vehicle in wind (intruder paper eq. 43 bounds).
        radius: the observation radius [m] (initial and target disks), margins included.
        horizon: the longest interval between two observations it must serve [s].
        spacing: grid spacing in position [m]; n_headings: heading nodes (even, so that ``theta + pi`` is a node).
        accuracy: solver preset.
    """

    v_min: float
    v_max: float
    omega_max: float
    wind: float
    radius: float
    horizon: float
    spacing: float
    n_headings: int = 36
    accuracy: str = "medium"

    def __post_init__(self):
        for name in ("v_max", "omega_max", "radius", "horizon", "spacing"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0; got {v!r}.")
        if not (0 <= self.v_min <= self.v_max) or not self.wind >= 0:
            raise ValueError(f"need 0 <= v_min <= v_max and wind >= 0; got {self.v_min}, {self.v_max}, {self.wind}.")
        if isinstance(self.n_headings, bool) or not isinstance(self.n_headings, int) or self.n_headings < 8 or \
                self.n_headings % 2:
            raise ValueError(f"n_headings must be an even integer >= 8; got {self.n_headings!r}.")
        if self.radius < 5 * self.spacing / 2:
            raise ValueError(f"radius {self.radius} spans fewer than 5 cells at spacing {self.spacing} (small targets "
                             "smear away under the solver's dissipation); refine the grid.")

    @property
    def half_width(self) -> float:
        return (self.v_max + self.wind) * self.horizon + self.radius + 3 * self.spacing

    def grid(self) -> hj.Grid:
        n = 2 * math.ceil(self.half_width / self.spacing) + 1
        h = (n - 1) / 2 * self.spacing
        return hj.Grid.from_bounds([-h, -h, -math.pi], [h, h, math.pi], (n, n, self.n_headings), periodic=2)

    def vehicle(self) -> DubinsWind:
        return DubinsWind(v_min=self.v_min, v_max=self.v_max, omega_max=self.omega_max, wind=self.wind)


@dataclasses.dataclass(frozen=True)
class ExactRegions:
    """``ttr`` ``(nx, ny, n_theta)``: ``T_F`` on the grid [s] (``FAR`` where not reached within the horizon);
    ``reversal_error``: max ``|T_B - T_F(., theta + pi)|`` over nodes reached by both when checked, else NaN."""

    config: ExactRegionConfig
    ttr: np.ndarray
    reversal_error: float

    def _fields(self):
        g = self.config.grid()
        return g, jnp.asarray(np.moveaxis(self.ttr, 2, 0), jnp.float32)   # (n_theta, nx, ny)

    def sum_times(self, q1, q2, points):
        """``min_theta T_F(p - q1, theta) + T_B(p - q2, theta)`` at ``points`` ``(P, 2)`` [s]."""
        g, f = self._fields()
        half = self.config.n_headings // 2
        return _sum_times(f, jnp.roll(f, -half, axis=0), jnp.asarray(g.lo[:2], jnp.float32),
                          jnp.float32(g.spacing[0]), jnp.asarray(q1, jnp.float32), jnp.asarray(q2, jnp.float32),
                          jnp.asarray(points, jnp.float32))

    def secure_fn(self, forbidden, fallback=None, sample_spacing: float | None = None):
        """``secure(q1, t1, q2, t2)``: no sample point of the forbidden polygons (a lattice of ``sample_spacing``,
        default half a grid cell, and their boundaries) lies in the region. Intervals longer than the horizon use
        ``fallback`` (e.g. the ellipse test, whose region contains this one) or count as insecure."""
        h = self.config.spacing / 2 if sample_spacing is None else sample_spacing
        pts = jnp.asarray(np.concatenate([polygon_samples(p, h) for p in forbidden]), jnp.float32)

        def secure(q1, t1, q2, t2):
            delta = t2 - t1
            if delta > self.config.horizon + 1e-9:
                return bool(fallback(q1, t1, q2, t2)) if fallback is not None else False
            if fallback is not None and fallback(q1, t1, q2, t2):
                return True   # the ellipse misses the zones, so does the region inside it
            return bool(jnp.min(self.sum_times(q1, q2, pts)) > delta)

        return secure

    def region_mask(self, q1, q2, delta, lo, hi, spacing):
        """The region on a raster over ``[lo, hi]``: ``(mask (ny, nx), xs, ys)``."""
        xs = np.arange(lo[0], hi[0] + 1e-9, spacing)
        ys = np.arange(lo[1], hi[1] + 1e-9, spacing)
        pts = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
        s = np.asarray(self.sum_times(q1, q2, pts)).reshape(len(ys), len(xs))
        return s <= delta, xs, ys


@jax.jit
def _sum_times(f, f_rev, lo, dx, q1, q2, points):
    def lower(field, p):
        """The smallest of the four nodes around each point (not the bilinear value): the region may grow by up
        to a cell, never shrink. A first-arrival time jumps across the observation disk's rim with the heading
        (0 inside; a turn-around loop just outside for a heading pointing back in), and bilinear values there would
        cut up to a cell off the region."""
        idx = (p - lo) / dx
        n = jnp.asarray(field.shape)
        i0 = jnp.floor(idx).astype(jnp.int32)
        inside = jnp.all((i0 >= 0) & (i0 <= n - 2), axis=-1)
        i0 = jnp.clip(i0, 0, n - 2)
        corners = [field[i0[:, 0] + a, i0[:, 1] + b] for a in (0, 1) for b in (0, 1)]
        return jnp.where(inside, jnp.min(jnp.stack(corners), axis=0), FAR)

    a = jax.vmap(lambda fk: lower(fk, points - q1))(f)
    b = jax.vmap(lambda fk: lower(fk, points - q2))(f_rev)
    return jnp.min(a + b, axis=0)


def polygon_samples(vertices, spacing: float) -> np.ndarray:
    """Points of a convex polygon: a lattice of ``spacing`` inside it and its boundary at the same spacing."""
    v = np.asarray(vertices, float)
    lo, hi = v.min(0), v.max(0)
    xs = np.arange(lo[0], hi[0] + spacing / 2, spacing)
    ys = np.arange(lo[1], hi[1] + spacing / 2, spacing)
    pts = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    e = np.roll(v, -1, 0) - v
    cross = e[:, 0][None] * (pts[:, 1][:, None] - v[:, 1][None]) - e[:, 1][None] * (pts[:, 0][:, None] - v[:, 0][None])
    inside = np.all(cross >= -1e-9, 1) | np.all(cross <= 1e-9, 1)
    edge = []
    for a, b in zip(v, np.roll(v, -1, 0)):
        k = max(2, int(np.ceil(np.linalg.norm(b - a) / spacing)) + 1)
        edge.append(a + np.linspace(0, 1, k)[:, None] * (b - a))
    return np.concatenate([pts[inside], *edge])


def _solve_ttr(config: ExactRegionConfig, backward: bool, progress: bool) -> np.ndarray:
    grid = config.grid()
    target = hj.shapes.cylinder(grid, dims=(0, 1), center=(0.0, 0.0), radius=config.radius)
    mode = "min" if backward else "max"
    dyn = config.vehicle().with_modes(control_mode=mode, disturbance_mode=mode)
    times = [0.0, -config.horizon] if backward else [0.0, config.horizon]
    res = hj.solve(hj.SolverSettings.with_accuracy(config.accuracy), dyn, grid, times, target, tube=True,
                   time_to_reach=True, progress=progress)
    ttr = np.asarray(res.time_to_reach, np.float32)
    return np.where(np.isfinite(ttr), ttr, FAR).astype(np.float32)


def compute(config: ExactRegionConfig, *, store=None, check_reversal: bool = False,
            progress: bool = True) -> ExactRegions:
    """The forward time-to-reach field (cached in the artifact store, keyed by ``config``); with
    ``check_reversal`` the backward one too, to measure ``|T_B - T_F(., theta + pi)|``."""
    from stp_env.artifacts import ArtifactStore

    store = ArtifactStore() if store is None else store
    ttr = store.load_or_compute("coobs_exact_region", config,
                                lambda: {"ttr": _solve_ttr(config, False, progress)}).arrays["ttr"]
    err = float("nan")
    if check_reversal:
        back = store.load_or_compute("coobs_exact_region_backward", config,
                                     lambda: {"ttr": _solve_ttr(config, True, progress)}).arrays["ttr"]
        flipped = np.roll(ttr, -config.n_headings // 2, axis=2)
        both = (back < FAR / 2) & (flipped < FAR / 2)
        err = float(np.max(np.abs(back - flipped)[both])) if both.any() else float("nan")
    return ExactRegions(config=config, ttr=ttr, reversal_error=err)


def area_ratio(regions: ExactRegions, q1, q2, delta: float, spacing: float | None = None) -> dict:
    """Area of the exact region over that of the ellipse with foci ``q1, q2`` and semi-major
    ``(v_max + wind) delta / 2 + radius``, both measured on the same raster of ``spacing`` (default a grid cell)."""
    from stp_env.coobservation import ellipse

    cfg = regions.config
    spacing = cfg.spacing if spacing is None else spacing
    a = ellipse.semi_major(cfg.v_max + cfg.wind, 0.0, delta, cfg.radius)
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    lo = np.minimum(q1, q2) - a
    hi = np.maximum(q1, q2) + a
    mask, xs, ys = regions.region_mask(q1, q2, delta, lo, hi, spacing)
    pts = np.stack(np.meshgrid(xs, ys), -1)
    in_ellipse = (np.linalg.norm(pts - q1, axis=-1) + np.linalg.norm(pts - q2, axis=-1)) <= 2 * a
    exact_area = float(mask.sum()) * spacing**2
    ellipse_area = float(in_ellipse.sum()) * spacing**2
    c = float(np.linalg.norm(q2 - q1)) / 2
    return {"exact_area": exact_area, "ellipse_area": ellipse_area, "ratio": exact_area / ellipse_area,
            "ellipse_area_closed_form": math.pi * a * math.sqrt(max(a * a - c * c, 0.0)),
            "outside_ellipse": float((mask & ~in_ellipse).sum()) * spacing**2}
