"""The main job end to end: evaluate the configurations, write the results (JSON, CSV, markdown, replayable
events) and the figures (:mod:`stp_env.evaluation.plots`)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from stp_env.evaluation import plots, report
from stp_env.evaluation.config import resolve_vehicle_policy
from stp_env.evaluation.runner import evaluate, replay


def showcase_result(results):
    """The configuration whose showcase episode forced the most vehicles (the first on ties)."""
    with_showcase = [r for r in results if r.showcase is not None]
    return max(with_showcase, key=lambda r: r.summary["forced_max"]) if with_showcase else None


def counterpart(result, vehicle_policy: str):
    """The showcase episode replayed under another vehicle policy (``"nominal"``: ``u^PP`` with the safety filter
    off; ``"switching"``: ``u*`` with it on): the same seed, wind draws and intruder spawn (the intruder's policy
    reacts to the vehicles it sees)."""
    params = dataclasses.replace(result.params, safety_filter=vehicle_policy != "nominal")
    _, intruder_policy = result.config.policies()
    return replay(result.seed, result.showcase["index"], params, resolve_vehicle_policy(vehicle_policy),
                  intruder_policy, result.n_steps)


def run(configs, out_dir, *, episodes: int = 1000, seed: int = 0, batch_size: int = 250, confidence: float = 0.95,
        store=None, progress: bool = True, figures: bool = True) -> dict:
    """Evaluate ``configs`` and write everything to ``out_dir``; returns ``{"summaries", "markdown", "files",
    "seconds"}``."""
    start = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = evaluate(configs, episodes=episodes, seed=seed, batch_size=batch_size, confidence=confidence,
                       store=store, progress=progress)
    summaries = [r.summary for r in results]
    markdown = report.markdown_table(summaries)
    files = [
        report.write_json(summaries, out / "results.json", seed=seed, episodes=episodes, batch_size=batch_size),
        report.write_csv(summaries, out / "results.csv"),
        *report.write_events(results, out),
        report.write_episodes(results, out / "episodes.npz"),
    ]
    (out / "results.md").write_text(markdown + "\n")
    files.append(str(out / "results.md"))
    if figures:
        files.append(plots.plot_forced_histograms(summaries, str(out / "forced_histogram.png")))
        files.append(plots.plot_summary(summaries, str(out / "summary.png")))
        best = showcase_result(results)
        if best is not None:
            show = best.showcase
            scenario = best.config.make_scenario()
            what = (f"{best.config.intruder} intruder, k̄ = {best.config.kbar}, seed {best.seed}, episode "
                    f"{show['index']}: |N^RP| = {int(show['final']['n_forced'])}")
            files.append(plots.plot_episode(show, show["final"], best.params, scenario, str(out / "episode.png"),
                                            title=f"{scenario.name}: {what}"))
            own = best.config.vehicle_policy
            other = "nominal" if own == "switching" else "switching"
            other_final, other_traj = counterpart(best, other)
            runs = {own: (show, show["final"]), other: (other_traj, other_final)}
            files.append(plots.plot_distance_vs_time(
                *runs["switching"], *runs["nominal"], best.params, str(out / "distance_vs_time.png"),
                title=f"distance to the intruder, avoidance u* vs nominal u^PP\n{scenario.name}: {what}"))
    return {"summaries": summaries, "markdown": markdown, "files": files,
            "seconds": round(time.perf_counter() - start, 1)}
