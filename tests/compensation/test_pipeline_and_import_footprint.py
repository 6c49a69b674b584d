"""Issue 27: what `import cmmpose` loads, the Parquet writers' encodings, the
compensate pipeline (a bounded queue between a reader thread, the kernel and
a writer thread) and its failure paths. Correctness only: no timings."""

from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pyarrow.parquet as pq
import pytest

import cmmpose
from cmmpose import filecompensation
from cmmpose.formats import pointfiles
from cmmpose.errors import InputError, OutputError
from cmmpose.formats.pointclouds import read_point_cloud
from cmmpose.formats.pointformats import csv as csvformat
from repo import REPO

POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)
MAPS = cmmpose.ErrorMapSet.thesis()


def test_import_cmmpose_loads_no_heavy_optional_dependency():
    """pyarrow, matplotlib, scipy, dask, pandas and rich load when a command needs them, not on import."""
    code = ("import sys, cmmpose; heavy = ('pyarrow', 'matplotlib', 'scipy', 'dask', 'distributed', 'pandas', 'rich');"
            "print(sorted({m.split('.')[0] for m in sys.modules} & set(heavy)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_fit_command_loads_neither_pyarrow_nor_the_run_format():
    """`cmmpose fit` on an XYZ scan needs NumPy's text reader, the kernel and rich: not pyarrow, not the run
    format, nor what other commands need (the evaluation, its uncertainty budget, the diagnosis, the simulator):
    each command group imports those where it uses them. (The effect registry loads: `simulate --help`
    lists the effects, built when the command group is defined.)"""
    scan = REPO / "data" / "nist_dmg" / "SPH101.xyz"
    code = ("import sys; from cmmpose.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "heavy = ('pyarrow', 'matplotlib', 'scipy', 'dask', 'pandas', 'cmmpose.run', 'cmmpose.evaluation.ballbar',"
            " 'cmmpose.evaluation.artefact', 'cmmpose.calibration', 'cmmpose.diagnosis', 'cmmpose.sim')\n"
            "print(sorted(m for m in heavy if m in sys.modules), file=sys.stderr)")
    res = subprocess.run([sys.executable, "-c", code, "fit", str(scan), "--units", "m", "--radius", "50",
                          "--scanner-origin", "0,0,0", "--segment", "e3125"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "3118 / 6474" in res.stdout
    assert res.stderr.strip().splitlines()[-1] == "[]"


def test_lazy_names_still_resolve():
    assert cmmpose.Run.__name__ == "Run"
    assert callable(cmmpose.evaluate) and callable(cmmpose.load_truth)
    assert callable(cmmpose.evaluation.ballbar.machine_temperature)
    assert "Evaluation" in dir(cmmpose)


def _points(n, seed=3):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    return uv, scales


def _write_input(path, n, temps=None):
    uv, scales = (a.round(6) for a in _points(n))  # as written
    lines = ["u,v,D,E,F,scan_id" + (",T" if temps is not None else "")]
    for k in range(n):
        row = [*uv[k], *scales[k]]
        line = ",".join(f"{x:.6f}" for x in row) + f",{k // 10}"
        if temps is not None:
            line += f",{temps[k]:.3f}"
        lines.append(line)
    path.write_text("\n".join(lines) + "\n")
    return uv, scales


def test_parquet_point_file_encodes_each_column_for_what_it_holds(tmp_path):
    """Coordinates without a dictionary (BYTE_STREAM_SPLIT, zstd); an integer column with one."""
    xyz = np.random.default_rng(1).normal(size=(1000, 3))
    path = tmp_path / "p.parquet"
    pointfiles.write_points(path, xyz, {"scan_id": np.arange(1000) // 100})
    column = {pq.ParquetFile(path).metadata.row_group(0).column(k).path_in_schema:
              pq.ParquetFile(path).metadata.row_group(0).column(k) for k in range(4)}
    for c in "XYZ":
        assert "BYTE_STREAM_SPLIT" in column[c].encodings and not column[c].has_dictionary_page
        assert column[c].compression == "ZSTD"
    assert column["scan_id"].has_dictionary_page
    np.testing.assert_array_equal(read_point_cloud(path).xyz, xyz)


def test_run_tables_encode_floats_without_a_dictionary(tmp_path, simulated_run):
    run = simulated_run
    run.save(tmp_path / "r")
    meta = pq.ParquetFile(tmp_path / "r" / "points.parquet").metadata.row_group(0)
    kinds = {meta.column(k).path_in_schema: meta.column(k) for k in range(meta.num_columns)}
    assert not kinds["u"].has_dictionary_page and "BYTE_STREAM_SPLIT" in kinds["u"].encodings
    assert kinds["scan_id"].has_dictionary_page
    back = cmmpose.Run.load(tmp_path / "r")
    np.testing.assert_array_equal(back.points["u"], run.points["u"])


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".npy"])
def test_compensate_file_matches_compensate_over_many_chunks(tmp_path, monkeypatch, suffix):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    src = tmp_path / "in.csv"
    uv, scales = _write_input(src, 100)
    out = tmp_path / f"out{suffix}"
    seen = []
    done = cmmpose.compensate_file(src, out, MAPS, POSE, OFFSET, 25.0,
                                   progress=lambda at, size: seen.append((at, size)))
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, 25.0)
    got = read_point_cloud(out)
    np.testing.assert_allclose(got.xyz, want, rtol=0, atol=5e-7 if suffix == ".csv" else 0)
    np.testing.assert_array_equal(got.columns["scan_id"], np.arange(100) // 10)
    assert done.points == 100 and done.report.points == 100
    assert seen and seen[-1][1] == src.stat().st_size


def test_the_csv_reader_gathers_small_blocks_into_whole_chunks(tmp_path, monkeypatch):
    """Blocks far smaller than a chunk (bounded read-ahead) still give chunks of `chunk` rows."""
    monkeypatch.setattr(csvformat, "BLOCK_BYTES", 256)
    src = tmp_path / "in.csv"
    uv, _ = _write_input(src, 100)
    _, chunks = pointfiles.point_chunks(src, 30)
    sizes = [len(c[0]) for c in chunks]
    assert sizes == [30, 30, 30, 10]
    whole = pointfiles.read_points(src)[0]
    np.testing.assert_allclose(whole, uv, atol=5e-7)


def test_a_map_set_without_temperature_is_an_error_naming_the_file(tmp_path):
    src = tmp_path / "in.csv"
    _write_input(src, 20)
    with pytest.raises(InputError, match="in.csv: a map set needs a temperature"):
        cmmpose.compensate_file(src, tmp_path / "o.csv", MAPS, POSE, OFFSET)
    assert not (tmp_path / "o.csv").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["in.csv"]


def test_a_bad_row_late_in_the_file_stops_the_pipeline_leaving_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    src = tmp_path / "in.csv"
    _write_input(src, 50)
    lines = src.read_text().splitlines()
    lines[45] = lines[45].replace(",", ",x", 1)
    src.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"in.csv:46"):
        cmmpose.compensate_file(src, tmp_path / "o.parquet", MAPS, POSE, OFFSET, 25.0)
    assert [p.name for p in tmp_path.iterdir()] == ["in.csv"]
    assert not [t for t in threading.enumerate() if t.name.startswith("cmmpose point")]


def test_a_writer_failure_stops_the_reader_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 7)
    src = tmp_path / "in.csv"
    _write_input(src, 100)
    real = pointfiles.PointWriter.write
    calls = []

    def failing(self, xyz, extras=None):
        calls.append(len(xyz))
        if len(calls) == 3:
            raise OutputError(f"{self.path}: cannot write (No space left on device)")
        return real(self, xyz, extras)

    monkeypatch.setattr(pointfiles.PointWriter, "write", failing)
    with pytest.raises(OutputError, match="No space left"):
        cmmpose.compensate_file(src, tmp_path / "o.csv", MAPS, POSE, OFFSET, 25.0)
    assert [p.name for p in tmp_path.iterdir()] == ["in.csv"]
    assert len(calls) == 3
    assert not [t for t in threading.enumerate() if t.name.startswith("cmmpose point")]


def test_the_queues_are_bounded(tmp_path, monkeypatch):
    """A writer that does not keep up holds the reader back: never more than a
    few chunks read ahead of the one being written."""
    monkeypatch.setattr(pointfiles, "CHUNK_POINTS", 5)
    src = tmp_path / "in.csv"
    _write_input(src, 200)
    read, written = [], []
    real_chunks = pointfiles.point_chunks

    def counting(*args, **kw):
        size, chunks = real_chunks(*args, **kw)

        def gen():
            for c in chunks:
                read.append(1)
                yield c
        return size, gen()

    real_write = pointfiles.PointWriter.write
    ahead = []

    def slow(self, xyz, extras=None):
        ahead.append(len(read) - len(written))
        written.append(1)
        return real_write(self, xyz, extras)

    monkeypatch.setattr(filecompensation, "point_chunks", counting)
    monkeypatch.setattr(pointfiles.PointWriter, "write", slow)
    cmmpose.compensate_file(src, tmp_path / "o.csv", MAPS, POSE, OFFSET, 25.0)
    assert len(written) == 40
    # in flight at most: the reader's, read_q, the kernel's, write_q, the writer's
    assert max(ahead) <= 2 * filecompensation.QUEUE_CHUNKS + 3


def test_the_cli_compensate_uses_the_pipeline_and_prints_its_summary(tmp_path):
    from click.testing import CliRunner

    from cmmpose.cli import main

    src = tmp_path / "in.csv"
    _write_input(src, 30, temps=np.full(30, 25.0))
    r = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / "o.csv"), "--maps", "thesis",
                                  "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"])
    assert r.exit_code == 0, r.output
    assert "per point (T column)" in r.output
    assert read_point_cloud(tmp_path / "o.csv").xyz.shape == (30, 3)


@pytest.mark.parametrize("suffix", [".npy", ".ply"])
def test_memory_mapped_inputs_read_the_same_after_their_pages_are_released(tmp_path, suffix):
    """NPY and binary PLY chunks give their pages back as they go (release_pages):
    every value still reads as written, including rows on shared page edges."""
    from cmmpose.formats.pointformats.common import release_pages

    n = 20_011  # chunks of 997 rows: blocks start and end inside pages
    rng = np.random.default_rng(7)
    cols = {c: rng.normal(size=n) for c in ("u", "v", "D", "E", "F")}
    src = tmp_path / f"in{suffix}"
    if suffix == ".npy":
        np.save(src, np.column_stack([cols[c] for c in cols]))
    else:
        header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % n
        header += "".join(f"property double {c}\n" for c in cols) + "end_header\n"
        rows = np.empty(n, [(c, "<f8") for c in cols])
        for c in cols:
            rows[c] = cols[c]
        src.write_bytes(header.encode() + rows.tobytes())
    for _ in range(2):  # the second pass reads the released pages again
        _, chunks = pointfiles.point_chunks(src, 997)
        uv = np.concatenate([c[0] for c in chunks])
        np.testing.assert_array_equal(uv, np.column_stack([cols["u"], cols["v"]]))
    release_pages(np.zeros(10))  # not a memory map: nothing to do
