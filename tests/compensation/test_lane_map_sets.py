"""Issue 27: random (unsorted) readings with a map set and a temperature per
point take the lane-wise block path (every lane's temperature interval, then
table by table). Its points must be the per-row path's bit for bit: the
per-row path is what ``out_of_range='clamp'`` runs (clamping counts per row),
which changes nothing for inputs inside the maps. Against the independent
NumPy reference (tests/support/numpy_reference.py) the tolerance is the one
tests/compensation/test_kernel_vs_reference.py derives for the kernel's arithmetic."""

from __future__ import annotations

import numpy as np
import pytest

import cmmpose
from numpy_reference import compensate as reference

POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)
MAPS = cmmpose.ErrorMapSet.thesis()
LO, HI = min(MAPS.temperatures), max(MAPS.temperatures)


def random_readings(n: int, seed: int):
    rng = np.random.default_rng(seed)
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    return uv, scales, rng


def reference_maps():
    return [{"temperature": m.temperature, "squareness": m.squareness, **{c: m.table(c) for c in "XYZ"}}
            for m in MAPS.maps]


@pytest.mark.parametrize("spread", ["across intervals", "one interval", "on map temperatures"])
def test_random_readings_with_a_temperature_per_point_match_the_per_row_path(spread):
    n = 20_000
    uv, scales, rng = random_readings(n, 1)
    lo, hi = LO, HI
    temps = {"across intervals": rng.uniform(lo, hi, n),
             "one interval": rng.uniform(21.0, 23.5, n),
             "on map temperatures": rng.choice(MAPS.temperatures, n)}[spread]
    lanes, report = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, return_report=True)
    rows = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, out_of_range="clamp")
    np.testing.assert_array_equal(lanes, rows)
    assert report.points == n and report.clamped_points == 0 and report.held_temperature == 0


def test_lane_path_against_the_numpy_reference():
    n = 5_000
    uv, scales, rng = random_readings(n, 2)
    temps = rng.uniform(LO, HI, n)
    got = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps)
    want = reference(uv, scales, reference_maps(), POSE, OFFSET, temps)
    # test_kernel_vs_reference.py's TOL_MM: coordinates up to ~1e3 mm, whose ulp
    # is 1.1e-13 mm, summed over a few dozen differently ordered operations.
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_temperatures_held_at_the_edge_go_row_by_row_and_are_counted():
    """A block holding one temperature within the tolerance outside the maps
    is given back to the per-row path: the same points, the hold counted."""
    n = 10_000
    uv, scales, rng = random_readings(n, 3)
    lo, hi = LO, HI
    temps = rng.uniform(lo, hi, n)
    temps[[17, 5000, 9999]] = [hi + 0.2, lo - 0.1, hi + 0.3]
    got, report = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, return_report=True,
                                     temperature_tolerance=0.5)
    assert report.held_temperature == 3
    clamped = np.clip(temps, lo, hi)
    np.testing.assert_array_equal(got, cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, clamped))


def test_a_reading_outside_a_table_names_its_row():
    uv, scales, rng = random_readings(9_000, 4)
    temps = rng.uniform(LO, HI, 9_000)
    scales[8123, 1] = 600.0
    with pytest.raises(cmmpose.OutOfRangeError, match="8123"):
        cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps)
