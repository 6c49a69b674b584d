"""`cmmpose compensate` streams a file of any size in chunks (bounded
memory): the result equals compensating the whole file at once, a bad line
after the first chunk names the line and leaves no output, and a chunk the
fast reader refuses is read again by the strict one."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import pointfiles
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
    want = cmmpose.compensate(a[:, :2], a[:, 2:5], MAPS, POSE, OFFSET, a[:, 5])
    return csv, npy, want


@pytest.mark.parametrize("suffix", [".csv", ".npy"])
@pytest.mark.parametrize("fmt", ["csv", "npy"])
def test_chunks_give_the_whole_file_result(tmp_path, points, monkeypatch, suffix, fmt):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    src = points[0] if fmt == "csv" else points[1]
    out = tmp_path / f"out{suffix}"
    r = cli("compensate", src, out)
    assert r.exit_code == 0, r.output
    got = np.load(out) if suffix == ".npy" else np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(got, points[2], rtol=0, atol=5e-7 if suffix == ".csv" else 0)


def test_a_bad_line_late_in_the_file_names_it_and_leaves_nothing(tmp_path, points, monkeypatch):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    text = points[0].read_text().splitlines()
    text[200] = text[200] + ",1"
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(text) + "\n")
    r = cli("compensate", bad, tmp_path / "o.csv")
    assert r.exit_code != 0 and "bad.csv:201: expected 6 fields" in r.output
    assert sorted(f.name for f in tmp_path.iterdir()) == ["bad.csv", "p.csv", "p.npy"]


def test_a_chunk_the_fast_reader_refuses_is_read_again_strictly(tmp_path, points, monkeypatch):
    real = pointfiles.pa_csv.open_csv

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

    monkeypatch.setattr(pointfiles.pa_csv, "open_csv", Flaky)
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    out = tmp_path / "o.npy"
    r = cli("compensate", points[0], out)
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(np.load(out), points[2])
