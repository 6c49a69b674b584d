"""`cmmpose compensate` streams a file of any size in chunks (bounded
memory): the result equals compensating the whole file at once, a bad line
after the first chunk names the line and leaves no output, and a chunk the
fast reader refuses is read again by the strict one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.formats import pointfiles
from cmmpose.formats.pointformats import csv as csvformat
from cmmpose.cli import main

MAPS = cmmpose.ErrorMapSet.thesis()
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture
def points(tmp_path):
    rng = np.random.default_rng(3)
    n = 250
    a = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(-30, 30, n), rng.uniform(0, 900, n),
                         rng.uniform(0, 550, n), rng.uniform(-500, 0, n), rng.uniform(20.5, 29.5, n)]).round(4)
    csv = tmp_path / "p.csv"
    csv.write_text("u,v,D,E,F,T\n" + "".join(",".join(repr(float(x)) for x in row) + "\n" for row in a))
    npy = tmp_path / "p.npy"
    np.save(npy, a)
    # Parquet in several row groups, columns in another order, D as float32-free float64.
    parquet = tmp_path / "p.parquet"
    pq.write_table(pa.table({c: a[:, k] for k, c in sorted(enumerate("uvDEFT"), key=lambda kc: kc[1])}), parquet,
                   row_group_size=60)
    want = cmmpose.compensate(a[:, :2], a[:, 2:5], MAPS, POSE, OFFSET, a[:, 5])
    return csv, npy, want, parquet


def read_output(out):
    if out.suffix == ".npy":
        return np.load(out)
    if out.suffix == ".parquet":
        t = pq.read_table(out)
        assert t.schema.names == ["X", "Y", "Z"]
        return np.column_stack([t[c].to_numpy() for c in "XYZ"])
    return np.loadtxt(out, delimiter=",", skiprows=1)


@pytest.mark.parametrize("suffix", [".csv", ".npy", ".parquet"])
@pytest.mark.parametrize("fmt", ["csv", "npy", "parquet"])
def test_chunks_give_the_whole_file_result(tmp_path, points, monkeypatch, suffix, fmt):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    src = {"csv": points[0], "npy": points[1], "parquet": points[3]}[fmt]
    out = tmp_path / f"out{suffix}"
    r = cli("compensate", src, out)
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(read_output(out), points[2], rtol=0, atol=5e-7 if suffix == ".csv" else 0)


def test_an_npy_output_is_written_as_it_goes(tmp_path, monkeypatch):
    """The NPY writer holds no chunk: the file grows chunk by chunk and its
    header gets the count at the end (a fixed-size header, read by NumPy)."""
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    w = pointfiles.PointWriter(tmp_path / "o.npy")
    x = np.arange(30.0).reshape(10, 3)
    w.write(x[:4])
    w.f.flush()
    assert Path(w.tmp).stat().st_size == 128 + 4 * 24
    w.write(x[4:])
    w.close()
    assert np.array_equal(np.load(tmp_path / "o.npy"), x)
    assert (tmp_path / "o.npy").read_bytes()[:10] == b"\x93NUMPY\x01\x00v\x00"


@pytest.mark.parametrize(
    "table, words",
    [
        (pa.table({"u": [1.0], "v": [2.0], "D": [3.0], "E": [4.0]}), r"columns \['F'\] missing"),
        (pa.table({"u": [1.0], "v": [2.0], "D": [3.0], "E": [4.0], "F": ["x"]}), "column 'F' holds string"),
        (pa.table({"u": [1.0, 2.0], "v": [2.0, None], "D": [3.0, 3.0], "E": [4.0, 4.0], "F": [5.0, 5.0]}),
         "column 'v', row 1: empty"),
    ],
)
def test_a_bad_parquet_file_is_named_and_leaves_nothing(tmp_path, table, words):
    src = tmp_path / "bad.parquet"
    pq.write_table(table, src)
    r = cli("compensate", src, tmp_path / "o.parquet")
    assert r.exit_code != 0 and "bad.parquet" in r.output
    assert __import__("re").search(words, r.output), r.output
    assert not (tmp_path / "o.parquet").exists()
    (tmp_path / "junk.parquet").write_bytes(b"PAR1 not really")
    r = cli("compensate", tmp_path / "junk.parquet", tmp_path / "o.parquet")
    assert r.exit_code != 0 and "junk.parquet: not a readable Parquet file" in r.output


def test_a_bad_line_late_in_the_file_names_it_and_leaves_nothing(tmp_path, points, monkeypatch):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    text = points[0].read_text().splitlines()
    text[200] = text[200] + ",1"
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(text) + "\n")
    r = cli("compensate", bad, tmp_path / "o.csv")
    assert r.exit_code != 0 and "bad.csv:201: expected 6 fields" in r.output
    assert sorted(f.name for f in tmp_path.iterdir()) == ["bad.csv", "p.csv", "p.npy", "p.parquet"]


def test_a_chunk_the_fast_reader_refuses_is_read_again_strictly(tmp_path, points, monkeypatch):
    real = csvformat.pa_csv.open_csv

    class Flaky:
        def __init__(self, *a, **k):
            self.inner = iter(real(*a, **k))
            self.k = 0

        def __iter__(self):
            return self

        def __next__(self):
            self.k += 1
            if self.k == 2:
                raise pa.ArrowInvalid("refused")
            return next(self.inner)

    monkeypatch.setattr(csvformat.pa_csv, "open_csv", Flaky)
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    out = tmp_path / "o.npy"
    r = cli("compensate", points[0], out)
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(np.load(out), points[2])


def test_quoted_header_names_are_read(tmp_path, points):
    """pyarrow and spreadsheets quote the names in the header row."""
    text = points[0].read_text().splitlines()
    text[0] = ",".join(f'"{c}"' for c in text[0].split(","))
    quoted = tmp_path / "q.csv"
    quoted.write_text("\n".join(text) + "\n")
    uv, scales, temps = pointfiles.read_points(quoted)
    want = pointfiles.read_points(points[0])
    assert all(np.array_equal(a, b) for a, b in zip((uv, scales, temps), want))
    r = cli("compensate", quoted, tmp_path / "o.npy")
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(np.load(tmp_path / "o.npy"), points[2])
