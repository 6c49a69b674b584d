"""Inputs that used to give silent wrong results or tracebacks (issue 11):
each is now a clear cmmpose error naming the file (line, field) or argument,
with nothing partially written."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.acquire.plan import Plan, plan_from_run
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.formats.pointfiles import read_points, write_points
from cmmpose.run import Run

MAPS = cmmpose.ErrorMapSet.thesis()
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)
HEADER = "u,v,D,E,F\n"


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


# -- point files ---------------------------------------------------------------------------

def test_a_row_with_an_extra_field_is_refused_not_shifted(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text(HEADER + "1,2,450,275,-250\n10,5,300,3,00,-200\n")
    with pytest.raises(cmmpose.InputError, match=r"p.csv:3: expected 5 fields like the header, got 6"):
        read_points(p)


@pytest.mark.parametrize(("encoding", "match"), [("latin-1", r":2: not UTF-8"), ("utf-16", r":1: not UTF-8")])
def test_text_that_is_not_utf8_names_the_line(tmp_path, encoding, match):
    p = tmp_path / "p.csv"
    p.write_bytes((HEADER + "1,2,450,275,-250 # µ\n").encode(encoding))
    with pytest.raises(cmmpose.InputError, match=match):
        read_points(p)


def test_a_byte_order_mark_is_fine(tmp_path):
    p = tmp_path / "p.csv"
    p.write_bytes(b"\xef\xbb\xbf" + (HEADER + "1,2,450,275,-250\n").encode())
    uv, scales, t = read_points(p)
    assert uv.tolist() == [[1.0, 2.0]] and t is None


@pytest.mark.parametrize("field", ["1_0", "\u0661\u0660", "0x10", "1,,"])
def test_lenient_numbers_in_point_files_are_refused(tmp_path, field):
    p = tmp_path / "p.csv"
    p.write_text(HEADER + f"{field},2,450,275,-250\n".replace("1,,,", "1,,"))
    with pytest.raises(cmmpose.InputError, match=r"p.csv:2"):
        read_points(p)


def _npy(tmp_path, name, make):
    p = tmp_path / name
    make(p)
    return p


@pytest.mark.parametrize(("make", "match"), [
    (lambda p: np.savez(p.with_suffix(".npz"), a=np.zeros((2, 5))) or p.with_suffix(".npz").rename(p), "zip archive"),
    (lambda p: np.save(p, np.array([["a"] * 5] * 2)), "expected real numbers"),
    (lambda p: np.save(p, np.zeros((2, 5), complex)), "expected real numbers"),
    (lambda p: p.write_bytes(b""), "empty"),
    (lambda p: p.write_bytes(b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 5), }"
                             + b" " * 45 + b"\n"), "not a readable .npy"),
    (lambda p: np.save(p, np.zeros((2, 4))), r"shape \(N, 5\) or \(N, 6\)"),
])
def test_bad_npy_files_are_clear_errors(tmp_path, make, match):
    p = _npy(tmp_path, "p.npy", make)
    with pytest.raises(cmmpose.InputError, match=match):
        read_points(p)


def test_output_suffix_in_any_case_and_a_missing_folder(tmp_path):
    xyz = np.arange(6.0).reshape(2, 3)
    write_points(tmp_path / "OUT.NPY", xyz)
    assert (tmp_path / "OUT.NPY").is_file() and not (tmp_path / "OUT.NPY.npy").exists()
    np.testing.assert_array_equal(np.load(tmp_path / "OUT.NPY"), xyz)
    pts = tmp_path / "p.csv"
    pts.write_text(HEADER + "1,2,450,275,-250\n")
    r = cli("compensate", pts, tmp_path / "nowhere" / "o.csv", "--temperature", 22)
    assert r.exit_code != 0 and "does not exist" in r.output
    assert not (tmp_path / "nowhere").exists()
    assert [f.name for f in tmp_path.iterdir() if f.name.startswith(".")] == []  # no temporary left


# -- arrays and arguments -------------------------------------------------------------------

def test_complex_boolean_and_text_arrays_are_refused():
    uv = np.zeros((2, 2))
    scales = np.array([[450.0, 275.0, -250.0]] * 2)
    for bad, match in ((uv + 1j, "complex"), (uv.astype(bool), "booleans"), (uv.astype(str), "text")):
        with pytest.raises(cmmpose.InputError, match=f"uv: .*{match}"):
            cmmpose.compensate(bad, scales, MAPS, POSE, OFFSET, 22.0)
    with pytest.raises(cmmpose.InputError, match="pose"):
        cmmpose.compensate(uv, scales, MAPS, [True, 90, 0], OFFSET, 22.0)
    with pytest.raises(cmmpose.InputError, match="pose"):
        cmmpose.Pose(True, 90, 0)


def test_finite_input_never_gives_inf():
    # Numbers beyond a machine's lengths are refused before they can overflow (or give a finite nonsense).
    uv = np.array([[1.7e308, 1.7e308]])
    scales = np.array([[1.7e308, 1.7e308, 1.7e308]])
    with pytest.raises(cmmpose.InputError, match=r"^uv: row 0: 1.7e308 mm is beyond \+-100000 mm"):
        cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, 22.0, out_of_range="clamp")


# -- map and model files --------------------------------------------------------------------

@pytest.mark.parametrize("bad", ["1_0", "\u0661\u0660", "infinity", "1e5000"])
def test_lenient_numbers_in_map_files_are_refused(tmp_path, bad):
    m = tmp_path / "m.csv"
    MAPS.maps[0].write(m)
    lines = m.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("X,25,"))
    fields = lines[k].split(",")
    fields[2] = bad
    lines[k] = ",".join(fields)
    m.write_text("\n".join(lines) + "\n")
    with pytest.raises(cmmpose.MapError, match=f"m.csv:{k + 1}"):
        cmmpose.ErrorMap.read(m)


def test_model_files_with_a_bad_kind_no_maps_or_a_bad_map_name_the_file(tmp_path):
    good = Model(MAPS).to_dict()
    for change, match in ((lambda d: d["maps"].update(kind="sett"), "maps.kind must be 'set' or 'map'"),
                          (lambda d: d["maps"].update(csv=[]), "lists no map"),
                          (lambda d: d["maps"]["csv"].__setitem__(0, "not,a,map\n"), r"model.json \(maps.csv\[0\]\)")):
        doc = json.loads(json.dumps(good))
        change(doc)
        p = tmp_path / "model.json"
        p.write_text(json.dumps(doc))
        with pytest.raises(cmmpose.Error, match=match) as exc:
            Model.load(p)
        assert "/tmp" not in str(exc.value).replace(str(tmp_path), "")


def test_deeply_nested_json_is_a_clear_error(tmp_path, simulated_run):
    deep = "[" * 100_000 + "]" * 100_000
    simulated_run.save(tmp_path / "r")
    (tmp_path / "r" / "run.json").write_text(deep)
    with pytest.raises(cmmpose.RunError, match="run.json"):
        Run.load(tmp_path / "r")
    (tmp_path / "m.json").write_text(deep)
    with pytest.raises(cmmpose.InputError, match="m.json"):
        Model.load(tmp_path / "m.json")
    (tmp_path / "plan.json").write_text(deep)
    with pytest.raises(cmmpose.AcquisitionError, match="plan.json"):
        Plan.read(tmp_path / "plan.json")


def test_string_numbers_in_run_json_are_refused(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    doc = json.loads((tmp_path / "r" / "run.json").read_text())
    doc["artefact"]["ball_radius_mm"] = "12.7"
    (tmp_path / "r" / "run.json").write_text(json.dumps(doc))
    with pytest.raises(cmmpose.RunError, match=r"run.json.*artefact.ball_radius_mm.*'12.7'"):
        Run.load(tmp_path / "r")


def test_a_plan_with_bad_types_fails_at_the_start(tmp_path, simulated_run):
    doc = plan_from_run(simulated_run).to_dict()
    doc["poses"][0]["alpha"] = True
    p = tmp_path / "plan.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(cmmpose.AcquisitionError, match=r"plan.json: plan: poses\[0\]: alpha = True"):
        Plan.read(p)
    doc = plan_from_run(simulated_run).to_dict()
    doc["scans"][1]["position"] = "3"
    p.write_text(json.dumps(doc))
    with pytest.raises(cmmpose.AcquisitionError, match=r"scans\[1\]: position = '3' is not an integer"):
        Plan.read(p)


# -- damaged runs ---------------------------------------------------------------------------

def test_a_flipped_bit_in_a_run_table_names_the_file_or_changes_nothing(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    path = tmp_path / "r" / "points.parquet"
    clean = path.read_bytes()
    rng = np.random.default_rng(0)
    silent = 0
    for trial in range(120):
        b = bytearray(clean)
        i = int(rng.integers(len(b)))
        b[i] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(b))
        try:
            got = Run.load(tmp_path / "r")
        except cmmpose.RunError as exc:
            assert "points.parquet" in str(exc)
            continue
        silent += not all(np.array_equal(got.points[c], simulated_run.points[c])
                          for c in simulated_run.points)
    path.write_bytes(clean)
    assert silent == 0


# -- optional dependencies ------------------------------------------------------------------

def test_diagnose_report_without_matplotlib_still_saves_the_result(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    code = ("import sys; sys.modules['matplotlib'] = None; from cmmpose.cli import main; "
            f"main(['diagnose', {str(tmp_path / 'r')!r}, '--max-effects', '0', '--report', "
            f"{str(tmp_path / 'd')!r}, '--save-model', {str(tmp_path / 'm.json')!r}])")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={"COLUMNS": "200", **__import__("os").environ})
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "m.json").is_file() and not (tmp_path / "d" / "diagnose.html").exists()
    assert "pip install 'cmmpose[plot]'" in res.stderr + res.stdout
