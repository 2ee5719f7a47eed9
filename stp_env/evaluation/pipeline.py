"""The main job end to end: evaluate the configurations, write the results (JSON, CSV, markdown, replayable
events) and the figures (:mod:`stp_env.evaluation.plots`), all or nothing (:func:`run`)."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path

from stp_env.evaluation import plots, report
from stp_env.evaluation.config import resolve_vehicle_policy
from stp_env.evaluation.replays import replay
from stp_env.evaluation.runner import evaluate


def showcase_result(results):
    """The configuration whose showcase episode forced the most vehicles (the first on ties)."""
    with_showcase = [r for r in results if r.showcase is not None]
    return max(with_showcase, key=lambda r: r.summary["forced_max"]) if with_showcase else None


def counterpart(result, vehicle_policy: str):
    """The showcase episode replayed under another vehicle policy (``"nominal"``: ``u^PP`` with the safety filter
    off; ``"switching"``: ``u*`` with it on): the same seed, wind draws and intruder spawn (the intruder's policy
    reacts to the vehicles it sees)."""
    params = result.params.replace(episode=dict(safety_filter=vehicle_policy != "nominal"))
    _, intruder_policy = result.config.policies()
    return replay(result.seed, result.showcase["index"], params, resolve_vehicle_policy(vehicle_policy),
                  intruder_policy, result.n_steps, airborne_only=result.airborne_only)


OUTPUT_NAMES = ("results.json", "results.csv", "results.md", "events.json", "events.npz", "episodes.npz",
                "forced_histogram.png", "summary.png", "episode.png", "distance_vs_time.png")
"""Every file :func:`run` writes (``results.json`` first: it is removed first and published last)."""
STAGING_PREFIX = ".stp-env-staging-"
PIECES = "pieces"
"""The folder of ``out_dir`` that holds the finished batches of a run until its results are written."""


def check_output_dir(out_dir, option: str = "--out") -> Path:
    """``out_dir`` as a ``Path`` if it is (or can be made) a writable directory; a one-line ``ValueError`` naming
    ``option`` and the path otherwise. Called before any computation, so that results are not lost at the end."""
    from stp_env.artifacts import probe_writable

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{option} {out}: exists and is not a directory.")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe_writable(out)
    except OSError as err:
        raise ValueError(f"{option} {out}: cannot write there ({type(err).__name__}: {err.strerror or err}).") \
            from None
    return out


def _publish(staging: Path, out: Path) -> list[str]:
    """Replace ``out``'s outputs of an earlier run by the new ones in ``staging``.

    Every known output of an earlier run is removed first (``results.json`` first), then the new files are moved
    in (``os.replace``, ``results.json`` last). An interruption leaves either a subset of the old outputs without
    ``results.json`` or a subset of the new ones without it, never old and new files side by side; an output
    directory with ``results.json`` holds one complete run."""
    for name in OUTPUT_NAMES:
        with contextlib.suppress(FileNotFoundError):
            (out / name).unlink()
    new = [name for name in OUTPUT_NAMES if (staging / name).exists()]
    for name in [*new[1:], *new[:1]] if new and new[0] == "results.json" else new:
        os.replace(staging / name, out / name)
    return [str(out / name) for name in new]


def run(configs, out_dir, *, episodes: int = 1000, seed: int = 0, batch_size: int = 250, confidence: float = 0.95,
        store=None, progress: bool = True, figures: bool = True, airborne_only: bool = True,
        executor=None) -> dict:
    """Evaluate ``configs`` and write everything to ``out_dir``; returns ``{"summaries", "markdown", "files",
    "seconds"}``. ``airborne_only``, ``executor``: as in :func:`stp_env.evaluation.evaluate`.

    Every finished batch is written to ``out_dir/pieces`` (:data:`PIECES`) as it ends: a run that was killed and is
    started again with the same arguments computes only the batches it had not finished. The folder is removed
    once the results are written.

    ``out_dir`` is checked to be writable before anything is computed (:func:`check_output_dir`). The files are
    written into a staging directory inside it and then replace the outputs of an earlier run (see
    :func:`_publish`): a run that fails or is interrupted leaves the earlier outputs as they were. Staging
    directories of runs that were killed are removed on the next run."""
    from stp_env.files import remove_stale_temporaries, writer_tag

    start = time.perf_counter()
    out = check_output_dir(out_dir)
    remove_stale_temporaries(out, STAGING_PREFIX)
    results = evaluate(configs, episodes=episodes, seed=seed, batch_size=batch_size, confidence=confidence,
                       store=store, progress=progress, airborne_only=airborne_only, executor=executor,
                       pieces_dir=out / PIECES)
    staging = Path(tempfile.mkdtemp(dir=out, prefix=STAGING_PREFIX + writer_tag()))
    try:
        summaries, markdown = _write_all(results, staging, seed=seed, episodes=episodes, batch_size=batch_size,
                                         figures=figures, progress=progress)
        files = _publish(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    shutil.rmtree(out / PIECES, ignore_errors=True)  # published: nothing left to resume
    return {"summaries": summaries, "markdown": markdown, "files": files,
            "seconds": round(time.perf_counter() - start, 1)}


def _write_all(results, out: Path, *, seed, episodes, batch_size, figures, progress=None):
    from stp_env import progress as progress_mod

    progress_mod.note(f"writing the results ({len(results)} configuration(s)) to {out.parent}", progress)
    summaries = [r.summary for r in results]
    markdown = report.markdown_table(summaries)
    report.write_json(summaries, out / "results.json", seed=seed, episodes=episodes, batch_size=batch_size)
    report.write_csv(summaries, out / "results.csv")
    report.write_events(results, out)
    report.write_episodes(results, out / "episodes.npz")
    report.write_text(markdown + "\n", out / "results.md")
    if figures:
        progress_mod.note("drawing the figures", progress)
        plots.plot_forced_histograms(summaries, str(out / "forced_histogram.png"))
        plots.plot_summary(summaries, str(out / "summary.png"))
        best = showcase_result(results)
        if best is not None:
            show = best.showcase
            scenario = best.config.make_scenario()
            what = (f"{best.config.intruder} intruder, k̄ = {best.config.kbar}, seed {best.seed}, episode "
                    f"{show['index']}: |N^RP| = {int(show['final']['n_forced'])}")
            plots.plot_episode(show, show["final"], best.params, scenario, str(out / "episode.png"),
                               title=f"{scenario.name}: {what}")
            runs = {best.config.vehicle_policy: (show, show["final"])}
            for other in ("switching", "nominal"):  # the figure compares u* with u^PP (a "worst" run has neither)
                if other not in runs:
                    progress_mod.note(f"replaying the showcase episode with {other} vehicles for distance_vs_time.png "
                                      "(compiles its simulator program once per machine)", progress)
                    other_final, other_traj = counterpart(best, other)
                    runs[other] = (other_traj, other_final)
            plots.plot_distance_vs_time(
                *runs["switching"], *runs["nominal"], best.params, str(out / "distance_vs_time.png"),
                title=f"distance to the intruder, avoidance u* vs nominal u^PP\n{scenario.name}: {what}")
    return summaries, markdown
