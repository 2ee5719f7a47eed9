"""Figures of the co-observation study (matplotlib; the caller picks the backend: Agg in scripts and the CLI)."""

from __future__ import annotations

import numpy as np

from stp_env.coobservation import ellipse

COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")


def draw_polygon(ax, vertices, **kwargs):
    from matplotlib.patches import Polygon

    ax.add_patch(Polygon(np.asarray(vertices), closed=True, **kwargs))


def draw_zones(ax, obstacles=(), forbidden=(), labels=True, names=None):
    """Obstacles in grey, forbidden zones hatched red; ``names`` labels them in order (obstacles first)."""
    k = 0
    for v in obstacles:
        draw_polygon(ax, v, facecolor="0.55", edgecolor="0.3", zorder=1)
        if labels:
            c = np.mean(np.asarray(v), 0)
            ax.text(*c, names[k] if names else "obstacle", ha="center", va="center", fontsize=8, zorder=5)
        k += 1
    for v in forbidden:
        draw_polygon(ax, v, facecolor=(1.0, 0.85, 0.85), edgecolor="tab:red", hatch="//", zorder=1)
        if labels:
            c = np.mean(np.asarray(v), 0)
            ax.text(*c, names[k] if names else "forbidden", ha="center", va="center", fontsize=8, color="darkred",
                    zorder=5)
        k += 1


def draw_ellipse(ax, q1, q2, a, **kwargs):
    pts = np.asarray(ellipse.boundary_points(np.asarray(q1, np.float32), np.asarray(q2, np.float32), float(a), 240))
    pts = np.concatenate([pts, pts[:1]])
    ax.plot(pts[:, 0], pts[:, 1], **kwargs)


def draw_trajectories(ax, q, labels=None, marker=".", **kwargs):
    """``q`` ``(n, T + 1, 2)``: one coloured polyline per robot, start as a square, goal as a star."""
    for i, traj in enumerate(np.asarray(q)):
        c = COLORS[i % len(COLORS)]
        ax.plot(traj[:, 0], traj[:, 1], marker=marker, color=c, ms=4, lw=1.5,
                label=None if labels is None else labels[i], zorder=3, **kwargs)
        ax.plot(*traj[0], "s", color=c, ms=7, zorder=4)
        ax.plot(*traj[-1], "*", color=c, ms=11, zorder=4)


def draw_variance(ax, cost, q, lo, hi, vmax=None):
    """The final Kalman-filter variance of each point of interest (Example 1) as a grey-scale background."""
    import jax.numpy as jnp

    p = np.asarray(cost.variances(jnp.asarray(q, jnp.float32))[-1])
    pts = np.asarray(cost.points)
    xs, ys = np.unique(pts[:, 0]), np.unique(pts[:, 1])
    img = np.full((len(ys), len(xs)), np.nan)
    ix = np.searchsorted(xs, pts[:, 0])
    iy = np.searchsorted(ys, pts[:, 1])
    img[iy, ix] = p
    dx = xs[1] - xs[0] if len(xs) > 1 else 1.0
    dy = ys[1] - ys[0] if len(ys) > 1 else 1.0
    return ax.imshow(img, origin="lower", extent=(xs[0] - dx / 2, xs[-1] + dx / 2, ys[0] - dy / 2, ys[-1] + dy / 2),
                     cmap="Greys", vmin=0.0, vmax=vmax if vmax is not None else float(np.nanmax(p)), alpha=0.5,
                     zorder=0)


def margin_histograms(rows, path, bins: int = 40) -> None:
    """One panel per schedule: the histogram of the attempts' time margins [s] per attacker
    (:attr:`stp_env.coobservation.evaluation.Row.margins`, finite margins only: lost attempts are counted in the
    legend; >= 0 is an undetected entry), a line at 0; attackers without attempts appear in the legend only. Saves
    the figure to ``path``."""
    import matplotlib.pyplot as plt

    schedules = list(dict.fromkeys(r.schedule for r in rows))
    fig, axes = plt.subplots(1, len(schedules), figsize=(4.5 * len(schedules), 3.4), squeeze=False)
    everything = np.concatenate([r.margins for r in rows if r.margins is not None and len(r.margins)] or [np.zeros(1)])
    edges = np.histogram_bin_edges(everything, bins=bins)
    for ax, name in zip(axes[0], schedules):
        for k, r in enumerate(x for x in rows if x.schedule == name):
            label = (f"{r.attacker}: {r.attempts} attempts in {r.episodes}, {r.undetected_entries} undetected, "
                     f"{r.lost_attempts} lost")
            if r.margins is None or not len(r.margins):  # no line, but in the legend: 0 attempts is a finding
                ax.plot([], [], color=COLORS[k % len(COLORS)], lw=1.4, ls=":", label=label)
                continue
            ax.hist(r.margins, bins=edges, histtype="step", color=COLORS[k % len(COLORS)], lw=1.4, label=label)
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yscale("log")
        ax.set_title(f"{name} schedule")
        ax.set_xlabel("time margin to the detecting observation [s]")
        ax.set_ylabel("attempts")
        ax.legend(fontsize=7)
    fig.tight_layout()
    from stp_env.files import atomic_open

    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=120)
    plt.close(fig)
