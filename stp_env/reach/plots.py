"""Figures of the reachability sets, in the spirit of the intruder paper's Figs. 2 and 3.

Sets are drawn as position footprints in the body frame of the (higher-priority) vehicle, which sits at the
origin heading to +x: a footprint is ``{p : exists theta, V(p, theta) <= 0}``. Minkowski sums with disks (the
base obstacle ``M``, a tracking-error bubble) are computed exactly on the plotting grid from distances.
"""

from __future__ import annotations

import math

import numpy as np

from stp_env.files import save_figure
from stp_env.reach.avoid import AvoidRegion
from stp_env.reach.buffer import BufferRadii, RelativeBuffer


def _footprint(grid, values):
    """``(grid, min_theta V)``: the position footprint's value (``<= 0`` inside) on the position plane."""
    return np.asarray(values).min(axis=tuple(range(2, np.ndim(values))))


def _resample_mask(grid, projected, xs, ys):
    """Bilinear interpolation of a projected value on a plotting grid, thresholded at zero (False outside the
    source grid)."""
    gx, gy = grid.coordinate_vector(0), grid.coordinate_vector(1)
    fx = (xs - gx[0]) / (gx[1] - gx[0])
    fy = (ys - gy[0]) / (gy[1] - gy[0])
    okx = (fx >= 0) & (fx <= len(gx) - 1)
    oky = (fy >= 0) & (fy <= len(gy) - 1)
    i = np.clip(np.floor(fx).astype(int), 0, len(gx) - 2)
    j = np.clip(np.floor(fy).astype(int), 0, len(gy) - 2)
    a = np.clip(fx - i, 0, 1)[:, None]
    b = np.clip(fy - j, 0, 1)[None, :]
    v = projected
    val = ((1 - a) * (1 - b) * v[np.ix_(i, j)] + a * (1 - b) * v[np.ix_(i + 1, j)]
           + (1 - a) * b * v[np.ix_(i, j + 1)] + a * b * v[np.ix_(i + 1, j + 1)])
    return (val <= 0) & okx[:, None] & oky[None, :]


def _dilate(mask, xs, ys, radius):
    """``mask`` grown by a disk of ``radius`` (Minkowski sum), from distances to the mask's nodes."""
    if radius <= 0:
        return mask.copy()
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    src = pts[mask.reshape(-1)]
    # Only boundary nodes matter for the distance to the set.
    inner = mask.copy()
    inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
    src = pts[(mask & ~inner).reshape(-1)] if (mask & ~inner).any() else src
    out = mask.reshape(-1).copy()
    for start in range(0, len(pts), 4096):
        chunk = pts[start:start + 4096]
        d2 = ((chunk[:, None, :] - src[None, :, :]) ** 2).sum(-1).min(axis=1)
        out[start:start + 4096] |= d2 <= radius**2
    return out.reshape(mask.shape)


def _setup(ax, extent, title):
    ax.set_aspect("equal")
    ax.set_xlim(-extent, extent)
    ax.set_ylim(-extent, extent)
    ax.set_xlabel("p_x [m] (vehicle frame, heading +x)")
    ax.set_ylabel("p_y [m]")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)


def plot_sets(avoid: AvoidRegion, tracking_bound: float, buffer: RelativeBuffer, path: str) -> str:
    """Four panels like Fig. 2: base obstacle ``M``, avoid region ``V^A(0, t_IAT)``, separation region
    ``S = M + dV^A`` and relative buffer region ``V^B(0, t_BRD)``."""
    import matplotlib.pyplot as plt

    wa = float(avoid.grid.hi[0])
    xa = np.linspace(-wa, wa, 401)
    va = _resample_mask(avoid.grid, _footprint(avoid.grid, avoid.values[0]), xa, xa)
    s_region = _dilate(va, xa, xa, tracking_bound)
    wb = float(buffer.config.grid.hi[0])
    xb = np.linspace(-wb, wb, 401)
    vb = _resample_mask(buffer.config.grid, _footprint(buffer.config.grid, buffer.values), xb, xb)
    fig, axes = plt.subplots(2, 2, figsize=(11, 11), constrained_layout=True)
    panels = [
        (None, None, f"Base obstacle M: tracking-error bubble, r = {tracking_bound:.1f} m"),
        (va, xa, r"Avoid region $V^A(0, t_{IAT})$ footprint"),
        (s_region, xa, r"Separation region $S = M + \partial V^A$ footprint"),
        (vb, xb, rf"Relative buffer region $V^B(0, t_{{BRD}})$, k̄ = {buffer.config.kbar}, "
                 rf"$t_{{BRD}}$ = {buffer.config.t_brd:.2f} s"),
    ]
    for ax, (mask, xs, title) in zip(axes.flat, panels):
        if mask is None:
            zoom = max(4 * tracking_bound, 10.0)
            ax.add_patch(plt.Circle((0, 0), tracking_bound, color="tab:blue", alpha=0.4))
            _setup(ax, zoom, title)
        else:
            ax.contourf(xs, xs, mask.T.astype(float), levels=[0.5, 1.5], colors=["tab:red"], alpha=0.35)
            ax.contour(xs, xs, mask.T.astype(float), levels=[0.5], colors=["tab:red"])
            ax.add_patch(plt.Circle((0, 0), avoid.config.collision_radius, color="0.5", alpha=0.4))
            _setup(ax, float(xs[-1]), title)
        ax.annotate("", xy=(0.3 * ax.get_xlim()[1], 0), xytext=(0, 0),
                    arrowprops={"arrowstyle": "->", "lw": 2})
    cfg = avoid.config
    fig.suptitle(f"Sets around one vehicle (grey: danger zone R_c = {cfg.collision_radius:g} m); wind "
                 f"{cfg.vehicle.wind:g} m/s, t_IAT = {cfg.t_iat:g} s")
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def plot_buffer_regions(avoid: AvoidRegion, tracking_bound: float, buffers: dict[int, RelativeBuffer],
                        radii: dict[int, BufferRadii], path: str) -> str:
    """Like Fig. 3: the buffer regions ``B = M + dV^A + V^B + M`` (footprints, filled) for several ``k̄``,
    with the conservative disks the planner uses (dashed)."""
    import matplotlib.pyplot as plt

    extent = max(r.buffer for r in radii.values()) * 1.08
    xs = np.linspace(-extent, extent, 321)
    ys = xs
    va = _resample_mask(avoid.grid, _footprint(avoid.grid, avoid.values[0]), xs, ys)
    fig, ax = plt.subplots(figsize=(8.5, 8.5), constrained_layout=True)
    colors = plt.cm.viridis(np.linspace(0.15, 0.85, len(buffers)))
    for (kbar, buf), col in sorted(zip(buffers.items(), colors), key=lambda kv: -kv[0][1].radius):
        grown = _dilate(va, xs, ys, 2 * tracking_bound + buf.radius)
        ax.contourf(xs, ys, grown.T.astype(float), levels=[0.5, 1.5], colors=[col], alpha=0.25)
        ax.contour(xs, ys, grown.T.astype(float), levels=[0.5], colors=[col], linewidths=2)
        r = radii[kbar].buffer
        ax.add_patch(plt.Circle((0, 0), r, fill=False, ls="--", color=col, lw=1.5))
        ax.plot([], [], color=col, lw=2, label=f"k̄ = {kbar}: t_BRD = {buf.config.t_brd:.2f} s, disk {r:.0f} m")
    ax.contourf(xs, ys, va.T.astype(float), levels=[0.5, 1.5], colors=["tab:red"], alpha=0.4)
    ax.plot([], [], color="tab:red", lw=6, alpha=0.4, label=r"$V^A(0, t_{IAT})$ footprint")
    ax.add_patch(plt.Circle((0, 0), avoid.config.collision_radius, color="0.4", alpha=0.5))
    ax.annotate("", xy=(0.15 * extent, 0), xytext=(0, 0), arrowprops={"arrowstyle": "->", "lw": 2})
    _setup(ax, extent, "Buffer regions for several k̄ (filled: grid sets; dashed: planner disks)")
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def footprint_area_ratio(avoid: AvoidRegion, tracking_bound: float, buffer: RelativeBuffer,
                         radius: float, resolution: int = 321) -> float:
    """Disk area over the area of the buffer-region grid set ``M + dV^A + V^B + M`` footprint (>= 1)."""
    extent = radius * 1.05
    xs = np.linspace(-extent, extent, resolution)
    va = _resample_mask(avoid.grid, _footprint(avoid.grid, avoid.values[0]), xs, xs)
    grown = _dilate(va, xs, xs, 2 * tracking_bound + buffer.radius)
    cell = (xs[1] - xs[0]) ** 2
    return math.pi * radius**2 / (grown.sum() * cell)


def plot_avoid_region(region: AvoidRegion, path: str, headings_deg=(0, 90, 180, -90)) -> str:
    """Writes a PNG: slices of ``V^A(0, t_IAT)`` at several relative headings, and its projection on the
    position plane with the danger zone and the detection range ``d^A``."""
    import matplotlib.pyplot as plt

    cfg = region.config
    grid = region.grid
    xs, ys, ths = (grid.coordinate_vector(i) for i in range(3))
    v0 = np.asarray(region.values[0])
    d_a = region.detection_range()
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.4), constrained_layout=True)

    ax = axes[0]
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(headings_deg)))
    for deg, col in zip(headings_deg, colors):
        k = int(np.argmin(np.abs(np.angle(np.exp(1j * (ths - np.deg2rad(deg)))))))
        ax.contour(xs, ys, v0[:, :, k].T, levels=[0.0], colors=[col], linewidths=2)
        ax.plot([], [], color=col, lw=2, label=f"relative heading {np.rad2deg(ths[k]):.0f} deg")
    _danger_and_vehicle(ax, cfg.collision_radius)
    ax.set_title(r"Avoid region $V^A(0, t_{IAT})$: slices by relative heading")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=8, frameon=False)

    ax = axes[1]
    proj = v0.min(axis=2)
    ax.contourf(xs, ys, proj.T, levels=[proj.min() - 1, 0.0], colors=["tab:red"], alpha=0.35)
    ax.contour(xs, ys, proj.T, levels=[0.0], colors=["tab:red"], linewidths=2)
    ax.plot([], [], color="tab:red", lw=2, label="union over headings")
    circle = plt.Circle((0, 0), d_a, fill=False, ls="--", color="k")
    ax.add_patch(circle)
    ax.plot([], [], "k--", label=f"detection range $d^A$ = {d_a:.0f} m")
    _danger_and_vehicle(ax, cfg.collision_radius)
    ax.set_title("Projection on the relative position plane")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=8, frameon=False)

    for ax in axes:
        ax.set_xlabel(r"$p_x$ of intruder in vehicle frame [m] (vehicle heads to +x)")
        ax.set_ylabel(r"$p_y$ [m]")
        ax.set_aspect("equal")
        ax.set_xlim(xs[0], xs[-1])
        ax.set_ylim(ys[0], ys[-1])
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"Intruder avoid region: v in [{cfg.vehicle.v_min:g}, {cfg.vehicle.v_max:g}] m/s, "
        f"|omega| <= {cfg.vehicle.omega_max:g} rad/s, wind {cfg.vehicle.wind:g} + {cfg.intruder.wind:g} m/s, "
        f"t_IAT = {cfg.t_iat:g} s, R_c = {cfg.collision_radius:g} m, grid {grid.shape}")
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path


def _danger_and_vehicle(ax, radius: float) -> None:
    import matplotlib.pyplot as plt

    ax.add_patch(plt.Circle((0, 0), radius, color="0.6", alpha=0.5))
    ax.plot([], [], "s", color="0.6", label=f"danger zone R_c = {radius:g} m")
    ax.annotate("", xy=(0.6 * radius, 0), xytext=(0, 0), arrowprops={"arrowstyle": "->", "lw": 2})
