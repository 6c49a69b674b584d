"""The diagnosis a user can read (issue 33, section 8): a verdict first, in
at most 40 lines at 100 columns, with the final model's values; the
candidate tables behind --verbose; tables that fold rather than cut
(section 7, honest words: tests/diagnosis/test_wording.py).

Console text is read at an explicit width (COLUMNS or Console(width=...)),
never at the terminal's."""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.diagnosis.console import as_text


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


def test_evaluate_prints_a_summary_within_40_lines_and_the_budgets_behind_verbose(squareness_run):
    res = CliRunner().invoke(main, ["evaluate", str(squareness_run)], env={"COLUMNS": "100"})
    assert res.exit_code == 0, res.output
    lines = res.stdout.rstrip("\n").splitlines()
    assert len(lines) <= 40 and max(len(line) for line in lines) <= 100, res.stdout
    flat = _flat(res.stdout)
    assert re.search(r"rms accuracy error \(um\) [0-9.]+ ± [0-9.]+ [0-9.]+ ± [0-9.]+", flat), flat
    assert "improvement: rms" in flat and "Uncertainty budget" not in flat
    assert re.search(r"the rms accuracy error (fell|rose) from [0-9.]+ um to [0-9.]+ um|unchanged", flat), flat
    res = CliRunner().invoke(main, ["evaluate", str(squareness_run), "--verbose"], env={"COLUMNS": "100"})
    assert res.exit_code == 0, res.output
    flat = _flat(res.stdout)
    assert "Uncertainty budget: mean length" in flat and "left out:" in flat and "Ballbar evaluation" in flat


def test_a_joint_verdict_with_two_open_sets_stays_within_40_lines(tmp_path):
    """Two plates at one height with a periodic X error and a twisted table (benches/unseen_placements.py,
    ``periodic+twist``): two ambiguity sets stay open and nothing is added. The first set is given in full,
    the second in a sentence; with nothing added the history table (one row) is left out; 38 lines."""
    import warnings

    from repo_scripts import bench as load_bench

    bench = load_bench("unseen_placements")
    folders = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, placement in enumerate(bench.TRAIN):
            folders.append(str(tmp_path / f"r{i}"))
            bench.plate_run("periodic+twist", placement, 100 + i, 48).save(folders[-1])
    res = CliRunner().invoke(main, ["diagnose", *folders, "--joint", "--maps", "thesis"], env={"COLUMNS": "100"})
    assert res.exit_code == 0, res.output
    lines = res.stdout.rstrip("\n").splitlines()
    assert len(lines) <= 40 and max(len(line) for line in lines) <= 100, res.stdout
    flat = _flat(res.stdout)
    assert flat.count("the data cannot choose between") == 2 and "either" in flat
    assert "fell" not in flat.split("ambiguous:")[0]
