"""Resumable pieces prove where they came from (``stp_env/execution.py``): a piece file is read back only when it
carries this job's fingerprint, its own index and a digest that matches its content. Anything else in a piece's
place (forged values, a piece of another seed's run, a piece of a shorter run, an empty file, a directory, an
archive with arrays missing, a piece of an earlier version without provenance) is moved aside and computed again,
with one warning that names the file, and the results are those of an untouched run."""

from __future__ import annotations

import io
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from stp_env import execution
from stp_env.evaluation import Configuration, runner

FINGERPRINT = "ab" * 16
TINY = Configuration(scenario="tiny-intruder", kbar=2, intruder="greedy", vehicle_policy="nominal")
EVALUATION = {"episodes": 5, "seed": 1, "batch_size": 2, "progress": False}  # 3 batches: 2 + 2 + 1 episodes


def _powers(context, i):
    return {"x": np.asarray([i ** context]), "name": np.asarray(f"piece {i}")}


def _job(power: int = 2, n: int = 3, fingerprint: str = FINGERPRINT) -> execution.Job:
    return execution.Job(name="powers", function=_powers, context=power, arguments=tuple(range(n)),
                         fingerprint=fingerprint)


def _rewrite(path: Path, change) -> None:
    """``path``'s arrays (provenance included) passed through ``change`` and written back in place."""
    arrays = dict(np.load(path))
    change(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


def _forge(arrays):
    arrays["x"] = arrays["x"] + 1


def _drop_x(arrays):
    del arrays["x"]


def _old_format(arrays):
    for key in execution.PROVENANCE:
        del arrays[key]


def _run_warning(job, out_dir) -> tuple[list[dict], list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        results = execution.LocalExecutor().run(job, out_dir=out_dir)
    return results, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def _values(results) -> list:
    return [{k: v.tobytes() for k, v in r.items()} for r in results]


def _place_foreign(folder: Path, tmp_path: Path) -> None:
    """Piece 1 of the same job with another context and fingerprint (another seed's run) copied in."""
    other = _job(power=3, fingerprint="cd" * 16)
    execution.LocalExecutor().run(other, out_dir=tmp_path / "other")
    shutil.copy(execution.piece_path(other.folder(tmp_path / "other"), 1), execution.piece_path(folder, 1))


def _place_shifted(folder: Path, tmp_path: Path) -> None:
    """Piece 0 copied into piece 1's place (a piece of another size or position)."""
    shutil.copy(execution.piece_path(folder, 0), execution.piece_path(folder, 1))


def _place_empty(folder: Path, tmp_path: Path) -> None:
    execution.piece_path(folder, 1).write_bytes(b"")


def _place_directory(folder: Path, tmp_path: Path) -> None:
    path = execution.piece_path(folder, 1)
    path.unlink()
    path.mkdir()
    (path / "inside").write_text("x")


CASES = {
    "forged": lambda folder, tmp: _rewrite(execution.piece_path(folder, 1), _forge),
    "missing-arrays": lambda folder, tmp: _rewrite(execution.piece_path(folder, 1), _drop_x),
    "no-provenance": lambda folder, tmp: _rewrite(execution.piece_path(folder, 1), _old_format),
    "foreign": _place_foreign,
    "shifted": _place_shifted,
    "empty": _place_empty,
    "directory": _place_directory,
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_piece_that_is_not_this_job_s_runs_again_with_one_warning(tmp_path, case):
    job = _job()
    untouched = execution.LocalExecutor().run(job)
    execution.LocalExecutor().run(job, out_dir=tmp_path)
    folder = job.folder(tmp_path)
    CASES[case](folder, tmp_path)
    results, messages = _run_warning(job, tmp_path)
    assert _values(results) == _values(untouched)
    assert len(messages) == 1 and "piece-000001.npz" in messages[0] and "\n" not in messages[0], messages
    assert len(list(folder.glob("piece-000001.npz.rejected-*"))) == 1       # kept aside, never read again
    again, messages = _run_warning(job, tmp_path)                           # rewritten: the next run is quiet
    assert _values(again) == _values(untouched) and messages == []


def test_a_piece_of_this_job_is_read_back_not_recomputed(tmp_path):
    calls = []
    job = _job()
    execution.LocalExecutor().run(job, out_dir=tmp_path)
    counted = execution.Job(name="powers", function=lambda c, i: (calls.append(i), _powers(c, i))[1], context=2,
                            arguments=(0, 1, 2), fingerprint=FINGERPRINT)
    results, messages = _run_warning(counted, tmp_path)
    assert calls == [] and messages == [] and _values(results) == _values(execution.LocalExecutor().run(job))


def test_a_result_cannot_use_the_provenance_names():
    job = execution.Job(name="j", function=lambda c, i: {"__piece_digest__": np.zeros(1)}, context=None,
                        arguments=(0,))
    with pytest.raises(ValueError, match="reserved"):
        execution.LocalExecutor().run(job)


# ------------------------------------------------------------------------------------------------ the evaluation
def _evaluation_pieces(tmp_path: Path, **overrides) -> Path:
    out = tmp_path / f"pieces-{len(list(tmp_path.iterdir()))}"
    runner.evaluate([TINY], pieces_dir=out, **{**EVALUATION, **overrides})
    (folder,) = out.iterdir()
    return folder


def _same_summary(a, b) -> None:
    drop = ("seconds", "episodes_per_s")
    x = {k: v for k, v in a.summary.items() if k not in drop}
    y = {k: v for k, v in b.summary.items() if k not in drop}
    assert x.keys() == y.keys()
    for k in x:
        assert x[k] == y[k] or (x[k] != x[k] and y[k] != y[k]), k
    for k in a.episodes:
        assert np.asarray(a.episodes[k]).tobytes() == np.asarray(b.episodes[k]).tobytes(), k


@pytest.mark.slow
def test_an_evaluation_never_merges_a_forged_foreign_or_short_piece(tmp_path):
    """The evaluation's own pieces: a forged value (a separation that never happened), a batch of another seed's
    run and the last batch of a shorter run, each in batch 1's place, are computed again: the summary is that of
    an untouched run, with one warning per run naming the file."""
    untouched = runner.evaluate([TINY], **EVALUATION)[0]
    folder = _evaluation_pieces(tmp_path)
    foreign = _evaluation_pieces(tmp_path, seed=2)
    short = _evaluation_pieces(tmp_path, episodes=3)              # batches 2 + 1: its piece 1 has one episode

    def forge(arrays):
        key = next(k for k in arrays if k.startswith("ep/") and arrays[k].dtype.kind == "f")
        arrays[key] = arrays[key] * 0 + 0.12

    places = {"forged": lambda p: _rewrite(p, forge),
              "foreign": lambda p: shutil.copy(execution.piece_path(foreign, 1), p),
              "short": lambda p: shutil.copy(execution.piece_path(short, 1), p)}
    for case, place in places.items():
        place(execution.piece_path(folder, 1))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            (result,) = runner.evaluate([TINY], pieces_dir=folder.parent, **EVALUATION)
        messages = [str(w.message) for w in caught if "piece-000001.npz" in str(w.message)]
        assert len(messages) == 1, (case, [str(w.message) for w in caught])
        assert result.summary["episodes"] == EVALUATION["episodes"], case
        _same_summary(untouched, result)


# ------------------------------------------------------------------------------------------------ the falsifier
@pytest.mark.slow
def test_a_search_never_merges_a_forged_restart(tmp_path):
    import jax

    from stp_env.falsify.search import SearchConfig, search

    def objective(x):
        return jax.numpy.sum((x - 0.25) ** 2, axis=-1)

    config = SearchConfig(budget=40, population=10, restarts=2, batch=10)
    untouched = search(objective, 3, jax.random.key(3), config)
    search(objective, 3, jax.random.key(3), config, out_dir=tmp_path)
    (folder,) = tmp_path.iterdir()

    def forge(arrays):
        key = next(k for k in sorted(arrays) if not k.startswith("__") and arrays[k].dtype.kind == "f")
        arrays[key] = arrays[key] - 100.0

    _rewrite(execution.piece_path(folder, 1), forge)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = search(objective, 3, jax.random.key(3), config, out_dir=tmp_path)
    assert sum("piece-000001.npz" in str(w.message) for w in caught) == 1
    assert np.asarray(again.values).tobytes() == np.asarray(untouched.values).tobytes()
    assert float(again.best_value) == float(untouched.best_value)
