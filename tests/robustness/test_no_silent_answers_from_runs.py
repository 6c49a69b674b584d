"""Issue 23, silent wrong answers: incomplete or ambiguous ballbar positions,
the acceptance exit status, repeated columns and rows in diagnose-fits and
iso230-2 inputs, standard JSON only, the CSV point writer's large values, and
run tables cut short."""

from __future__ import annotations

import dataclasses
import json
import logging
import re
from importlib import resources

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose._json import dumps as strict_json
from cmmpose.cli import main
from cmmpose.formats.pointfiles import PointWriter
from cmmpose.sim import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner
from cmmpose.standards.acceptance import acceptance_test
from cmmpose.standards.interim import interim_check

MAPS = cmmpose.ErrorMapSet.thesis()


def _strict(text: str):
    """JSON as the standard has it: NaN and Infinity refused."""
    def no_constant(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=no_constant)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    run, truth = simulate_ballbar_run(MAPS, 20.0, jitter=0.003, calibrated=("length", "radius"),
                                      scanner=Scanner(points_per_profile=32), seed=5)
    path = tmp_path_factory.mktemp("silent") / "run"
    run.save(path, truth=truth)
    return run, path


def _relabelled(run, how: str):
    """``run`` with scan 5 (position 3, ball 2) relabelled as ``how`` says."""
    sc = {k: v.copy() for k, v in run.scans.items()}
    i = int(np.flatnonzero(sc["scan_id"] == 5)[0])
    assert (sc["position"][i], sc["ball"][i]) == (3, 2)
    if how == "ball 3":
        sc["ball"][i] = 3
    elif how == "position -1":
        sc["position"][i] = -1
    elif how == "duplicated":
        sc["ball"][i] = 1  # two scans of position 3 ball 1, none of ball 2
    elif how == "both balls gone":
        sc["position"][i] = -1
        sc["ball"][i] = -1
        j = int(np.flatnonzero(sc["scan_id"] == 4)[0])
        sc["position"][j] = 7  # position 7 now has three scans
    return dataclasses.replace(run, scans=sc)


@pytest.mark.parametrize("how, words", [("ball 3", "scan 5 has ball 3"),
                                        ("position -1", "scan 5 (position -1, ball 2) names no position"),
                                        ("duplicated", "position 3 ball 1: scans 4, 5"),
                                        ("both balls gone", "position 7 ball 1: scans")])
def test_a_mislabelled_scan_is_an_error_naming_it(sim, how, words):
    run, _ = sim
    bad = _relabelled(run, how)
    with pytest.raises(cmmpose.RunError, match="incomplete or ambiguous") as exc:
        cmmpose.evaluate(bad, MAPS, 20.0)
    assert words in str(exc.value) and "skip_incomplete=True" in str(exc.value)
    for check in (lambda: acceptance_test(bad, MAPS, 20.0, mpe_form=100, mpe_size=100, mpe_length="100"),
                  lambda: interim_check(bad, MAPS, 20.0)):
        with pytest.raises(cmmpose.RunError, match=re.escape(words)):
            check()


def test_skip_incomplete_lists_what_was_skipped(sim):
    run, _ = sim
    bad = _relabelled(run, "ball 3")
    ev = cmmpose.evaluate(bad, MAPS, 20.0, skip_incomplete=True)
    assert 3 not in ev.uncompensated.positions.tolist() and len(ev.uncompensated.positions) == 19
    assert ev.skipped == [{"position": 3, "scan_ids": [4, 5], "reason": ev.skipped[0]["reason"]}]
    assert "scan 5 has ball 3" in ev.skipped[0]["reason"]
    doc = _strict(ev.to_json())
    assert doc["provenance"]["skipped"][0]["position"] == 3
    assert any("skipped" in n and "position 3" in n for n in doc["provenance"]["notes"])
    # a complete run skips nothing
    assert cmmpose.evaluate(run, None, 20.0).skipped == []
    acc = acceptance_test(bad, MAPS, 20.0, mpe_form=100, mpe_size=100, mpe_length="100", skip_incomplete=True)
    assert acc.to_dict()["skipped"][0]["position"] == 3
    assert "position 3" not in " ".join(c.item for c in acc.checks if c.test == "length").split(", ")
    assert not any(c.item.startswith("position 3 ") or c.item == "position 3" for c in acc.checks)
    assert any("skipped" in n for n in acc.notes) and "skipped" in acc.to_markdown()
    ic = interim_check(bad, MAPS, 20.0, skip_incomplete=True)
    assert ic.positions == 19 and ic.to_dict()["skipped"][0]["scan_ids"] == [4, 5]
    assert "skipped" in ic.to_markdown()
    with pytest.raises(cmmpose.InputError, match="skip_incomplete"):
        cmmpose.evaluate(bad, MAPS, 20.0, skip_incomplete="yes")


def test_cli_refuses_an_incomplete_position_unless_told(sim, tmp_path):
    run, _ = sim
    path = tmp_path / "bad"
    _relabelled(run, "position -1").save(path)
    common = ["--maps", "thesis", "--temperature", "20"]
    acc = ["--mpe-form", "1000", "--mpe-size", "1000", "--mpe-length", "1000"]
    for cmd in (["evaluate", str(path), *common], ["standards", "acceptance", str(path), *common, *acc],
                ["standards", "interim-check", str(path), *common]):
        res = CliRunner().invoke(main, cmd)
        assert res.exit_code == 1, (cmd, res.output)
        assert "position 3 ball 2: no scan" in res.output and "--skip-incomplete" in res.output
        assert "skip_incomplete=" not in res.output and "Traceback" not in res.output
        ok = CliRunner().invoke(main, [*cmd, "--skip-incomplete", "--json"])
        assert ok.exit_code == 0, (cmd, ok.output)
        doc = _strict(ok.stdout)
        skipped = doc["provenance"]["skipped"] if cmd[0] == "evaluate" else doc["skipped"]
        assert [s["position"] for s in skipped] == [3, None]
    rep = CliRunner().invoke(main, ["evaluate", str(path), *common, "--skip-incomplete", "--report",
                                    str(tmp_path / "rep")])
    assert rep.exit_code == 0, rep.output
    assert _strict((tmp_path / "rep" / "evaluation.json").read_text())["provenance"]["skipped"][0]["position"] == 3
    table = CliRunner().invoke(main, ["evaluate", str(path), *common, "--skip-incomplete"])
    assert "skipped (incomplete or ambiguous)" in table.output


def test_acceptance_exit_status_follows_the_decision(sim):
    _, path = sim
    common = ["standards", "acceptance", str(path), "--maps", "thesis", "--temperature", "20"]
    fail = CliRunner().invoke(main, [*common, "--mpe-form", "0.01", "--mpe-size", "0.01", "--mpe-length", "0.01",
                                     "--json"])
    assert _strict(fail.stdout)["decision"] == "fail"
    assert fail.exit_code == 1, fail.output
    ok = CliRunner().invoke(main, [*common, "--mpe-form", "1000", "--mpe-size", "1000", "--mpe-length", "1000"])
    assert ok.exit_code == 0, ok.output
    assert "PASS" in ok.output
    assert "Exit status: 0 when the decision is pass; 1 when it is fail" in CliRunner().invoke(main, ["standards", "acceptance", "--help"]).output


# -- diagnose-fits and iso230-2 inputs ------------------------------------------------------------------
def _appendix_c_text_rows():
    text = resources.files("cmmpose").joinpath("data", "thesis", "appendix_c_ballbar.csv").read_text()
    return [ln for ln in text.splitlines() if ln and not ln.startswith("#")]


def _appendix_c_rows():
    lines = _appendix_c_text_rows()
    return lines[0], [ln for ln in lines[1:] if ln.startswith("compensated,")]


def test_diagnose_fits_refuses_repeated_rows_and_columns(tmp_path):
    header, rows = _appendix_c_rows()
    (tmp_path / "dup.csv").write_text("\n".join([header, *rows, rows[3]]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "dup.csv")])
    assert res.exit_code == 1, res.output
    assert "position 2 ball 2 (state 'compensated') is given twice (lines 5 and 42)" in res.output
    # repeated in a state not asked for: the file is still ambiguous
    unc = [ln for ln in _appendix_c_text_rows() if ln.startswith("uncompensated,")]
    (tmp_path / "dup2.csv").write_text("\n".join([header, *unc, unc[0], *rows]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "dup2.csv"), "--state", "compensated"])
    assert res.exit_code == 1 and "position 1 ball 1 (state 'uncompensated') is given twice (lines 2 and 42)" \
        in res.output, res.output
    (tmp_path / "col.csv").write_text("\n".join([header + ",x_mm", *(r + ",0" for r in rows)]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "col.csv")])
    assert res.exit_code == 1 and "x_mm repeated (columns x_mm at 7, 11)" in res.output, res.output
    # both states without --state: the same ball twice, and which states say so
    text = resources.files("cmmpose").joinpath("data", "thesis", "appendix_c_ballbar.csv").read_text()
    (tmp_path / "both.csv").write_text(text)
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "both.csv")])
    assert res.exit_code == 1 and "'uncompensated' and 'compensated'" in res.output, res.output
    assert CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "both.csv"), "--state", "compensated"]).exit_code == 0


def test_diagnose_fits_json_is_standard_json_at_1e300(tmp_path):
    header, rows = _appendix_c_rows()
    cols = header.split(",")
    first = rows[0].split(",")
    first[cols.index("radius_mm")] = "1e300"
    (tmp_path / "big.csv").write_text("\n".join([header, ",".join(first), *rows[1:]]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "big.csv"), "--json"])
    assert res.exit_code == 0, res.output
    doc = _strict(res.stdout)
    assert {"key": "radius_sd_um", "value": "inf"} in doc["non_finite"] and doc["radius_sd_um"] is None


def _positioning_rows():
    rows = ["target_mm,direction,cycle,deviation_um"]
    rows += [f"{t},{d},{c},{0.001 * t + 0.05 * c * d}" for t in (0, 100, 200) for d in (1, -1) for c in (1, 2, 3)]
    return rows


def test_iso230_2_refuses_a_repeated_column_and_names_repeated_rows(tmp_path):
    rows = _positioning_rows()
    (tmp_path / "col.csv").write_text("\n".join([rows[0] + ",deviation_um", *(r + ",9" for r in rows[1:])]) + "\n")
    res = CliRunner().invoke(main, ["standards", "iso230-2", str(tmp_path / "col.csv")])
    assert res.exit_code == 1 and "deviation_um repeated (columns deviation_um at 4, 5)" in res.output, res.output
    (tmp_path / "dup.csv").write_text("\n".join([*rows, rows[4]]) + "\n")
    res = CliRunner().invoke(main, ["standards", "iso230-2", str(tmp_path / "dup.csv")])
    assert res.exit_code == 1 and "given twice (lines 5 and 20)" in res.output, res.output


def test_iso230_2_json_is_standard_json_at_1e300(tmp_path):
    rows = _positioning_rows()
    rows[1] = rows[1].rsplit(",", 1)[0] + ",1e300"
    (tmp_path / "big.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(main, ["standards", "iso230-2", str(tmp_path / "big.csv"), "--json"])
    assert res.exit_code == 0, res.output
    doc = _strict(res.stdout)
    assert doc["R"] is None and {"key": "R", "value": "inf"} in doc["non_finite"]
    res = CliRunner().invoke(main, ["standards", "iso230-2", str(tmp_path / "big.csv"), "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert _strict((tmp_path / "rep" / "iso230-2.json").read_text())["non_finite"]


def test_strict_json_helper():
    assert _strict(strict_json({"a": float("nan"), "b": [np.float64(-np.inf)], "c": np.int64(3)})) == {
        "a": None, "b": [None], "c": 3, "non_finite": [{"key": "b[0]", "value": "-inf"}]}
    assert _strict(strict_json([{"x": np.inf}, {"x": 1.0}])) == [
        {"x": None, "non_finite": [{"key": "x", "value": "inf"}]}, {"x": 1.0}]
    with pytest.raises(ValueError, match="not finite"):
        strict_json(float("inf"))


# -- CSV point writer ---------------------------------------------------------------------------------------
def test_csv_writer_writes_large_values_exactly(tmp_path):
    xyz = np.array([[1.8e302, -1.7976931348623157e308, 123.4567894], [1e15 + 0.5, 9.5e9 + 1e-6, -0.0]])
    w = PointWriter(tmp_path / "p.csv")
    w.write(xyz)
    w.close()
    text = (tmp_path / "p.csv").read_text().splitlines()
    got = np.array([[float(v) for v in line.split(",")] for line in text[1:]])
    assert np.isfinite(got).all()
    assert got[0, 0] == 1.8e302 and got[0, 1] == -1.7976931348623157e308
    assert got[0, 2] == 123.456789  # rounded to 1 nm as before
    assert got[1, 0] == 1e15 + 0.5 and got[1, 2] == 0.0 and not np.signbit(got[1, 2])


# -- run tables cut short ---------------------------------------------------------------------------------
def test_a_points_table_cut_inside_its_last_scan_is_an_error(sim, tmp_path, caplog):
    run, _ = sim
    path = tmp_path / "run"
    run.save(path)
    rows = json.loads((path / "run.json").read_text())["rows"]
    assert rows == {"points": run.n_points, "scans": 40, "poses": 1, "temperatures": len(run.temperatures["t"])}
    assert cmmpose.Run.load(path).n_points == run.n_points
    table = pq.read_table(path / "points.parquet")
    pq.write_table(table.slice(0, table.num_rows - 7), path / "points.parquet")
    with pytest.raises(cmmpose.RunError, match=rf"points.parquet: {run.n_points - 7} rows, run.json says "
                                               rf"{run.n_points}: the table is cut short"):
        cmmpose.Run.load(path)
    res = CliRunner().invoke(main, ["evaluate", str(path), "--maps", "thesis"])
    assert res.exit_code == 1 and "cut short" in res.output
    # a table longer than saved
    pq.write_table(pq.read_table(path / "scans.parquet").slice(0, 39), path / "scans.parquet")
    pq.write_table(table, path / "points.parquet")
    with pytest.raises(cmmpose.RunError, match="scans.parquet: 39 rows, run.json says 40"):
        cmmpose.Run.load(path)
    # a run.json of an older cmmpose (no counts) still loads, with a note in the log
    run.save(path, overwrite=True)
    doc = json.loads((path / "run.json").read_text())
    del doc["rows"]
    (path / "run.json").write_text(json.dumps(doc))
    with caplog.at_level(logging.INFO, logger="cmmpose.run"):
        assert cmmpose.Run.load(path).n_points == run.n_points
    assert "no row counts" in caplog.text
    doc["rows"] = {"points": -1}
    (path / "run.json").write_text(json.dumps(doc))
    with pytest.raises(cmmpose.RunError, match="'rows' must be"):
        cmmpose.Run.load(path)
