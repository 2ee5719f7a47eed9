"""An episode as an animated GIF (matplotlib's ``PillowWriter``), or PNG frames when pillow is missing.

Kept small on purpose: the encounter only (from a few seconds before the intruder appears until a few seconds
after it leaves), a zoom on it, a frame every ``frame_dt`` seconds, a low resolution.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile
from pathlib import Path

import numpy as np

from stp_env.sim.types import AVOIDING, COLLIDED, FLYING, PRESENT


def render_episode(traj, final, params, scenario, path: str, *, frame_dt: float = 0.5, margin_s: float = 5.0,
                   fps: int = 8, dpi: int = 70, title: str = "", progress: bool | None = None
                   ) -> tuple[list[str], int]:
    """Write the episode to ``path`` (``.gif``); returns the written files (the GIF, or the PNG frames in
    ``path`` with its suffix removed when pillow is not installed) and the number of frames. ``progress``: a bar
    over the frames (:mod:`stp_env.progress`; ``None``: in a terminal)."""
    import matplotlib.pyplot as plt
    from matplotlib import animation
    from tqdm.auto import tqdm

    from stp_env import progress as progress_mod
    from stp_env.evaluation.plots import _draw_scene, vehicle_color

    t = traj["t"]
    t_app, t_iat = float(final["t_appear"]), float(params.intruder.t_iat)
    dt = float(params.episode.dt)
    window = (t >= t_app - margin_s) & (t <= t_app + t_iat + margin_s)
    if not window.any():
        window[:] = True
    steps = np.flatnonzero(window)[:: max(1, round(frame_dt / dt))]
    present = traj["intruder_status"] == PRESENT
    n = traj["x"].shape[1]
    fly = traj["status"] == FLYING
    # the view: around the intruder's path and the vehicles that fly near it
    pts = [traj["intruder_x"][present, :2]] if present.any() else []
    near = np.flatnonzero(np.isfinite(final["avoid_start"]))
    pts += [traj["x"][steps][fly[steps][:, i], i, :2] for i in near]
    pts = np.concatenate(pts) if pts and sum(len(p) for p in pts) else traj["x"][steps][fly[steps]][:, :2]
    lo, hi = np.asarray(params.episode.domain_lo), np.asarray(params.episode.domain_hi)
    if len(pts):
        c = 0.5 * (pts.min(0) + pts.max(0))
        half = 0.5 * max(np.ptp(pts, axis=0).max(), 6 * float(params.episode.collision_radius)) + 200.0
    else:
        c, half = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    fig, ax = plt.subplots(figsize=(5, 5.3), constrained_layout=True)
    _draw_scene(ax, scenario, params)
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("p_x [m]")
    ax.set_ylabel("p_y [m]")
    trails = [ax.plot([], [], color=vehicle_color(i), lw=1.2)[0] for i in range(n)]
    dots = [ax.plot([], [], "o", color=vehicle_color(i), ms=6)[0] for i in range(n)]
    disks = [plt.Circle((0, 0), float(params.episode.collision_radius), fill=False, ls=":", color=vehicle_color(i))
             for i in range(n)]
    for d in disks:
        ax.add_patch(d)
    intruder_trail = ax.plot([], [], "r-", lw=1.8)[0]
    intruder_dot = ax.plot([], [], "r^", ms=9)[0]
    text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", fontsize=8,
                   bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax.set_title(title or "episode", fontsize=9)

    def draw(k):
        start = steps[0]
        for i in range(n):
            seg = fly[start:k + 1, i]
            xy = traj["x"][start:k + 1, i, :2][seg]
            trails[i].set_data(xy[:, 0], xy[:, 1])
            on = fly[k, i] or traj["status"][k, i] == COLLIDED
            p = traj["x"][k, i, :2] if on else (np.nan, np.nan)
            dots[i].set_data([p[0]], [p[1]])
            dots[i].set_markeredgecolor("k" if traj["mode"][k, i] == AVOIDING else vehicle_color(i))
            dots[i].set_markersize(9 if traj["mode"][k, i] == AVOIDING else 6)
            disks[i].set_center(p)
            disks[i].set_visible(bool(on) and traj["mode"][k, i] == AVOIDING)
        ip = traj["intruder_x"][start:k + 1][present[start:k + 1]]
        intruder_trail.set_data(ip[:, 0], ip[:, 1])
        if present[k]:
            intruder_dot.set_data([traj["intruder_x"][k, 0]], [traj["intruder_x"][k, 1]])
        else:
            intruder_dot.set_data([], [])
        avoiding = int(np.sum(traj["mode"][k] == AVOIDING))
        forced = int(np.sum(final["avoid_start"] <= t[k] + 1e-6))
        text.set_text(f"t = {t[k]:.1f} s, t - t_ = {t[k] - t_app:+.1f} s\n|N^RP| = {forced}, avoiding: {avoiding}"
                      f"\ncollided: {int(np.sum(traj['status'][k] == COLLIDED))}")
        return [*trails, *dots, *disks, intruder_trail, intruder_dot, text]

    out = Path(path)
    if importlib.util.find_spec("PIL") is not None:
        from stp_env.artifacts import TEMP_PREFIX, writer_tag
        from stp_env.evaluation.report import plain_file_mode

        anim = animation.FuncAnimation(fig, draw, frames=list(steps), blit=False)
        bar = tqdm(total=len(steps), unit="frame", desc=f"rendering {out.name}",
                   disable=not progress_mod.enabled(progress))
        # written beside the target and moved onto it: an interrupted render leaves no half-written GIF
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=TEMP_PREFIX + writer_tag(), suffix=out.suffix or ".gif")
        os.close(fd)
        try:
            anim.save(tmp, writer=animation.PillowWriter(fps=fps), dpi=dpi,
                      progress_callback=lambda i, n: bar.update(1))
            os.chmod(tmp, plain_file_mode())
            os.replace(tmp, out)
        finally:
            bar.close()
            plt.close(fig)
            if os.path.exists(tmp):
                os.remove(tmp)
        return [str(out)], len(steps)
    frames_dir = out.with_suffix("")
    frames_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for j, k in enumerate(tqdm(steps, unit="frame", desc=f"rendering {frames_dir.name}",
                               disable=not progress_mod.enabled(progress))):
        draw(k)
        name = frames_dir / f"frame_{j:04d}.png"
        fig.savefig(name, dpi=dpi)
        written.append(str(name))
    plt.close(fig)
    return written, len(steps)
