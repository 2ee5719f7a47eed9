"""Figures of an evaluation (matplotlib, Agg backend).

* :func:`plot_forced_histograms`: the distribution of ``|N^RP|`` (eq. 39) for each k̄, the bound drawn.
* :func:`plot_distance_vs_time`: distance from each forced vehicle to the intruder against time, under the
  avoidance control ``u*`` (eq. 38) and under nominal tracking ``u^PP`` (intruder paper Fig. 5).
* :func:`plot_episode`: one episode's trajectories with the intruder's path and the avoid-start markers (Figs.
  6-7), the whole domain and a close-up of the encounter, drawn by the scene renderer (:mod:`stp_env.render`).
* :func:`plot_summary`: every configuration at a glance.
"""

from __future__ import annotations

import numpy as np

from stp_env.files import save_figure
from stp_env.render import vehicle_color
from stp_env.sim.types import COLLIDED, FLYING, PRESENT


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _intruder_colors(names):
    plt = _plt()
    cmap = plt.get_cmap("tab10")
    return {name: cmap(i % 10) for i, name in enumerate(dict.fromkeys(names))}


def _with_series(summaries: list[dict]) -> list[dict]:
    """Copies of ``summaries`` with a ``"series"`` name for legends and colours: the intruder, prefixed by the
    scenario and suffixed by the vehicles' policy where the configurations differ in them (the default suite mixes
    both)."""
    scenarios = len({s["scenario"] for s in summaries}) > 1
    policies = len({s["vehicle_policy"] for s in summaries}) > 1
    return [{**s, "series": (f"{s['scenario']}: " if scenarios else "") + s["intruder"]
             + (f", {s['vehicle_policy']} vehicles" if policies else "")} for s in summaries]


def _scenarios(summaries: list[dict]) -> str:
    return ", ".join(dict.fromkeys(s["scenario"] for s in summaries))


def plot_forced_histograms(summaries: list[dict], path: str) -> str:
    """One panel per k̄: the fraction of episodes with ``|N^RP| = m`` for each intruder (log scale, so that rare
    counts show), the bound k̄ as a dashed vertical line, and each intruder's exact upper bound on
    ``P(|N^RP| > k̄)`` as a dashed horizontal line over the region beyond k̄."""
    plt = _plt()
    summaries = _with_series(summaries)
    kbars = sorted({s["kbar"] for s in summaries})
    colors = _intruder_colors(s["series"] for s in summaries)
    n_lines = max(sum(s["kbar"] == k for s in summaries) for k in kbars)
    fig, axes = plt.subplots(1, len(kbars), figsize=(max(6.5, 5.4 * len(kbars)), 4.9 + 0.25 * n_lines),
                             squeeze=False, sharey=True, constrained_layout=True)
    conf = summaries[0]["confidence"]
    for ax, kbar in zip(axes[0], kbars):
        group = [s for s in summaries if s["kbar"] == kbar]
        m_max = max(max(np.flatnonzero(s["forced_hist"]), default=0) for s in group)
        m_show = max(m_max, kbar + 1) + 1
        width = 0.8 / len(group)
        lines = []
        for g, s in enumerate(group):
            hist = np.zeros(m_show)
            hist[:min(m_show, len(s["forced_hist"]))] = s["forced_hist"][:m_show]
            frac = hist / s["episodes"]
            xs = np.arange(m_show) - 0.4 + width * (g + 0.5)
            col = colors[s["series"]]
            ax.bar(xs, np.where(frac > 0, frac, np.nan), width=width, color=col,
                   label=f"{s['series']} (n = {s['episodes']})")
            ax.hlines(s["exceed_upper"], kbar + 0.5, m_show - 0.5, colors=[col], linestyles="--", lw=1.5)
            lines.append(f"{s['series']}: {s['exceed']}/{s['episodes']} > k̄, P ≤ {_fmt_p(s['exceed_upper'])}")
        ax.axvline(kbar + 0.5, color="k", ls="--", lw=1.2)
        ax.text(kbar + 0.55, 0.03, "k̄", transform=ax.get_xaxis_transform(), fontsize=11)
        ax.set_yscale("log")
        ax.set_ylim(0.3 / max(s["episodes"] for s in group), 2.0)
        ax.set_xlim(-0.6, m_show - 0.4)
        ax.set_xticks(np.arange(m_show))
        ax.set_xlabel("|N^RP|: vehicles forced to avoid in an episode")
        ax.set_title(f"k̄ = {kbar}\n" + "\n".join(lines), fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    axes[0][0].set_ylabel("fraction of episodes")
    handles = {}
    for ax in axes[0]:                       # every series once, whichever panels it appears in
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label.split(" (n = ")[0], handle)
    fig.legend(list(handles.values()), list(handles), fontsize=8, loc="outside lower center",
               ncol=min(len(handles), 3))
    fig.suptitle(f"{_scenarios(summaries)}: vehicles forced to avoid\n(dashed horizontal: {100 * conf:g}% "
                 "upper bound on P(|N^RP| > k̄))", fontsize=10)
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path


def _fmt_p(p: float) -> str:
    return f"{p:.2g}" if p < 0.01 else f"{p:.3f}"


def _intruder_distance(traj) -> np.ndarray:
    """``(T, N)`` distance of each flying vehicle to the present intruder (NaN otherwise)."""
    d = np.hypot(*(traj["x"][:, :, :2] - traj["intruder_x"][:, None, :2]).transpose(2, 0, 1))
    ok = (traj["status"] == FLYING) & (traj["intruder_status"] == PRESENT)[:, None]
    return np.where(ok, d, np.nan)


def plot_distance_vs_time(avoid_traj, avoid_final, nominal_traj, nominal_final, params, path: str,
                          title: str = "") -> str:
    """Distance to the intruder against the time since it appeared, for each vehicle forced to avoid in either
    run, under ``u*`` (solid) and under ``u^PP`` (dashed: the same episode, same seed, with the vehicles ignoring
    the intruder); ``R_c`` as a line, avoid starts as dots, collisions as crosses (intruder paper Fig. 5)."""
    plt = _plt()
    t_app = float(avoid_final["t_appear"])
    t_iat = float(params.intruder.t_iat)
    r_c = float(params.episode.collision_radius)
    forced = np.flatnonzero(np.isfinite(avoid_final["avoid_start"]) | np.isfinite(nominal_final["avoid_start"]))
    if forced.size == 0:   # nobody forced: show the vehicles that came closest
        d = np.nanmin(_intruder_distance(avoid_traj), axis=0)
        forced = np.argsort(np.where(np.isfinite(d), d, np.inf))[:2]
    fig, ax = plt.subplots(figsize=(7.5, 4.6), constrained_layout=True)
    d_avoid, d_nom = _intruder_distance(avoid_traj), _intruder_distance(nominal_traj)
    tau_a, tau_n = avoid_traj["t"] - t_app, nominal_traj["t"] - t_app
    ymax = 0.0
    for i in forced:
        col = vehicle_color(i)
        ax.plot(tau_a, d_avoid[:, i], color=col, lw=2, label=f"vehicle {i}: avoidance u* (eq. 38)")
        ax.plot(tau_n, d_nom[:, i], color=col, lw=1.5, ls="--", label=f"vehicle {i}: nominal u^PP")
        ymax = max(ymax, np.nanmax(np.r_[d_avoid[:, i], d_nom[:, i], 0.0]))
        for traj, final, tau, d in ((avoid_traj, avoid_final, tau_a, d_avoid),
                                    (nominal_traj, nominal_final, tau_n, d_nom)):
            t_i = final["avoid_start"][i]
            if np.isfinite(t_i):
                k = int(np.argmin(np.abs(traj["t"] - t_i)))
                ax.plot(tau[k], d[k, i], "o", color=col, ms=7, mec="k")
        for traj, final, tau, d in ((avoid_traj, avoid_final, tau_a, d_avoid),
                                    (nominal_traj, nominal_final, tau_n, d_nom)):
            if final["status"][i] == COLLIDED:
                k = int(np.argmin(np.abs(traj["t"] - final["collision_time"][i])))
                ax.plot(tau[k], np.nanmin(d[max(k - 2, 0):k + 1, i]), "x", color=col, ms=10, mew=2.5)
    ax.axhline(r_c, color="r", lw=1.2)
    ax.text(0.2, r_c, f" R_c = {r_c:g} m", color="r", va="bottom", fontsize=9)
    ax.plot([], [], "o", color="0.5", mec="k", label="avoid start t_i (eqs. 17-18)")
    ax.plot([], [], "x", color="0.5", mew=2.5, label="collision")
    ax.set_xlim(0, t_iat)
    ax.set_ylim(0, min(ymax * 1.05, 4 * float(params.tables.detection_range)) if ymax > 0 else 1.0)
    ax.set_xlabel("time since the intruder appeared, t - t_ [s]")
    ax.set_ylabel("distance to the intruder [m]")
    ax.set_title(title or "distance to the intruder: avoidance vs nominal control (cf. intruder paper Fig. 5)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best", framealpha=0.9)
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path


def plot_episode(traj, final, params, scenario, path: str, title: str = "") -> str:
    """An episode (recorded trajectory and final state) drawn by the scene renderer
    (:func:`stp_env.render.draw_scene`, look :data:`~stp_env.render.FIGURE`): each vehicle's path while flying
    (thick while avoiding), the intruder's path, avoid-start markers with the collision disk ``R_c`` there,
    collisions; the whole domain (left) and the encounter (right)."""
    plt = _plt()
    from stp_env.render import FIGURE, draw_scene

    fig, axes = plt.subplots(1, 2, figsize=(12, 6.3), constrained_layout=True)
    present = traj["intruder_status"] == PRESENT
    ip = traj["intruder_x"][present]
    forced = np.flatnonzero(np.isfinite(final["avoid_start"]))
    for ax in axes:
        draw_scene(ax, params, scenario, history=traj, final=final, look=FIGURE, legend=ax is axes[0])
    axes[0].set_title("whole domain (thick: avoiding; x: collision)", fontsize=10)
    if ip.size:
        pts = [ip[:, :2]] + [traj["x"][present, i, :2] for i in forced]
        pts = np.concatenate(pts)
        c = 0.5 * (pts.min(0) + pts.max(0))
        half = 0.5 * max(np.ptp(pts, axis=0).max(), 4 * float(params.episode.collision_radius)) + 150.0
        axes[1].set_xlim(c[0] - half, c[0] + half)
        axes[1].set_ylim(c[1] - half, c[1] + half)
        axes[0].add_patch(plt.Rectangle(c - half, 2 * half, 2 * half, fill=False, ls="--", color="0.4"))
    axes[1].set_title("encounter: ▲ intruder appears, ● avoid start\n(dotted: R_c around it), "
                      "red ●: the intruder then", fontsize=10)
    axes[0].legend(fontsize=8, loc="lower left", ncol=2)
    fig.suptitle(title or "episode", fontsize=11)
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return path


def plot_summary(summaries: list[dict], path: str) -> str:
    """Four panels over the configurations: ``P(|N^RP| > k̄)`` with its exact upper bound; mean and max
    ``|N^RP|`` against k̄; collisions and guarantee violations per 1000 episodes; the smallest separation against
    ``R_c`` and the on-time arrival rate."""
    plt = _plt()
    summaries = _with_series(summaries)
    colors = _intruder_colors(s["series"] for s in summaries)
    intruders = list(colors)
    kbars = sorted({s["kbar"] for s in summaries})
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), constrained_layout=True)
    off = {name: (i - (len(intruders) - 1) / 2) * 0.12 for i, name in enumerate(intruders)}
    ax = axes[0, 0]
    for s in summaries:
        x = s["kbar"] + off[s["series"]]
        col = colors[s["series"]]
        ax.plot([x, x], [max(s["exceed_rate"], 1e-5), s["exceed_upper"]], color=col, lw=2)
        ax.plot(x, s["exceed_upper"], "v", color=col, ms=7)
        ax.plot(x, max(s["exceed_rate"], 1e-5), "o", color=col, ms=6, mfc="white" if s["exceed"] == 0 else col)
    ax.set_yscale("log")
    ax.set_ylim(1e-5, 1.5)
    ax.set_title(f"P(|N^RP| > k̄): observed (o; hollow at 0) and {100 * summaries[0]['confidence']:g}% upper "
                 "bound (v)", fontsize=10)
    ax.set_xlabel("k̄")
    ax.set_xticks(kbars)
    ax = axes[0, 1]
    for name in intruders:
        group = sorted((s for s in summaries if s["series"] == name), key=lambda s: s["kbar"])
        ks = [s["kbar"] + off[name] for s in group]
        ax.plot(ks, [s["forced_mean"] for s in group], "o-", color=colors[name], label=f"{name}: mean")
        ax.plot(ks, [s["forced_max"] for s in group], "s--", color=colors[name], mfc="white", label=f"{name}: max")
    ax.hlines(kbars, np.asarray(kbars) - 0.35, np.asarray(kbars) + 0.35, colors="k", linestyles=":",
              label="k̄ (the bound)")
    ax.set_xticks(kbars)
    ax.set_xlim(min(kbars) - 0.5, max(kbars) + 0.5)
    ax.set_ylim(0, max(max(kbars), max(s["forced_max"] for s in summaries)) + 0.5)
    ax.set_xlabel("k̄")
    ax.set_ylabel("|N^RP|")
    ax.set_title("vehicles forced to avoid", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[1, 0]
    labels = [f"{s['series']}\nk̄={s['kbar']}".replace(": ", "\n").replace(", ", "\n") for s in summaries]
    xs = np.arange(len(summaries))
    per = np.asarray([1000.0 / s["episodes"] for s in summaries])
    ax.bar(xs - 0.2, per * [s["collisions"] for s in summaries], width=0.4, color="tab:orange",
           label="collisions (vehicles)")
    ax.bar(xs + 0.2, per * [s["guarantee_violations"] for s in summaries], width=0.4, color="tab:red",
           label="guarantee violations")
    for x, s in zip(xs, summaries):
        ax.text(x, 0.02, f"{s['collisions']} / {s['guarantee_violations']}", ha="center", fontsize=8,
                transform=ax.get_xaxis_transform())
    ax.set_xticks(xs, labels, fontsize=8)
    ax.set_ylabel("per 1000 episodes")
    ax.set_ylim(0, max(1.0, 1.15 * max(per * [max(s["collisions"], s["guarantee_violations"]) for s in summaries])))
    ax.set_title("collisions / guarantee violations (counts printed)", fontsize=10)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    seps = np.asarray([s["min_separation_m"] if s["min_separation_m"] is not None else np.nan for s in summaries])
    ax.bar(xs, seps, color=[colors[s["series"]] for s in summaries], alpha=0.8)
    r_c = summaries[0]["collision_radius_m"]
    ax.axhline(r_c, color="r", lw=1.2)
    ax.text(-0.45, r_c, f"R_c = {r_c:g} m", color="r", va="bottom", fontsize=8)
    for x, s, sep in zip(xs, summaries, seps):
        on_time = "n/a" if s["on_time_rate"] is None else f"{100 * s['on_time_rate']:.0f}%"
        ax.text(x, 0.5 * np.nan_to_num(sep, nan=r_c), f"{sep:.0f} m\n\non time:\n{on_time}\nof {s['due']}",
                ha="center", va="center", fontsize=8, color="k")
    ax.set_xticks(xs, labels, fontsize=8)
    ax.set_ylabel("smallest separation [m]")
    ax.set_ylim(0, 1.2 * max(np.nanmax(np.r_[seps, r_c]), r_c))
    ax.set_title("smallest vehicle-vehicle / vehicle-intruder distance;\non-time arrivals of the due vehicles",
                 fontsize=10)
    for a in axes.flat:
        a.grid(alpha=0.3)
    fig.suptitle(f"{_scenarios(summaries)}: evaluation summary ({summaries[0]['episodes']} episodes per "
                 "configuration)", fontsize=12)
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return path
