"""A moving table's own measured motion turned into map components (issue 26;
docs/conventions.md, moving tables): checked against an exact rigid-body
motion of the table (rotation matrix, not the small-angle cross product),
analytic cases, and the command line."""

from __future__ import annotations

import json

import cmmpose
import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose.cli import main
from cmmpose.formats.tablemotion import table_motion_to_map
from scipy.spatial.transform import Rotation

ARCSEC = np.pi / 648000.0


def _table_map(rng, carriage="Y", n=12, angle=10.0, delta=5.0):
    base = cmmpose.ErrorMap.zero()
    tables = {c: base.table(c).copy() for c in cmmpose.CARRIAGES}
    lo, hi = base.ranges[cmmpose.CARRIAGES.index(carriage)]
    t = np.zeros((n, 7))
    t[:, 0] = np.linspace(lo, hi, n)
    t[:, 1:4] = rng.uniform(-delta, delta, (n, 3))
    t[:, 4:7] = rng.uniform(-angle, angle, (n, 3))
    tables[carriage] = t
    return cmmpose.ErrorMap(tables["X"], tables["Y"], tables["Z"], (1.0, -2.0, 3.0), 20.0, source="table")


def test_agrees_with_the_exact_rigid_motion_of_the_table():
    rng = np.random.default_rng(7)
    m = _table_map(rng)
    r_t, p = np.array([120.0, -40.0, 15.0]), np.array([-380.0, 260.0, 140.0])
    converted = table_motion_to_map(m, "Y", r_t, p)
    t = m.table("Y")
    # The table moves every point q of it to r_T + d_T + R (q - r_T); the probe relative to the part point p moves
    # by minus the part point's displacement, and turns by the inverse rotation.
    rot = Rotation.from_rotvec(t[:, 4:7] * ARCSEC)
    moved = t[:, 1:4] * 1e-3 + rot.apply(p - r_t) - (p - r_t)  # mm
    expected = -moved * 1e3  # um
    got = converted.table("Y")[:, 1:4]
    # Tolerance: the small-angle cross product misses the rotation's second order, |eps|^2 |p - r_T| / 2 (mm), plus
    # rounding of um-sized numbers (1e-9 um).
    eps = np.linalg.norm(t[:, 4:7] * ARCSEC, axis=1)
    bound = eps**2 * np.linalg.norm(p - r_t) / 2 * 1e3 + 1e-9
    assert np.all(np.abs(got - expected).max(axis=1) <= bound)
    assert bound.max() < 2e-3  # about 1 nm for 17 arc-seconds over 600 mm: first order is exact enough here
    np.testing.assert_array_equal(converted.table("Y")[:, 4:7], -t[:, 4:7])
    # And the swing is not negligible: dropping it misses by micrometres.
    assert np.abs(-t[:, 1:4] - expected).max() > 1.0


def test_analytic_yaw_and_the_rest_of_the_map_kept():
    m = _table_map(np.random.default_rng(1))
    t = m.table("Y").copy()
    t[:, 1:7] = 0.0
    t[:, 6] = 2.0  # eps_z 2 arc-seconds, nothing else
    yaw = cmmpose.ErrorMap(m.table("X"), t, m.table("Z"), m.squareness, m.temperature)
    converted = table_motion_to_map(yaw, "y", (0, 0, 0), (500.0, 0, 0))
    # eps_z x (500, 0, 0) = (0, 500 eps_z, 0); the map's d_y is minus that: -2 * 4.848e-6 rad * 500 mm = -4.85 um.
    np.testing.assert_allclose(converted.table("Y")[:, 2], -2.0 * ARCSEC * 500.0 * 1e3, rtol=1e-14)
    np.testing.assert_array_equal(converted.table("Y")[:, [1, 3]], 0.0)
    for c in ("X", "Z"):
        np.testing.assert_array_equal(converted.table(c), m.table(c))
    assert converted.squareness == m.squareness and converted.temperature == m.temperature
    np.testing.assert_array_equal(yaw.table("Y"), t)  # input not modified


@pytest.mark.parametrize("kwargs, match", [
    ({"carriage": "W"}, "carriage: expected X, Y or Z"),
    ({"part_point": (1.0, np.nan, 0.0)}, "part_point"),
    ({"measured_at": (1.0, 2.0)}, "measured_at"),
])
def test_bad_arguments_name_themselves(kwargs, match):
    args = {"carriage": "Y", "measured_at": (0, 0, 0), "part_point": (0, 0, 0), **kwargs}
    with pytest.raises(cmmpose.InputError, match=match):
        table_motion_to_map(cmmpose.ErrorMap.appendix_b(), **args)
    with pytest.raises(TypeError, match="error_map: expected an ErrorMap"):
        table_motion_to_map("map.csv", "Y", (0, 0, 0), (0, 0, 0))


def test_the_command(tmp_path):
    src = tmp_path / "table.csv"
    _table_map(np.random.default_rng(3)).write(src)
    out = tmp_path / "map.csv"
    r = CliRunner().invoke(main, ["map", "table-motion", str(src), "-o", str(out), "--carriage", "Y",
                                  "--measured-at", "0,0,0", "--part-point", "300,100,50", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["output"] == str(out)
    expected = table_motion_to_map(cmmpose.ErrorMap.read(src), "Y", (0, 0, 0), (300, 100, 50))
    np.testing.assert_array_equal(cmmpose.ErrorMap.read(out).table("Y"), expected.table("Y"))
    r = CliRunner().invoke(main, ["map", "table-motion", str(src), "-o", str(src), "--carriage", "Y",
                                  "--measured-at", "0,0,0", "--part-point", "1,2,3"])
    assert r.exit_code != 0 and "input" in r.output.lower()  # never overwrites its input
