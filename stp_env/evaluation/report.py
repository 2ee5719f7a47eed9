"""Results as JSON, CSV and a markdown table; bad episodes as replayable records (``events.json`` +
``events.npz``); every episode's final state (``episodes.npz``). Every file is written atomically
(:func:`stp_env.files.atomic_open`)."""

from __future__ import annotations

import csv
import hashlib
import json
import platform
import subprocess
from pathlib import Path

import numpy as np

from stp_env.evaluation.events import load_event_state  # noqa: F401  (re-exported)
from stp_env.files import atomic_open, write_text

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
"""The ``stp_env`` package's directory (the one this module was imported from)."""

CSV_COLUMNS = (
    "label", "scenario", "kbar", "intruder", "scenario_wind_mps", "wind_model", "spawn_mode", "vehicle_policy",
    "episode", "episodes", "forced_mean", "forced_max", "exceed", "exceed_rate", "exceed_upper", "confidence",
    "kbar_reached", "kbar_reached_rate", "avoid_start_kth_min_s", "avoid_start_kth_median_s",
    "collision_episodes", "collisions", "intruder_collisions", "out_of_bounds", "guarantee_violations",
    "violation_episodes", "violation_upper", "assumption_failures", "tracking_violations", "max_tracking_error_m",
    "tracking_bound_m", "due", "on_time_rate", "arrived_rate",
    "min_separation_m", "min_separation_p5_m", "min_separation_median_m", "collision_radius_m", "seed", "n_steps",
    "batch_size", "devices", "seconds", "episodes_per_s",
)


def _pct(x) -> str:
    if x is None:
        return "n/a"
    if x == 0:
        return "0"
    return f"{100 * x:.2g}%" if x < 0.01 else f"{100 * x:.1f}%"


def markdown_table(summaries: list[dict]) -> str:
    """One row per configuration: what the report's numbers mean is in :func:`stp_env.evaluation.summarize`."""
    conf = summaries[0]["confidence"] if summaries else 0.95
    head = ("| scenario | intruder | vehicles | k̄ | wind [m/s] | episodes | mean \\|N^RP\\| | max \\|N^RP\\| | "
            "\\|N^RP\\| > k̄ | "
            f"P(\\|N^RP\\| > k̄) ≤ ({100 * conf:g}%) | collisions (intruder) | guarantee violations | "
            "max tracking error [m] (r_e) | on time | min sep. [m] | \\|N^RP\\| ≥ k̄ | "
            "k-th avoid start, median (earliest) [s] |")
    rows = [head, "|" + " --- |" * 17]
    for s in summaries:
        wind = f"{s['scenario_wind_mps']:g} {s['wind_model']}"
        rows.append(
            f"| {s['scenario']} | {s['intruder']} ({s['spawn_mode']}) | {s['vehicle_policy']} | {s['kbar']} | "
            f"{wind} | {s['episodes']} | "
            f"{s['forced_mean']:.2f} | {s['forced_max']} | {s['exceed']} | {_pct(s['exceed_upper'])} | "
            f"{s['collisions']} ({s['intruder_collisions']}) | {s['guarantee_violations']} | "
            f"{_num(s['max_tracking_error_m'])} ({s['tracking_bound_m']:.2f}) | "
            f"{_pct(s['on_time_rate'])} | {s['min_separation_m']} | {_pct(s.get('kbar_reached_rate'))} | "
            f"{_kth_times(s)} |")
    return "\n".join(rows)


def _num(x) -> str:
    """``x`` with two decimals, ``n/a`` for ``None`` (nothing measured)."""
    return "n/a" if x is None else f"{x:.2f}"


def _kth_times(s: dict) -> str:
    """``t_1, t_2, ...`` of the summary's k-th avoid starts: ``median (earliest)``, ``-`` where none."""
    meds, lows = s.get("avoid_start_kth_median_s") or [], s.get("avoid_start_kth_min_s") or []
    return ", ".join("-" if m is None else f"{m:g} ({lo:g})" for m, lo in zip(meds, lows)) or "-"


def write_csv(summaries: list[dict], path) -> str:
    with atomic_open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for s in summaries:
            writer.writerow(s)
    return str(path)


def source_hash() -> str:
    """SHA-256 (first 16 hex digits) of every ``.py`` file of the installed ``stp_env`` package, in path order: the
    code that produced a result, whether or not it was installed from a git checkout."""
    root = PACKAGE_ROOT
    h = hashlib.sha256()
    for file in sorted(root.rglob("*.py")):
        h.update(file.relative_to(root).as_posix().encode())
        h.update(file.read_bytes())
    return h.hexdigest()[:16]


def git_commit() -> str | None:
    """The commit of the checkout the package is imported from (an editable install), ``"<sha>-dirty"`` with local
    changes, or ``None`` (a wheel install, or no ``git``)."""
    root = PACKAGE_ROOT
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "."], cwd=root, capture_output=True,
                               text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{sha}-dirty" if dirty else sha


def provenance() -> dict:
    """What produced a result: package version, source hash, git commit (if any), the artifacts' numerics version,
    and the JAX, NumPy and Python versions. Results of the same seed depend on the code, so every results file
    records this."""
    import jax

    from stp_env.artifacts import CODE_VERSION
    from stp_env.version import __version__

    return {"stp_env_version": __version__, "source_hash": source_hash(), "git_commit": git_commit(),
            "numerics_code_version": CODE_VERSION, "jax_version": jax.__version__, "numpy_version": np.__version__,
            "python_version": platform.python_version()}


def write_json(summaries: list[dict], path, **extra) -> str:
    """``{"provenance": provenance(), **extra, "configurations": summaries}`` as indented JSON."""
    record = {"provenance": provenance(), **extra, "configurations": summaries}
    return write_text(json.dumps(record, indent=1) + "\n", path)


def write_events(results, out_dir) -> tuple[str, str]:
    """``events.json`` (one record per saved bad episode: configuration, seed, index, step count, what went
    wrong) and ``events.npz`` (each record's final state, keys ``"{n}/{field}"`` with ``n`` its position in the
    JSON list). :func:`stp_env.evaluation.replay_event` replays a record."""
    out_dir = Path(out_dir)
    records, arrays = [], {}
    for result in results:
        for event in result.events:
            n = len(records)
            records.append({k: v for k, v in event.items() if k != "state"} | {"npz_prefix": f"{n}/"})
            for field, value in event["state"].items():
                arrays[f"{n}/{field}"] = np.asarray(value)
    json_path, npz_path = out_dir / "events.json", out_dir / "events.npz"
    with atomic_open(npz_path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    write_text(json.dumps(records, indent=1) + "\n", json_path)
    return str(json_path), str(npz_path)


def write_episodes(results, path) -> str:
    """Every episode's final state, keys ``"{label}/{field}"`` (plus ``n_forced`` and ``index``), for analyses
    beyond the summary."""
    arrays = {f"{r.config.label}/{k}": np.asarray(v) for r in results for k, v in r.episodes.items()}
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return str(path)
