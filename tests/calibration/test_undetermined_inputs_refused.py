"""Checks that turn silent wrong answers into refusals: a LinuxCNC compensation
file read with the other COMP_FILE_TYPE, a mount offset from poses that do not
determine it, an inward plane normal in the alignment, and a stored alignment
replaced without --replace."""

from __future__ import annotations

import dataclasses
import json

import cmmpose
import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose.calibration import STANDARD_POSES, gamma_from_plane_scan
from cmmpose.calibration.alignment import ReferenceReading, mount_offset
from cmmpose.calibration.alignment.offset import MAX_OFFSET_AMPLIFICATION
from cmmpose.cli import main
from cmmpose.formats.linuxcnc import read_comp_file, read_comp_files, write_comp_files
from cmmpose.sim import Plane, plane_scan

OFFSET = np.array(cmmpose.MountOffset.thesis())


# ---------------------------------------------------------------------------
# 1. LinuxCNC COMP_FILE_TYPE mismatch
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("written, read", [(1, 0), (0, 1)])
def test_linuxcnc_file_of_the_other_type_is_refused_naming_the_fix(tmp_path, written, read):
    m = cmmpose.ErrorMapSet.thesis().at(20.0)
    files = {a: tmp_path / f"{a.lower()}.comp" for a in "XYZ"}
    write_comp_files(m, files, comp_file_type=written)
    # Read as the other type, every deviation is minus the nominal (-25 mm at 25 mm): refused, file and row named.
    with pytest.raises(cmmpose.MapError, match=rf"x\.comp:2: .* at nominal 25 .* -25\.00\d* mm .*"
                                               rf"comp_file_type={written} \(--comp-file-type {written}\)"):
        read_comp_files(files, comp_file_type=read)
    back = read_comp_files(files, comp_file_type=written)  # the right type still reads, to the written digits
    pos, dev = back.table("X")[:, 0], back.table("X")[:, 1]
    assert np.allclose(dev, m.position_error(np.column_stack([pos, 0 * pos, 0 * pos]))[:, 0] * 1e3, atol=1e-3)


def test_linuxcnc_deviation_limit_lets_real_errors_through(tmp_path):
    # 1.9 mm on a 100 mm axis (below the 2 mm floor) and 9 mm on a 1000 mm axis (below 1 %) are read as given;
    # 2.1 mm on the 100 mm axis is not, and when neither type gives small values the message says so.
    p = tmp_path / "x.comp"
    p.write_text("0 0 0\n100 101.9 101.9\n")
    assert read_comp_file(p, "X").up_um[1] == pytest.approx(1900.0)
    p.write_text("0 0 0\n1000 1009 1009\n")
    assert read_comp_file(p, "X").up_um[1] == pytest.approx(9000.0)
    p.write_text("0 0 0\n100 102.1 102.1\n")
    with pytest.raises(cmmpose.MapError, match=r"x\.comp:2: .*too large as well .* check the file's units and columns"):
        read_comp_file(p, "X")


def test_linuxcnc_cli_import_of_the_other_type_fails_naming_the_flag(tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["map", "export", "thesis@20", "--format", "linuxcnc", "--comp-file-type", "1",
                               "-o", str(tmp_path / "lc")])
    assert res.exit_code == 0, res.output
    out = tmp_path / "m.csv"
    res = runner.invoke(main, ["map", "import", "linuxcnc", f"X={tmp_path / 'lc' / 'x.comp'}", "-o", str(out)])
    assert res.exit_code != 0 and "--comp-file-type 1" in res.output and "x.comp:2" in res.output, res.output
    assert "Traceback" not in res.output and not out.exists()


# ---------------------------------------------------------------------------
# 2. mount offset from poses that do not determine it
# ---------------------------------------------------------------------------


def _rot(axis, angle_rad):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * kx + (1 - np.cos(angle_rad)) * kx @ kx


def _readings(poses, tilts):
    """Readings as a compensated alignment gives them: lever R E313 with the map's small rotation R (tilt, rad)."""
    c = np.array([450.0, 380.0, -420.0])
    out = []
    for pose, tilt in zip(poses, tilts):
        lever = _rot((1.0, 2.0, 3.0), tilt) @ cmmpose.Pose(*pose).matrix()
        r = ReferenceReading.from_reading(pose, c + lever @ OFFSET, 0.01)
        out.append(dataclasses.replace(r, position=c + lever @ OFFSET, lever=lever))
    return out


def test_two_poses_never_determine_the_offset_even_with_a_maps_rotation():
    # Two poses W along X (gamma 0 and 90): W1 trades off against the centre along X. The map's rotation
    # (5e-5 rad, ~10 a-s) breaks the exact rank deficiency that the old check needed; the fit then claimed W1.
    with pytest.raises(cmmpose.GeometryError, match=r"do not determine the mount offset: W1 is not determined.*"
                                                    r"machine axis, \[1\.0, 0\.0, 0\.0\].*another machine axis"):
        mount_offset(_readings(STANDARD_POSES[:2], (0.0, 5e-5)))
    # W along X and W along Y, both at gamma 0: turned about Z, V1 (along v = Z at both) is free.
    with pytest.raises(cmmpose.GeometryError, match=r"V1 is not determined.*\[0\.0, 0\.0, 1\.0\]"):
        mount_offset(_readings([STANDARD_POSES[0], STANDARD_POSES[2]], (0.0, 5e-5)))
    with pytest.raises(cmmpose.GeometryError, match="not determined"):
        mount_offset(_readings([STANDARD_POSES[0]] * 3, (0.0, 5e-5, -5e-5)))


def test_offset_conditioning_accepts_well_and_moderately_conditioned_poses():
    fit = mount_offset(_readings(STANDARD_POSES, (0.0, 5e-5, -3e-5)))
    assert np.allclose(fit.offset, OFFSET, atol=1e-6) and fit.uncertainty.max() < 0.02
    # A third pose turned only 5 degrees about Z from the first: determined, with an honest, larger uncertainty
    # (amplification below the limit), not refused.
    poses = [STANDARD_POSES[0], STANDARD_POSES[1], (95.0, 90.0, 0.0)]
    fit = mount_offset(_readings(poses, (0.0, 5e-5, -3e-5)))
    assert np.allclose(fit.offset, OFFSET, atol=1e-6)
    assert 0.02 < fit.uncertainty.max() < MAX_OFFSET_AMPLIFICATION * 0.01


# ---------------------------------------------------------------------------
# 3. inward plane normal; replacing a stored alignment
# ---------------------------------------------------------------------------


def test_gamma_scan_along_the_face_cannot_tell_the_normal_sign_and_gamma0_can():
    maps = cmmpose.ErrorMapSet.thesis()
    pose = STANDARD_POSES[0]
    p = plane_scan(pose, maps=maps, temperature=20.0, seed=1)
    n = np.asarray(p.plane.normal)
    kw = {"offset": OFFSET, "maps": maps, "temperature": 20.0}
    right = gamma_from_plane_scan(p.uv, p.scales, 90.0, 90.0, normal=n, **kw)
    wrong = gamma_from_plane_scan(p.uv, p.scales, 90.0, 90.0, normal=-n, **kw)
    # The scan fits both branches: the sign of the normal alone picks one, and the result says so.
    assert abs(right.gamma) < 0.01 and abs(abs(wrong.gamma) - 180.0) < 0.01
    assert right.branch_from_normal and wrong.branch_from_normal
    assert right.opposite_rms == pytest.approx(right.rms, rel=0.01)
    with pytest.raises(cmmpose.CalibrationError, match=r"back of a face whose outward normal is \[0\.0, 0\.0, -1\.0\]"
                                                       r".*or is it \[0\.0, 0\.0, 1\.0\]"):
        gamma_from_plane_scan(p.uv, p.scales, 90.0, 90.0, normal=-n, gamma0=0.0, **kw)
    assert abs(gamma_from_plane_scan(p.uv, p.scales, 90.0, 90.0, normal=n, gamma0=0.0, **kw).gamma) < 0.01
    # A face tilted 17 deg: the sweep moves along its normal, and the scan itself tells the branches apart.
    tilted = np.array([0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    q = plane_scan(pose, plane=Plane(p.plane.centre, tilted, radius=300.0), maps=maps, temperature=20.0, seed=2)
    g = gamma_from_plane_scan(q.uv, q.scales, 90.0, 90.0, normal=tilted, **kw)
    assert not g.branch_from_normal and g.opposite_rms > 100 * g.rms
    with pytest.raises(cmmpose.CalibrationError, match="outward normal"):
        gamma_from_plane_scan(q.uv, q.scales, 90.0, 90.0, normal=-tilted, **kw)


@pytest.fixture(scope="module")
def aligned(tmp_path_factory):
    """The README's three simulated alignments, calibrated into a library."""
    folder = tmp_path_factory.mktemp("align")
    runner = CliRunner()
    commands = {}
    for name, pose, normal in (("A90B90", "90,90,0", "0,0,1"), ("A90B90G90", "90,90,90", "0,-1,0"),
                               ("A180B90", "180,90,0", "0,0,1")):
        res = runner.invoke(main, ["calibrate", "simulate-alignment", "--pose", pose, "--name", name, "-o",
                                   str(folder)], catch_exceptions=False)
        assert res.exit_code == 0, res.output
        commands[name] = ["calibrate", "alignment", "--vernier", str(folder / f"{name}-vernier.csv"),
                          "--vernier-uncertainty", "9", "--plane-scan", str(folder / f"{name}-plane.csv"),
                          "--reference-scan", str(folder / f"{name}-sphere.csv"), "--name", name,
                          "--maps", "thesis", "--temperature", "20", "--json"]
        normals = commands.setdefault("normals", {})
        normals[name] = normal
    lib = folder / "align.json"
    notes = {}
    for name in ("A90B90", "A90B90G90", "A180B90"):
        res = runner.invoke(main, [*commands[name], "--plane-normal", commands["normals"][name], "--library",
                                   str(lib)], catch_exceptions=False)
        assert res.exit_code == 0, res.output
        notes[name] = json.loads(res.output)["notes"]
    return folder, lib, commands, notes


def test_alignment_notes_an_unchecked_branch_and_checks_it_against_the_library(aligned):
    _, _, _, notes = aligned
    # The first two could not be checked (a note says how to check); the third was, against the first two.
    assert all("--nominal-pose" in n for k in ("A90B90", "A90B90G90") for n in notes[k]) and notes["A90B90"]
    assert notes["A180B90"] == []


def test_alignment_refuses_to_replace_silently_and_an_inward_normal(aligned, tmp_path):
    _, lib, commands, _ = aligned
    before = lib.read_bytes()
    runner = CliRunner()
    cmd = [*commands["A90B90"], "--library", str(lib)]
    res = runner.invoke(main, [*cmd, "--plane-normal", "0,0,1"])
    assert res.exit_code != 0 and "already aligned" in res.output and "--replace" in res.output, res.output
    # The inward normal, replacing: the library's other two alignments fit only the other branch.
    res = runner.invoke(main, [*cmd, "--plane-normal", "0,0,-1", "--replace"])
    assert res.exit_code != 0 and "Traceback" not in res.output, res.output
    assert "--plane-normal 0,0,1" in res.output and "back of the face" in res.output, res.output
    assert lib.read_bytes() == before
    # With the nominal pose the inward normal is refused on its own, in a new library.
    new = tmp_path / "new.json"
    res = runner.invoke(main, [*commands["A90B90"], "--library", str(new), "--plane-normal", "0,0,-1",
                               "--nominal-pose", "90,90,0"])
    assert res.exit_code != 0 and "--plane-normal" in res.output and "back of a face" in res.output, res.output
    assert not new.exists()
    # The right normal with --replace is stored, checked against the others (no note).
    res = runner.invoke(main, [*cmd, "--plane-normal", "0,0,1", "--replace"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["notes"] == []
    assert cmmpose.calibration.AlignmentLibrary(lib).names() == ["A180B90", "A90B90", "A90B90G90"]


def test_nominal_pose_checks_the_vernier_w_and_the_solved_gamma(aligned, tmp_path):
    _, _, commands, _ = aligned
    new = tmp_path / "n.json"
    base = [*commands["A90B90"], "--library", str(new), "--plane-normal", "0,0,1"]
    for nominal, message in (("180,90,0", "from the w of --nominal-pose 180,90,0"),
                             ("90,90,90", "90.0 deg from the gamma of --nominal-pose 90,90,90")):
        res = CliRunner().invoke(main, [*base, "--nominal-pose", nominal])
        assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output, res.output
        assert not new.exists()
    res = CliRunner().invoke(main, [*base, "--nominal-pose", "90,90,0"], catch_exceptions=False)
    assert res.exit_code == 0 and json.loads(res.output)["notes"] == [], res.output  # checked: no note
