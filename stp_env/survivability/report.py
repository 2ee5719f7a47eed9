"""Results files and figures of a survivability study (``results.json``, ``results.csv``, ``results.md`` and the
PNGs of Figs. 7-12 of the survivability paper), with the paper's findings next to ours."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from stp_env.files import atomic_open, save_figure, write_text
from stp_env.survivability import analysis
from stp_env.survivability.config import POLICIES, StudyConfig
from stp_env.survivability.records import read_study

LABEL = {"R": "π_R", "Nf": "π_Nf", "S": "π_S", "AvgR": "π_Avg(R)"}
COLOR = {"Nf": "tab:blue", "S": "tab:orange", "R": "tab:green", "AvgR": "tab:purple"}
PAPER = {
    "phi_np100": 229.9,
    "eta_range": [0.64, 0.38],
    "eta_total300": 0.644,
    "survival_gain_S_100": 0.2824,
}


def build_report(config: StudyConfig, out, n_boot: int = 2000) -> dict:
    """Summaries, thresholds and the paper comparison of the study in ``out`` (a dict, also written to
    ``results.json``, ``results.csv`` and ``results.md``)."""
    out = Path(out)
    rows = read_study(out)
    if not rows:
        raise ValueError(f"{out} has no completed missions yet (missions*.csv).")
    policies = config.policies
    summary = analysis.summarize(rows, policies)
    thr = analysis.thresholds(rows, policies, config.n_partial, config.n_unknown, n_boot=n_boot)
    comp = analysis.comparisons(rows, policies)
    # One set-up per (scenario, instance), repeated on each policy's row.
    setup_s = {(r["n_partial"], r["n_unknown"], r["instance"]): r["instance_s"] for r in rows}
    mission_s = [r["mission_s"] for r in rows]
    n_inst = len(setup_s)
    report = {
        "config": config.fingerprint(),
        "instances_per_scenario": {f"{k[0]},{k[1]}": v[policies[0]]["survival"]["n"] for k, v in summary.items()},
        "timing": {"instances": n_inst, "missions": len(rows),
                   "mean_instance_setup_s": sum(setup_s.values()) / n_inst,
                   "mean_mission_s": sum(mission_s) / len(mission_s),
                   "mean_instance_total_s": (sum(setup_s.values()) + sum(mission_s)) / n_inst},
        "scenarios": [{"n_partial": k[0], "n_unknown": k[1], **{p: v[p] for p in policies}}
                      for k, v in summary.items()],
        "thresholds": {"phi": {str(k): v for k, v in thr["phi"].items()},
                       "eta": {str(k): v for k, v in thr["eta"].items()}},
        "comparisons": {f"{k[0]},{k[1]}": v for k, v in comp.items()},
        "goal_loss": {f"{k[0]},{k[1]}": v for k, v in analysis.goal_loss(rows, policies).items()},
        "conflicts_per_mission": {f"{k[0]},{k[1]}": v for k, v in analysis.conflicts(rows, policies).items()},
        "airborne_fraction": airborne(config),
        "paper": PAPER,
    }
    report["findings"] = findings(summary, thr, comp, config, analysis.outcome_table(rows, policies))
    _write(out / "results.json", json.dumps(report, indent=1, default=_json_default))
    _write_csv(out / "results.csv", summary, policies)
    _write(out / "results.md", markdown(report, summary, policies))
    return report


AIRBORNE_INSTANCES = 20
"""Traffic instances per scenario that :func:`airborne` draws (the share of intruders in flight is an average over
intruders and minutes: 20 instances of the smallest scenario hold 1,000 intruders)."""


def airborne(config: StudyConfig) -> dict:
    """The mean share of intruders in flight at a minute of the mission, per diagonal scenario, over the first
    :data:`AIRBORNE_INSTANCES` traffic instances of the study (drawn as the study draws them)."""
    import numpy as np

    from stp_env.survivability.traffic import airborne_fraction, sample_traffic

    out = {}
    for p, u in config.scenarios:
        if p != u:
            continue
        traffic = config.traffic.with_overrides(n_partial=p, n_unknown=u)
        shares = []
        for i in range(min(AIRBORNE_INSTANCES, config.n_instances)):
            traffic_seq, _ = np.random.SeedSequence((config.seed, i)).spawn(2)  # as make_instance draws it
            shares.append(airborne_fraction(sample_traffic(traffic_seq, config.mission, traffic), config.mission))
        out[f"{p},{u}"] = float(np.mean(shares))
    return out


def diagonal_findings(table, summary, config) -> dict:
    """Fig. 7 of the paper along the diagonal ``N_p = N_u``: per total, the policy with the best success and the
    one with the best survival, each with its lead over the runner-up (paired difference over the same instances,
    :func:`stp_env.survivability.analysis.paired`, with a 95 % interval: ``resolved`` when it excludes 0).
    ``table``: :func:`stp_env.survivability.analysis.outcome_table`. The paper's findings: (A) at low traffic pi_R
    has the best success at the cost of survival; (B) at 300 intruders pi_S is best on both; (C) at 400 pi_Nf has
    the best success and at 500 the best survival."""
    out = {}
    for (p, u), per in summary.items():
        if p != u:
            continue
        row = {}
        for what in ("success", "survival"):
            order = sorted(config.policies, key=lambda q: -per[q][what]["rate"])
            entry = {"best": order[0], "rates": {q: per[q][what]["rate"] for q in config.policies}}
            if len(order) > 1:
                _, a = analysis.indicators(table[(p, u)][order[0]], what)
                _, b = analysis.indicators(table[(p, u)][order[1]], what)
                lead = analysis.paired(a, b)
                entry.update(runner_up=order[1], lead=lead,
                             resolved=bool(math.isfinite(lead["ci95"][0]) and lead["ci95"][0] > 0))
            row[what] = entry
        out[p + u] = row
    return out


def findings(summary, thr, comp, config, table=None) -> dict:
    """The paper's findings, ours next to them (``table``: the outcome table, for Fig. 7's paired leads)."""
    f = {"fig7_diagonal": diagonal_findings(table, summary, config)} if table is not None else {}
    nu_fixed = 100 if 100 in config.n_unknown else config.n_unknown[0]
    fig8 = {}
    for p in config.n_partial:
        if (p, nu_fixed) in summary:
            best = max(config.policies, key=lambda q: summary[(p, nu_fixed)][q]["survival"]["rate"])
            fig8[p] = {"best": best, **{f"survival[{q}]-survival[S]": comp[(p, nu_fixed)].get(
                f"survival[{q}]-survival[S]") for q in config.policies if q != "S"}}
    f[f"pi_S_best_partially_known (N_u = {nu_fixed})"] = fig8
    np_fixed = 100 if 100 in config.n_partial else config.n_partial[0]
    fig9 = {}
    for u in config.n_unknown:
        if (np_fixed, u) in summary:
            best = max(config.policies, key=lambda q: summary[(np_fixed, u)][q]["survival"]["rate"])
            fig9[u] = {"best": best, "survival[Nf]-survival[S]": comp[(np_fixed, u)].get("survival[Nf]-survival[S]")}
    f[f"pi_Nf_best_unknown (N_p = {np_fixed})"] = fig9
    f["phi(N_p = 100)"] = {"ours": thr["phi"].get(100), "paper": PAPER["phi_np100"]}
    f["phi(N_p = 50)"] = {"ours": thr["phi"].get(50), "paper": None}
    f["eta(N_total)"] = {"ours": {k: v["value"] for k, v in thr["eta"].items()}, "paper": "64 % falling to 38 %"}
    key = (50, 50)
    if key in comp and "S" in config.policies:
        f["survival-success[S] at 100 intruders"] = {"ours": comp[key]["survival-success[S]"],
                                                     "paper": PAPER["survival_gain_S_100"]}
        # the paper's "28.24" read as a relative gain instead: (survival - success) / success
        s_rate, v_rate = summary[key]["S"]["success"]["rate"], summary[key]["S"]["survival"]["rate"]
        f["survival/success[S] - 1 at 100 intruders"] = {"ours": (v_rate - s_rate) / s_rate if s_rate else None,
                                                         "paper": PAPER["survival_gain_S_100"]}
    return f


def _json_default(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    raise TypeError(type(o))


def _write(path: Path, text: str) -> None:
    write_text(text, path)


def _write_csv(path: Path, summary, policies) -> None:
    with atomic_open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["n_partial", "n_unknown", "policy", "n", "success", "success_lo", "success_hi", "survival",
                    "survival_lo", "survival_hi"])
        for (p, u), per in summary.items():
            for q in policies:
                s, v = per[q]["success"], per[q]["survival"]
                w.writerow([p, u, q, s["n"], f"{s['rate']:.4f}", f"{s['ci95'][0]:.4f}", f"{s['ci95'][1]:.4f}",
                            f"{v['rate']:.4f}", f"{v['ci95'][0]:.4f}", f"{v['ci95'][1]:.4f}"])


def _pct(r):
    return f"{100 * r['rate']:.1f} ({100 * r['ci95'][0]:.1f}-{100 * r['ci95'][1]:.1f})"


def markdown(report, summary, policies) -> str:
    lines = ["| N_p | N_u | n | " + " | ".join(f"survival {LABEL[p]} %" for p in policies) + " | " +
             " | ".join(f"success {LABEL[p]} %" for p in policies) + " |",
             "|---|---|---|" + "---|" * (2 * len(policies))]
    for (p, u), per in summary.items():
        n = per[policies[0]]["survival"]["n"]
        lines.append(f"| {p} | {u} | {n} | " + " | ".join(_pct(per[q]["survival"]) for q in policies) + " | " +
                     " | ".join(_pct(per[q]["success"]) for q in policies) + " |")
    lines.append("")
    thr = report["thresholds"]
    for name, unit in (("phi", ""), ("eta", "")):
        for k, v in thr[name].items():
            val = v["value"]
            lo, hi = v["ci95"]
            lines.append(f"- {name}({k}) = {_fmt(val)} (95 % bootstrap {_fmt(lo)}-{_fmt(hi)}; no crossing in "
                         f"{100 * v['no_crossing_fraction']:.0f} % of resamples; n = {v['n']}){unit}")
    lines += _findings_markdown(report, policies)
    return "\n".join(lines) + "\n"


def _lead(entry) -> str:
    lead = entry.get("lead")
    if lead is None:
        return LABEL[entry["best"]]
    lo, hi = lead["ci95"]
    return (f"{LABEL[entry['best']]} (+{100 * lead['diff']:.1f} over {LABEL[entry['runner_up']]}, "
            f"{100 * lo:.1f} to {100 * hi:.1f}{'' if entry['resolved'] else ', not resolved'})")


def _findings_markdown(report, policies) -> list[str]:
    """Fig. 7 along the diagonal, the survival gain at 100 intruders, the airborne share and the conflicts."""
    f = report.get("findings", {})
    lines = []
    diag = f.get("fig7_diagonal", {})
    if diag:
        lines += ["", "Fig. 7 along the diagonal (N_p = N_u): the best policy and its paired lead over the runner-up "
                  "(points, 95 % interval):", "", "| N_total | best success | best survival |", "|---|---|---|"]
        lines += [f"| {k} | {_lead(v['success'])} | {_lead(v['survival'])} |" for k, v in sorted(diag.items())]
    points = f.get("survival-success[S] at 100 intruders")
    relative = f.get("survival/success[S] - 1 at 100 intruders")
    if points:
        lo, hi = points["ours"]["ci95"]
        lines += ["", f"- pi_S's survival over success at 100 intruders (50, 50): {100 * points['ours']['diff']:.2f} "
                      f"points ({100 * lo:.2f} to {100 * hi:.2f}); relative {_pct_or_none(relative['ours'])}; "
                      f"paper: 28.24"]
    air, conf = report.get("airborne_fraction", {}), report.get("conflicts_per_mission", {})
    if air:
        lines += ["", "Intruders in flight at a minute of the mission (share, over the first instances' traffic) and "
                  "conflicts per mission (intruders revealed), on the diagonal:", "",
                  "| N_p, N_u | airborne | " + " | ".join(f"conflicts {LABEL[q]}" for q in policies) + " |",
                  "|---|---|" + "---|" * len(policies)]
        for key, share in air.items():
            per = conf.get(key, {})
            lines.append(f"| {key} | {100 * share:.1f} % | "
                         + " | ".join(f"{per[q]['mean']:.2f}" if q in per else "-" for q in policies) + " |")
    return lines


def _pct_or_none(v) -> str:
    return "n/a" if v is None else f"{100 * v:.2f} %"


def _fmt(v):
    if v is None:
        return "beyond the grid"
    return f"{v:.3g}"


# ---- figures -------------------------------------------------------------------------------------------------------

def figures(config: StudyConfig, out, report: dict | None = None) -> list[Path]:
    """Figures like the paper's Figs. 7-12 into ``out`` (needs matplotlib; call with a non-interactive backend)."""
    import matplotlib.pyplot as plt
    import numpy as np

    out = Path(out)
    rows = read_study(out)
    policies = config.policies
    summary = analysis.summarize(rows, policies)
    report = report or build_report(config, out)
    paths = []

    def band(ax, x, recs, q, what="survival", **kw):
        y = [100 * r[q][what]["rate"] for r in recs]
        lo = [100 * r[q][what]["ci95"][0] for r in recs]
        hi = [100 * r[q][what]["ci95"][1] for r in recs]
        ax.plot(x, y, "o-", color=COLOR[q], label=LABEL[q], **kw)
        ax.fill_between(x, lo, hi, color=COLOR[q], alpha=0.15)

    n_min = min(v[policies[0]]["survival"]["n"] for v in summary.values())
    note = f"{n_min}+ instances per scenario; bands: 95 % Clopper-Pearson"

    # Fig. 7: success vs survival on the diagonal.
    diag = [(p, u) for p, u in summary if p == u]
    if diag:
        fig, ax = plt.subplots(figsize=(9, 4.2))
        w = 0.8 / len(policies)
        for j, q in enumerate(policies):
            xs = np.arange(len(diag)) + (j - (len(policies) - 1) / 2) * w
            surv = np.array([summary[k][q]["survival"]["rate"] for k in diag]) * 100
            succ = np.array([summary[k][q]["success"]["rate"] for k in diag]) * 100
            def err(what, q=q):
                return np.array([[100 * (summary[d][q][what]["rate"] - summary[d][q][what]["ci95"][0]),
                                  100 * (summary[d][q][what]["ci95"][1] - summary[d][q][what]["rate"])]
                                 for d in diag]).T

            ax.bar(xs, surv, w, color=COLOR[q], alpha=0.35, yerr=err("survival"), capsize=2,
                   label=f"{LABEL[q]} survival")
            ax.bar(xs, succ, w, color=COLOR[q], yerr=err("success"), capsize=2, label=f"{LABEL[q]} success")
        ax.set_xticks(np.arange(len(diag)), [f"{p + u}\n({p}, {u})" for p, u in diag])
        ax.set_xlabel("intruders N_total (N_p, N_u)")
        ax.set_ylabel("rate [%]")
        ax.set_title("Mission success (solid) and survival (light) per policy")
        ax.legend(ncol=4, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.3))
        ax.grid(axis="y", alpha=0.3)
        fig.text(0.99, 0.01, note, ha="right", fontsize=7)
        paths.append(_save(fig, out / "fig7_success_survival.png"))

    # Figs. 8 and 9: survival against N_p (N_u = 100) and against N_u (N_p = 100).
    for fixed_name, fixed, fname, xlabel in (("N_u", 100, "fig8_survival_vs_np.png", "partially known intruders N_p"),
                                             ("N_p", 100, "fig9_survival_vs_nu.png", "unknown intruders N_u")):
        if fixed_name == "N_u":
            keys = [(p, fixed) for p in config.n_partial if (p, fixed) in summary]
            x = [k[0] for k in keys]
        else:
            keys = [(fixed, u) for u in config.n_unknown if (fixed, u) in summary]
            x = [k[1] for k in keys]
        if len(keys) < 2:
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        for q in policies:
            band(ax, x, [summary[k] for k in keys], q)
        if fixed_name == "N_p":
            phi = report["thresholds"]["phi"].get(str(fixed))
            if phi and phi["value"] is not None:
                ax.axvline(phi["value"], color="red", lw=1)
                ax.text(phi["value"], ax.get_ylim()[1], f" φ = {phi['value']:.0f}", color="red", va="top")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("mission survival rate [%]")
        ax.set_title(f"Survival with {fixed_name} = {fixed}")
        ax.legend()
        ax.grid(alpha=0.3)
        fig.text(0.99, 0.01, note, ha="right", fontsize=7)
        paths.append(_save(fig, out / fname))

    # Fig. 10: survival difference pi_Nf - pi_S over the grid and the switching boundary phi(N_p).
    if {"Nf", "S"} <= set(policies):
        grid = np.full((len(config.n_partial), len(config.n_unknown)), np.nan)
        for a, p in enumerate(config.n_partial):
            for b, u in enumerate(config.n_unknown):
                if (p, u) in summary:
                    grid[a, b] = 100 * (summary[(p, u)]["Nf"]["survival"]["rate"] -
                                        summary[(p, u)]["S"]["survival"]["rate"])
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        lim = np.nanmax(np.abs(grid)) if np.isfinite(grid).any() else 1.0
        im = ax.imshow(grid, origin="lower", cmap="coolwarm_r", vmin=-lim, vmax=lim, aspect="auto",
                       extent=[config.n_unknown[0] - 25, config.n_unknown[-1] + 25,
                               config.n_partial[0] - 25, config.n_partial[-1] + 25])
        fig.colorbar(im, ax=ax, label="survival π_Nf − π_S [points]")
        phis = [(int(k), v) for k, v in report["thresholds"]["phi"].items() if v["value"] is not None]
        edge = config.n_unknown[-1] + 25
        if phis:
            def ci(v, i):
                return v["ci95"][i] if v["ci95"][i] is not None else edge

            ax.errorbar([v["value"] for _, v in phis], [k for k, _ in phis],
                        xerr=[[max(v["value"] - ci(v, 0), 0) for _, v in phis],
                              [max(ci(v, 1) - v["value"], 0) for _, v in phis]],
                        fmt="o-", color="red", capsize=3, label="φ(N_p), 95 % bootstrap (open: beyond the grid)")
            ax.legend(loc="upper left", fontsize=8)
        ax.set_xlabel("unknown intruders N_u")
        ax.set_ylabel("partially known intruders N_p")
        ax.set_title("Where π_Nf (blue) beats π_S (red)")
        paths.append(_save(fig, out / "fig10_switching_boundary.png"))

    # Fig. 11: survival against the unknown ratio at N_total = 300.
    keys = sorted(((p, u) for (p, u) in summary if p + u == 300), key=lambda k: k[1])
    if len(keys) >= 2:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        x = [100 * u / 300 for _, u in keys]
        for q in policies:
            band(ax, x, [summary[k] for k in keys], q)
        eta = report["thresholds"]["eta"].get("300")
        if eta and eta["value"] is not None:
            ax.axvline(100 * eta["value"], color="red", lw=1)
            ax.text(100 * eta["value"], ax.get_ylim()[1], f" η = {100 * eta['value']:.0f} %", color="red", va="top")
        ax.set_xlabel("unknown intruders [% of N_total = 300]")
        ax.set_ylabel("mission survival rate [%]")
        ax.set_title("Survival with 300 intruders")
        ax.legend()
        ax.grid(alpha=0.3)
        fig.text(0.99, 0.01, note, ha="right", fontsize=7)
        paths.append(_save(fig, out / "fig11_survival_vs_ratio.png"))

    # Fig. 12: eta(N_total).
    etas = [(int(k), v) for k, v in report["thresholds"]["eta"].items()]
    if etas:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        pts = [(k, v) for k, v in etas if v["value"] is not None]
        if pts:
            lo = [v["ci95"][0] if v["ci95"][0] is not None else 1.0 for _, v in pts]
            hi = [v["ci95"][1] if v["ci95"][1] is not None else 1.0 for _, v in pts]
            ax.errorbar([k for k, _ in pts], [100 * v["value"] for _, v in pts],
                        yerr=[[100 * max(v["value"] - a, 0) for (_, v), a in zip(pts, lo)],
                              [100 * max(b - v["value"], 0) for (_, v), b in zip(pts, hi)]],
                        fmt="o-", color="red", capsize=3, label="ours, 95 % bootstrap")
        none = [k for k, v in etas if v["value"] is None]
        if none:
            ax.plot(none, [100] * len(none), "x", color="gray", label="no crossing on the grid")
        ax.plot([300], [64.4], "k*", ms=10, label="paper: η(300) = 64.4 %")
        ax.axhline(38, color="k", ls=":", lw=1, label="paper: lowest η, 38 % (most intruders)")
        ax.set_xlabel("intruders N_total")
        ax.set_ylabel("η: unknown share where π_Nf overtakes π_S [%]")
        ax.set_ylim(0, 105)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        paths.append(_save(fig, out / "fig12_eta.png"))

    # When the goal was lost: the window of the loss, over every scenario, and what followed.
    loss = report.get("goal_loss", {})
    if loss:
        fig, axes = plt.subplots(1, len(policies), figsize=(3.2 * len(policies), 3.4), sharey=True, squeeze=False)
        for ax, q in zip(axes[0], policies):
            totals: dict = {}
            for per in loss.values():
                for w, cell in per[q]["by_window"].items():
                    t = totals.setdefault(int(w), {"A": 0, "L_at_loss": 0, "L_later": 0})
                    for kind, n in cell.items():
                        t[kind] += n
            ws = sorted(totals)
            bottom = np.zeros(len(ws))
            for kind, color, label in (("A", "tab:green", "then an alternative site"),
                                       ("L_at_loss", "tab:red", "emergency landing in that window"),
                                       ("L_later", "tab:orange", "emergency landing later")):
                h = np.array([totals[w][kind] for w in ws], float)
                ax.bar(ws, h, bottom=bottom, color=color, label=label)
                bottom += h
            ax.set_title(LABEL[q])
            ax.set_xlabel("cruise window of the loss")
            ax.grid(axis="y", alpha=0.3)
        axes[0][0].set_ylabel("missions that lost the goal")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8)
        fig.text(0.99, 0.01, "all scenarios", ha="right", fontsize=7)
        paths.append(_save(fig, out / "fig13_goal_loss_window.png", rect=(0, 0.08, 1, 1)))
    return paths


def _save(fig, path: Path, rect=None) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout(**({} if rect is None else {"rect": rect}))
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["POLICIES", "build_report", "figures"]
