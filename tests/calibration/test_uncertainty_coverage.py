"""The command-line calibration's stated uncertainties against its errors, on a
machine that is not the thesis's, with the map and three vernier points (the
thesis's procedure): about 95 % within 2 standard uncertainties. And the CLI
gives the Python chain's numbers, field for field."""

import json

import numpy as np
from calibration_study import GROUPS, TEMPERATURE, VERNIER_NOISE, cli_trial, coverage
from click.testing import CliRunner

from cmmpose.calibration import (AlignmentLibrary, AlignmentRecord, alpha_beta_from_vernier, calibrated_pose,
                                 gamma_from_plane_scan, mount_offset, reference_centre_reading)
from cmmpose.cli import main
from cmmpose.machine import Machine

TRIALS = 60  # 1260 standardised errors: the fraction within 2 has a binomial sd of about 0.6 %


def test_cli_uncertainties_cover_the_errors(tmp_path):
    trials = [cli_trial(seed, tmp_path / str(seed)) for seed in range(TRIALS)]
    cov = coverage(trials)
    # 95.4 % for a normal z; 0.92-0.98 is about 5 binomial sd either side.
    assert 0.92 <= cov["all"] <= 0.98, cov
    for g in GROUPS:
        z = np.array([t[g] for t in trials]).reshape(TRIALS, -1)
        sd = z.std(axis=0)
        assert np.all((0.75 < sd) & (sd < 1.3)), (g, sd)  # each component's scatter is its stated one
        assert np.abs(z).max() < 5, g
        assert 0.88 <= cov[g] <= 0.995, (g, cov)


def test_cli_record_and_offset_are_the_python_chains(tmp_path):
    """One meaning per field: the CLI stores what AlignmentRecord.from_calibration
    stores from the Python solvers, and `calibrate offset` gives mount_offset's fit."""
    cli_trial(7, tmp_path)
    machine = Machine.example("moving-bridge")
    maps = machine.maps()
    em = {"maps": maps, "temperature": TEMPERATURE}
    lib = AlignmentLibrary(tmp_path / "alignments.json")
    readings = []
    for k in range(3):
        plane = np.loadtxt(tmp_path / f"plane{k}.csv", delimiter=",", skiprows=1)
        sphere = np.loadtxt(tmp_path / f"sphere{k}.csv", delimiter=",", skiprows=1)
        stored = lib.load(f"P{k}")
        vern = alpha_beta_from_vernier(np.loadtxt(tmp_path / f"vernier{k}.csv", delimiter=",", skiprows=1),
                                       point_uncertainty=VERNIER_NOISE, **em)
        normal = json.loads((tmp_path / "trial.json").read_text())["plane_normals"][k]
        gam = gamma_from_plane_scan(plane[:, :2], plane[:, 2:5], vern.alpha, vern.beta, normal=normal,
                                    offset=tuple(machine.offset), alpha_beta_covariance=vern.covariance, **em)
        cp = calibrated_pose(vern, gam)
        ref = reference_centre_reading(sphere[:, :2], sphere[:, 2:5], cp.pose, tuple(machine.offset),
                                       pose_covariance=cp.covariance, **em)
        rec = AlignmentRecord.from_calibration(cp, ref, tuple(machine.offset))
        for f in ("pose", "reading", "pose_uncertainty", "reading_uncertainty", "position"):
            np.testing.assert_allclose(getattr(stored, f), getattr(rec, f), rtol=1e-9, atol=1e-12, err_msg=f)
        for f in ("pose_covariance", "reading_covariance", "pose_jacobian", "lever"):
            np.testing.assert_allclose(np.array(getattr(stored, f)), np.array(getattr(rec, f)), rtol=1e-9,
                                       atol=1e-15, err_msg=f)
        # reading_uncertainty is the reading's own; the total adds the pose's
        np.testing.assert_allclose(stored.reading_uncertainty, np.sqrt(np.diag(ref.fit_covariance)), rtol=1e-9)
        assert np.all(stored.reference_reading().uncertainty > np.asarray(stored.reading_uncertainty))
        readings.append(ref)
    python_fit = mount_offset(readings)
    res = CliRunner().invoke(main, ["calibrate", "offset", "P0", "P1", "P2", "--library",
                                    str(tmp_path / "alignments.json"), "--json"], catch_exceptions=False)
    cli_fit = json.loads(res.output)
    np.testing.assert_allclose(cli_fit["offset"], python_fit.offset, rtol=0, atol=1e-9)
    np.testing.assert_allclose(cli_fit["covariance"], python_fit.covariance, rtol=1e-7, atol=1e-15)
    assert abs(cli_fit["chi2"] - python_fit.chi2) < 1e-6 * max(1.0, python_fit.chi2)
