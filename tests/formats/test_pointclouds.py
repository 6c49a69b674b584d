"""Point-cloud formats (cmmpose.formats.pointformats, read_point_cloud /
write_point_cloud): round trips per format with extra columns and their
types, the NIST scans, PLY in all three encodings, units, clear errors
naming the file and the line or element, and `cmmpose compensate` passing
scan_id and intensity through."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import PointCloud, read_point_cloud, write_point_cloud
from cmmpose.formats import pointfiles
from cmmpose.formats import pointformats
from cmmpose.cli import main
from nist import NIST

MAPS = cmmpose.ErrorMapSet.thesis()
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture
def cloud():
    rng = np.random.default_rng(14)
    n = 300
    xyz = rng.normal(size=(n, 3)) * [200.0, 150.0, 100.0] + [450.0, 275.0, -250.0]
    return PointCloud(xyz, {"scan_id": np.repeat(np.arange(3, dtype=np.int64), n // 3),
                            "intensity": rng.uniform(0, 1, n)})


def assert_same(got: PointCloud, want: PointCloud, atol=0.0, int_kind=True):
    np.testing.assert_allclose(got.xyz, want.xyz, rtol=0, atol=atol)
    assert list(got.columns) == list(want.columns)
    for name, values in want.columns.items():
        np.testing.assert_array_equal(got.columns[name], values, err_msg=name)
        assert got.columns[name].dtype.kind == values.dtype.kind, (name, got.columns[name].dtype)


# -- round trips ------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix, fmt, atol", [
    (".csv", None, 5e-7),  # coordinates written to 1 nm
    (".npy", None, 0),
    (".parquet", None, 0),
    (".ply", None, 0),
    (".ply", "ply-ascii", 0),
    (".ply", "ply-big-endian", 0),
    (".xyz", None, 0),
    (".e57", None, 1e-12),  # metres in the file: mm / 1000 * 1000
])
def test_round_trip_keeps_coordinates_and_columns(tmp_path, cloud, suffix, fmt, atol):
    path = tmp_path / f"cloud{suffix}"
    write_point_cloud(path, cloud, format=fmt)
    got = read_point_cloud(path)
    assert_same(got, cloud, atol)
    assert got.columns["scan_id"].dtype.kind == "i"


def test_pts_round_trip_with_intensity_and_colour(tmp_path, cloud):
    rgb = np.random.default_rng(1).integers(0, 256, size=(len(cloud), 3))
    c = PointCloud(cloud.xyz, {"intensity": cloud.columns["intensity"], "red": rgb[:, 0], "green": rgb[:, 1],
                               "blue": rgb[:, 2]})
    write_point_cloud(tmp_path / "c.pts", c)
    assert (tmp_path / "c.pts").read_text().split("\n", 1)[0].strip() == str(len(c))
    assert_same(read_point_cloud(tmp_path / "c.pts"), c)


def test_pts_refuses_columns_it_cannot_carry(tmp_path, cloud):
    with pytest.raises(cmmpose.InputError, match=r"c\.pts: a PTS file holds x y z .*\['scan_id', 'intensity'\]"):
        write_point_cloud(tmp_path / "c.pts", cloud)
    assert not list(tmp_path.iterdir())


def test_e57_keeps_double_precision_and_colours(tmp_path):
    xyz = np.array([[1234.5678901234, -0.000123456789, 987654.321012345], [1.0, 2.0, 3.0]])
    c = PointCloud(xyz, {"red": np.array([0, 255], np.uint8), "green": np.array([7, 8], np.uint8),
                         "blue": np.array([9, 10], np.uint8), "row": np.array([1, 2]),
                         "temperature": np.array([20.5, 21.0])})
    write_point_cloud(tmp_path / "c.e57", c)
    got = read_point_cloud(tmp_path / "c.e57")
    np.testing.assert_allclose(got.xyz, xyz, rtol=1e-15)  # not pye57's single precision
    for name in c.columns:
        np.testing.assert_array_equal(got.columns[name], c.columns[name], err_msg=name)
    # the standard's own fields, readable by any E57 reader
    import pye57

    e = pye57.E57(str(tmp_path / "c.e57"))
    fields = e.get_header(0).point_fields
    e.close()
    assert {"cartesianX", "colorRed", "rowIndex", "cmmpose:temperature"} <= set(fields)


def test_e57_of_several_scans_gets_a_scan_id_and_each_pose(tmp_path):
    """A file written by pye57 itself: two scans, the second with a pose."""
    import pye57

    path = tmp_path / "two.e57"
    a = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    b = np.array([[0.5, 0.0, 0.0]])
    e = pye57.E57(str(path), mode="w")
    e.write_scan_raw({"cartesianX": a[:, 0], "cartesianY": a[:, 1], "cartesianZ": a[:, 2],
                      "intensity": np.array([0.25, 0.5])})
    # 90 degrees about z, then 10 m along x
    e.write_scan_raw({"cartesianX": b[:, 0], "cartesianY": b[:, 1], "cartesianZ": b[:, 2],
                      "intensity": np.array([0.75])},
                     rotation=np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]),
                     translation=np.array([10.0, 0, 0]))
    e.close()
    got = read_point_cloud(path)
    np.testing.assert_array_equal(got.columns["scan_id"], [0, 0, 1])
    np.testing.assert_allclose(got.xyz, [[1000, 2000, 3000], [4000, 5000, 6000], [10000, 500, 0]], atol=1e-4)
    np.testing.assert_array_equal(got.columns["intensity"], [0.25, 0.5, 0.75])


def test_an_empty_cloud_round_trips(tmp_path):
    empty = PointCloud(np.zeros((0, 3)), {"scan_id": np.zeros(0, np.int64)})
    for suffix in (".csv", ".npy", ".parquet", ".ply", ".xyz", ".e57"):
        write_point_cloud(tmp_path / f"e{suffix}", empty)
        got = read_point_cloud(tmp_path / f"e{suffix}")
        assert got.xyz.shape == (0, 3) and list(got.columns) == ["scan_id"], suffix


def test_inputs_are_not_modified_and_the_cloud_is_read_only(tmp_path, cloud):
    xyz = np.array(cloud.xyz)
    c = PointCloud(xyz, {"i": np.arange(len(xyz))})
    write_point_cloud(tmp_path / "c.e57", c)  # converted to metres on the way
    np.testing.assert_array_equal(xyz, cloud.xyz)
    assert not c.xyz.flags.writeable and not c.columns["i"].flags.writeable
    with pytest.raises(cmmpose.InputError, match="would collide"):
        PointCloud(xyz, {"X": np.zeros(len(xyz))})
    with pytest.raises(cmmpose.InputError, match="has 2 values for 300 points"):
        PointCloud(xyz, {"a": np.zeros(2)})


# -- units ------------------------------------------------------------------------------------

@pytest.mark.parametrize("units, factor", [("mm", 1.0), ("m", 1000.0), ("um", 1e-3), ("in", 25.4)])
def test_units_convert_to_mm_once(tmp_path, units, factor):
    p = tmp_path / "c.xyz"
    p.write_text("1 2 3\n-4.5 0 1e-3\n")
    got = read_point_cloud(p, units=units)
    np.testing.assert_allclose(got.xyz, np.array([[1, 2, 3], [-4.5, 0, 1e-3]]) * factor, rtol=1e-15)
    write_point_cloud(tmp_path / "back.xyz", got, units=units)
    np.testing.assert_allclose(read_point_cloud(tmp_path / "back.xyz", units=units).xyz, got.xyz, rtol=1e-15)


def test_an_unknown_unit_is_refused(tmp_path):
    (tmp_path / "c.xyz").write_text("1 2 3\n")
    with pytest.raises(cmmpose.InputError, match=r"units='ft'"):
        read_point_cloud(tmp_path / "c.xyz", units="ft")


# -- the NIST scans -----------------------------------------------------------------------------

def test_nist_scans_are_read_in_metres():
    assert NIST.is_dir(), f"{NIST} is missing: the NIST scans ship in data/nist_dmg"
    files = sorted(NIST.glob("SPH10*.xyz"))
    assert len(files) == 5, files
    for f in files:
        raw = np.loadtxt(f)
        got = read_point_cloud(f, units="m")
        assert got.columns == {} and got.xyz.shape == raw.shape
        np.testing.assert_allclose(got.xyz, raw * 1000.0, rtol=1e-15)
        # about 5 m from the scanner at the origin
        assert 1000 < np.median(np.linalg.norm(got.xyz, axis=1)) < 20000


def test_xyz_header_comments_commas_and_default_names(tmp_path):
    p = tmp_path / "h.xyz"
    p.write_text("//X Y Z scan_id reflectance\n# a comment\n1 2 3 4 0.5\n\n5\t6\t7\t8\t0.25\n")
    got = read_point_cloud(p)
    assert list(got.columns) == ["scan_id", "reflectance"] and got.columns["scan_id"].dtype == np.int64
    np.testing.assert_array_equal(got.columns["reflectance"], [0.5, 0.25])
    p.write_text("1,2,3\n4,5,6\n")
    np.testing.assert_array_equal(read_point_cloud(p).xyz, [[1, 2, 3], [4, 5, 6]])
    p.write_text("1 2 3 9 10 11 12\n")
    assert list(read_point_cloud(p).columns) == ["intensity", "red", "green", "blue"]
    p.write_text("x y z nx\n1 2 3 0.5\n")
    assert list(read_point_cloud(p).columns) == ["nx"]


# -- PLY ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_written_by_plyfile_is_read_in_every_encoding(tmp_path, encoding):
    import plyfile

    order = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}[encoding]
    v = np.array([(1.5, 2.5, 3.5, 7, 200), (4.0, 5.0, 6.0, 8, 13)],
                 dtype=[("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"), ("scan_id", order + "i4"),
                        ("red", "u1")])
    faces = np.array([([0, 1, 0],)], dtype=[("vertex_indices", "i4", (3,))])
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(faces, "face")],
                    text=encoding == "ascii", byte_order=order).write(str(tmp_path / "p.ply"))
    got = read_point_cloud(tmp_path / "p.ply")
    np.testing.assert_array_equal(got.xyz, [[1.5, 2.5, 3.5], [4, 5, 6]])
    np.testing.assert_array_equal(got.columns["scan_id"], [7, 8])
    assert got.columns["scan_id"].dtype == np.int32 and got.columns["red"].dtype == np.uint8
    assert got.columns["scan_id"].dtype.byteorder in "=|<"  # native, whatever the file's order


def test_ascii_ply_is_read_a_chunk_of_lines_at_a_time_with_plyfiles_values(tmp_path):
    import plyfile

    # Every scalar type, values that round when parsed (float32 from decimal text), a face element after the
    # vertices and one before them: the chunked reader gives plyfile's whole-file values bit for bit.
    rng = np.random.default_rng(3)
    n = 1001
    v = np.empty(n, dtype=[("x", "f8"), ("y", "f8"), ("z", "f4"), ("scan_id", "i4"), ("red", "u1"),
                           ("q", "i2")])
    v["x"], v["y"] = rng.normal(0, 300, n), rng.uniform(-1e-9, 1e9, n)
    v["z"], v["scan_id"] = rng.normal(0, 1, n).astype("f4"), rng.integers(-2**31, 2**31, n)
    v["red"], v["q"] = rng.integers(0, 256, n), rng.integers(-2**15, 2**15, n)
    faces = np.array([([0, 1, 2],)] * 5, dtype=[("vertex_indices", "i4", (3,))])
    cam = np.array([(1.0,)], dtype=[("f", "f8")])
    path = tmp_path / "a.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(cam, "camera"), plyfile.PlyElement.describe(v, "vertex"),
                     plyfile.PlyElement.describe(faces, "face")], text=True).write(str(path))
    whole = plyfile.PlyData.read(str(path))["vertex"].data
    need = pointformats.Need(names=("x", "y", "z"))
    size, chunks = pointformats.get("ply").chunks(path, 100, need)
    parts = [c for c, _ in chunks]
    assert [len(c["x"]) for c in parts] == [100] * 10 + [1]  # a chunk of lines at a time, never the whole file
    for name in v.dtype.names:
        got = np.concatenate([c[name] for c in parts])
        assert got.dtype == whole.dtype[name] and got.tobytes() == whole[name].tobytes(), name
    got = read_point_cloud(path)
    assert got.xyz.tobytes() == np.column_stack([whole["x"], whole["y"], whole["z"].astype("f8")]).tobytes()


def test_ascii_ply_memory_is_bounded_by_the_chunk_not_the_file(tmp_path):
    import tracemalloc

    n = 200_000  # 6.4 MB of text, 4.8 MB as float64 columns
    path = tmp_path / "big.ply"
    with path.open("w") as f:
        f.write(f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty double x\nproperty double y\n"
                "property double z\nend_header\n")
        np.savetxt(f, np.arange(3 * n, dtype=float).reshape(n, 3) / 7, fmt="%.6f")
    need = pointformats.Need(names=("x", "y", "z"))
    tracemalloc.start()
    try:
        _, chunks = pointformats.get("ply").chunks(path, 1000, need)
        first, _ = next(chunks)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(first["x"]) == 1000 and first["y"][1] == pytest.approx(4 / 7, abs=1e-6)
    assert peak < 1_000_000, peak  # the whole file parsed would be > 4.8 MB; one chunk of lines is ~0.1 MB


def test_ply_header_of_each_written_encoding(tmp_path, cloud):
    encodings = (("ply", b"binary_little_endian"), ("ply-ascii", b"ascii"), ("ply-big-endian", b"binary_big_endian"))
    for fmt, word in encodings:
        write_point_cloud(tmp_path / f"{fmt}.ply", cloud, format=fmt)
        head = (tmp_path / f"{fmt}.ply").read_bytes()[:400]
        assert b"format " + word + b" 1.0" in head and b"property int scan_id" in head, fmt


def test_ply_refuses_integers_beyond_32_bits(tmp_path):
    c = PointCloud(np.zeros((1, 3)), {"scan_id": np.array([2**40])})
    with pytest.raises(cmmpose.InputError, match=r"big\.ply: column 'scan_id' holds values beyond PLY's int32"):
        write_point_cloud(tmp_path / "big.ply", c)
    assert not list(tmp_path.iterdir())


# -- errors name the file and the line or element -----------------------------------------------

PLY_HEAD = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"


@pytest.mark.parametrize("name, content, pattern", [
    ("bad.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty flot x\nend_header\n",
     r"bad\.ply:4: malformed PLY header: field type 'flot'"),
    ("bad.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n",
     r"bad\.ply:\d+: malformed PLY header"),
    ("bad.ply", "not a ply at all\n", r"bad\.ply:1: malformed PLY header"),
    ("bad.ply", PLY_HEAD + "1 2 3\n1 x 3\n",
     r"bad\.ply: PLY element 'vertex', row 1, property 'y' \(line 9\): malformed input"),
    ("bad.ply", PLY_HEAD + "1 2 3\n\n", r"bad\.ply: PLY element 'vertex', row 1, property 'x' \(line 9\): early end-of-line"),
    ("bad.ply", PLY_HEAD + "1 2 3 4\n1 2 3\n", r"bad\.ply: PLY element 'vertex', row 0 \(line 8\): expected end-of-line"),
    ("bad.ply", PLY_HEAD.replace("float z", "int z") + "1 2 3\n1 2 3.5\n",
     r"bad\.ply: PLY element 'vertex', row 1, property 'z' \(line 9\): malformed input"),
    ("bad.ply", "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n",
     r"bad\.ply: no 'vertex' element \(has \['face'\]\)"),
    ("bad.xyz", "1 2 3\n4 5 6\n7 8 nine\n", r"bad\.xyz:3: value 'nine' in column 3 is not a number"),
    ("bad.xyz", "1 2 3\n4 5 6 7\n", r"bad\.xyz:2: expected 3 numbers, got 4"),
    ("bad.xyz", "1 2\n", r"bad\.xyz:1: expected at least x y z, got 2"),
    ("bad.xyz", "X Y Z scan_id\n1 2 3 4.5\n", r"bad\.xyz:2: column 'scan_id' must hold whole numbers"),
    ("bad.xyz", "X Y Z a\n1 2 3\n", r"bad\.xyz:2: 3 numbers, but the header names 4 columns"),
    ("bad.pts", "1 2 3\n", r"bad\.pts:1: expected the number of points"),
    ("bad.pts", "3\n1 2 3\n4 5 6\n", r"bad\.pts:1: the count line says 3 points, the file holds 2"),
    ("bad.e57", "not an e57 file", r"bad\.e57: not a readable E57 file"),
    ("bad.csv", "X,Y,Z\n1,2,3\n4,5,x\n", r"bad\.csv:3: value 'x' in column 3 is not a number"),
    ("bad.csv", "X,Y\n1,2\n", r"bad\.csv: no Z coordinate column \(have \['X', 'Y'\]\)"),
    ("bad.las", "anything", r"bad\.las: unknown point-file suffix '\.las'; known: .*\.e57"),
])
def test_bad_files_are_named_with_the_line_or_element(tmp_path, name, content, pattern):
    p = tmp_path / name
    p.write_text(content)
    with pytest.raises(cmmpose.InputError, match=pattern):
        read_point_cloud(p)


def test_truncated_binary_ply_names_the_row(tmp_path, cloud):
    write_point_cloud(tmp_path / "t.ply", cloud)
    raw = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(raw[:-10])
    with pytest.raises(cmmpose.InputError, match=r"t\.ply: PLY element 'vertex', row 299: early end-of-file"):
        read_point_cloud(tmp_path / "t.ply")


def test_a_non_utf8_xyz_names_the_line(tmp_path):
    (tmp_path / "b.xyz").write_bytes(b"1 2 3\n4 5 6 \xff\n")
    with pytest.raises(cmmpose.InputError, match=r"b\.xyz:2: not UTF-8"):
        read_point_cloud(tmp_path / "b.xyz")


def test_e57_without_cartesian_fields(tmp_path):
    """An E57 scan whose points hold only an intensity."""
    import uuid

    from pye57 import E57, libe57 as lib

    path = tmp_path / "nocart.e57"
    e = E57(str(path), mode="w")
    imf = e.image_file
    proto = lib.StructureNode(imf)
    proto.set("intensity", lib.FloatNode(imf, 0.0, lib.E57_DOUBLE))
    scan = lib.StructureNode(imf)
    scan.set("guid", lib.StringNode(imf, "{%s}" % uuid.uuid4()))
    scan.set("points", lib.CompressedVectorNode(imf, proto, lib.VectorNode(imf, True)))
    e.data3d.append(scan)
    e.close()
    with pytest.raises(cmmpose.InputError, match=r"nocart\.e57: scan 0 has no cartesianX/Y/Z .*\['intensity'\]"):
        read_point_cloud(path)


def _raw_e57(path, fields, values, invalid=None):
    """A one-scan E57 written with libE57Format: ``fields`` maps a field name
    to a prototype node maker, ``values`` to its data."""
    import uuid

    from pye57 import E57, libe57 as lib

    e = E57(str(path), mode="w")
    imf = e.image_file
    proto = lib.StructureNode(imf)
    for name, make in fields.items():
        proto.set(name, make(lib, imf))
    scan = lib.StructureNode(imf)
    scan.set("guid", lib.StringNode(imf, "{%s}" % uuid.uuid4()))
    points = lib.CompressedVectorNode(imf, proto, lib.VectorNode(imf, True))
    scan.set("points", points)
    e.data3d.append(scan)
    n = len(next(iter(values.values())))
    arrays = {k: np.ascontiguousarray(v) for k, v in values.items()}
    buffers = lib.VectorSourceDestBuffer()
    for k, a in arrays.items():
        buffers.append(lib.SourceDestBuffer(imf, k, a, n, True, True))
    w = points.writer(buffers)
    w.write(n)
    w.close()
    e.close()


def test_e57_scaled_integer_and_spherical_scans_and_invalid_points(tmp_path):
    """What scanners write: coordinates as scaled integers (0.1 mm steps), or
    only spherical ones; points flagged invalid are dropped."""
    scaled = {f: (lambda lib, imf: lib.ScaledIntegerNode(imf, 0, -10**6, 10**6, 1e-4, 0.0))
              for f in ("cartesianX", "cartesianY", "cartesianZ")}
    scaled["cartesianInvalidState"] = lambda lib, imf: lib.IntegerNode(imf, 0, 0, 2)
    xyz = np.array([[1.2345, -0.5, 2.0], [9.9, 9.9, 9.9], [0.0001, 0.0, -3.0]])
    _raw_e57(tmp_path / "s.e57", scaled, {"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2],
                                         "cartesianInvalidState": np.array([0, 2, 0], dtype="q")})
    got = read_point_cloud(tmp_path / "s.e57")
    np.testing.assert_allclose(got.xyz, xyz[[0, 2]] * 1000, atol=1e-9)
    assert got.columns == {}

    spherical = {f: (lambda lib, imf: lib.FloatNode(imf, 0.0, lib.E57_DOUBLE))
                 for f in ("sphericalRange", "sphericalAzimuth", "sphericalElevation")}
    _raw_e57(tmp_path / "r.e57", spherical, {"sphericalRange": np.array([2.0, 5.0]),
                                            "sphericalAzimuth": np.array([0.0, np.pi / 2]),
                                            "sphericalElevation": np.array([0.0, np.pi / 6])})
    got = read_point_cloud(tmp_path / "r.e57")
    np.testing.assert_allclose(got.xyz, [[2000, 0, 0], [0, 5000 * np.cos(np.pi / 6), 2500]], atol=1e-9)


def test_an_unknown_format_name_is_refused(tmp_path):
    (tmp_path / "c.xyz").write_text("1 2 3\n")
    with pytest.raises(cmmpose.InputError, match=r"unknown point-file format 'las'; known: csv"):
        read_point_cloud(tmp_path / "c.xyz", format="las")
    assert set(pointformats.names()) >= {"csv", "npy", "parquet", "ply", "ply-ascii", "ply-big-endian", "xyz",
                                         "pts", "e57"}


def test_a_format_by_name_reads_any_suffix(tmp_path):
    (tmp_path / "scan.txt").write_text("1\t2\t3\n")
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "scan.txt", format="xyz").xyz, [[1, 2, 3]])


# -- compensate passes the extra columns through --------------------------------------------------

@pytest.fixture
def scanner_points():
    rng = np.random.default_rng(5)
    n = 120
    a = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(-30, 30, n), rng.uniform(0, 900, n),
                         rng.uniform(0, 550, n), rng.uniform(-500, 0, n), rng.uniform(20.5, 29.5, n)]).round(4)
    extras = {"scan_id": np.repeat(np.arange(4, dtype=np.int64), n // 4), "intensity": rng.uniform(0, 1, n).round(6)}
    want = cmmpose.compensate(a[:, :2], a[:, 2:5], MAPS, POSE, OFFSET, a[:, 5])
    return a, extras, want


def _csv_text(cols):
    body = np.column_stack([np.asarray(v, dtype=object) for v in cols.values()])
    return ",".join(cols) + "\n" + "".join(",".join(str(x) for x in row) + "\n" for row in body.tolist())


def _write_input(path: Path, a, extras):
    cols = {**{c: a[:, k] for k, c in enumerate("uvDEFT")}, **extras}
    if path.suffix == ".csv":
        path.write_text(_csv_text(cols))
    elif path.suffix == ".npy":
        rec = np.empty(len(a), [(c, np.asarray(v).dtype) for c, v in cols.items()])
        for c, v in cols.items():
            rec[c] = v
        np.save(path, rec)
    elif path.suffix == ".parquet":
        pq.write_table(pa.table(cols), path, row_group_size=25)
    elif path.suffix == ".xyz":
        path.write_text(_csv_text(cols).replace(",", " "))
    elif path.suffix == ".ply":
        import plyfile

        rec = np.empty(len(a), [(c, np.asarray(v).dtype if c != "scan_id" else np.int32) for c, v in cols.items()])
        for c, v in cols.items():
            rec[c] = v
        plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(path))


@pytest.mark.parametrize("src_suffix", [".csv", ".npy", ".parquet", ".ply", ".xyz"])
@pytest.mark.parametrize("out_suffix", [".csv", ".npy", ".parquet", ".ply"])
def test_compensate_passes_scan_id_and_intensity_through(tmp_path, scanner_points, monkeypatch, src_suffix,
                                                         out_suffix):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)  # many chunks
    a, extras, want = scanner_points
    src = tmp_path / f"in{src_suffix}"
    _write_input(src, a, extras)
    out = tmp_path / f"out{out_suffix}"
    r = cli("compensate", src, out, "--maps", "thesis", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575")
    assert r.exit_code == 0, r.output
    got = read_point_cloud(out)
    np.testing.assert_allclose(got.xyz, want, rtol=0, atol=5e-7 if out_suffix == ".csv" else 0)
    assert list(got.columns) == ["scan_id", "intensity"]
    np.testing.assert_array_equal(got.columns["scan_id"], extras["scan_id"])
    assert got.columns["scan_id"].dtype.kind == "i"
    np.testing.assert_array_equal(got.columns["intensity"], extras["intensity"])


def test_a_csv_the_fast_reader_refuses_keeps_its_extra_columns(tmp_path, scanner_points, monkeypatch):
    """scan_id read as whole numbers first; a later block the fast reader
    refuses is read again by the strict reader, which keeps scan_id int."""
    from cmmpose.formats.pointformats import csv as csvformat

    a, extras, want = scanner_points
    src = tmp_path / "in.csv"
    _write_input(src, a, extras)
    real = csvformat.pa_csv.open_csv

    def refusing(*args, **kw):
        reader = real(*args, **kw)
        yield next(iter(reader))
        raise pa.ArrowInvalid("refused")

    monkeypatch.setattr(csvformat.pa_csv, "open_csv", refusing)
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    r = cli("compensate", src, tmp_path / "o.parquet", "--maps", "thesis", "--pose", "90,90,0", "--offset",
            "1.001,264.505,129.575")
    assert r.exit_code == 0, r.output
    t = pq.read_table(tmp_path / "o.parquet")
    assert t.schema.names == ["X", "Y", "Z", "scan_id", "intensity"] and t.schema.field("scan_id").type == pa.int64()
    np.testing.assert_array_equal(t["scan_id"].to_numpy(), extras["scan_id"])
    np.testing.assert_array_equal(t["intensity"].to_numpy(), extras["intensity"])
    np.testing.assert_array_equal(np.column_stack([t[c].to_numpy() for c in "XYZ"]), want)


def test_compensate_into_e57_and_xyz_writes_the_standard_units(tmp_path, scanner_points):
    a, extras, want = scanner_points
    src = tmp_path / "in.parquet"
    _write_input(src, a, extras)
    for out in (tmp_path / "out.e57", tmp_path / "out.xyz"):
        r = cli("compensate", src, out, "--maps", "thesis", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575")
        assert r.exit_code == 0, r.output
        got = read_point_cloud(out)  # E57 in metres, converted back to mm
        np.testing.assert_allclose(got.xyz, want, rtol=1e-15, atol=1e-12)
        np.testing.assert_array_equal(got.columns["scan_id"], extras["scan_id"])


def test_compensate_plain_npy_output_without_extras_is_unchanged(tmp_path, scanner_points):
    a, _, want = scanner_points
    src = tmp_path / "in.npy"
    np.save(src, a)
    r = cli("compensate", src, tmp_path / "o.npy", "--maps", "thesis", "--pose", "90,90,0", "--offset",
            "1.001,264.505,129.575")
    assert r.exit_code == 0, r.output
    out = np.load(tmp_path / "o.npy")
    assert out.dtype == np.float64 and out.shape == (len(a), 3)
    np.testing.assert_array_equal(out, want)


def test_compensate_extras_to_pts_is_a_clear_error_leaving_nothing(tmp_path, scanner_points):
    a, extras, _ = scanner_points
    src = tmp_path / "in.parquet"
    _write_input(src, a, extras)
    r = cli("compensate", src, tmp_path / "o.pts", "--maps", "thesis", "--pose", "90,90,0")
    assert r.exit_code != 0 and re.search(r"o\.pts: a PTS file holds x y z", r.output), r.output
    assert sorted(f.name for f in tmp_path.iterdir()) == ["in.parquet"]


def test_compensate_refuses_a_non_numeric_extra_column(tmp_path, scanner_points):
    a, _, _ = scanner_points
    src = tmp_path / "in.csv"
    _write_input(src, a[:3], {"label": np.array(["a", "b", "c"], dtype=object)})
    r = cli("compensate", src, tmp_path / "o.csv", "--maps", "thesis", "--pose", "90,90,0")
    assert r.exit_code != 0 and "in.csv:2: value 'a' in column 7 is not a number" in r.output, r.output
