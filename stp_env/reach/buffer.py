"""Relative buffer region ``V^B(0, t_BRD)``, separation and buffer regions, and their conservative disk radii.

Intruder paper Sections IV-B (Case 1) and VII-A (Case 2):

* ``t_BRD = t_IAT / k̄`` (beginning of Section IV).
* Relative buffer region ``V^B(0, t_BRD)``, eqs. (46)-(47): the relative states (intruder relative to a vehicle,
  in its body frame) from which the intruder can reach the avoid region ``V^A(t_BRD, t_IAT)`` within ``t_BRD``
  when *everyone* (vehicle, intruder, both winds) helps: all players minimise. Eq. (22) defines the same set in
  the other relative frame (vehicle relative to intruder, in the intruder's frame); its position footprint has
  the same radius.
* Separation region ``S_j = M_j + dV^A(0, t_IAT)`` (eq. 20; ``t_RD = t_IAT - t_BRD`` in Case 2, eq. 45) and buffer
  regions ``B_ij = S_j + V^B`` (eq. 21) and ``B_ji = M_j + V^B + (-V^A)`` (eq. 48).

For the planner these sets are replaced by rotation-invariant disks around the higher-priority vehicle's nominal
position, with radii (``r_M`` = tracking-error bound of robust trajectory tracking, the base obstacle ``M``)

    S:     r_S  = r_M + d^A
    B_ij:  r_B  = r_M + d^A + r_VB (+ r_M of the lower-priority vehicle itself, Remark 1)
    B_ji:  the same radius (``M + V^B + (-V^A)`` has the same footprint bound),

where ``d^A`` and ``r_VB`` are the largest position norms over ``V^A(0, t_IAT)`` and ``V^B(0, t_BRD)``.
:func:`disk_conservatism` reports how much area the disks add over the grid sets.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.artifacts import ArtifactStore
from stp_env.reach.avoid import AvoidRegion, AvoidRegionConfig, compute_avoid_region


def brd_time(t_iat: float, kbar: int) -> float:
    """``t_BRD = t_IAT / k̄``."""
    if isinstance(kbar, bool) or not isinstance(kbar, (int, np.integer)) or kbar < 1:
        raise ValueError(f"k̄ must be an integer >= 1 (the number of vehicles the intruder may force to avoid); "
                         f"got {kbar!r}.")
    if not (math.isfinite(t_iat) and t_iat > 0):
        raise ValueError(f"t_IAT must be positive; got {t_iat}.")
    return t_iat / kbar


@dataclasses.dataclass(frozen=True, kw_only=True)
class BufferConfig:
    """Parameters of the relative buffer region for one ``k̄``.

    Attributes:
        avoid: the avoid-region parameters (dynamics, ``R_c``, ``t_IAT``).
        kbar: ``k̄ >= 1``.
        half_width: position half-width of the (larger) grid of ``V^B`` [m]; ``None`` picks
            ``1.25 * (R_c + (v_i + v_I + winds) t_IAT / k̄ + margin)``.
        grid_points: grid points of ``V^B``.
    """

    avoid: AvoidRegionConfig = dataclasses.field(default_factory=AvoidRegionConfig)
    kbar: int = 3
    half_width: float | None = None
    grid_points: tuple[int, int, int] = (61, 61, 60)

    def __post_init__(self) -> None:
        brd_time(self.avoid.t_iat, self.kbar)
        if self.half_width is not None and not self.half_width > self.avoid.half_width * 0.5:
            raise ValueError(f"half_width {self.half_width} m is too small for the avoid region.")
        if len(self.grid_points) != 3 or min(self.grid_points) < 5:
            raise ValueError(f"grid_points must be 3 counts >= 5; got {self.grid_points}.")

    @property
    def t_brd(self) -> float:
        return brd_time(self.avoid.t_iat, self.kbar)

    @property
    def closing_speed(self) -> float:
        """Largest rate at which the two vehicles can approach each other [m/s]."""
        a = self.avoid
        return a.vehicle.v_max + a.intruder.v_max + a.vehicle.wind + a.intruder.wind

    @property
    def grid(self) -> hj.Grid:
        if self.half_width is None:
            w = 1.2 * (self.avoid.half_width + self.closing_speed * self.t_brd)
        else:
            w = self.half_width
        return hj.Grid.from_bounds((-w, -w, -math.pi), (w, w, math.pi), self.grid_points, periodic=2)


@dataclasses.dataclass(frozen=True)
class RelativeBuffer:
    """``V^B(0, t_BRD)`` on ``config.grid`` and its position radius ``r_VB``."""

    config: BufferConfig
    values: np.ndarray
    radius: float
    n_steps: int


def position_radius(grid: hj.Grid, values, n_rays: int = 720) -> float:
    """Largest ``||p||`` over ``{V <= 0}`` (positions in the first two grid dimensions), resolved below a cell
    by bilinear sampling of ``min_theta V`` along rays."""
    proj = jnp.asarray(np.asarray(values).min(axis=tuple(range(2, np.ndim(values)))))
    plane = hj.Grid.from_bounds(grid.lo[:2], grid.hi[:2], grid.shape[:2])
    step = 0.1 * min(plane.spacing)
    radii = np.arange(0.0, min(abs(grid.lo[0]), grid.hi[0], abs(grid.lo[1]), grid.hi[1]), step)
    angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    pts = np.stack([np.outer(np.cos(angles), radii), np.outer(np.sin(angles), radii)], -1)
    vals = np.asarray(jax.vmap(jax.vmap(lambda s: hj.interpolation.interpolate(plane, proj, s)))(
        jnp.asarray(pts, proj.dtype)))
    inside = vals <= 0
    return float(np.max(np.where(inside, radii[None, :], 0.0))) if inside.any() else 0.0


def resample(src_grid: hj.Grid, values, dst_grid: hj.Grid) -> jnp.ndarray:
    """``values`` on ``src_grid`` interpolated at the nodes of ``dst_grid`` (clamped outside the source)."""
    states = dst_grid.states().reshape(-1, dst_grid.ndim)
    flat = jax.jit(jax.vmap(lambda s: hj.interpolation.interpolate(src_grid, values, s)))(states)
    return flat.reshape(dst_grid.shape)


def swap_relative_frame(grid: hj.Grid, values) -> jnp.ndarray:
    """Re-expresses a set of relative states ``x_Ij`` (intruder relative to vehicle ``j``, in ``j``'s frame) in
    the other frame ``x_jI`` (vehicle relative to intruder, in the intruder's frame), by interpolation.

    ``p_jI = -R(-theta_Ij) p_Ij`` and ``theta_jI = -theta_Ij``; the map is its own inverse. It turns ``V^B`` of
    eq. (46) into the set of eq. (22), which the paper writes loosely with a minus sign."""
    x = grid.states()
    th = -x[..., 2]
    c, s = jnp.cos(th), jnp.sin(th)
    # Source state (in the x_Ij frame) of each destination node: p = -R(-theta') p', theta = -theta'.
    px = -(c * x[..., 0] + s * x[..., 1])
    py = -(-s * x[..., 0] + c * x[..., 1])
    src = jnp.stack([px, py, th], -1).reshape(-1, 3)
    flat = jax.jit(jax.vmap(lambda q: hj.interpolation.interpolate(grid, jnp.asarray(values), q)))(src)
    return flat.reshape(grid.shape)


def compute_relative_buffer(config: BufferConfig, avoid: AvoidRegion | None = None, *,
                            store: ArtifactStore | None = None, progress: bool = True) -> RelativeBuffer:
    """Solves eqs. (46)-(47): the tube of ``V^A(t_BRD, t_IAT)`` over ``t_BRD`` with every player minimising.

    The avoid slice is resampled onto the larger buffer grid; outside the avoid grid the clamped values are
    positive, which does not move the zero level set: with all players minimising, ``V^B`` is exactly the set
    from which ``{V^A <= 0}`` is reachable, whatever positive values the target takes elsewhere.
    """
    if avoid is None:
        avoid = compute_avoid_region(config.avoid, store=store, progress=progress)
    if avoid.config != config.avoid:
        raise ValueError("The avoid region passed was computed with other parameters than config.avoid.")

    def compute():
        taus = avoid.taus
        k = int(np.argmin(np.abs(taus - config.t_brd)))
        if abs(taus[k] - config.t_brd) > 1e-6 * config.avoid.t_iat:
            slab = hj.interpolation.interpolate_in_time(taus, jnp.asarray(avoid.values), config.t_brd)
        else:
            slab = jnp.asarray(avoid.values[k])
        target = resample(avoid.grid, slab, config.grid)
        dyn = config.avoid.relative_dynamics.with_modes(control_mode="min", disturbance_mode="min")
        settings = hj.SolverSettings.with_accuracy(config.avoid.accuracy)
        res = hj.solve(settings, dyn, config.grid, [0.0, -config.t_brd], target, tube=True, progress=progress)
        return {"values": np.asarray(res.values[-1]), "n_steps": np.asarray(res.n_steps)}

    arrays = compute() if store is None else store.load_or_compute("relative_buffer", config, compute).arrays
    values = np.asarray(arrays["values"])
    grid = config.grid
    if grid.boundary_faces_min(values) <= 0:
        raise ValueError(f"V^B for k̄={config.kbar} touches its grid boundary; increase BufferConfig.half_width.")
    return RelativeBuffer(config=config, values=values, radius=position_radius(grid, values),
                          n_steps=int(arrays["n_steps"]))


@dataclasses.dataclass(frozen=True)
class BufferRadii:
    """Conservative rotation-invariant disk radii around a higher-priority vehicle's nominal position [m].

    Attributes:
        kbar, t_brd: the design parameter and ``t_IAT / k̄`` [s].
        tracking_bound: ``r_M``, radius of the base obstacle ``M`` (tracking-error bubble).
        detection_range: ``d^A`` (eq. 16).
        relative_buffer: ``r_VB``, position radius of ``V^B(0, t_BRD)``.
        separation: ``r_S = r_M + d^A`` (eq. 20).
        buffer: ``r_M + d^A + r_VB + r_M`` (eqs. 21, 48, with the lower-priority vehicle's own tracking error).
    """

    kbar: int
    t_brd: float
    tracking_bound: float
    detection_range: float
    relative_buffer: float
    separation: float
    buffer: float


def buffer_radii(kbar: int, tracking_bound: float, detection_range: float, relative_buffer: float,
                 t_iat: float) -> BufferRadii:
    if tracking_bound < 0 or detection_range <= 0 or relative_buffer <= 0:
        raise ValueError("Radii must be positive (tracking bound >= 0).")
    return BufferRadii(
        kbar=kbar, t_brd=brd_time(t_iat, kbar), tracking_bound=tracking_bound,
        detection_range=detection_range, relative_buffer=relative_buffer,
        separation=tracking_bound + detection_range,
        buffer=2 * tracking_bound + detection_range + relative_buffer,
    )


def projection_area(grid: hj.Grid, values) -> float:
    """Area of the position footprint ``{p : exists theta, V(p, theta) <= 0}`` (node count times cell area)."""
    proj = np.asarray(values).min(axis=2)
    return float((proj <= 0).sum() * grid.spacing[0] * grid.spacing[1])


def disk_conservatism(grid: hj.Grid, values, radius: float) -> float:
    """Area of the disk of ``radius`` over the area of the set's position footprint (>= 1; 1 = exact)."""
    area = projection_area(grid, values)
    return math.pi * radius**2 / area if area > 0 else math.inf
