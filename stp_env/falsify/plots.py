"""Figures of an attack: what the worst input does in the simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_attack(attack, z, path, *, title: str = "") -> Path:
    """Draw the attack at ``z`` into ``path`` (PNG): paths, and the attacked quantity over time."""
    from matplotlib.figure import Figure

    tr = attack.trace(z)
    fig = Figure(figsize=(11, 4.8))  # no pyplot: any backend (or none) can save it
    ax, ax2 = fig.subplots(1, 2)
    if attack.name == "tracking":
        ref, veh = tr["reference"], tr["vehicle"]
        ax.plot(ref[:, 0], ref[:, 1], "k--", lw=1, label="reference (legal, U^p)")
        ax.plot(veh[:, 0], veh[:, 1], "C0", lw=1.2, label="vehicle (u^PP)")
        err = np.hypot(*(veh[:, :2] - _at(ref, tr["t"], float(attack.base.dt))[:, :2]).T)
        ax2.plot(tr["t"], err, "C0", label="distance to reference")
        ax2.axhline(attack.bound, color="C3", ls="--", label=f"r_e = {attack.bound:.2f} m")
        ax2.set_ylabel("error [m]")
    elif attack.name == "avoidance":
        veh, intr = tr["vehicle"], tr["intruder"]
        ax.plot(veh[:, 0], veh[:, 1], "C0", label="vehicle (u*)")
        ax.plot(intr[:, 0], intr[:, 1], "C3", label="intruder")
        ax.plot(intr[0, 0], intr[0, 1], "C3o", ms=4)
        d = np.hypot(*(veh[:, :2] - intr[:, :2]).T)
        ax2.plot(tr["t"], d, "C0", label="vehicle-intruder distance")
        ax2.axhline(float(tr["collision_radius"]), color="C3", ls="--", label="R_c")
        if np.isfinite(tr["avoid_start"]):
            ax2.axvline(float(tr["avoid_start"]), color="k", lw=0.8, label="avoid start")
        ax2.set_ylabel("distance [m]")
    else:
        veh, intr, t = tr["vehicles"], tr["intruder"], tr["t"]
        present = (t >= float(tr["t_appear"])) & (t <= float(tr["t_appear"]) + float(attack.base.t_iat))
        for i in range(veh.shape[1]):
            forced = np.isfinite(tr["avoid_start"][i])
            ax.plot(veh[:, i, 0], veh[:, i, 1], color="C3" if forced else "C0", lw=0.8)
        ax.plot(intr[present, 0], intr[present, 1], "k", lw=1.5, label="intruder")
        d = np.min(np.hypot(veh[:, :, 0] - intr[:, None, 0], veh[:, :, 1] - intr[:, None, 1]), axis=1)
        ax2.plot(t[present], d[present], "k", label="closest vehicle to the intruder")
        for s in tr["avoid_start"][np.isfinite(tr["avoid_start"])]:
            ax2.axvline(float(s), color="C3", lw=0.8)
        ax2.axhline(float(tr["collision_radius"]), color="C3", ls="--", label="R_c")
        ax2.set_ylabel("distance [m]")
        ax.set_title(f"|N^RP| = {int(tr['forced'])} (red: forced), k̄ = {int(attack.base.kbar)}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8)
    ax2.set_xlabel("t [s]")
    ax2.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def _at(states, t, dt):
    """Reference samples at the recorded step times (the plan is sampled at the step)."""
    k = np.clip(np.round(np.asarray(t) / dt).astype(int), 0, len(states) - 1)
    return states[k]
