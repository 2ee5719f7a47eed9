"""The survivability study's record (stp_env/survivability/study.py): a study resumes from, and reports, only the rows
of its missions files that prove they are its own (its fingerprint, a key among its scenarios, policies and
instances, a digest of the row that matches). Rows of another study, rows appended for instances the study does not
have, edited rows and files of the older format are left out with one warning naming the file, and the missions
they stood for are flown again: the results are those of an untouched study."""

from __future__ import annotations

import csv
import json
import shutil
import warnings

import pytest
from _cli import run_cli
from test_survivability import small

from stp_env.survivability.config import PlannerConfig, StudyConfig, TrafficConfig
from stp_env.survivability.records import read_study
from stp_env.survivability.report import build_report
from stp_env.survivability.study import run_study

KEYS = ("outcome", "reveals", "omega_switch", "n_dp", "windows")


def _config(seed: int = 1, n_instances: int = 4) -> StudyConfig:
    """One scenario (4, 4) of the small mission, four instances: seeds 0 and 1 fly different missions, and seed 1
    has a best policy for survival (pi_S)."""
    return StudyConfig(n_partial=(4,), n_unknown=(4,), n_instances=n_instances, seed=seed, mission=small(),
                       traffic=TrafficConfig(reach_km=4), planner=PlannerConfig(n_mc=64, n_survival=64))


def _missions(out) -> dict:
    return {(r["n_partial"], r["n_unknown"], r["instance"], r["policy"]): tuple(r[k] for k in KEYS)
            for r in read_study(out)}


def _report(config: StudyConfig, out) -> dict:
    report = build_report(config, out, n_boot=50)
    report.pop("timing")
    return json.loads(json.dumps(report, default=str))


def _run(config: StudyConfig, out) -> tuple[dict, dict, list[str]]:
    """Run (or resume) the study and report it: its missions, its report (but for the timing) and the messages of
    the warnings about missions files."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_study(config, out, progress=False)
        missions, report = _missions(out), _report(config, out)
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning) and "missions" in str(w.message)]
    return missions, report, said


def _one_warning_naming(said: list[str], path, why: str) -> None:
    assert len(said) == 1, said
    assert str(path) in said[0] and why in said[0] and "\n" not in said[0], said[0]


def _rows(path) -> tuple[list[str], list[dict]]:
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames), list(reader)


def _write_rows(path, header, rows) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, header)
        writer.writeheader()
        writer.writerows(rows)


def _sign(header, row: dict) -> dict:
    """``row`` with the digest its values have, where the file's format has one (the digest is no secret: what it
    proves is the row's study and values, so that a row of another index is refused by the index check)."""
    if "digest" in header:
        from stp_env.survivability.records import FIELDS, row_digest

        row["digest"] = row_digest(row["study"], [row[k] for k in FIELDS])
    return row


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The untouched seed-1 study: its folder, missions and report; it warns about nothing."""
    out = tmp_path_factory.mktemp("seed1")
    missions, report, said = _run(_config(), out)
    assert said == [] and len(missions) == 4 * 4
    return out, missions, report


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    """The seed-0 study (otherwise the same options): its folder and missions."""
    out = tmp_path_factory.mktemp("seed0")
    run_study(_config(seed=0), out, progress=False)
    return out, _missions(out)


@pytest.mark.parametrize("into", ["finished", "fresh"])
def test_a_missions_file_of_another_study_is_not_reported_as_this_one(reference, foreign, tmp_path, into):
    """Seed 0's missions.csv copied into a seed-1 study's folder (a finished one, or a fresh one): none of its rows
    is used, one warning names the file, and the study flies its own missions: the results of the untouched study."""
    ref_out, ref_missions, ref_report = reference
    assert foreign[1] != ref_missions                                   # the other seed flew other missions
    out = tmp_path / "study"
    if into == "finished":
        shutil.copytree(ref_out, out)
    else:
        out.mkdir()
    shutil.copyfile(foreign[0] / "missions.csv", out / "missions.csv")
    missions, report, said = _run(_config(), out)
    assert missions == ref_missions and report == ref_report
    _one_warning_naming(said, out / "missions.csv", "another study")
    assert len(list(out.glob("missions.csv.rejected-*"))) == 1        # the refused file is kept, never read again
    _, again, said = _run(_config(), out)                               # a rerun: nothing to say, nothing changed
    assert again == ref_report and said == []


def test_rows_of_instances_the_study_does_not_have_are_not_counted(reference, tmp_path):
    """Rows appended for instances beyond the study's four are left out with one warning: the instance count and
    the best policy are the untouched study's. (a) The rows of a longer run of the same study (six instances, every
    row genuine); (b) instances 100-119 in which pi_Nf lands at the goal and every other policy crashes, which would
    make pi_Nf the best policy if they counted."""
    ref_out, ref_missions, ref_report = reference
    best = ref_report["findings"]["fig7_diagonal"]["8"]["survival"]["best"]
    assert best == "S" and ref_report["instances_per_scenario"] == {"4,4": 4}

    longer = tmp_path / "longer"
    run_study(_config(n_instances=6), longer, progress=False)
    assert len(_missions(longer)) == 6 * 4
    missions, report, said = _run(_config(), longer)
    assert missions == ref_missions and report == ref_report
    _one_warning_naming(said, longer / "missions.csv", "beyond")

    appended = tmp_path / "appended"
    shutil.copytree(ref_out, appended)
    header, rows = _rows(appended / "missions.csv")
    template = {r["policy"]: r for r in rows if r["outcome"] == ("G" if r["policy"] == "Nf" else "L")}
    assert len(template) == 4
    extra = [_sign(header, {**template[p], "instance": str(100 + k)}) for k in range(20) for p in template]
    _write_rows(appended / "missions.csv", header, rows + extra)
    missions, report, said = _run(_config(), appended)
    assert missions == ref_missions and report == ref_report
    assert report["instances_per_scenario"] == {"4,4": 4} and report["findings"]["fig7_diagonal"]["8"]["survival"][
        "best"] == best
    _one_warning_naming(said, appended / "missions.csv", "80 rows not used")


def test_an_edited_row_is_flown_again(reference, tmp_path, monkeypatch):
    """pi_S's outcome in instance 0 edited from a landing at an alternative site to an emergency landing: the row's
    digest no longer matches, one warning names the file, and that instance (every policy) is flown again, nothing
    else."""
    from stp_env.survivability import study

    ref_out, ref_missions, ref_report = reference
    out = tmp_path / "study"
    shutil.copytree(ref_out, out)
    header, rows = _rows(out / "missions.csv")
    row = next(r for r in rows if r["policy"] == "S" and r["instance"] == "0")
    assert row["outcome"] == "A"
    row["outcome"] = "L"
    _write_rows(out / "missions.csv", header, rows)
    calls = []
    piece = study.study_piece
    monkeypatch.setattr(study, "study_piece", lambda c, a: (calls.append(a), piece(c, a))[1])
    missions, report, said = _run(_config(), out)
    assert calls == [(0, 4, (4,))]
    assert missions == ref_missions and report == ref_report
    _one_warning_naming(said, out / "missions.csv", "do not match their digest")
    assert len(_rows(out / "missions.csv")[1]) == 4 * 4                 # no row twice


def test_a_missions_file_of_the_older_format_is_refused_and_flown_again(reference, tmp_path):
    """A missions file without the study's fingerprint and digest (written before the rows carried them) cannot
    prove whose it is: one warning (no traceback) names it, and the study flies its missions again."""
    ref_out, ref_missions, ref_report = reference
    out = tmp_path / "study"
    shutil.copytree(ref_out, out)
    header, rows = _rows(out / "missions.csv")
    older = [k for k in header if k not in ("study", "digest")]
    _write_rows(out / "missions.csv", older, [{k: r[k] for k in older} for r in rows])
    missions, report, said = _run(_config(), out)
    assert missions == ref_missions and report == ref_report
    _one_warning_naming(said, out / "missions.csv", "older format")


def test_the_report_of_another_configuration_s_folder_is_refused(reference, tmp_path):
    """``--report-only`` with options other than the study's in the folder is one line naming it, not a report of
    that study as this one."""
    out = tmp_path / "study"
    shutil.copytree(reference[0], out)
    code, _, err = run_cli(["survivability", "--out", str(out), "--report-only", "--no-figures", "--partial", "4",
                            "--unknown", "4", "--instances", "4", "--seed", "1", "--bootstrap", "10"])
    assert code == 2 and err.count("\n") == 1 and "different configuration" in err and str(out) in err, err
