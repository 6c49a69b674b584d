"""Map exchange (docs/formats.md): ISO 230-2 style CSV (cmmpose.formats.iso230) and
LinuxCNC compensation files (cmmpose.formats.linuxcnc) to and from the canonical map.

Tolerances of the round trips (map -> format -> map, linear components):
- ISO 230-2 CSV: deviations are written with 3 decimals of um, so each comes
  back within half the last digit, 0.0005 um (plus float rounding, 1e-9);
  positions are written in the shortest form that reads back the same, so
  they come back exactly.
- LinuxCNC, mm, 6 decimals: the nominal position is rounded to 1e-6 mm
  first and the forward position (type 0) or the trim (type 1) is printed
  to 1e-6 mm, so the deviation comes back within half that, 0.0005 um, and
  positions within 5e-7 mm (exact for the thesis grids, multiples of 25 mm).
- LinuxCNC, inch, 6 decimals: the same in inches, 0.5e-6 in = 0.0127 um for
  deviations and 1.27e-5 mm for positions.
"""

import logging

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import ErrorMap, ErrorMapSet
from cmmpose.formats import mapformats
from cmmpose.cli import main
from cmmpose.formats.iso230 import read_iso230, write_iso230
from cmmpose.formats.linuxcnc import read_comp_files, write_comp_files

FLOAT = 1e-9  # float rounding of the arithmetic, um


def linear(m, axis):
    k = "XYZ".index(axis)
    t = m.table(axis)
    return t[:, 0], t[:, 1 + k]


def odd_map():
    """A map with irregular grids and deviations with many digits."""
    rng = np.random.default_rng(7)
    tables = []
    for lo, hi, n in ((0.0, 900.0, 37), (-3.5, 550.25, 11), (-500.0, 0.0, 2)):
        pos = np.sort(rng.uniform(lo, hi, n - 2))
        pos = np.concatenate([[lo], pos, [hi]])
        t = rng.normal(0, 10, (n, 7))
        t[:, 0] = pos
        tables.append(t)
    return ErrorMap(*tables, (1.5, -2.0, 3.25), 21.5, source="odd")


MAPS = [lambda: ErrorMapSet.thesis().at(20), ErrorMap.appendix_b, odd_map]


# -- round trips ---------------------------------------------------------------------------------
@pytest.mark.parametrize("make", MAPS)
def test_iso230_round_trip_keeps_the_linear_components(tmp_path, make):
    m = make()
    path = tmp_path / "iso.csv"
    m.write(path, format="iso230-2")
    back = ErrorMap.read(path, format="iso230-2")
    for axis in "XYZ":
        pos, dev = linear(m, axis)
        pos2, dev2 = linear(back, axis)
        assert np.array_equal(pos, pos2)
        assert np.max(np.abs(dev2 - dev)) <= 0.0005 + FLOAT
        others = [c for c in range(1, 7) if c != 1 + "XYZ".index(axis)]
        assert not back.table(axis)[:, others].any()
    assert back.squareness == (0.0, 0.0, 0.0)
    assert back.temperature is None


@pytest.mark.parametrize("make", MAPS)
@pytest.mark.parametrize("comp_file_type", [0, 1])
@pytest.mark.parametrize("units, dev_tol, pos_tol", [("mm", 0.0005, 5e-7), ("inch", 0.0127, 1.27e-5)])
def test_linuxcnc_round_trip_keeps_the_linear_components(tmp_path, make, comp_file_type, units, dev_tol, pos_tol):
    m = make()
    files = {a: tmp_path / f"{a.lower()}.comp" for a in "XYZ"}
    write_comp_files(m, files, comp_file_type=comp_file_type, units=units)
    back = read_comp_files(files, comp_file_type=comp_file_type, units=units)
    for axis in "XYZ":
        pos, dev = linear(m, axis)
        pos2, dev2 = linear(back, axis)
        assert np.max(np.abs(pos2 - pos)) <= pos_tol + 1e-12
        assert np.max(np.abs(dev2 - dev)) <= dev_tol + FLOAT


def test_merge_into_the_base_replaces_only_the_linear_components(tmp_path):
    base = ErrorMap.appendix_b()
    other = ErrorMapSet.thesis().at(25)
    path = tmp_path / "iso.csv"
    write_iso230(other, path)
    merged = read_iso230(path, base=base)
    assert merged.squareness == base.squareness
    assert merged.temperature == base.temperature
    for k, axis in enumerate("XYZ"):
        b, t = base.table(axis), merged.table(axis)
        keep = [c for c in range(7) if c != 1 + k]
        assert np.array_equal(t[:, keep], b[:, keep])
        pos, dev = linear(other, axis)
        assert np.allclose(t[:, 1 + k], np.interp(b[:, 0], pos, dev), atol=0.0005 + FLOAT, rtol=0)


# -- analytic imports ----------------------------------------------------------------------------
def write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


def test_iso230_import_of_a_hand_written_file(tmp_path, caplog):
    path = write(tmp_path / "r.csv", (
        "# made by hand\n"
        '"target_mm",axis,mean_deviation_down_um,mean_deviation_up_um\n'
        "0,X,-1,1\n"
        "100,X,2,4\n"
        "200,x,5.5,6.5\n"
        "\n"
        "-400,Z,0,0\n"
        "0,Z,-2.5,-1.5\n"
    ))
    with caplog.at_level(logging.INFO, logger="cmmpose"):
        m = read_iso230(path, temperature=20.0, reversal_limit_um=1.5)
    assert np.array_equal(m.table("X")[:, 0], [0, 100, 200])
    assert np.array_equal(m.table("X")[:, 1], [0.0, 3.0, 6.0])  # (up + down) / 2
    assert np.array_equal(m.table("Z")[:, 0], [-400, 0])
    assert np.array_equal(m.table("Z")[:, 3], [0.0, -2.0])
    assert m.ranges[1] == ErrorMap.zero().ranges[1] and not m.table("Y").any(axis=0)[1:].any()
    assert m.temperature == 20.0
    # Reversal (up - down): 2 um at X 0 and 100 mm, above the 1.5 um limit -> a warning; Z 1 um -> info.
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "X max |reversal| 2 um at 0 mm" in warnings[0].getMessage()
    assert any("no Y results" in r.getMessage() and "zero over 0..550 mm" in r.getMessage() for r in caplog.records)
    assert "X max |reversal| 2 um" in m.source and "no results for Y" in m.source
    # The model: position error at a scale reading of 50 mm on X is delta_x = 1.5 um (linear interpolation).
    e = m.position_error([[50.0, 0.0, 0.0]])
    assert e[0, 0] == pytest.approx(1.5e-3, abs=1e-12)


def test_linuxcnc_import_of_hand_written_files(tmp_path):
    # Type 0: actual positions; deviation = actual - nominal, forward 10 um and reverse 6 um at 100 mm.
    x = write(tmp_path / "x.comp", "0.000000 0.000000 0.000000\n100.000000 100.010000 100.006000\n200 199.996 199.992\n\n")
    m = read_comp_files({"X": x})
    assert np.allclose(m.table("X")[:, 1], [0.0, 8.0, -6.0], atol=1e-9, rtol=0)
    # Type 1: trims = nominal - actual, so the deviation is minus the trim; inches to mm and um.
    y = write(tmp_path / "y.comp", "0 0 0\n10 -0.0001 -0.0003\n")
    m1 = read_comp_files({"y": y}, comp_file_type=1, units="inch", base=None, ranges=[(0, 1), (0, 254), (-1, 0)])
    assert np.allclose(m1.table("Y")[:, 0], [0.0, 254.0], atol=1e-12, rtol=0)
    assert np.allclose(m1.table("Y")[:, 2], [0.0, 0.0002 * 25.4e3], atol=1e-9, rtol=0)  # 5.08 um
    assert m1.ranges[0] == (0.0, 1.0)


def test_written_linuxcnc_files_follow_the_sign_convention(tmp_path):
    m = ErrorMap(np.array([[0, 0, 0, 0, 0, 0, 0], [100, 12.5, 0, 0, 0, 0, 0]], float),
                 np.array([[0] + [0] * 6, [10] + [0] * 6], float),
                 np.array([[-1] + [0] * 6, [0] + [0] * 6], float), (0, 0, 0))
    write_comp_files(m, {"X": tmp_path / "x0.comp"})
    write_comp_files(m, {"X": tmp_path / "x1.comp"}, comp_file_type=1)
    assert (tmp_path / "x0.comp").read_text().splitlines() == [
        "0.000000 0.000000 0.000000", "100.000000 100.012500 100.012500"]
    assert (tmp_path / "x1.comp").read_text().splitlines() == [
        "0.000000 0.000000 0.000000", "100.000000 -0.012500 -0.012500"]


def test_written_iso230_file(tmp_path):
    m = ErrorMap(np.array([[0, -0.0001, 0, 0, 0, 0, 0], [25.5, 1.23456, 0, 0, 0, 0, 0]], float),
                 np.array([[0] + [0] * 6, [10] + [0] * 6], float),
                 np.array([[-1] + [0] * 6, [0, 0, 0, 2, 0, 0, 0]], float), (0, 0, 0))
    path = tmp_path / "iso.csv"
    write_iso230(m, path)
    rows = [r for r in path.read_text().splitlines() if not r.startswith("#")]
    assert rows == ["axis,target_mm,mean_deviation_up_um,mean_deviation_down_um",
                    "X,0,0.000,0.000", "X,25.5,1.235,1.235", "Y,0,0.000,0.000", "Y,10,0.000,0.000",
                    "Z,-1,0.000,0.000", "Z,0,2.000,2.000"]
    assert mapformats.detect(path) == "iso230-2"


# -- bad input -----------------------------------------------------------------------------------
HEADER = "axis,target_mm,mean_deviation_up_um,mean_deviation_down_um\n"


@pytest.mark.parametrize("text, fragment", [
    ("", r"r\.csv: empty file"),
    ("# only a comment\n\n", r"r\.csv: empty file"),
    (HEADER, r"r\.csv: no data rows"),
    (HEADER + "X,0,1,1\nX,1O0,1,1\n", r"r\.csv:3: target_mm '1O0' is not a number"),
    (HEADER + "X,0,1,1\nX,100,1,nan\n", r"r\.csv:3: mean_deviation_down_um is not finite"),
    (HEADER + "X,0,1,1\nX,100,1,1e\n", r"r\.csv:3: mean_deviation_down_um '1e' is not a number"),
    (HEADER + "X,0,1,1\nX,100,1,1\nX,50,1,1\n", r"r\.csv:4: X target 50 mm is less than the previous X target 100 mm \(line 3\)"),
    (HEADER + "X,0,1,1\nY,0,1,1\nX,0,2,2\n", r"r\.csv:4: X target 0 mm duplicates line 2"),
    ("axis,target_mm,mean_deviation_up_um\nX,0,1\nX,1,1\n", r"r\.csv:1: missing column\(s\) mean_deviation_down_um \(each target needs"),
    ("axis,target_mm,mean_deviation_um,mean_deviation_down_um\n", r"r\.csv:1: unknown column 'mean_deviation_um'"),
    ("axis,target_mm,target_mm,mean_deviation_up_um,mean_deviation_down_um\n", r"r\.csv:1: column 'target_mm' appears twice"),
    (HEADER + "X,0,1,1\nX,100,1\n", r"r\.csv:3: expected 4 fields, got 3"),
    (HEADER + "W,0,1,1\n", r"r\.csv:2: axis 'W' is not X, Y or Z"),
    (HEADER + "X,0,1,1\n", r"r\.csv:2: the X axis has 1 target; at least 2"),
])
def test_iso230_bad_input_names_the_file_and_line(tmp_path, text, fragment):
    path = write(tmp_path / "r.csv", text)
    with pytest.raises(cmmpose.MapError, match=fragment):
        read_iso230(path)


def test_iso230_not_utf8_names_the_line(tmp_path):
    path = tmp_path / "r.csv"
    path.write_bytes(HEADER.encode() + b"X,0,1,1\nX,\xff100,1,1\n")
    with pytest.raises(cmmpose.MapError, match=r"r\.csv:3: not UTF-8"):
        read_iso230(path)


@pytest.mark.parametrize("text, fragment", [
    ("", r"x\.comp: empty compensation file"),
    ("\n\n", r"x\.comp: empty compensation file"),
    ("0 0 0\n100 100.01\n", r"x\.comp:2: expected 3 numbers \(nominal, forward position, reverse position\), got 2 fields"),
    ("0 0 0\n\n100 100 100\n", r"x\.comp:2: expected 3 numbers .* got a blank line; LinuxCNC stops"),
    ("# x axis\n0 0 0\n100 100 100\n", r"x\.comp:1: expected 3 numbers .* got a comment; LinuxCNC stops"),
    ("0 0 0\n100 100,01 100\n", r"x\.comp:2: forward position '100,01' is not a number"),
    ("0 0 0\n100 100 inf\n", r"x\.comp:2: reverse position is not finite"),
    ("0 0 0\n100 100 100\n50 50 50\n", r"x\.comp:3: nominal 50 is less than the previous nominal 100 \(line 2\)"),
    ("0 0 0\n0 0 0\n", r"x\.comp:2: nominal 0 duplicates the previous nominal 0"),
    ("0 0 0\n", r"x\.comp: 1 line; at least 2"),
    ("".join(f"{i} {i} {i}\n" for i in range(257)), r"x\.comp:257: more than 256 lines"),
])
def test_linuxcnc_bad_input_names_the_file_and_line(tmp_path, text, fragment):
    path = write(tmp_path / "x.comp", text)
    with pytest.raises(cmmpose.MapError, match=fragment):
        read_comp_files({"X": path})


def test_linuxcnc_bad_options(tmp_path):
    path = write(tmp_path / "x.comp", "0 0 0\n1 1 1\n")
    with pytest.raises(cmmpose.InputError, match="comp_file_type: expected 0 or 1"):
        read_comp_files({"X": path}, comp_file_type=2)
    with pytest.raises(cmmpose.InputError, match="units: expected one of 'mm', 'inch'"):
        read_comp_files({"X": path}, units="cm")
    with pytest.raises(cmmpose.InputError, match="axis 'A' is not 'X', 'Y' or 'Z'"):
        read_comp_files({"A": path})
    with pytest.raises(cmmpose.InputError, match="axis X given twice"):
        read_comp_files({"X": path, "x": path})
    with pytest.raises(cmmpose.InputError, match="at least one"):
        read_comp_files({})


def test_linuxcnc_refuses_to_write_more_entries_than_it_keeps(tmp_path):
    zero = ErrorMap.zero()
    x = np.column_stack([np.linspace(0, 900, 300), np.zeros((300, 6))])
    m = ErrorMap(x, zero.table("Y"), zero.table("Z"), (0, 0, 0))
    with pytest.raises(cmmpose.InputError, match="X grid has 300 positions; LinuxCNC keeps at most 256"):
        write_comp_files(m, {"X": tmp_path / "x.comp"})
    assert not (tmp_path / "x.comp").exists()


def test_positions_outside_the_base_are_refused(tmp_path):
    base = ErrorMap.appendix_b()  # X 0..900 mm
    path = write(tmp_path / "r.csv", HEADER + "X,0,1,1\nX,450,2,2\nX,950,3,3\n")
    with pytest.raises(cmmpose.MapError, match=r"r\.csv:4: X target 950 mm is outside the base map's X range 0\.\.900 mm"):
        read_iso230(path, base=base)
    x = write(tmp_path / "x.comp", "-10 -10 -10\n900 900 900\n")
    with pytest.raises(cmmpose.MapError, match=r"x\.comp:1: X target -10 mm is outside the base map's X range"):
        read_comp_files({"X": x}, base=base)


def test_a_base_grid_beyond_the_targets_needs_hold_ends(tmp_path, caplog):
    base = ErrorMap.appendix_b()  # X grid 0..900 mm in 25 mm steps
    path = write(tmp_path / "r.csv", HEADER + "X,100,1,3\nX,800,5,7\n")
    with pytest.raises(cmmpose.MapError, match=r"r\.csv: the X targets span 100\.\.800 mm but the base map's X grid "
                                               r"runs 0\.\.900 mm \(8 grid positions beyond the targets\)"):
        read_iso230(path, base=base)
    with caplog.at_level(logging.WARNING, logger="cmmpose"):
        m = read_iso230(path, base=base, hold_ends=True)
    assert any("end values are held" in r.getMessage() for r in caplog.records)
    pos, dev = linear(m, "X")
    assert np.allclose(dev, np.interp(pos, [100, 800], [2, 6]), atol=1e-12, rtol=0)
    assert dev[0] == 2 and dev[-1] == 6


# -- registry and CLI ----------------------------------------------------------------------------
def test_iso230_is_registered_and_sniffed(tmp_path):
    assert "iso230-2" in mapformats.names()
    fmt = mapformats.get("iso230-2")
    assert fmt.write is not None and fmt.description
    path = write(tmp_path / "r.txt", "\ufeff# note\naxis,target_mm,mean_deviation_up_um,mean_deviation_down_um\nX,0,1,1\nX,5,1,1\n")
    assert mapformats.detect(path) == "iso230-2"
    assert mapformats.detect(cmmpose.data_path("maps", "thesis_20C.csv")) == "csv"
    assert ErrorMap.read(path, format="auto").table("X")[1, 1] == 1.0


def test_cli_import_and_export(tmp_path):
    runner = CliRunner()
    out = runner.invoke(main, ["map", "export", "thesis@20", "--format", "linuxcnc", "-o", str(tmp_path / "lc")])
    assert out.exit_code == 0, out.output
    assert sorted(p.name for p in (tmp_path / "lc").iterdir()) == ["x.comp", "y.comp", "z.comp"]
    out = runner.invoke(main, ["map", "import", "linuxcnc", f"X={tmp_path / 'lc' / 'x.comp'}",
                               f"Z={tmp_path / 'lc' / 'z.comp'}", "-o", str(tmp_path / "m.csv"),
                               "--base", "appendix-b"])
    assert out.exit_code == 0, out.output
    merged, base, thesis = ErrorMap.read(tmp_path / "m.csv"), ErrorMap.appendix_b(), ErrorMapSet.thesis().at(20)
    assert np.allclose(linear(merged, "X")[1], linear(thesis, "X")[1], atol=0.0005, rtol=0)
    assert np.array_equal(merged.table("Y"), base.table("Y"))  # no Y file: the base's kept
    out = runner.invoke(main, ["map", "export", str(tmp_path / "m.csv"), "--format", "iso230-2",
                               "-o", str(tmp_path / "m.iso.csv")])
    assert out.exit_code == 0, out.output
    out = runner.invoke(main, ["map", "import", "iso230-2", str(tmp_path / "m.iso.csv"), "-o", str(tmp_path / "m2.csv"),
                               "--temperature", "21"])
    assert out.exit_code == 0, out.output
    m2 = ErrorMap.read(tmp_path / "m2.csv")
    assert m2.temperature == 21.0
    for axis in "XYZ":
        assert np.allclose(linear(m2, axis)[1], linear(merged, axis)[1], atol=0.0005, rtol=0)


@pytest.mark.parametrize("args, fragment", [
    (["import", "iso230-2", "missing.csv", "-o", "m.csv"], "missing.csv: cannot read"),
    (["import", "linuxcnc", "x.comp", "-o", "m.csv"], "expected AXIS=FILE"),
    (["import", "linuxcnc", "A=x.comp", "-o", "m.csv"], "expected AXIS=FILE"),
    (["export", "thesis@x", "--format", "csv", "-o", "m.csv"], "expected thesis@<temperature C>"),
])
def test_cli_errors_are_clear(tmp_path, monkeypatch, args, fragment):
    monkeypatch.chdir(tmp_path)
    out = CliRunner().invoke(main, ["map", *args])
    assert out.exit_code != 0
    assert fragment in out.output
