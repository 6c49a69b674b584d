"""A machine's numbers have physical bounds (issue 35: "a range for every number"): a map's components, its
squareness and temperature, a scale reading and a scan-plane point. The core holds the bounds
(``cmmpose_core::units``) and refuses what is beyond them whatever the NaN or range policy, naming the file, the
row and the value; the file schemas state the same numbers."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import _core
from cmmpose.cli import main
from cmmpose.errors import InputError, MapError
from cmmpose.formats import mapformats
from cmmpose.schemas import TEMPERATURE_C
from cmmpose.schemas import model as model_schema
from cmmpose.schemas._common import LENGTH_MM
from cmmpose.schemas.machine import TRAVEL_LIMIT_MM

THESIS_MAP = cmmpose.errormap.data_path("maps", "thesis_20C.csv")
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def test_the_schemas_state_the_cores_bounds():
    assert model_schema.UNIT_BOUNDS["um"] == _core.MAX_TRANSLATION_UM
    assert model_schema.UNIT_BOUNDS["arc-second"] == _core.MAX_ANGLE_ARCSEC
    assert tuple(TEMPERATURE_C) == tuple(_core.TEMPERATURE_RANGE_C)
    assert LENGTH_MM == TRAVEL_LIMIT_MM == _core.MAX_LENGTH_MM


def _edited_map(tmp_path, edit) -> str:
    """The bundled 20 C map with one line edited, its checksum line dropped (the edit is deliberate)."""
    lines = [line for line in THESIS_MAP.read_text().splitlines() if not line.startswith("# sha256")]
    path = tmp_path / "edited.csv"
    path.write_text("\n".join(edit(line) for line in lines) + "\n")
    return str(path)


@pytest.mark.parametrize("edit, words", [
    (lambda l: "X,25,1e30,0,0,0,0.57,-0.37" if l.startswith("X,25,") else l, "component dx is 1e30 um, beyond"),
    (lambda l: "X,25,2,0,0,0,0.57,-3601" if l.startswith("X,25,") else l, "component ez is -3601 arc-second"),
    (lambda l: l.replace("squareness_yz_arcsec: -19", "squareness_yz_arcsec: -1e9"), "S_yz is -1e9 arc-second"),
    (lambda l: l.replace("temperature_C: 20", "temperature_C: -273.16"), "-273.16 C is outside -50 to 150 C"),
    (lambda l: "Z,150000,0,0,0,0,0,0" if l.startswith("Z,0,") else l, None),
])
def test_a_map_file_beyond_a_machines_bounds_is_refused_naming_the_file(tmp_path, edit, words):
    path = _edited_map(tmp_path, edit)
    with pytest.raises(MapError) as info:
        mapformats.read(path)
    assert str(info.value).startswith(path)
    if words is not None:
        assert words in str(info.value)
    result = CliRunner().invoke(main, ["compensate", "data/examples/sphere_scan.csv", str(tmp_path / "out.csv"),
                                       "--maps", path, "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"])
    assert result.exit_code == 1 and path in result.output
    assert not (tmp_path / "out.csv").exists()


def test_maps_at_the_bounds_are_taken():
    rows = np.zeros((2, 7))
    rows[1] = [100.0, 1e5, -1e5, 0.0, 3600.0, -3600.0, 0.0]
    m = cmmpose.ErrorMap(rows, rows, rows, (3600.0, -3600.0, 0.0), temperature=150.0)
    assert m.temperature == 150.0
    with pytest.raises(MapError, match="component dx is 100001 um"):
        cmmpose.ErrorMap(np.where(rows == 1e5, 1e5 + 1, rows), rows, rows, (0.0, 0.0, 0.0))


def _points(n=2000):
    rng = np.random.default_rng(3)
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    scales = np.column_stack([rng.uniform(100, 800, n), rng.uniform(50, 500, n), rng.uniform(-450, -50, n)])
    return uv, scales


@pytest.mark.parametrize("profiles", [False, True])
def test_points_beyond_a_machines_lengths_are_refused_naming_the_row(profiles):
    # Profiles (rows sharing a reading) and random readings take different kernel paths; both refuse, whatever
    # the NaN and range policies, where 1e300 mm would give a finite nonsense.
    uv, scales = _points()
    if profiles:
        scales = np.repeat(scales[::100], 100, axis=0)
    maps = cmmpose.ErrorMapSet.thesis().maps[0]
    bad = uv.copy()
    bad[1234, 1] = 1e300
    for options in ({}, {"nan_policy": "propagate", "out_of_range": "clamp"}):
        with pytest.raises(InputError) as info:
            cmmpose.compensate(bad, scales, maps, POSE, OFFSET, **options)
        assert (info.value.row, info.value.value, info.value.unit) == (1234, 1e300, "mm")
        assert str(info.value) == "uv: row 1234: 1e300 mm is beyond +-100000 mm: not millimetres on a machine"
    far = scales.copy()
    far[1500, 0] = -2e5
    with pytest.raises(InputError, match=r"^scales: row 1500: -200000 mm is beyond"):
        cmmpose.compensate(uv, far, maps, POSE, OFFSET, out_of_range="clamp")
    assert np.all(np.isfinite(cmmpose.compensate(uv, scales, maps, POSE, OFFSET)))


def test_a_point_file_beyond_a_machines_lengths_names_the_file_row_and_columns(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("u,v,D,E,F,T\n1,120,499.575,275,-47.37,21.8\n1e300,120,499.575,275,-47.37,21.8\n")
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(main, ["compensate", str(path), str(out), "--maps", "thesis", "--pose", "90,90,0",
                                       "--offset", "1.001,264.505,129.575", "--temperature", "20"])
    assert result.exit_code == 1
    assert f"{path}: columns u, v: row 1: 1e300 mm is beyond +-100000 mm" in " ".join(result.output.split())
    assert not out.exists()


@pytest.mark.parametrize("t", [-300.0, 1e300, 150.5])
def test_a_points_temperature_no_machine_works_at_is_refused_not_held(tmp_path, t):
    # Under --out-of-range clamp a temperature outside the maps is held at their edge; one outside -50 to 150 C
    # is not a temperature on a machine (a unit slip, a broken thermocouple) and is refused naming the row.
    path = tmp_path / "scan.csv"
    path.write_text(f"u,v,D,E,F,T\n1,120,499.575,275,-47.37,21.8\n1,120,499.575,275,-47.37,{t!r}\n")
    out = tmp_path / "out.csv"
    result = CliRunner().invoke(main, ["compensate", str(path), str(out), "--maps", "thesis", "--pose", "90,90,0",
                                       "--offset", "1.001,264.505,129.575", "--out-of-range", "clamp"])
    assert result.exit_code == 1, result.output
    words = " ".join(result.output.split())
    assert f"{path}: column T: row 1: " in words and "C is outside -50 to 150 C: not degrees C on a machine" in words
    assert not out.exists()
