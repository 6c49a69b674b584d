"""The bundled thesis maps (Tables 7-16) as ErrorMapSet.thesis(), and blending
between their temperatures."""

from pathlib import Path

import numpy as np
import pytest

import cmmpose
from cmmpose import ErrorMap, ErrorMapSet


@pytest.fixture(scope="module")
def thesis():
    return ErrorMapSet.thesis()


def by_temperature(s, t):
    (m,) = [m for m in s.maps if m.temperature == t]
    return m


# -- where the data comes from -------------------------------------------------------


@pytest.mark.parametrize("parts", [("maps", "thesis_20C.csv"), ("maps", "thesis_25C.csv"),
                                   ("maps", "thesis_30C.csv"), ("errors_1102.txt",)])
def test_data_files_are_installed_with_the_package(parts):
    path = Path(str(cmmpose.data_path(*parts)))
    assert path.is_file()
    assert path.resolve().is_relative_to(Path(cmmpose.__file__).resolve().parent)


def test_thesis_set_is_read_from_the_installed_files(thesis):
    for t in (20, 25, 30):
        assert by_temperature(thesis, t) == ErrorMap.read(cmmpose.data_path("maps", f"thesis_{t}C.csv"))


# -- contents against the thesis text ------------------------------------------------


def test_temperatures(thesis):
    assert thesis.temperatures == [20.0, 25.0, 30.0]
    assert len(thesis) == 3
    assert [m.temperature for m in thesis.maps] == [20.0, 25.0, 30.0]


@pytest.mark.parametrize(
    ("temperature", "squareness"),
    [(20, (-173.0, -19.0, 21.0)), (25, (-178.0, -4.0, 42.0)), (30, (-172.0, -20.0, 1.0))],
)
def test_squareness_is_table_7(thesis, temperature, squareness):
    assert by_temperature(thesis, temperature).squareness == squareness


@pytest.mark.parametrize("t", [20, 25, 30])
def test_grids_are_25_mm_over_the_volume(thesis, t):
    m = by_temperature(thesis, t)
    np.testing.assert_array_equal(m.table("X")[:, 0], np.arange(0, 901, 25))
    np.testing.assert_array_equal(m.table("Y")[:, 0], np.arange(0, 551, 25))
    np.testing.assert_array_equal(m.table("Z")[:, 0], np.arange(-500, 1, 25))


# (temperature, carriage, position): (dx, dy, dz um, ex, ey, ez a-s), copied from
# Tables 8-16 (first and last rows of every table, plus rows in between).
THESIS_ROWS = {
    (20, "X", 0): (0, 0, 0, 0, 0, 0),
    (20, "X", 725): (64.7, 2, 0, 0, 10.03, -1.53),
    (20, "X", 900): (79.4, 0, 0, 0, 12.57, -2.4),
    (20, "Y", 0): (0, 0, 0, 0, 0, 0),
    (20, "Y", 100): (0, 10.7, 0, -1.1, 0, 0.675),
    (20, "Y", 175): (-7, 18.3, 0, -2.4, 0, 0.45),
    (20, "Y", 550): (0, 51.8, 0, -5.85, 0, 2.1),
    (20, "Z", -500): (0, 0, -11.3, -2.3, -3.05, 0),
    (20, "Z", -175): (1, -1, -5.5, -0.27, -2.97, 0),
    (20, "Z", 0): (0, 0, 0, 0, 0, 0),
    (25, "X", 0): (0, 0, 0, 0, 0, 0),
    (25, "X", 500): (48.0, 2.0, 0, 0, 19.2, 1.8),
    (25, "X", 900): (76.6, 0, 0, 0, 34.7, 2.9),
    (25, "Y", 0): (0, 0, 0, 0, 0, 0),
    (25, "Y", 525): (6.0, 73.5, 0, -3.8, 0, -0.1),
    (25, "Y", 550): (0, 76.7, 0, -4.1, 0, 0.1),
    (25, "Z", -500): (0, 0, -26.8, -2.3, -3.1, 0),
    (25, "Z", -50): (0, 0, 3.3, -0.1, -1.0, 0),
    (25, "Z", 0): (0, 0, 0, 0, 0, 0),
    (30, "X", 0): (0, 0, 0, 0, 0, 0),
    (30, "X", 625): (104.0, -1.0, 1.0, 0, 10.3, -2.2),
    (30, "X", 900): (140.9, 0, 0, 0, 15.8, -2.0),
    (30, "Y", 0): (0, 0, 0, 0, 0, 0),
    (30, "Y", 200): (-7.0, 39.9, 1.0, -2.7, 0, -0.5),
    (30, "Y", 550): (0, 106.3, 0, -5.1, 0, -0.5),
    (30, "Z", -500): (0, 0, -46.2, 2.0, -0.8, 0),
    (30, "Z", -125): (0, -1.0, -0.9, 0.6, -1.0, 0),
    (30, "Z", 0): (0, 0, 0, 0, 0, 0),
}


@pytest.mark.parametrize(("temperature", "carriage", "position"), list(THESIS_ROWS))
def test_table_values_match_the_thesis(thesis, temperature, carriage, position):
    table = by_temperature(thesis, temperature).table(carriage)
    (row,) = np.flatnonzero(table[:, 0] == position)
    np.testing.assert_array_equal(table[row, 1:], THESIS_ROWS[temperature, carriage, position])


# -- blending in temperature ---------------------------------------------------------


def test_midway_map_is_the_mean_of_its_neighbours(thesis):
    m20, m25 = by_temperature(thesis, 20), by_temperature(thesis, 25)
    mid = thesis.at(22.5)
    assert mid.temperature == 22.5
    for c in cmmpose.CARRIAGES:
        np.testing.assert_allclose(mid.table(c), 0.5 * (m20.table(c) + m25.table(c)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(mid.squareness, 0.5 * (np.array(m20.squareness) + m25.squareness), rtol=0, atol=1e-12)
    assert mid.squareness[2] == pytest.approx(31.5)  # (21 + 42) / 2, not a trivially equal value


@pytest.mark.parametrize("t", [20, 25, 30])
def test_map_at_a_map_temperature_is_that_map(thesis, t):
    m = by_temperature(thesis, t)
    at = thesis.at(t)
    for c in cmmpose.CARRIAGES:
        np.testing.assert_allclose(at.table(c), m.table(c), rtol=0, atol=1e-12)
    np.testing.assert_allclose(at.squareness, m.squareness, rtol=0, atol=1e-12)


@pytest.mark.parametrize("t", [19, 30.8])  # beyond the 0.5 K held at the edge (cmmpose.policy)
def test_temperature_outside_the_set_raises(thesis, t):
    with pytest.raises(cmmpose.OutOfRangeError) as exc:
        thesis.at(t)
    msg = str(exc.value)
    assert "[20, 30]" in msg and f"{t:g}" in msg


@pytest.mark.parametrize(("t", "end"), [(19, 20), (31, 30)])
def test_clamped_temperature_gives_the_end_map(thesis, t, end):
    m = by_temperature(thesis, end)
    clamped = thesis.at(t, out_of_range="clamp")
    for c in cmmpose.CARRIAGES:
        np.testing.assert_array_equal(clamped.table(c), m.table(c))
    assert clamped.squareness == m.squareness
