"""An episode as an animated GIF (matplotlib's ``PillowWriter``), or PNG frames when pillow is missing.

Kept small on purpose: the encounter only (from a few seconds before the intruder appears until a few seconds
after it leaves), a zoom on it, a frame every ``frame_dt`` seconds, a low resolution. Each frame is drawn by the
scene renderer (:func:`stp_env.render.draw_scene`, look :data:`~stp_env.render.FIGURE`).
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
    from stp_env.render import FIGURE, SCENE_FIELDS, draw_scene

    t = traj["t"]
    t_app, t_iat = float(final["t_appear"]), float(params.intruder.t_iat)
    dt = float(params.episode.dt)
    window = (t >= t_app - margin_s) & (t <= t_app + t_iat + margin_s)
    if not window.any():
        window[:] = True
    steps = np.flatnonzero(window)[:: max(1, round(frame_dt / dt))]
    present = traj["intruder_status"] == PRESENT
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
    start = steps[0]

    def draw(k):
        # the scene up to step k, drawn afresh by the one renderer: paths since the first frame, the vehicles and
        # the intruder at step k
        ax.clear()
        draw_scene(ax, params, scenario, now={key: traj[key][k] for key in SCENE_FIELDS},
                   history={key: traj[key][start:k + 1] for key in SCENE_FIELDS}, look=FIGURE)
        ax.set_xlim(c[0] - half, c[0] + half)
        ax.set_ylim(c[1] - half, c[1] + half)
        ax.set_title(title or "episode", fontsize=9)
        avoiding = int(np.sum(traj["mode"][k] == AVOIDING))
        forced = int(np.sum(final["avoid_start"] <= t[k] + 1e-6))
        text = ax.text(0.02, 0.98, f"t = {t[k]:.1f} s, t - t_ = {t[k] - t_app:+.1f} s\n|N^RP| = {forced}, "
                       f"avoiding: {avoiding}\ncollided: {int(np.sum(traj['status'][k] == COLLIDED))}",
                       transform=ax.transAxes, va="top", fontsize=8,
                       bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
        return [*ax.lines, *ax.patches, text]

    out = Path(path)
    if importlib.util.find_spec("PIL") is not None:
        from stp_env.files import TEMP_PREFIX, plain_file_mode, writer_tag

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
