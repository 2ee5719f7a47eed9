"""The package's one top-down scene renderer (matplotlib, imported inside the functions).

:func:`draw_scene` draws a scene on a matplotlib Axes: the domain, the scenario's buildings, the targets, the
nominal paths, the vehicles at one instant (pose, status and mode colours, the collision disk ``R_c``, optionally
each flying vehicle's avoid-region footprint), the intruder with its ``R_c`` disk, and a recorded history (each
vehicle's path while flying, thick while avoiding; the intruder's path; with the final state, the avoid starts with
``R_c`` there and the collisions). A :class:`Look` says how; two are defined:

* :data:`FRAME`: the environment's frame (``render_mode="rgb_array"`` / ``"human"`` of :mod:`stp_env.env`, drawn by
  :func:`draw_frame`): vehicles coloured by their mode, heading arrows.
* :data:`FIGURE`: the evaluation's figures (:func:`stp_env.evaluation.plots.plot_episode` and the frames of
  :func:`stp_env.evaluation.render.render_episode`): vehicles coloured by index (:func:`vehicle_color`), dots.

The instant (``now``) is an :class:`~stp_env.sim.EnvState` or a mapping with the same fields (a row of a recorded
trajectory); the history is a recorded trajectory (``{field: (T, ...) array}``, as :func:`stp_env.sim.rollout`
records it) and the final state a mapping of the state's fields.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.angles import wrap_angle
from stp_env.sim import tables
from stp_env.sim.types import AVOIDING, COLLIDED, FLYING, MODE_NAMES, PRESENT, WAITING

VEHICLE_COLOURS = {"nominal": "tab:blue", "avoiding": "tab:orange", "after_avoidance": "tab:purple"}
"""A vehicle's colour by its mode (:data:`FRAME`); red when it has collided."""

SCENE_FIELDS = ("t", "x", "status", "mode", "intruder_x", "intruder_status")
"""The fields of a recorded trajectory (and of an instant) that the scene reads."""

_VEHICLE_PALETTE = (0, 1, 2, 4, 5, 6, 7, 8, 9)   # tab10 without red: red is the intruder's


def vehicle_color(i: int):
    """Vehicle ``i``'s own colour (:data:`FIGURE`, and every recorded path): tab10 without red."""
    from matplotlib import colormaps

    return colormaps["tab10"](_VEHICLE_PALETTE[i % len(_VEHICLE_PALETTE)])


@dataclass(frozen=True)
class Look:
    """How :func:`draw_scene` draws.

    ``targets``: ``"ring"`` (an outline labelled with the vehicles bound there) or ``"disk"`` (a light disk).
    ``colour_by``: the vehicles at the instant, ``"mode"`` (:data:`VEHICLE_COLOURS`) or ``"vehicle"``
    (:func:`vehicle_color`). ``vehicles``: ``"arrow"`` (heading arrow, dashed ``R_c`` ring, index, a grey square
    while waiting) or ``"dot"`` (a dot, black-edged and larger while avoiding, a dotted ``R_c`` ring then).
    ``intruder``: ``"disk"`` (a red ``R_c`` disk and a heading arrow) or ``"triangle"``."""

    building_color: str = "0.55"
    building_alpha: float = 1.0
    targets: str = "ring"
    nominal_paths: bool = True
    colour_by: str = "mode"
    vehicles: str = "arrow"
    intruder: str = "disk"
    grid: bool = False
    xlabel: str = "x [m]"
    ylabel: str = "y [m]"


FRAME = Look()
FIGURE = Look(building_color="0.3", building_alpha=0.8, targets="disk", nominal_paths=False, colour_by="vehicle",
              vehicles="dot", intruder="triangle", grid=True, xlabel="p_x [m]", ylabel="p_y [m]")


def _field(state, name):
    """``state.name`` of an :class:`~stp_env.sim.EnvState`, or ``state[name]`` of a mapping, as numpy."""
    return np.asarray(state[name] if isinstance(state, Mapping) else getattr(state, name))


def _poses(params, x) -> np.ndarray:
    """``(..., 3)`` ``(x, y, heading)`` of vehicle states ``x``, whatever the vehicle model."""
    return np.asarray(params.vehicles.model.pose(np.asarray(x)))


def _footprint(params, now, i, n=81):
    """``V^A(tau)`` of vehicle ``i`` against the intruder's current relative heading, on a world-frame grid."""
    grid = params.tables.avoid_grid
    w = float(grid.hi[0])
    s = np.linspace(-w, w, n)
    px, py = np.meshgrid(s, s, indexing="ij")
    xi = _field(now, "intruder_x")
    pose = _poses(params, _field(now, "x")[i])
    rel_heading = wrap_angle(float(xi[2]) - float(pose[2]))
    pts = jnp.stack([px.ravel(), py.ravel(), jnp.full(px.size, rel_heading)], 1).astype(jnp.float32)
    tau = _field(now, "t") - _field(now, "t_appear")
    vals = np.asarray(jax.vmap(lambda r: tables.avoid_value(params, tau, r))(pts)).reshape(n, n)
    th = float(pose[2])
    c, sn = np.cos(th), np.sin(th)
    wx = float(pose[0]) + c * px - sn * py
    wy = float(pose[1]) + sn * px + c * py
    return wx, wy, vals


def _draw_static(ax, params, scenario, look: Look):
    from matplotlib.patches import Circle, Polygon

    for b in scenario.buildings:
        ax.add_patch(Polygon(np.asarray(b.vertices), closed=True, color=look.building_color,
                             alpha=look.building_alpha, zorder=1))
    if look.targets == "ring":
        targets = {}
        for i, (c, r) in enumerate(zip(np.asarray(params.vehicles.targets), np.asarray(params.vehicles.target_radii))):
            targets.setdefault((float(c[0]), float(c[1]), float(r)), []).append(i)
        for (cx, cy, r), owners in targets.items():
            ax.add_patch(Circle((cx, cy), r, fill=False, ec="tab:green", lw=1.2, zorder=2))
            ax.annotate(",".join(map(str, owners)), (cx, cy), fontsize=7, color="tab:green", ha="center",
                        va="center")
    else:
        for tgt, r in zip(np.asarray(params.vehicles.targets), np.asarray(params.vehicles.target_radii)):
            ax.add_patch(Circle(tgt, r, color="g", alpha=0.15, zorder=2))
    if look.nominal_paths:
        states = np.asarray(params.vehicles.nominal_states)
        lengths = np.asarray(params.vehicles.nominal_len)
        for i in range(params.vehicles.n):
            ax.plot(states[i, :lengths[i], 0], states[i, :lengths[i], 1], color="0.8", lw=0.8, zorder=1)


def _draw_history(ax, params, history, final, legend: bool):
    from matplotlib.patches import Circle

    rc = float(params.episode.collision_radius)
    xy_all = _poses(params, history["x"])[..., :2]
    status, mode, t = np.asarray(history["status"]), np.asarray(history["mode"]), np.asarray(history["t"])
    present = np.asarray(history["intruder_status"]) == PRESENT
    ip = np.asarray(history["intruder_x"])[present]
    for i in range(xy_all.shape[1]):
        col = vehicle_color(i)
        fly = status[:, i] == FLYING
        xy = np.where(fly[:, None], xy_all[:, i], np.nan)
        ax.plot(xy[:, 0], xy[:, 1], color=col, lw=1.2, label=f"vehicle {i}" if legend else None, zorder=3)
        avoid = fly & (mode[:, i] == AVOIDING)
        xa = np.where(avoid[:, None], xy_all[:, i], np.nan)
        ax.plot(xa[:, 0], xa[:, 1], color=col, lw=3.5, zorder=3)
        if final is not None and _field(final, "status")[i] == COLLIDED:
            k = int(np.argmin(np.abs(t - _field(final, "collision_time")[i])))
            ax.plot(*xy_all[k, i], "x", color="k", ms=10, mew=2.5, zorder=5)
    if ip.size:
        ax.plot(ip[:, 0], ip[:, 1], color="r", lw=2.2 if final is not None else 1.8,
                label="intruder" if legend else None, zorder=3)
        if final is not None:
            ax.plot(*ip[0, :2], "r^", ms=9, zorder=5)
    if final is None:
        return
    for i in np.flatnonzero(np.isfinite(_field(final, "avoid_start"))):
        k = int(np.argmin(np.abs(t - _field(final, "avoid_start")[i])))
        p = xy_all[k, i]
        ax.plot(*p, "o", color=vehicle_color(i), ms=8, mec="k", zorder=5)
        ax.add_patch(Circle(p, rc, fill=False, ls=":", color=vehicle_color(i), zorder=4))
        if ip.size:
            kk = min(int(np.searchsorted(t[present], t[k])), len(ip) - 1)
            ax.plot(*ip[kk, :2], "o", color="r", ms=6, mec="k", zorder=5)


def _draw_now(ax, params, now, look: Look, avoid_regions: bool):
    from matplotlib.patches import Circle

    lo, hi = np.asarray(params.episode.domain_lo), np.asarray(params.episode.domain_hi)
    span = float(np.max(hi - lo))
    arrow = 0.03 * span
    rc = float(params.episode.collision_radius)
    x = _poses(params, _field(now, "x"))
    status, mode = _field(now, "status"), _field(now, "mode")
    present = int(_field(now, "intruder_status")) == PRESENT
    for i in range(x.shape[0]):
        if status[i] == WAITING and look.vehicles == "arrow":
            ax.plot(*x[i, :2], marker="s", ms=3, color="0.6", zorder=3)
            continue
        if status[i] != FLYING and status[i] != COLLIDED:
            continue
        if look.colour_by == "vehicle":
            colour = vehicle_color(i)
        else:
            colour = "red" if status[i] == COLLIDED else VEHICLE_COLOURS[MODE_NAMES[mode[i]]]
        avoiding = mode[i] == AVOIDING
        if look.vehicles == "arrow":
            ax.add_patch(Circle(x[i, :2], rc, fill=False, ec=colour, lw=0.8, ls="--", zorder=3))
            ax.arrow(x[i, 0], x[i, 1], arrow * np.cos(x[i, 2]), arrow * np.sin(x[i, 2]), width=0.004 * span,
                     color=colour, zorder=4, length_includes_head=True)
            ax.annotate(str(i), x[i, :2], xytext=(4, 4), textcoords="offset points", fontsize=7)
        else:
            ax.plot(*x[i, :2], "o", color=colour, ms=9 if avoiding else 6, mec="k" if avoiding else colour,
                    zorder=4)
            if avoiding:
                ax.add_patch(Circle(x[i, :2], rc, fill=False, ls=":", color=colour, zorder=4))
        if avoid_regions and present and status[i] == FLYING:
            wx, wy, vals = _footprint(params, now, i)
            ax.contour(wx, wy, vals, levels=[0.0], colors=[colour], linewidths=0.8)
    if present:
        xi = _field(now, "intruder_x")
        if look.intruder == "disk":
            ax.add_patch(Circle(xi[:2], rc, color="red", alpha=0.25, zorder=3))
            ax.arrow(xi[0], xi[1], arrow * np.cos(xi[2]), arrow * np.sin(xi[2]), width=0.005 * span, color="red",
                     zorder=5, length_includes_head=True)
        else:
            ax.plot(xi[0], xi[1], "r^", ms=9, zorder=5)


def draw_scene(ax, params, scenario, *, now=None, history=None, final=None, look: Look = FRAME,
               avoid_regions: bool = False, legend: bool = False):
    """Draw a scene of ``scenario`` (its buildings) under ``params`` (domain, targets, plans, ``R_c``, the
    vehicle model) on ``ax``, and return ``ax``; the axes get the domain as limits (a caller may zoom after).

    ``now``: the vehicles and the intruder at one instant (an :class:`~stp_env.sim.EnvState` or a mapping of its
    fields; ``t`` and ``t_appear`` too for ``avoid_regions``). ``history``: a recorded trajectory, drawn as paths;
    ``final``: its final state, which adds the avoid starts (``R_c`` around them, the intruder then), the
    collisions and the intruder's first position. ``avoid_regions``: each flying vehicle's avoid-region footprint
    (the zero level of ``V^A``) while the intruder is present. ``legend``: label the paths (vehicle ``i``, intruder)
    for a legend."""
    _draw_static(ax, params, scenario, look)
    if history is not None:
        _draw_history(ax, params, history, final, legend)
    if now is not None:
        _draw_now(ax, params, now, look, avoid_regions)
    lo, hi = np.asarray(params.episode.domain_lo), np.asarray(params.episode.domain_hi)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    if look.grid:
        ax.grid(alpha=0.3)
    ax.set_xlabel(look.xlabel)
    ax.set_ylabel(look.ylabel)
    return ax


def draw_frame(env, fig=None):
    """The environment's frame: ``env``'s current state drawn by :func:`draw_scene` (:data:`FRAME`) into ``fig``
    (created when ``None``), titled with the time and the forced count; returns the figure."""
    import matplotlib.pyplot as plt

    params, state, scenario = env.params, jax.device_get(env.env_state), env.scenario
    if fig is None:
        fig = plt.figure(figsize=(6, 6), dpi=80)
    fig.clf()
    ax = fig.add_subplot(1, 1, 1)
    draw_scene(ax, params, scenario, now=state, look=FRAME, avoid_regions=env.render_avoid_regions)
    status, mode = np.asarray(state.status), np.asarray(state.mode)
    n_forced = int(np.isfinite(np.asarray(state.avoid_start)).sum())
    kbar = int(params.intruder.kbar)
    avoiding = int(np.sum((mode == AVOIDING) & (status == FLYING)))
    ax.set_title(f"t = {float(state.t):7.1f} s   forced |N^RP| = {n_forced} (k̄ = {kbar})   avoiding now: {avoiding}",
                 fontsize=9)
    fig.tight_layout()
    return fig


def show_frame(env, fig, mode: str, *, fps: float):
    """The environment's ``render()``: its frame drawn into ``fig`` (a new one when ``None``), returned with the
    figure as an RGB array (``"rgb_array"``) or shown in a window (``"human"``: ``None``)."""
    fig = draw_frame(env, fig)
    if mode == "rgb_array":
        fig.canvas.draw()
        return fig, np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    import matplotlib
    import matplotlib.pyplot as plt

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "ps", "cairo", "template"):
        plt.pause(1.0 / fps)
    return fig, None


def close_figure(fig) -> None:
    """Closes the environment's window; ``None``, the figure it holds after."""
    import matplotlib.pyplot as plt

    plt.close(fig)
