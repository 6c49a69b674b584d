"""Issue 23, silent wrong answers in files and options: each case below was
once read without a word (a repeated map key won, a cut map or PLY loaded
short, a machine file without its mount took the thesis's, a library in
radians read as degrees, an empty --pose took the default, a dropped
thermocouple and a held log were not in the provenance). Each is now an
error naming the file, key or option, or a stated note."""

from __future__ import annotations

import dataclasses
import json
import logging
import re

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import ErrorMap
from cmmpose.calibration.library import AlignmentLibrary, AlignmentRecord
from cmmpose.cli import main
from cmmpose.errors import CalibrationError, InputError, MapError
from cmmpose.machine import Machine, example_names, example_text, load_machine
from cmmpose.formats.mapfiles import body_sha256
from cmmpose.formats.pointclouds import PointCloud, read_point_cloud, write_point_cloud

BUNDLED = cmmpose.data_path("maps", "thesis_20C.csv")
SCAN = cmmpose.data_path("examples", "sphere_scan.csv")


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def map_lines():
    return BUNDLED.read_text(encoding="utf-8").splitlines()


def write(tmp_path, lines, name="m.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# -- map CSV: repeated keys, self-checking files ---------------------------------------------------


def test_a_repeated_map_header_key_is_refused_naming_the_key_and_both_lines(tmp_path):
    lines = map_lines()
    i = next(k for k, line in enumerate(lines) if line.startswith("# squareness_xy_arcsec"))
    lines.insert(i + 1, "# squareness_xy_arcsec: -1000")
    path = write(tmp_path, lines)
    with pytest.raises(MapError) as info:
        ErrorMap.read(path)
    msg = str(info.value)
    assert f"{path}:{i + 2}:" in msg and "'squareness_xy_arcsec' is repeated" in msg and f"line {i + 1}" in msg
    r = cli("compensate", SCAN, tmp_path / "out.csv", "--maps", path, "--temperature", 20)
    assert r.exit_code == 1 and "m.csv" in r.output and "repeated" in r.output
    assert not (tmp_path / "out.csv").exists()


def test_a_map_cut_at_a_row_boundary_is_refused(tmp_path):
    lines = map_lines()
    last_x = max(k for k, line in enumerate(lines) if line.startswith("X,"))
    del lines[last_x - 3:last_x + 1]  # the X table's last 4 rows: a shorter map that would interpolate fine
    path = write(tmp_path, lines)
    with pytest.raises(MapError, match=r"X has 33 \(declared 37\)") as info:
        ErrorMap.read(path)
    assert str(path) in str(info.value) and "# rows: X=37 Y=23 Z=21" in str(info.value)


def test_a_map_cut_at_its_end_is_refused(tmp_path):
    lines = map_lines()[:-1]  # the last Z row gone
    path = write(tmp_path, lines)
    with pytest.raises(MapError, match=r"Z has 20 \(declared 21\)"):
        ErrorMap.read(path)


def test_a_changed_number_fails_the_checksum(tmp_path):
    lines = map_lines()
    i = next(k for k, line in enumerate(lines) if line.startswith("X,100,"))
    lines[i] = lines[i].replace(",8.9,", ",8.8,")
    path = write(tmp_path, lines)
    with pytest.raises(MapError, match="does not match its '# sha256:' line") as info:
        ErrorMap.read(path)
    assert str(path) in str(info.value)


def test_a_map_without_check_lines_loads_with_a_note(tmp_path, caplog):
    lines = [line for line in map_lines() if not line.startswith(("# rows:", "# sha256:"))]
    path = write(tmp_path, lines)
    with caplog.at_level(logging.INFO, logger="cmmpose"):
        m = ErrorMap.read(path)
    assert m == ErrorMap.read(BUNDLED)
    notes = [r.getMessage() for r in caplog.records if str(path) in r.getMessage()]
    assert notes and "'# rows:' or '# sha256:'" in notes[0] and "cannot be detected" in notes[0]


def test_written_and_bundled_maps_carry_their_check_lines(tmp_path, caplog):
    for t in (20, 25, 30):
        text = cmmpose.data_path("maps", f"thesis_{t}C.csv").read_text(encoding="utf-8")
        assert "# rows: X=37 Y=23 Z=21\n" in text
        body = [line for line in text.splitlines() if line and not line.startswith("#")]
        assert f"# sha256: {body_sha256(body)}\n" in text
    m = ErrorMap.read(cmmpose.data_path("maps", "thesis_25C.csv"))
    out = tmp_path / "w.csv"
    with caplog.at_level(logging.INFO, logger="cmmpose"):
        m.write(out)
        assert ErrorMap.read(out) == m
        ErrorMap.read(BUNDLED)
    assert not [r for r in caplog.records if "sha256" in r.getMessage()]
    assert re.search(r"^# sha256: [0-9a-f]{64}$", out.read_text(), re.M)


# -- PLY: a body that disagrees with its header -----------------------------------------------------


@pytest.mark.parametrize("fmt", ["ply", "ply-ascii", "ply-big-endian"])
@pytest.mark.parametrize("declared", [100, 400])
def test_a_ply_body_that_disagrees_with_its_header_is_refused(tmp_path, fmt, declared):
    xyz = np.random.default_rng(0).normal(size=(300, 3))
    good = tmp_path / "good.ply"
    write_point_cloud(good, PointCloud(xyz), format=fmt)
    assert len(read_point_cloud(good).xyz) == 300
    raw = good.read_bytes()
    m = re.search(rb"element vertex (\d+) *", raw)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(raw[:m.start()] + f"element vertex {declared}".ljust(len(m.group(0))).encode() + raw[m.end():])
    words = "beyond the header's count" if declared < 300 else f"declares {declared} 'vertex' rows, the file holds 300"
    with pytest.raises(InputError, match=words) as info:
        read_point_cloud(bad)
    assert str(bad) in str(info.value)


# -- machine files ----------------------------------------------------------------------------------


def without_table(text: str, table: str) -> str:
    out, skip = [], False
    for line in text.splitlines():
        if line.strip().startswith("["):
            skip = line.strip().startswith(f"[{table}]")
        if not skip:
            out.append(line)
    return "\n".join(out) + "\n"


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda t: without_table(t, "mount"), r"\[mount\] is missing"),
        (lambda t: without_table(t, "maps"), r"\[maps\] is missing"),
        (lambda t: without_table(t, "thermocouples"), r"\[thermocouples\] is missing"),
        (lambda t: without_table(t, "travel"), r"\[travel\] is missing"),
        (lambda t: t.replace('kinematics = "moving-bridge"\n', ""), "kinematics is missing"),
        (lambda t: t.replace("pose_deg = [90.0, 90.0, 0.0]", "# no pose"), "mount.pose_deg is missing"),
        (lambda t: t.replace("artefact = 12.0", "artefact = -1e9"), r"expansion.artefact = -1e\+09 ppm/K is outside"),
        (lambda t: t.replace("artefact = 12.0", "artefact = 1200.0"), "expansion.artefact = 1200 ppm/K is outside"),
        (lambda t: t.replace("artefact = 12.0", 'artefact = "12.0"'), "expansion.artefact: expected a finite number"),
        (lambda t: t.replace("profile_rate_hz = 6.6", 'profile_rate_hz = "6.6"'), "scanner.profile_rate_hz"),
        (lambda t: t.replace("x = [0.0, 900.0]", "x = [0.0, 9e9]"), "travel.x: .* mm is beyond"),
        (lambda t: t.replace("offset_mm = [1.001, 264.505, 129.575]", 'offset_mm = ["1.001", 264.505, 129.575]'),
         "mount.offset_mm: expected three numbers"),
        (lambda t: t.replace("offset_mm = [1.001, 264.505, 129.575]", "offset_mm = [1.001, 264.505, 1e9]"),
         "mount.offset_mm: .* is beyond"),
        (lambda t: t.replace("pose_deg = [90.0, 90.0, 0.0]", "pose_deg = [90.0, 1e9, 0.0]"),
         "mount.pose_deg: pose angle beta = 1e\\+09 deg is beyond"),
        (lambda t: t.replace('GB = "granite_bottom"', 'GB = ["granite_bottom"]'), "thermocouples.GB"),
    ],
)
def test_a_machine_file_missing_a_required_key_or_out_of_range_is_refused(tmp_path, edit, words):
    path = tmp_path / "m.toml"
    path.write_text(edit(example_text("moving-bridge")), encoding="utf-8")
    with pytest.raises(InputError, match=words) as info:
        load_machine(path)
    assert str(path) in str(info.value)
    r = cli("machine", "check", path)
    assert r.exit_code == 1 and "ok:" not in r.output and "Traceback" not in r.output


def test_defaults_taken_are_stated_by_machine_show_and_check(tmp_path):
    text = example_text("moving-bridge").replace("noise_um = 8.0\n", "")
    text = re.sub(r"\[expansion\].*", "", text, flags=re.S)
    path = tmp_path / "m.toml"
    path.write_text(text, encoding="utf-8")
    machine = load_machine(path)
    assert machine.defaults == ("scanner.noise_um = 8.0", "expansion.artefact = 12.0 ppm/K (steel)")
    notes = machine.check()
    assert any("scanner.noise_um = 8.0 (the default" in n for n in notes)
    assert any("expansion.artefact = 12.0 ppm/K" in n for n in notes)
    for command in ("show", "check"):
        r = cli("machine", command, path)
        out = " ".join(r.output.split())
        assert r.exit_code == 0 and "defaults taken" in out and "scanner.noise_um = 8.0" in out, r.output
    r = cli("machine", "check", path)
    assert "note:" in r.output and "the default" in r.output


def test_the_bundled_machines_give_every_key():
    for name in example_names():
        m = Machine.example(name)
        assert m.defaults == () and m.check() == []
        assert dict(m.describe())["defaults taken"].startswith("none")


# -- the alignment library ----------------------------------------------------------------------------


def library(tmp_path):
    lib = AlignmentLibrary(tmp_path / "align.json")
    lib.save("A90B90", AlignmentRecord(pose=(90.0, 90.0, 0.0), reading=(449.0, 509.575, -155.495),
                                       offset=(1.001, 264.505, 129.575), reading_uncertainty=(0.001, 0.001, 0.001)))
    return lib


def edit_library(lib, change):
    doc = json.loads(lib.path.read_text())
    change(doc)
    lib.path.write_text(json.dumps(doc))


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: d["units"].update(pose="radian"), "units.pose is 'radian'"),
        (lambda d: d["units"].update(reading="m (D0, E0, F0)"), "units.reading is 'm"),
        (lambda d: d["units"].update(angle="degree"), "units: unknown field 'angle'"),
        (lambda d: d.update(unit={}), "unknown key"),
        (lambda d: d["poses"]["A90B90"].update(pose=["90", 90, 0]), "pose must be numbers, not text"),
        (lambda d: d["poses"]["A90B90"].update(pose_covariance=[["1", 0, 0], [0, 1, 0], [0, 0, 1]]),
         "pose_covariance must be numbers, not text"),
    ],
)
def test_an_alignment_library_in_other_units_or_with_text_numbers_is_refused(tmp_path, change, words):
    lib = library(tmp_path)
    assert lib.load("A90B90").pose == (90.0, 90.0, 0.0)
    edit_library(lib, change)
    with pytest.raises(CalibrationError, match=words) as info:
        lib.load("A90B90")
    assert str(lib.path) in str(info.value)


# -- --pose and --offset ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "option, value, words",
    [
        ("--pose", "", "an empty value"),
        ("--offset", "", "an empty value"),
        ("--pose", " ", "an empty value"),
        ("--pose", "1e9,90,0", "alpha = 1e\\+09 deg is beyond \\+-360 deg"),
        ("--pose", "90,-361,0", "beta = -361 deg"),
        ("--pose", "nan,90,0", "finite"),
        ("--offset", "inf,0,0", "finite"),
    ],
)
def test_an_empty_or_absurd_pose_or_offset_is_a_usage_error(tmp_path, option, value, words):
    out = tmp_path / "out.csv"
    r = cli("compensate", SCAN, out, "--temperature", 20, option, value)
    assert r.exit_code == 2, r.output
    assert option in r.output and re.search(words, " ".join(r.output.split())), r.output
    assert not out.exists()


def test_calibrate_alignment_and_simulate_refuse_absurd_poses(tmp_path):
    r = cli("calibrate", "simulate-alignment", "--pose", "90,1e9,0", "--name", "A", "-o", tmp_path / "align")
    assert r.exit_code == 2 and "--pose" in r.output and "beyond" in r.output
    r = cli("simulate", "--reference-pose", "0,1e9,0", "-o", tmp_path / "run")
    assert r.exit_code == 2 and "--reference-pose" in r.output and "beyond" in r.output
    assert not (tmp_path / "run").exists()


# -- a dropped thermocouple and a held log are in the provenance ------------------------------------


def test_a_dropped_thermocouple_and_a_held_log_are_in_the_provenance(simulated_run, tmp_path):
    log = {k: np.array(v, copy=True) for k, v in simulated_run.temperatures.items()}
    log["X1"][:] = 1e6  # a broken channel reading a constant 1e6 C
    end = float(np.max(simulated_run.points["t"])) - 5.0  # the log ends 5 s before the last point
    log = {k: v[log["t"] <= end] for k, v in log.items()}
    run = dataclasses.replace(simulated_run, temperatures=log)
    ev = cmmpose.evaluate(run, cmmpose.ErrorMapSet.thesis())
    prov = json.loads(json.dumps(ev.to_dict()))["provenance"]
    tlog = prov["temperature"]["log"]
    (x1,) = tlog["channels_dropped"]
    assert x1["channel"] == "X1" and x1["samples_dropped"] == x1["samples"] == len(log["t"])
    assert "entirely" in x1["action"] and "1e+06" in " ".join(x1["problems"])
    assert "X1" not in tlog["channels_used"] and "X2" in tlog["channels_used"]
    held = tlog["held"]
    want = int(np.sum(run.points["t"] > log["t"].max()))
    assert held["points"] == want > 0 and held["before_log_s"] == 0.0
    assert held["after_log_s"] == pytest.approx(float(np.max(run.points["t"]) - log["t"].max()), abs=1e-3)
    notes = " ".join(prov["notes"])
    assert "thermocouple X1" in notes and f"does not cover {want} points" in notes
    # the same from the command line: the run saved, evaluate --json and its printed notes
    run.save(tmp_path / "run")
    r = cli("evaluate", tmp_path / "run", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["provenance"]["temperature"]["log"]["channels_dropped"][0]["channel"] == "X1"
    r = cli("evaluate", tmp_path / "run")
    out = " ".join(r.output.split())
    assert r.exit_code == 0 and "thermocouple X1" in out and "does not cover" in out


def test_a_clean_log_has_nothing_dropped_or_held(simulated_run):
    ev = cmmpose.evaluate(simulated_run, cmmpose.ErrorMapSet.thesis())
    tlog = ev.provenance["temperature"]["log"]
    assert tlog["channels_dropped"] == [] and tlog["held"] is None
    assert len(tlog["channels_used"]) == 9


# -- compensate: an error late in a file names the file and its row ---------------------------------------------


@pytest.mark.parametrize("suffix", [".csv", ".npy"])
def test_compensate_file_names_the_file_and_its_row_not_the_chunks(tmp_path, suffix):
    n = 2500  # three chunks of 1000 rows
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(110, 170, n), rng.uniform(100, 800, n),
                         rng.uniform(50, 500, n), rng.uniform(-450, -50, n), np.full(n, 22.0)])
    maps = cmmpose.ErrorMapSet.thesis()
    for row, col, value, cls, words in ((1234, 2, 950.0, cmmpose.OutOfRangeError, "X scale reading 950 mm"),
                                        (2345, 5, np.nan, InputError, "column T: non-finite")):
        bad = a.copy()
        bad[row, col] = value
        src = tmp_path / f"in{suffix}"
        if suffix == ".csv":
            src.write_text("u,v,D,E,F,T\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in bad) + "\n")
        else:
            np.save(src, bad)
        with pytest.raises(cls) as info:
            cmmpose.compensate_file(src, tmp_path / "out.csv", maps, (90, 90, 0), (1, 2, 3), chunk=1000)
        assert f"{src}: " in str(info.value) and f"row {row}" in str(info.value) and words in str(info.value)
        assert info.value.row == row and info.value.file == str(src)
        assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("name", ["out.csv.gz", "out.xyz.bz2", "out.zip"])
def test_a_compressed_point_file_name_is_refused_not_written_as_plain_text(tmp_path, name):
    src = tmp_path / "p.csv"
    src.write_text("u,v,D,E,F\n0,0,450,275,-250\n")
    res = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / name), "--temperature", "22"])
    assert res.exit_code != 0 and "compressed point files" in res.output and name in res.output, res.output
    assert not (tmp_path / name).exists()
    (tmp_path / "in.csv.gz").write_bytes(b"\x1f\x8b\x08\x00")
    with pytest.raises(InputError, match=r"in\.csv\.gz: compressed point files"):
        read_point_cloud(tmp_path / "in.csv.gz")
