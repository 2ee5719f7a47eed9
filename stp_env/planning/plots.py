"""Figures of plans: nominal trajectories, targets, buildings and the induced obstacles at one instant (in the
spirit of the intruder paper's Fig. 4 and the BEACLS paper's Figs. 5-11)."""

from __future__ import annotations

import numpy as np

from stp_env.files import save_figure


def plot_plan(plan, scenario, path: str, snapshot_time: float | None = None) -> str:
    """Writes a PNG of ``plan`` (from :func:`stp_env.planning.stp.plan_scenario`) for ``scenario``.

    ``snapshot_time`` (default: when the most vehicles are in the air) places each flying vehicle's marker and
    its induced obstacle disk (dashed: the lag-0 radius the lower-priority vehicles avoid)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    fig = Figure(figsize=(8.5, 8.5), constrained_layout=True)  # no pyplot: any backend (or none) can save it
    ax = fig.subplots()
    for b in scenario.buildings:
        xy = np.asarray(b.vertices)
        ax.fill(xy[:, 0], xy[:, 1], color="0.25", alpha=0.8)
    if snapshot_time is None:
        grid_t = np.linspace(min(v.plan.t_ldt for v in plan.vehicles),
                             max(v.plan.times[-1] for v in plan.vehicles), 400)
        flying = [sum((v.plan.t_ldt <= t <= v.plan.arrival_time) for v in plan.vehicles) for t in grid_t]
        snapshot_time = float(grid_t[int(np.argmax(flying))])
    colors = colormaps["tab10"](np.arange(len(plan.vehicles)) % 10)
    for v, spec, col in zip(plan.vehicles, scenario.vehicles, colors):
        times, st = v.plan.flight()
        ax.plot(st[:, 0], st[:, 1], color=col, lw=1.8)
        ax.add_patch(Circle(spec.target, spec.target_radius, color=col, alpha=0.25))
        ax.plot(*spec.start[:2], "o", color=col, ms=4)
        if times[0] <= snapshot_time <= times[-1]:
            x = np.interp(snapshot_time, times, st[:, 0])
            y = np.interp(snapshot_time, times, st[:, 1])
            th = np.interp(snapshot_time, times, np.unwrap(st[:, 2]))
            ax.annotate("", xy=(x + 0.04 * np.ptp(ax.get_xlim()) * np.cos(th), y + 0.04 * np.ptp(ax.get_xlim())
                                * np.sin(th)), xytext=(x, y), arrowprops={"arrowstyle": "->", "color": col})
            ax.add_patch(Circle((x, y), v.obstacle_radii[0], fill=False, ls="--", color=col))
            ax.text(x, y, str(v.priority + 1), fontsize=9, ha="center", va="center")
    ax.set_xlim(scenario.domain_lo[0], scenario.domain_hi[0])
    ax.set_ylim(scenario.domain_lo[1], scenario.domain_hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("p_x [m]")
    ax.set_ylabel("p_y [m]")
    mode = f"intruder-aware, k̄ = {plan.kbar}" if plan.kbar is not None else "no intruder"
    ax.set_title(f"{scenario.name}: nominal trajectories ({mode})\nnumbers = priority (1 = highest); dashed = "
                 f"induced obstacle at t = {snapshot_time:.1f} s", fontsize=10)
    ax.grid(alpha=0.3)
    save_figure(fig, path, dpi=110)
    return path
