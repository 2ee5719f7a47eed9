"""Top-down drawing of a simulation state (matplotlib): buildings, targets, nominal paths, vehicles with their
headings and danger zones, the intruder, and optionally each flying vehicle's avoid-region footprint."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.angles import wrap_angle
from stp_env.sim import tables
from stp_env.sim.types import AVOIDING, COLLIDED, FLYING, MODE_NAMES, PRESENT, WAITING

VEHICLE_COLOURS = {"nominal": "tab:blue", "avoiding": "tab:orange", "after_avoidance": "tab:purple"}


def _footprint(params, state, i, n=81):
    """``V^A(tau)`` of vehicle ``i`` against the intruder's current relative heading, on a world-frame grid."""
    grid = params.tables.avoid_grid
    w = float(grid.hi[0])
    s = np.linspace(-w, w, n)
    px, py = np.meshgrid(s, s, indexing="ij")
    xi = state.intruder_x
    pose = np.asarray(params.vehicles.model.pose(state.x[i]))
    rel_heading = wrap_angle(float(xi[2]) - float(pose[2]))
    pts = jnp.stack([px.ravel(), py.ravel(), jnp.full(px.size, rel_heading)], 1).astype(jnp.float32)
    tau = state.t - state.t_appear
    vals = np.asarray(jax.vmap(lambda r: tables.avoid_value(params, tau, r))(pts)).reshape(n, n)
    th = float(pose[2])
    c, sn = np.cos(th), np.sin(th)
    wx = float(pose[0]) + c * px - sn * py
    wy = float(pose[1]) + sn * px + c * py
    return wx, wy, vals


def draw_frame(env, fig=None):
    """Draw ``env``'s current state into ``fig`` (created when ``None``) and return the figure."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    params, state, scenario = env.params, jax.device_get(env.env_state), env.scenario
    if fig is None:
        fig = plt.figure(figsize=(6, 6), dpi=80)
    fig.clf()
    ax = fig.add_subplot(1, 1, 1)
    lo, hi = np.asarray(params.episode.domain_lo), np.asarray(params.episode.domain_hi)
    for b in scenario.buildings:
        ax.add_patch(Polygon(np.asarray(b.vertices), closed=True, color="0.55", zorder=1))
    rc = float(params.episode.collision_radius)
    targets = {}
    for i, (c, r) in enumerate(zip(np.asarray(params.vehicles.targets), np.asarray(params.vehicles.target_radii))):
        targets.setdefault((float(c[0]), float(c[1]), float(r)), []).append(i)
    for (cx, cy, r), owners in targets.items():
        ax.add_patch(Circle((cx, cy), r, fill=False, ec="tab:green", lw=1.2, zorder=2))
        ax.annotate(",".join(map(str, owners)), (cx, cy), fontsize=7, color="tab:green", ha="center", va="center")
    states = np.asarray(params.vehicles.nominal_states)
    lengths = np.asarray(params.vehicles.nominal_len)
    for i in range(params.vehicles.n):
        ax.plot(states[i, :lengths[i], 0], states[i, :lengths[i], 1], color="0.8", lw=0.8, zorder=1)
    x = np.asarray(params.vehicles.model.pose(state.x))  # (x, y, heading) whatever the vehicle model
    status, mode = np.asarray(state.status), np.asarray(state.mode)
    span = float(np.max(hi - lo))
    arrow = 0.03 * span
    present = int(state.intruder_status) == PRESENT
    for i in range(params.vehicles.n):
        if status[i] == WAITING:
            ax.plot(*x[i, :2], marker="s", ms=3, color="0.6", zorder=3)
            continue
        if status[i] != FLYING and status[i] != COLLIDED:
            continue
        colour = "red" if status[i] == COLLIDED else VEHICLE_COLOURS[MODE_NAMES[mode[i]]]
        ax.add_patch(Circle(x[i, :2], rc, fill=False, ec=colour, lw=0.8, ls="--", zorder=3))
        ax.arrow(x[i, 0], x[i, 1], arrow * np.cos(x[i, 2]), arrow * np.sin(x[i, 2]), width=0.004 * span,
                 color=colour, zorder=4, length_includes_head=True)
        ax.annotate(str(i), x[i, :2], xytext=(4, 4), textcoords="offset points", fontsize=7)
        if env.render_avoid_regions and present and status[i] == FLYING:
            wx, wy, vals = _footprint(params, state, i)
            ax.contour(wx, wy, vals, levels=[0.0], colors=[colour], linewidths=0.8)
    if present:
        xi = np.asarray(state.intruder_x)
        ax.add_patch(Circle(xi[:2], rc, color="red", alpha=0.25, zorder=3))
        ax.arrow(xi[0], xi[1], arrow * np.cos(xi[2]), arrow * np.sin(xi[2]), width=0.005 * span, color="red",
                 zorder=5, length_includes_head=True)
    n_forced = int(np.isfinite(np.asarray(state.avoid_start)).sum())
    kbar = int(params.intruder.kbar)
    avoiding = int(np.sum((mode == AVOIDING) & (status == FLYING)))
    ax.set_title(f"t = {float(state.t):7.1f} s   forced |N^RP| = {n_forced} (k̄ = {kbar})   avoiding now: {avoiding}",
                 fontsize=9)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.tight_layout()
    return fig
