"""The diagnosis a user can read (issue 33, sections 7 and 8): a verdict
first, in at most 40 lines at 100 columns, with the final model's values;
the candidate tables behind --verbose; tables that fold rather than cut; a
change said with the verb its sign calls for; no advice to take a
measurement the run already has; every run's figures of a joint diagnosis.

Console text is read at an explicit width (COLUMNS or Console(width=...)),
never at the terminal's."""

from __future__ import annotations

import functools
import json
import re
from dataclasses import replace

import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.diagnosis.console import as_text, verdict
from cmmpose.diagnosis.wording import change_text, without_held_needs
from cmmpose.sim import effects as E
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner


def _flat(text: str) -> str:
    """Text with Rich's wrapping and table rules undone: words separated by single spaces."""
    return " ".join(re.sub(r"[│┃┏┓┗┛┡┩└┘┌┐├┤┬┴┼━─╇╈╋┳┻]", " ", text).split())


@pytest.fixture(scope="module")
def squareness_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("console") / "run"
    res = CliRunner().invoke(main, ["simulate", "--effect", "squareness:xy=20", "-o", str(folder)])
    assert res.exit_code == 0, res.output
    return folder


@pytest.fixture(scope="module")
def squareness_diagnosis(squareness_run):
    return cmmpose.diagnose(cmmpose.Run.load(squareness_run))


def test_default_console_is_a_verdict_within_40_lines_of_100_columns(squareness_run):
    res = CliRunner().invoke(main, ["diagnose", str(squareness_run)], env={"COLUMNS": "100"})
    assert res.exit_code == 0, res.output
    lines = res.stdout.rstrip("\n").splitlines()
    assert len(lines) <= 40, res.stdout
    assert max(len(line) for line in lines) <= 100, res.stdout
    assert lines[0].startswith("Verdict")
    flat = _flat(res.stdout)
    for words in ("found:", "unexplained:", "next:", "Final model", "The error falling"):
        assert words in flat
    # the final model's values: each parameter with its value, uncertainty and unit
    assert re.search(r"squareness xy = \+(19|20|21)\.\d+ ± [0-9.]+ arc-second", flat), flat
    assert "Candidate effects" not in flat  # the full tables: --verbose


def test_verbose_console_holds_the_candidate_tables_uncut_at_100_columns(squareness_run, squareness_diagnosis):
    res = CliRunner().invoke(main, ["diagnose", str(squareness_run), "--verbose"], env={"COLUMNS": "100"})
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert max(len(line) for line in lines) <= 100
    flat = _flat(res.stdout)
    assert "Candidate effects against the model 'base'" in flat and "Not observable in this run" in flat
    # the decision column is whole: every candidate's decision word is there, none cut
    d = squareness_diagnosis
    assert "proposed" in flat
    for decision in {c.decision for c in d.steps[-1].ranking} - {"preferred", "not chosen"}:
        assert decision in flat, decision


@pytest.mark.parametrize("width", [80, 100, 160])
def test_no_column_is_cut_names_and_decisions_fold_whole(squareness_diagnosis, width):
    """The candidate table's first and last columns, read back line by line and joined, hold every candidate's
    whole name and decision in order: folded, never cropped."""
    import io

    from rich.console import Console

    from cmmpose.diagnosis.console import candidate_table

    d = squareness_diagnosis
    console = Console(width=width, record=True, file=io.StringIO())
    console.print(candidate_table(d, len(d.steps) - 1, width))
    text = console.export_text()
    rows = [line.split("│")[1:-1] for line in text.splitlines() if line.startswith("│")]
    assert rows and max(len(line) for line in text.splitlines()) <= width
    firsts = "".join(r[0].strip() for r in rows)
    wide = width >= 140  # the wide layout puts the physics under each name
    if not wide:
        assert firsts == "".join(c.name for c in d.steps[-1].ranking)
    decisions = " ".join(" ".join(r[-1].split()) for r in rows if r[-1].strip())
    for c in d.steps[-1].ranking:
        assert c.name in firsts.replace(" ", "") if not wide else True
        assert c.decision in decisions or c.decision in ("preferred", "not chosen")


def test_tables_fold_at_any_width_and_the_wide_layout_keeps_every_column(squareness_diagnosis):
    d = squareness_diagnosis
    for width in (60, 80, 100, 150):
        text = as_text(d, verbose=True, width=width)
        assert max(len(line) for line in text.splitlines()) <= width
    wide = _flat(as_text(d, verbose=True, width=160))
    for col in ("explains", "LR (dof)", "corr", "cond", "decision"):
        assert col in wide
    # the verdict view fits 40 lines at 100 columns from the Python side too
    short = as_text(d, verbose=False, width=100)
    assert len(short.rstrip("\n").splitlines()) <= 40


def test_a_rise_is_never_called_a_fall():
    assert change_text("the rms", 4.34, 4.35) == "the rms rose from 4.34 um to 4.35 um"
    assert change_text("the rms", 4.35, 4.34) == "the rms fell from 4.35 um to 4.34 um"
    assert change_text("the rms", 4.340, 4.3449) == "the rms stayed at 4.34 um"
    said = change_text("the rms", 4.34, 4.35, u_um=0.3)
    assert said.startswith("the rms is unchanged within its uncertainty") and "+0.01 ± 0.30 um" in said
    assert "fell" not in said and "rose" not in said
    assert "rose" in change_text("the rms", 4.34, 7.30, u_um=0.3)


def test_a_diagnosis_whose_error_rose_says_it_rose(squareness_diagnosis, tmp_path):
    """The steps' figures swapped: the 'final' model's error is the larger. Neither the console's verdict nor
    the HTML report's says it fell."""
    d = squareness_diagnosis
    first, last = d.steps[0], d.steps[-1]
    worse = replace(d, steps=[replace(first, figures=last.figures), *d.steps[1:-1], replace(last, figures=first.figures)])
    found = dict(verdict(worse))["found"]
    assert "rms accuracy error rose from" in found and "error fell" not in found, found
    from cmmpose.diagnosis.html_report import _verdict

    text = _verdict(worse, None, None)
    assert "rms accuracy error rose from" in text and "rms accuracy error fell" not in text, text


def test_no_advice_to_take_a_calibrated_length_the_run_has(tmp_path):
    res = CliRunner().invoke(main, ["simulate", "--calibrated", "--effect", "scale:x=10", "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    run = cmmpose.Run.load(tmp_path / "r")
    assert run.artefact.get("calibrated_length_mm") is not None
    d = cmmpose.diagnose(run)
    assert d.run_has["calibrated bar length"]
    doc = d.to_json()
    for text in (doc, str(d), as_text(d, verbose=False, width=100)):
        assert "needs: a calibrated bar length" not in text
        flat = _flat(text)
        assert not re.search(r"(scale|artefact-expansion): a calibrated bar length", flat), flat
    reasons = [x["reason"] for x in d.decisions() if x["name"] in ("scale", "artefact-expansion")]
    assert reasons and all("needs: a calibrated bar length" not in r for r in reasons)


def test_held_needs_are_rewritten_and_others_kept():
    reveal = "a calibrated bar length at 20 C, or runs at two temperatures"
    text = f"a typical x would stand only 0.1 sigma above the noise here; needs: {reveal}"
    said = without_held_needs(text, reveal, {"calibrated bar length": True})
    assert "needs:" not in said and "already has this (calibrated bar length)" in said
    assert without_held_needs(text, reveal, {"calibrated bar length": False}) == text
    assert without_held_needs(text, reveal, None) == text


TRUTH = [E.ArtefactExpansion(ppm_per_kelvin=11.5), E.SquarenessOffset(yz=12.0)]


@functools.lru_cache(maxsize=None)
def _joint_runs():
    return tuple(simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), t, TRUTH, jitter=0.0015, seed=s,
                                      scanner=Scanner(points_per_profile=256))[0] for t, s in ((21.0, 1), (27.0, 2)))


def test_a_joint_diagnosis_gives_every_runs_figures_at_every_step():
    from cmmpose.diagnosis.joint import diagnose_jointly

    d = diagnose_jointly(list(_joint_runs()), max_effects=3)
    assert len(d.steps) > 1
    for s, per_run in zip(d.steps, d.run_figures):
        assert s.run_figures is not None and len(s.run_figures) == 2
        assert [f.rms_accuracy_error for f in s.run_figures] == [f.rms_accuracy_error for f in per_run]
    doc = json.loads(d.to_json())
    for step in doc["steps"]:
        assert [r["run"] for r in step["runs"]] == ["run 1", "run 2"]
    second = [step["runs"][1]["rms_accuracy_error_um"] for step in doc["steps"]]
    assert second == pytest.approx([f[1].rms_accuracy_error * 1e3 for f in d.run_figures])
    assert second != [step["rms_accuracy_error_um"] for step in doc["steps"]]  # not the first run's again
    text = _flat(as_text(d, verbose=False, width=100))
    found = dict(verdict(d))["found"]
    for i, per_run in enumerate(zip(d.run_figures[0], d.run_figures[-1])):
        a, b = (f"{f.rms_accuracy_error * 1e3:.2f}" for f in per_run)
        assert f"run {i + 1}:" in found and a in found and b in found, found
        assert a in text and b in text
    assert len(as_text(d, verbose=False, width=100).rstrip("\n").splitlines()) <= 40
