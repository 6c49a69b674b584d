"""A solved calibration reaches compensation: `calibrate offset --store` puts the mount offset, with its
covariance, in the alignments' records, where `compensate --alignment NAME` and the per-point uncertainty take it
from (issue 35, item 6)."""

import json

import numpy as np
from click.testing import CliRunner

import cmmpose
from cmmpose.calibration import AlignmentLibrary, AlignmentRecord
from cmmpose.cli import main
from cmmpose.point_uncertainty import PoseUncertainty

NOMINAL = (1.001, 264.505, 129.575)
TRUE = (1.0105, 264.4885, 129.6077)
POSES = {"A90B90": (90.0, 90.0, 0.0), "A90B90G90": (90.0, 90.0, 90.0), "A180B90": (180.0, 90.0, 0.0)}


def library(tmp_path):
    """Three alignments of one sphere centre C: the reading with the laser origin at C is S = C + E313 l1."""
    lib = AlignmentLibrary(tmp_path / "align.json")
    centre = np.array([400.0, 250.0, -300.0])
    for name, pose in POSES.items():
        e = cmmpose.Pose(*pose).matrix()
        reading = centre + e @ np.array(TRUE)
        lib.save(name, AlignmentRecord(pose=pose, reading=tuple(reading), offset=NOMINAL,
                                       reading_uncertainty=(0.005, 0.005, 0.005), pose_uncertainty=(0.002,) * 3))
    return lib


def test_calibrate_offset_store_puts_the_solved_offset_where_compensation_takes_it(tmp_path):
    lib = library(tmp_path)
    r = CliRunner().invoke(main, ["calibrate", "offset", *POSES, "--library", str(lib.path), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["stored_in"] is None and lib.load("A90B90").offset == NOMINAL  # not asked: kept
    r = CliRunner().invoke(main, ["calibrate", "offset", *POSES, "--library", str(lib.path), "--store", "--json"])
    assert r.exit_code == 0, r.output
    fit = json.loads(r.output)
    np.testing.assert_allclose(fit["offset"], TRUE, atol=1e-9)
    for name in POSES:
        rec = lib.load(name)
        assert rec.offset == tuple(fit["offset"]) and rec.as_offset() == cmmpose.MountOffset(*fit["offset"])
        np.testing.assert_allclose(rec.offset_covariance, fit["covariance"])
        assert "offset solved from A90B90, A90B90G90, A180B90" in rec.note
        pu = PoseUncertainty.from_record(rec)
        np.testing.assert_allclose(pu.offset_covariance_mm2, fit["covariance"])
    # Solving again from the stored records gives the same fit (the readings were kept).
    again = CliRunner().invoke(main, ["calibrate", "offset", *POSES, "--library", str(lib.path), "--json"])
    assert json.loads(again.output)["offset"] == fit["offset"]
    # compensate --alignment NAME takes the solved offset.
    scan = tmp_path / "scan.csv"
    scan.write_text("u,v,D,E,F\n0,140,400,250,-300\n5,150,401,251,-301\n")
    out = tmp_path / "xyz.csv"
    r = CliRunner().invoke(main, ["compensate", str(scan), str(out), "--maps", "appendix-b", "--alignment",
                                  "A90B90", "--library", str(lib.path)])
    assert r.exit_code == 0, r.output
    got = np.loadtxt(out, delimiter=",", skiprows=1, usecols=(0, 1, 2), ndmin=2)
    want = cmmpose.compensate([[0, 140], [5, 150]], [[400, 250, -300], [401, 251, -301]],
                              cmmpose.ErrorMap.appendix_b(), POSES["A90B90"], fit["offset"])
    np.testing.assert_allclose(got, want, rtol=0, atol=5e-7 + 1e-12)  # CSV holds 1e-6 mm: half of it rounds
    assert np.abs(got - cmmpose.compensate([[0, 140], [5, 150]], [[400, 250, -300], [401, 251, -301]],
                                           cmmpose.ErrorMap.appendix_b(), POSES["A90B90"], NOMINAL)).max() > 0.01


def test_store_offset_refuses_an_unknown_pose_and_changes_nothing(tmp_path):
    lib = library(tmp_path)
    before = lib.path.read_bytes()
    r = CliRunner().invoke(main, ["calibrate", "offset", *POSES, "NOPE", "--library", str(lib.path), "--store"])
    assert r.exit_code != 0 and "NOPE" in r.output
    assert lib.path.read_bytes() == before
