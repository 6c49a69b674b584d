"""`diagnose-fits` on an artefact's measured centres (issue 24): a table of
placement, ball, centre and radius plus the artefact file, as a ballbar's
sphere fits are diagnosed (cmmpose.diagnosis.plate_fits)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cmmpose import artefacts
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.cli import main
from cmmpose.diagnosis.plate_fits import diagnose_plate_fits, read_plate_fits
from cmmpose.errormap import ErrorMap
from cmmpose.errors import InputError
from cmmpose.sim import Scale, Squareness
from cmmpose.sim.artefact_runs import simulate_artefact_run

TRUTH = (6.0, -4.0, 3.0, 8.0, -6.0, 5.0)  # squareness xy, yz, zx (arc-seconds), scale x, y, z (ppm)


def _table(run, plate):
    ev = evaluate_artefact(run, None, 20.0)
    rows = ["placement,ball,x_mm,y_mm,z_mm,radius_mm"]
    for p in ev.uncompensated.placements:
        for b in p.balls:
            rows.append(f"{p.position},{b.ball},{b.measured[0]:.6f},{b.measured[1]:.6f},{b.measured[2]:.6f},"
                        f"{plate.calibrated_radius + b.radius_error:.6f}")
    return rows


@pytest.fixture(scope="module")
def rows(plate):
    run, _ = simulate_artefact_run(plate, ["planes"], ErrorMap.zero(temperature=20.0), 20.0,
                                   [Squareness(*TRUTH[:3]), Scale(*TRUTH[3:])], seed=1)
    return _table(run, plate)


def test_linear_errors_of_a_plate_in_three_planes(tmp_path, plate, rows):
    path = tmp_path / "centres.csv"
    path.write_text("\n".join(rows) + "\n")
    d = diagnose_plate_fits(plate, read_plate_fits(path))
    assert np.all(np.isfinite(d.uncertainties)) and np.all(d.uncertainties < 1.0)
    assert np.all(np.abs(d.values - TRUTH) < 3 * d.uncertainties), (d.values, d.uncertainties)
    assert d.residual_rms_um < 0.4 * d.rms_um


def test_what_one_placement_cannot_show_is_undetermined(tmp_path, plate, rows):
    path = tmp_path / "centres.csv"
    path.write_text("\n".join([rows[0], *[r for r in rows[1:] if r.startswith("1,")]]) + "\n")
    d = diagnose_plate_fits(plate, read_plate_fits(path))
    # In the XY plane: S_xy, s_x and s_y; nothing of Z.
    assert np.all(np.isfinite(d.uncertainties[[0, 3, 4]]))
    assert np.all(np.isinf(d.uncertainties[[1, 2, 5]]))
    assert abs(d.values[0] - TRUTH[0]) < 3 * d.uncertainties[0]
    doc = json.loads(json.dumps(d.to_dict(), allow_nan=False))
    assert doc["linear_errors"][1]["value"] is None and doc["linear_errors"][1]["u"] is None


def test_cli_from_an_evaluation_report(tmp_path):
    cli = CliRunner()
    run, rep = tmp_path / "run", tmp_path / "rep"
    r = cli.invoke(main, ["simulate", "--artefact", "koba-0420", "--placement", "planes", "--effect",
                          "squareness:xy=6", "-o", str(run)])
    assert r.exit_code == 0, r.output
    r = cli.invoke(main, ["evaluate", str(run), "--report", str(rep)])
    assert r.exit_code == 0, r.output
    r = cli.invoke(main, ["diagnose-fits", str(rep / "centres.csv"), "--artefact", "koba-0420", "--state",
                          "compensated", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    xy = doc["linear_errors"][0]
    assert abs(xy["value"] - 6.0) < 3 * xy["u"]
    r = cli.invoke(main, ["diagnose-fits", str(rep / "centres.csv"), "--artefact", "koba-0420", "--state",
                          "compensated"])
    assert r.exit_code == 0 and "squareness xy" in r.output


HEADER = "placement,ball,x_mm,y_mm,z_mm,radius_mm"


@pytest.mark.parametrize("edit, message", [
    (lambda rows: ["placement,ball,x_mm,x_mm,z_mm,radius_mm", *rows[1:]], r"column\(s\) x_mm repeated"),
    (lambda rows: ["placement,ball,x_mm,y_mm,radius_mm", *rows[1:]], "missing column"),
    (lambda rows: [*rows, rows[1]], r"placement 1, ball 1 is given twice \(also line 2\)"),
    (lambda rows: [rows[0], "1,1,abc,0,0,11", *rows[2:]], ":2: expected whole numbers"),
    (lambda rows: [rows[0], "1,1,1e400,0,0,11", *rows[2:]], ":2: centre and radius must be finite"),
    (lambda rows: [rows[0], "1,99,0,0,0,11", *rows[2:]], ":2: ball 99: .* has no ball 99"),
    (lambda rows: [rows[0]], "no rows after the header"),
    (lambda rows: [rows[0], rows[1], rows[2], *[r for r in rows[3:] if not r.startswith("1,")]],
     "placement 1 has 2 ball"),
])
def test_bad_tables_name_the_file_and_line(tmp_path, plate, rows, edit, message):
    path = tmp_path / "centres.csv"
    path.write_text("\n".join(edit(rows)) + "\n")
    with pytest.raises(InputError, match=message):
        diagnose_plate_fits(plate, read_plate_fits(path))
    r = CliRunner().invoke(main, ["diagnose-fits", str(path), "--artefact", "koba-0420"])
    assert r.exit_code == 1 and "Traceback" not in r.output and "centres.csv" in r.output, r.output


@pytest.mark.parametrize("args, message", [
    (["--artefact", "koba-0420", "--nominal-radius", "11"], "--nominal-radius is a ballbar's"),
    (["--temperature", "21"], "--temperature takes --artefact"),
])
def test_cli_usage_errors(tmp_path, rows, args, message):
    path = tmp_path / "centres.csv"
    path.write_text("\n".join(rows) + "\n")
    r = CliRunner().invoke(main, ["diagnose-fits", str(path), *args])
    assert r.exit_code == 2 and message in r.output, r.output


def test_balls_of_one_placement_scanned_with_two_poses(tmp_path):
    """On the moving-bridge example a KOBA 0620 at z = -150 needs two poses:
    their scale readings sit at different offsets from the centres, which the
    `pose` column of evaluate's centres.csv lets the fit take out."""
    cli = CliRunner()
    m, run, rep = tmp_path / "m.toml", tmp_path / "run", tmp_path / "rep"
    assert cli.invoke(main, ["machine", "example", "moving-bridge", "-o", str(m)]).exit_code == 0
    r = cli.invoke(main, ["simulate", "--machine", str(m), "--artefact", "koba-0620", "--placement", "xy@z=-150",
                          "--placement", "xy@z=-450", "--effect", "squareness:xy=8", "-o", str(run)])
    assert r.exit_code == 0, r.output
    assert len(set(_poses(run, 1))) == 2
    r = cli.invoke(main, ["evaluate", str(run), "--machine", str(m), "--report", str(rep)])
    assert r.exit_code == 0, r.output
    table = read_plate_fits(rep / "centres.csv", "compensated")
    plate = artefacts.load_artefact("koba-0620")
    d = diagnose_plate_fits(plate, table)
    assert abs(d.values[0] - 8.0) < 3 * d.uncertainties[0] and d.uncertainties[0] < 0.5
    assert d.residual_rms_um < 1.0
    one_pose = diagnose_plate_fits(plate, {**table, "pose": np.zeros(len(table["ball"]), int)})
    assert one_pose.residual_rms_um > 2 * d.residual_rms_um  # the offsets left in: what the column is for


def _poses(run_dir, position):
    from cmmpose.run import Run

    scans = Run.load(run_dir).scans
    return scans["pose_id"][scans["position"] == position].tolist()
