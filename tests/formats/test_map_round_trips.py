"""Error maps written and read back keep what they are, and bad arguments of the
map API raise cmmpose errors that name the argument (red-team round 3:
kinematics dropped on write, a multi-line source breaking an ISO 230-2 file,
a blended map unequal to itself read back, non-cmmpose exceptions)."""

import math

import cmmpose
import numpy as np
import pytest
from cmmpose.formats import mapfiles

UV = np.array([[0.0, 0.0], [3.0, -4.0]])
SCALES = np.array([[800.0, 500.0, -450.0], [120.0, 40.0, -20.0]])
POSE = (90.0, 90.0, 0.0)


def _compensate(m):
    return cmmpose.compensate(UV, SCALES, m, POSE, cmmpose.MountOffset.thesis())


# -- kinematics in the canonical map file ----------------------------------------------------------------------------
@pytest.mark.parametrize("kinematics", ["moving-bridge", "gantry", "fixed-bridge", "horizontal-arm"])
def test_kinematics_survives_the_canonical_file(tmp_path, kinematics):
    m = cmmpose.ErrorMap.appendix_b().with_kinematics(kinematics)
    m.write(tmp_path / "k.csv")
    assert f"# kinematics: {kinematics}\n" in (tmp_path / "k.csv").read_text()
    r = cmmpose.ErrorMap.read(tmp_path / "k.csv")
    assert r.kinematics == kinematics
    assert r == m
    # The stacking changes the result (so the test can fail), and the round trip keeps it to the bit.
    assert np.abs(_compensate(m) - _compensate(m.with_kinematics("thesis"))).max() > 1e-4
    np.testing.assert_array_equal(_compensate(r), _compensate(m))


def test_thesis_map_file_has_no_kinematics_line_and_old_files_read_as_thesis(tmp_path):
    m = cmmpose.ErrorMap.appendix_b()
    m.write(tmp_path / "t.csv")
    assert "kinematics" not in (tmp_path / "t.csv").read_text()
    assert cmmpose.ErrorMap.read(tmp_path / "t.csv").kinematics == "thesis"
    bundled = cmmpose.ErrorMapSet.thesis()
    assert bundled.kinematics == "thesis"


def test_bad_or_repeated_kinematics_line_is_refused_naming_the_line(tmp_path):
    m = cmmpose.ErrorMap.appendix_b().with_kinematics("gantry")
    m.write(tmp_path / "k.csv")
    lines = (tmp_path / "k.csv").read_text().splitlines()
    n = next(i for i, t in enumerate(lines) if t.startswith("# kinematics:"))
    bad = lines.copy()
    bad[n] = "# kinematics: flying-saucer"
    (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
    with pytest.raises(cmmpose.MapError, match=rf"bad.csv:{n + 1}: kinematics"):
        cmmpose.ErrorMap.read(tmp_path / "bad.csv")
    twice = lines[: n + 1] + ["# kinematics: thesis"] + lines[n + 1:]
    (tmp_path / "twice.csv").write_text("\n".join(twice) + "\n")
    with pytest.raises(cmmpose.MapError, match="'kinematics' is repeated"):
        cmmpose.ErrorMap.read(tmp_path / "twice.csv")


def test_iso230_import_onto_a_base_keeps_its_kinematics(tmp_path):
    m = cmmpose.ErrorMap.appendix_b().with_kinematics("gantry")
    m.write(tmp_path / "iso.csv", format="iso230-2")
    r = cmmpose.ErrorMap.read(tmp_path / "iso.csv", format="iso230-2", base=m)
    assert r.kinematics == "gantry"


# -- ISO 230-2: a multi-line source ----------------------------------------------------------------------------------
def test_iso230_multiline_source_is_one_comment_line_each(tmp_path):
    m = cmmpose.ErrorMap.appendix_b()
    m.source = "interferometer run 12\r\nlab B\n\n  bench 3"
    m.write(tmp_path / "iso.csv", format="iso230-2")
    text = (tmp_path / "iso.csv").read_text().splitlines()
    head = [t for t in text if t.startswith("#")]
    assert head[:3] == ["# ISO 230-2 style linear positioning results, from interferometer run 12",
                        "# lab B", "# bench 3"]
    assert all(t.startswith("#") for t in text[: text.index(",".join(cmmpose.formats.iso230.HEADER))])
    r = cmmpose.ErrorMap.read(tmp_path / "iso.csv", format="iso230-2", base=m)
    for k, c in enumerate("XYZ"):
        np.testing.assert_allclose(r.table(c)[:, 1 + k], m.table(c)[:, 1 + k], rtol=0, atol=0.0005 + 1e-12)
    assert cmmpose.ErrorMap.read(tmp_path / "iso.csv", format="auto").source.startswith("ISO 230-2")


# -- equality is what a map is ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("t", [20.0, 22.5, 23.7, 27.25, 30.0])
def test_blended_map_equals_itself_read_back(tmp_path, t):
    m = cmmpose.ErrorMapSet.thesis().at(t)
    m.write(tmp_path / "b.csv")
    r = cmmpose.ErrorMap.read(tmp_path / "b.csv")
    assert r == m and m == r
    # The compensation agrees to the rounding of a kernel-unit value (1e-16 mm-scale), far below 1 nm.
    np.testing.assert_allclose(_compensate(r), _compensate(m), rtol=0, atol=1e-9)


def test_equality_still_sees_every_difference():
    m = cmmpose.ErrorMapSet.thesis().at(22.5)
    tables = [m.table(c) for c in "XYZ"]
    same = cmmpose.ErrorMap(*tables, m.squareness, m.temperature)
    assert same == m
    nudged = [t.copy() for t in tables]
    nudged[1][3, 4] = np.nextafter(nudged[1][3, 4], np.inf)
    assert cmmpose.ErrorMap(*nudged, m.squareness, m.temperature) != m
    sq = list(m.squareness)
    sq[2] = np.nextafter(sq[2], np.inf)
    assert cmmpose.ErrorMap(*tables, sq, m.temperature) != m
    assert m.with_temperature(22.6) != m
    assert m.with_kinematics("gantry") != m
    assert cmmpose.ErrorMapSet.thesis() == cmmpose.ErrorMapSet.thesis()


# -- errors that are cmmpose errors and name the argument ------------------------------------------------------------
@pytest.mark.parametrize("bad", ["22", None, True, b"22", [22.0]])
def test_set_at_refuses_a_non_number_temperature(bad):
    with pytest.raises(cmmpose.InputTypeError, match="^temperature: "):
        cmmpose.ErrorMapSet.thesis().at(bad)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_set_at_refuses_a_non_finite_temperature_without_pointing_to_nan_policy(bad):
    with pytest.raises(cmmpose.InputError, match="^temperature: .* not finite") as info:
        cmmpose.ErrorMapSet.thesis().at(bad)
    assert "nan_policy" not in str(info.value)


def test_set_at_still_takes_numpy_and_integer_temperatures():
    S = cmmpose.ErrorMapSet.thesis()
    assert S.at(np.float32(22.5)) == S.at(22.5)
    assert S.at(np.int64(25)) == S.at(25) == S.at(25.0)


def test_read_with_an_option_of_another_format_names_the_option_and_format(tmp_path):
    m = cmmpose.ErrorMap.appendix_b()
    m.write(tmp_path / "m.csv")
    with pytest.raises(cmmpose.InputError, match=r"^base: not an option of the map file format 'csv'"):
        cmmpose.ErrorMap.read(tmp_path / "m.csv", format="auto", base=m)
    with pytest.raises(cmmpose.InputError, match=r"hold_ends: not an option of the map file format 'csv'"):
        cmmpose.ErrorMap.read(tmp_path / "m.csv", hold_ends=True)
    m.write(tmp_path / "iso.csv", format="iso230-2")
    with pytest.raises(cmmpose.InputError, match=r"decimals: .*'iso230-2'.*base, temperature"):
        cmmpose.ErrorMap.read(tmp_path / "iso.csv", format="auto", decimals=3)
    # The options a format takes still reach it.
    assert cmmpose.ErrorMap.read(tmp_path / "iso.csv", format="auto", temperature=21.0).temperature == 21.0


def test_mixed_kinematics_set_names_the_configurations():
    maps = cmmpose.ErrorMapSet.thesis().maps
    with pytest.raises(cmmpose.InputError) as info:
        cmmpose.ErrorMapSet([maps[0], maps[1].with_kinematics("gantry"), maps[2]])
    text = str(info.value)
    assert "'thesis'" in text and "'gantry'" in text and "25 C" in text
    assert "Kinematics {" not in text and "stack" not in text


@pytest.mark.parametrize("bad", ["22", True, False, np.bool_(True), b"22"])
@pytest.mark.parametrize("which", ["set", "model"])
def test_compensate_refuses_text_and_boolean_temperatures(bad, which):
    maps = cmmpose.ErrorMapSet.thesis()
    if which == "model":
        maps = cmmpose.Model(maps)
    with pytest.raises(cmmpose.InputTypeError, match="^temperature: "):
        cmmpose.compensate(UV, SCALES, maps, POSE, cmmpose.MountOffset.thesis(), temperature=bad)


def test_compensate_still_takes_numbers_and_leaves_nan_to_nan_policy():
    S = cmmpose.ErrorMapSet.thesis()
    off = cmmpose.MountOffset.thesis()
    a = cmmpose.compensate(UV, SCALES, S, POSE, off, temperature=np.int64(22))
    np.testing.assert_array_equal(a, cmmpose.compensate(UV, SCALES, S, POSE, off, temperature=22.0))
    with pytest.raises(cmmpose.InputError):
        cmmpose.compensate(UV, SCALES, S, POSE, off, temperature=math.nan)
    assert np.isnan(cmmpose.compensate(UV, SCALES, S, POSE, off, temperature=math.nan, nan_policy="propagate")).all()


def test_unnamed_kinematics_constant_is_the_reader_default():
    assert mapfiles.DEFAULT_KINEMATICS == "thesis"
