"""Figures of an attack: what the worst input does in the simulator."""

from __future__ import annotations

from pathlib import Path

from stp_env.files import save_figure


def plot_attack(attack, z, path, *, title: str = "") -> Path:
    """Draw the attack at ``z`` into ``path`` (PNG): paths, and the attacked quantity over time (the attack's
    ``draw``)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.8))  # no pyplot: any backend (or none) can save it
    ax, ax2 = fig.subplots(1, 2)
    attack.draw(ax, ax2, z)  # the target's own figure (stp_env.falsify.targets)
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
    save_figure(fig, path, dpi=110)
    return path

