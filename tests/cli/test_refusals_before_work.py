"""Command-line checks made before any work: bad options and outputs refused before a run is read or a file written.

The fleet report's folder names, an existing file given as --report, non-positive or NaN calibrated sizes,
plan's usage errors naming the flags, the printed alignment command's --nominal-pose, implausible ISO 230-2
deviations and a table-motion part point far outside the map's travel."""

from __future__ import annotations

import json
import math
import shlex

import click
import pandas as pd
import pytest
from click.testing import CliRunner

from cmmpose.cli import main
from cmmpose.errormap import ErrorMap
from cmmpose.errors import InputError, MapError


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _usage_error(res, flag: str) -> None:
    """A usage error (exit 2) naming ``flag``, no traceback."""
    assert res.exit_code == 2, res.output
    assert flag in res.output and "Traceback" not in res.output, res.output


# -- 1: evaluate RUN... --report with two runs of one folder name ----------------------------------------------------

def test_fleet_report_refuses_two_runs_sharing_a_folder_name_before_any_work(tmp_path):
    # The check comes before any run is read: empty run folders show it (a run would only be evaluated later).
    day1, day2 = tmp_path / "day1" / "run", tmp_path / "day2" / "run"
    day1.mkdir(parents=True)
    day2.mkdir(parents=True)
    report = tmp_path / "R"
    res = _invoke("evaluate", day1, day2, "--scheduler", "threads", "--report", report)
    assert res.exit_code == 1, res.output
    assert "share a folder name" in res.output and "Traceback" not in res.output, res.output
    flat = "".join(res.output.split())  # the message may wrap: both runs named
    assert "".join(str(day1).split()) in flat and "".join(str(day2).split()) in flat, res.output
    assert not report.exists()  # nothing written, not even the folder
    # Without --scheduler (several runs: the same fleet path) the same refusal.
    res = _invoke("evaluate", day1, day2, "--report", report)
    assert res.exit_code == 1 and "share a folder name" in res.output, res.output


def test_report_folder_names_are_the_run_folders_names_and_shared_by_both_paths():
    from cmmpose.cli.evaluate import report_folder_names

    assert report_folder_names(["a/run1", "b/run2/"], "R") == ["run1", "run2"]
    assert report_folder_names(["a/run", "b/run"], None) == ["run", "run"]  # no report: nothing overwritten
    with pytest.raises(InputError, match=r"a/run and b/run"):
        report_folder_names(["a/run", "b/run"], "R")


# -- 2: diagnose --report naming an existing file that is not a report ----------------------------------------------

def test_diagnose_report_refuses_an_existing_file(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    res = _invoke("diagnose", run, "--no-auto", "--report", notes)
    _usage_error(res, "--report")
    assert "notes.txt" in res.output and "not a folder" in res.output, res.output
    assert notes.read_text() == "my notes\n"


def test_report_folder_html_takes_a_folder_and_marks_an_existing_file_for_refusal(tmp_path):
    from cmmpose.cli.common import check_report_file, report_folder_html

    ctx = click.Context(main.get_command(None, "diagnose"), info_name="diagnose")
    folder = tmp_path / "existing"
    folder.mkdir()
    assert report_folder_html(ctx, None, str(folder)) == str(folder / "diagnose.html")
    assert report_folder_html(ctx, None, str(tmp_path / "new")) == str(tmp_path / "new" / "diagnose.html")
    # A name ending in .html is a folder like any other: made if missing, refused if it is an existing file.
    assert report_folder_html(ctx, None, str(tmp_path / "r.html")) == str(tmp_path / "r.html" / "diagnose.html")
    for name, text in (("old.html", "<html></html>"), ("data.csv", "x\n1\n")):
        other = tmp_path / name
        other.write_text(text)
        passed = report_folder_html(ctx, None, str(other))
        assert passed == str(other)  # refused by the command, after check_outputs
        with pytest.raises(click.BadParameter, match="not a folder"):
            check_report_file(passed)
    # A report already in its folder (a second run of the command) is replaced, not refused.
    (folder / "diagnose.html").write_text("<html></html>")
    check_report_file(report_folder_html(ctx, None, str(folder)))
    check_report_file(str(tmp_path / "new" / "diagnose.html"))
    check_report_file(None)


def test_diagnose_report_refuses_an_existing_html_file(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    page = tmp_path / "old.html"
    page.write_text("<html></html>")
    res = _invoke("diagnose", run, "--no-auto", "--report", page)
    _usage_error(res, "--report")
    assert "old.html" in res.output and "not a folder" in res.output, res.output
    assert page.read_text() == "<html></html>"


def test_diagnose_report_naming_an_input_still_says_so(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    model = tmp_path / "model.json"
    model.write_text("{}")
    res = _invoke("diagnose", run, "--model", model, "--report", model)
    assert res.exit_code == 1 and "same file as the input" in res.output, res.output
    assert model.read_text() == "{}"


def test_diagnose_joint_report_refuses_an_existing_file(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    for r in runs:
        r.mkdir()
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    res = _invoke("diagnose", *runs, "--joint", "--report", notes)
    _usage_error(res, "--report")
    assert notes.read_text() == "my notes\n"


# -- 3: calibrated sizes on the command line: finite and > 0 mm ------------------------------------------------------

@pytest.mark.parametrize("args, flag", [
    (["--calibrated-length", "nan"], "--calibrated-length"),
    (["--calibrated-length", "0"], "--calibrated-length"),
    (["--calibrated-length", "-404"], "--calibrated-length"),
    (["--calibrated-length", "inf"], "--calibrated-length"),
    (["--calibrated-radius", "0"], "--calibrated-radius"),
    (["--calibrated-radius", "-38"], "--calibrated-radius"),
    (["--calibrated-radius", "nan"], "--calibrated-radius"),
])
def test_acceptance_refuses_calibrated_sizes_that_are_not_positive_mm(tmp_path, args, flag):
    run = tmp_path / "run"
    run.mkdir()
    res = _invoke("standards", "acceptance", run, "--mpe-form", "60", "--mpe-size", "10", "--mpe-length", "8+L/300",
                  *args)
    _usage_error(res, flag)
    assert "positive number of mm" in res.output, res.output


def test_interim_check_and_acceptance_sphere_refuse_sizes_that_are_not_positive_mm(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    _usage_error(_invoke("standards", "interim-check", run, "--calibrated-length", "nan"), "--calibrated-length")
    scan = tmp_path / "scan.csv"
    scan.write_text("x,y,z\n1,0,0\n0,1,0\n0,0,1\n-1,0,0\n0,-1,0\n")
    _usage_error(_invoke("standards", "acceptance-sphere", scan, "--radius", "0", "--mpe-form", "5", "--mpe-size",
                         "5"), "--radius")


def test_positive_type_takes_finite_positive_numbers_only():
    from cmmpose.cli.common import POSITIVE_MM

    assert POSITIVE_MM.convert("404.5", None, None) == 404.5
    assert POSITIVE_MM.convert(1e-6, None, None) == 1e-6
    for bad in ("nan", "-inf", "inf", "0", "-0.0", "-1", "twelve", ""):
        with pytest.raises(click.BadParameter, match="positive number of mm"):
            POSITIVE_MM.convert(bad, None, None)


# -- 4: plan's usage errors name --sigma and --budget and exit 2 ------------------------------------------------------

def test_plan_option_errors_name_the_flags(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    for args, flag in ((["--sigma", "0"], "--sigma"), (["--sigma", "nan"], "--sigma"), (["--sigma", "-1"], "--sigma"),
                       (["--budget", "0"], "--budget"), (["--budget", "-2"], "--budget")):
        res = _invoke("plan", run, *args)
        _usage_error(res, flag)
        assert "sigma_um" not in res.output and "budget:" not in res.output, res.output


def test_plan_without_degrees_of_freedom_asks_for_the_sigma_flag(tmp_path):
    run = tmp_path / "run"
    res = _invoke("simulate", "--seed", "1", "-o", run)
    assert res.exit_code == 0, res.output
    # Two positions: too few to estimate the noise from (as the red team's reproducer trims a run).
    scans = pd.read_parquet(run / "scans.parquet")
    scans = scans[scans.position.isin([1, 2])]
    points = pd.read_parquet(run / "points.parquet")
    points = points[points.scan_id.isin(scans.scan_id)]
    scans.to_parquet(run / "scans.parquet", index=False)
    points.to_parquet(run / "points.parquet", index=False)
    meta = json.loads((run / "run.json").read_text())
    meta["rows"].update(scans=len(scans), points=len(points))
    meta["artefact"]["positions"] = 2
    (run / "run.json").write_text(json.dumps(meta))
    res = _invoke("plan", run)
    _usage_error(res, "--sigma")
    assert "degrees of freedom" in res.output and "sigma_um" not in res.output, res.output


# -- 6: simulate-alignment prints a calibrate command with --nominal-pose that runs ----------------------------------

@pytest.mark.parametrize("pose", ["90,90,0", "-90,90,30"])
def test_simulate_alignment_prints_a_runnable_command_with_the_nominal_pose(tmp_path, pose):
    out = tmp_path / "m"
    res = _invoke("calibrate", "simulate-alignment", "--pose", pose, "--name", "P", "--temperature", "21",
                  "-o", out, "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    command = doc["calibrate_with"]
    assert f"--nominal-pose {pose}" in command, command
    args = shlex.split(command.replace("LIBRARY", shlex.quote(str(tmp_path / "lib.json"))))
    assert args[:3] == ["cmmpose", "calibrate", "alignment"]
    res = _invoke(*args[1:], "--json")
    assert res.exit_code == 0, res.output
    rec = json.loads(res.stdout)
    # The nominal pose checks the plane normal's branch: no "unchecked" note; the pose is the simulated one.
    assert rec["notes"] == [], rec["notes"]
    nominal = [float(a) for a in pose.split(",")]
    for got, want, u in zip(rec["pose"], doc["truth"]["true_pose"], rec["pose_uncertainty"]):
        assert abs(got - want) < 4 * u + 1e-9, (rec["pose"], doc["truth"]["true_pose"])
    assert all(abs(g - n) < 1 for g, n in zip(rec["pose"], nominal))


def test_simulate_alignment_command_quotes_a_folder_with_a_space(tmp_path):
    out = tmp_path / "my runs"
    res = _invoke("calibrate", "simulate-alignment", "--pose", "90,90,0", "--name", "A", "-o", out, "--json")
    assert res.exit_code == 0, res.output
    args = shlex.split(json.loads(res.stdout)["calibrate_with"])
    assert str(out / "A-vernier.csv") in args


# -- 7: implausible ISO 230-2 deviations; a table-motion point far outside the travel ---------------------------------

def _iso230(path, rows):
    path.write_text("axis,target_mm,mean_deviation_up_um,mean_deviation_down_um\n"
                    + "".join(f"{r}\n" for r in rows))
    return path


def test_map_import_refuses_a_deviation_no_machine_has_naming_file_and_row(tmp_path):
    bad = _iso230(tmp_path / "bad.csv", ["X,0,0,0.4", "X,500,1e9,2.9", "X,1000,3,3"])
    out = tmp_path / "out.csv"
    res = _invoke("map", "import", "iso230-2", bad, "-o", out)
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    assert "bad.csv:3" in res.output and "mean_deviation_up_um" in res.output, res.output
    assert not out.exists()
    # The limit: 1 % of the targets' span (200 mm: 2 mm), capped at 5 mm (a 1000 mm span), at least 500 um (a
    # short axis keeps its backlash).
    from cmmpose.formats.iso230 import deviation_limit_um, read_results

    assert deviation_limit_um(1000.0) == 5000.0
    assert deviation_limit_um(200.0) == 2000.0
    assert deviation_limit_um(10.0) == 500.0
    with pytest.raises(MapError, match=r"bad2\.csv:4: Y mean_deviation_down_um -5001"):
        read_results(_iso230(tmp_path / "bad2.csv", ["X,0,0,0", "X,100,1,1", "Y,0,0,-5001", "Y,1000,0,0"]))
    # Real deviations (tens of um, a reversal of hundreds on a short axis) still read.
    ok = read_results(_iso230(tmp_path / "ok.csv", ["X,0,0,0.4", "X,20,450,-400", "X,1000,4999,4999"]))
    assert ok["X"].up_um.tolist() == [0, 450, 4999]
    res = _invoke("map", "import", "iso230-2", tmp_path / "ok.csv", "-o", out)
    assert res.exit_code == 0, res.output


def test_table_motion_refuses_a_point_far_outside_the_travel(tmp_path):
    out = tmp_path / "tm.csv"
    for flag, args in (("--part-point", ["--measured-at", "0,0,0", "--part-point", "1e9,0,0"]),
                       ("--measured-at", ["--measured-at", "0,-5000,0", "--part-point", "100,100,-100"])):
        res = _invoke("map", "table-motion", "thesis@20", "-o", out, "--carriage", "X", *args)
        _usage_error(res, flag)
        assert "travel" in res.output, res.output
        assert not out.exists()
    # A part on the table, and one overhanging it by less than the travel, convert.
    res = _invoke("map", "table-motion", "thesis@20", "-o", out, "--carriage", "X", "--measured-at", "0,0,0",
                  "--part-point", "1200,-300,-100")
    assert res.exit_code == 0, res.output


def test_table_motion_library_error_names_the_argument_and_flag():
    from cmmpose.formats.tablemotion import table_motion_to_map

    base = ErrorMap.appendix_b()
    with pytest.raises(InputError, match="part_point: X 1e\\+09 mm") as info:
        table_motion_to_map(base, "X", (0, 0, 0), (1e9, 0, 0))
    assert info.value.option == "part_point" and info.value.cli_option == "--part-point"
    lo, hi = info.value.allowed
    assert math.isfinite(lo) and math.isfinite(hi) and lo < 0 < hi
