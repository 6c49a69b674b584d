"""Issue 36, item 1: each compensated point's uncertainty in every output
path. Every point format the project writes carries the u columns (and the
covariance and its common part), read back equal to what
``compensate(..., uncertainty=)`` returns for the same points; the streaming
path over several chunks and the Dask path equal one in-memory call; the
command line writes them and prints the budget; a format that cannot carry
them, and a set of sources that states none, are refused; bad option values
exit 2 naming the option."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.calibration.library import AlignmentLibrary, AlignmentRecord
from cmmpose.cli import main
from cmmpose.errors import InputError
from cmmpose.filecompensation import compensate_file
from cmmpose.point_uncertainty import PoseUncertainty, UncertaintySources
from cmmpose.uncertainty_columns import U_COLUMNS, columns_of, uncertainty_columns

MAPS = cmmpose.ErrorMapSet.thesis()  # states the thesis's interferometer and resolution figures
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)  # the thesis machine's
SOURCES = UncertaintySources(temperature_k=0.3, scanner_scale_ppm=20.0, scanner_noise_um=(2.0, 8.0))


def _points(n=2000, seed=3):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(-25, 25, n), rng.uniform(115, 165, n)])
    scales = np.column_stack([rng.uniform(10, 890, n), rng.uniform(10, 540, n), rng.uniform(-490, -10, n)])
    return uv, scales, rng.uniform(20.5, 29.5, n), (np.arange(n) // 100).astype(np.int64)


def _write_input(path, n=2000, seed=3):
    """A Parquet scan: u, v, D, E, F (mm), T (C) and a scan_id passed through."""
    uv, scales, temps, scan = _points(n, seed)
    cols = {"u": uv[:, 0], "v": uv[:, 1], "D": scales[:, 0], "E": scales[:, 1], "F": scales[:, 2], "T": temps,
            "scan_id": scan}
    pq.write_table(pa.table(cols), path)
    return uv, scales, temps, scan


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    path = tmp_path_factory.mktemp("in") / "scan.parquet"
    uv, scales, temps, ids = _write_input(path)
    return path, uv, scales, temps, ids


def _same_bits(a, b):
    a, b = np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


# -- every format round-trips the columns -------------------------------------------------------

@pytest.mark.parametrize("suffix", ["csv", "parquet", "npy", "ply", "xyz", "e57"])
def test_each_format_round_trips_the_uncertainty_columns(tmp_path, scan, suffix):
    path, uv, scales, temps, ids = scan
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=SOURCES, uncertainty_detail="split")
    out = tmp_path / f"out.{suffix}"
    done = compensate_file(path, out, MAPS, POSE, OFFSET, uncertainty=SOURCES, uncertainty_detail="split")
    cloud = cmmpose.read_point_cloud(out)
    names = uncertainty_columns("split")
    assert list(cloud.columns)[:15] == list(names) and list(cloud.columns)[15:] == ["scan_id"]  # after X, Y, Z
    for name, values in columns_of(want).items():
        # Binary formats keep the bits; the text ones write each value in the shortest form that reads back the same.
        assert _same_bits(cloud.columns[name], values), (suffix, name)
    np.testing.assert_array_equal(cloud.columns["scan_id"], ids)
    np.testing.assert_allclose(cloud.xyz, want.xyz, rtol=0, atol=5.1e-7 if suffix == "csv" else 1e-9)
    assert done.uncertainty.points == len(uv)
    np.testing.assert_allclose(done.uncertainty.rms_um, np.sqrt(np.mean(want.u ** 2, axis=0)) * 1e3, rtol=1e-12)
    np.testing.assert_allclose(done.uncertainty.max_um, want.u.max(axis=0) * 1e3, rtol=1e-15)


def test_the_standard_detail_writes_u_only_and_npy_is_structured(tmp_path, scan):
    path, uv, scales, temps, _ = scan
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=True)
    out = tmp_path / "out.npy"
    compensate_file(path, out, MAPS, POSE, OFFSET, uncertainty=True)
    rec = np.load(out)
    assert rec.dtype.names == ("X", "Y", "Z", *U_COLUMNS, "scan_id")
    assert _same_bits(np.column_stack([rec[c] for c in U_COLUMNS]), want.u)
    assert _same_bits(np.column_stack([rec["X"], rec["Y"], rec["Z"]]), want.xyz)
    assert want.u.min() > 0  # the thesis maps state an uncertainty: not a silent zero


def test_streaming_over_several_chunks_equals_one_call(tmp_path, scan):
    path, uv, scales, temps, _ = scan
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=SOURCES,
                              uncertainty_detail="covariance")
    out = tmp_path / "out.parquet"
    compensate_file(path, out, MAPS, POSE, OFFSET, chunk=300, uncertainty=SOURCES, uncertainty_detail="covariance")
    cloud = cmmpose.read_point_cloud(out)  # 7 chunks of 300 rows (the last shorter)
    assert list(cloud.columns)[:9] == list(uncertainty_columns("covariance"))
    for name, values in columns_of(want).items():
        assert _same_bits(cloud.columns[name], values), name
    assert _same_bits(cloud.xyz, want.xyz)


@pytest.mark.filterwarnings("ignore::cmmpose.errors.ModelDomainWarning")  # a stated, undetermined squareness
def test_a_model_adds_its_parameter_covariance_through_a_file(tmp_path, scan):
    from dataclasses import replace

    path, uv, scales, temps, _ = scan
    model = replace(cmmpose.Model(MAPS).with_values("squareness", [3.0, 0.0, 0.0]),
                    uncertainty={"squareness": np.array([2.0, 0.0, 0.0])})
    want = cmmpose.compensate(uv, scales, model, POSE, OFFSET, temps, uncertainty=SOURCES)
    plain = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=SOURCES)
    compensate_file(path, tmp_path / "out.npy", model, POSE, OFFSET, chunk=700, uncertainty=SOURCES)
    rec = np.load(tmp_path / "out.npy")
    assert _same_bits(np.column_stack([rec[c] for c in U_COLUMNS]), want.u)
    assert np.all(want.u[:, 0] > plain.u[:, 0])  # squareness xy's 2 arc-seconds move X with E


# -- refusals ---------------------------------------------------------------------------------

def test_a_format_that_cannot_carry_the_columns_refuses(tmp_path, scan):
    path = scan[0]
    out = tmp_path / "out.pts"
    with pytest.raises(InputError, match=r"PTS format cannot carry the uncertainty columns.*--uncertainty"):
        compensate_file(path, out, MAPS, POSE, OFFSET, uncertainty=True)
    assert not out.exists()


@pytest.mark.filterwarnings("ignore::cmmpose.errors.MapTemperatureWarning")  # one map for points at 20.5..29.5 C
def test_no_stated_source_is_refused_not_written_as_zeros(tmp_path, scan):
    path = scan[0]
    bare = MAPS.maps[0].with_uncertainty(None)  # a map file stating no uncertainty
    out = tmp_path / "out.csv"
    with pytest.raises(InputError, match="no source of uncertainty is stated.*every u would be 0"):
        compensate_file(path, out, bare, POSE, OFFSET, uncertainty=True)
    assert not out.exists()
    with pytest.raises(InputError, match="switched off: map"):  # every source switched off: said so
        compensate_file(path, out, MAPS, POSE, OFFSET, uncertainty=UncertaintySources().without("map"))
    # The temperature acts through a map set's thermal sensitivity only: with one map it is no source.
    with pytest.raises(InputError, match="no source of uncertainty"):
        compensate_file(path, out, bare, POSE, OFFSET, uncertainty=UncertaintySources(temperature_k=0.5))
    compensate_file(path, out, bare, POSE, OFFSET, uncertainty=UncertaintySources(scanner_noise_um=5.0))
    assert cmmpose.read_point_cloud(out).columns["u_z_mm"].min() > 0


def test_a_nan_row_propagates_to_its_uncertainty_and_is_not_counted(tmp_path):
    src = tmp_path / "nan.csv"
    src.write_text("u,v,D,E,F,T\n1,130,100,100,-100,21\nnan,130,100,100,-100,21\n2,131,200,100,-100,22\n")
    done = compensate_file(src, tmp_path / "out.npy", MAPS, POSE, OFFSET, nan_policy="propagate", uncertainty=True)
    rec = np.load(tmp_path / "out.npy")
    u = np.column_stack([rec[c] for c in U_COLUMNS])
    assert np.isnan(u[1]).all() and np.isfinite(u[[0, 2]]).all()
    assert done.uncertainty.points == 2
    np.testing.assert_allclose(done.uncertainty.max_um, np.nanmax(u, axis=0) * 1e3, rtol=1e-15)


def test_an_input_column_named_as_an_uncertainty_column_is_refused(tmp_path, scan):
    path = tmp_path / "again.parquet"
    compensate_file(scan[0], tmp_path / "first.parquet", MAPS, POSE, OFFSET, uncertainty=True)
    t = pq.read_table(tmp_path / "first.parquet")
    pq.write_table(t.rename_columns(["u", "v", "D", *t.column_names[3:]]).append_column("E", t["Y"])
                   .append_column("F", t["Z"]).append_column("T", t["scan_id"].cast("float64")), path)
    with pytest.raises(InputError, match="has a column 'u_x_mm'"):
        compensate_file(path, tmp_path / "second.parquet", MAPS, POSE, OFFSET, uncertainty=True)
    assert not (tmp_path / "second.parquet").exists()


# -- the Dask path --------------------------------------------------------------------------------

def test_dask_array_dataframe_and_dataset_equal_the_in_memory_call(tmp_path, scan):
    pytest.importorskip("distributed")
    da = pytest.importorskip("dask.array")
    dd = pytest.importorskip("dask.dataframe")
    import pandas as pd

    from cmmpose import scale

    path, uv, scales, temps, ids = scan
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=SOURCES, uncertainty_detail="split")
    rows = np.column_stack([want.xyz, *columns_of(want).values()])
    arr = da.from_array(np.column_stack([uv, scales, temps]), chunks=(450, 6))
    got = scale.compensate_array(arr, MAPS, POSE, OFFSET, uncertainty=SOURCES, uncertainty_detail="split")
    assert got.shape == (len(uv), 18)
    assert _same_bits(got.compute(scheduler="threads"), rows)
    frame = dd.from_pandas(pd.DataFrame({"u": uv[:, 0], "v": uv[:, 1], "D": scales[:, 0], "E": scales[:, 1],
                                         "F": scales[:, 2], "T": temps, "scan_id": ids}), npartitions=4)
    out = scale.compensate_dataframe(frame, MAPS, POSE, OFFSET, uncertainty=SOURCES,
                                     uncertainty_detail="covariance").compute(scheduler="threads")
    assert list(out.columns) == ["X", "Y", "Z", *uncertainty_columns("covariance"), "scan_id"]
    for name, values in columns_of(cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty=SOURCES,
                                                      uncertainty_detail="covariance")).items():
        assert _same_bits(out[name].to_numpy(), values), name
    folder = tmp_path / "ds"
    folder.mkdir()
    (folder / "a.parquet").write_bytes(path.read_bytes())
    result = scale.compensate_dataset(folder, tmp_path / "dsout", MAPS, POSE, OFFSET, batch_rows=512,
                                      uncertainty=SOURCES, uncertainty_detail="split")
    table = pq.read_table(tmp_path / "dsout" / "a.parquet")
    assert table.column_names == ["X", "Y", "Z", *uncertainty_columns("split"), "scan_id"]
    for name, values in columns_of(want).items():
        assert _same_bits(table[name].to_numpy(), values), name
    assert result.uncertainty.points == len(uv)
    np.testing.assert_allclose(result.uncertainty.max_um, want.u.max(axis=0) * 1e3, rtol=1e-15)
    with pytest.raises(InputError, match="no source of uncertainty"):
        scale.compensate_array(arr, MAPS.maps[0].with_uncertainty(None), POSE, OFFSET, uncertainty=True)
    # The command on a folder: the same columns, and the budget under "uncertainty" in --json.
    r = cli("compensate", folder, tmp_path / "cliout", "--uncertainty", "--temperature-uncertainty", 0.3,
            "--scanner-scale-ppm", 20, "--scanner-noise", "2,8", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout[r.stdout.index("{"):])["uncertainty"]["points"] == len(uv)
    table = pq.read_table(tmp_path / "cliout" / "a.parquet")
    assert table.column_names == ["X", "Y", "Z", *U_COLUMNS, "scan_id"]
    assert _same_bits(np.column_stack([table[c].to_numpy() for c in U_COLUMNS]), want.u)


# -- the command line -----------------------------------------------------------------------------

def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False, env={"COLUMNS": "200"})


def test_the_command_writes_the_columns_and_prints_the_budget(tmp_path, scan):
    path, uv, scales, temps, _ = scan
    out = tmp_path / "out.csv"
    r = cli("compensate", path, out, "--maps", "thesis", "--uncertainty", "--uncertainty-detail", "covariance",
            "--temperature-uncertainty", 0.3, "--scanner-scale-ppm", 20)
    assert r.exit_code == 0, r.output
    # The machine file's scanner noise (the thesis machine: 8 um on v) and the maps' stated figures by default.
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps, uncertainty_detail="covariance",
                              uncertainty=UncertaintySources(temperature_k=0.3, scanner_scale_ppm=20.0,
                                                             scanner_noise_um=(0.0, 8.0)))
    cloud = cmmpose.read_point_cloud(out)
    for name, values in columns_of(want).items():
        assert _same_bits(cloud.columns[name], values), name
    text = " ".join(r.output.split())
    assert "uncertainty budget (k = 1)" in text
    for words in ("temperature │ on │ 0.3 K │ --temperature-uncertainty", "scanner_scale │ on │ 20 ppm",
                  "scanner_noise │ on │ u 0 um, v 8 um", "scanner.noise_um",
                  "Harris thesis: interferometer 2.5 ppm", "pose │ on │ none stated"):
        assert words in text, words
    rms = np.sqrt(np.mean(want.u ** 2, axis=0)) * 1e3
    assert f"over 2,000 points: rms X {rms[0]:.3g}, Y {rms[1]:.3g}, Z {rms[2]:.3g} um" in text
    r = cli("compensate", path, tmp_path / "off.npy", "--maps", "thesis", "--uncertainty", "--json",
            "--uncertainty-off", "scanner_noise", "--uncertainty-off", "map", "--temperature-uncertainty", 0.3)
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)["uncertainty"]
    assert {b["source"]: b["on"] for b in doc["budget"]} == {
        "map": False, "temperature": True, "scanner_scale": True, "scanner_noise": False, "pose": True, "model": True}
    want = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps,
                              uncertainty=UncertaintySources(temperature_k=0.3).without("scanner_noise", "map"))
    rec = np.load(tmp_path / "off.npy")
    assert _same_bits(np.column_stack([rec[c] for c in U_COLUMNS]), want.u)
    assert doc["points"] == 2000 and doc["max_um"] == pytest.approx(list(want.u.max(axis=0) * 1e3), rel=1e-15)


@pytest.mark.filterwarnings("ignore::cmmpose.errors.ModelDomainWarning")
def test_the_command_takes_the_alignment_covariance_and_a_model(tmp_path, scan):
    from dataclasses import replace

    path, uv, scales, temps, _ = scan
    record = AlignmentRecord(pose=POSE, reading=(449.0, 509.6, -155.5), offset=OFFSET,
                             pose_uncertainty=(0.01, 0.01, 0.002), offset_uncertainty=(0.002, 0.002, 0.004),
                             temperature=21.0, date="2026-11-24T12:00:00+00:00", residuals={}, note="")
    AlignmentLibrary(tmp_path / "align.json").save("A90B90", record)
    r = cli("compensate", path, tmp_path / "a.parquet", "--alignment", "A90B90", "--library",
            tmp_path / "align.json", "--uncertainty")
    assert r.exit_code == 0, r.output
    stored = AlignmentLibrary(tmp_path / "align.json").load("A90B90")
    want = cmmpose.compensate(uv, scales, MAPS, stored.as_pose(), stored.as_offset(), temps,
                              uncertainty=UncertaintySources(scanner_noise_um=(0.0, 8.0),
                                                             pose=PoseUncertainty.from_record(stored)))
    assert _same_bits(cmmpose.read_point_cloud(tmp_path / "a.parquet").columns["u_y_mm"], want.u[:, 1])
    assert "alignment of 2026-11-24" in " ".join(r.output.split())
    model = replace(cmmpose.Model(MAPS).with_values("squareness", [3.0, 0.0, 0.0]),
                    uncertainty={"squareness": np.array([2.0, 0.0, 0.0])})
    m = model.save(tmp_path / "m.json")
    r = cli("compensate", path, tmp_path / "m.npy", "--model", m, "--uncertainty")
    assert r.exit_code == 0, r.output
    want = cmmpose.compensate(uv, scales, cmmpose.Model.load(m), POSE, OFFSET, temps,
                              uncertainty=UncertaintySources(scanner_noise_um=(0.0, 8.0)))
    rec = np.load(tmp_path / "m.npy")
    assert _same_bits(np.column_stack([rec[c] for c in U_COLUMNS]), want.u)
    assert "model │ on │ parameter covariance" in " ".join(r.output.split())


def test_the_command_refuses_a_format_and_a_budget_without_sources(tmp_path, scan):
    path = scan[0]
    r = cli("compensate", path, tmp_path / "out.pts", "--uncertainty")
    assert r.exit_code == 1 and "PTS format cannot carry the uncertainty columns" in " ".join(r.output.split())
    assert not (tmp_path / "out.pts").exists()
    r = cli("compensate", path, tmp_path / "out.csv", "--uncertainty", "--uncertainty-off", "map",
            "--uncertainty-off", "scanner_noise")
    assert r.exit_code == 1 and "no source of uncertainty is stated" in " ".join(r.output.split())
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("option, value", [
    ("--temperature-uncertainty", "-0.1"), ("--temperature-uncertainty", "nan"), ("--temperature-uncertainty", "1e9"),
    ("--scanner-noise", "-3"), ("--scanner-noise", "nan"), ("--scanner-noise", "1e9"), ("--scanner-noise", "2,3,4"),
    ("--scanner-scale-ppm", "-1"), ("--scanner-scale-ppm", "inf"), ("--scanner-scale-ppm", "1e9"),
    ("--uncertainty-off", "noise"), ("--uncertainty-detail", "full"),
])
def test_bad_option_values_exit_2_naming_the_option(tmp_path, scan, option, value):
    r = cli("compensate", scan[0], tmp_path / "out.csv", "--uncertainty", option, value)
    assert r.exit_code == 2 and option in r.output, r.output
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("option, value", [("--temperature-uncertainty", "0.2"), ("--scanner-noise", "3"),
                                           ("--scanner-scale-ppm", "5"), ("--uncertainty-off", "map"),
                                           ("--uncertainty-detail", "split")])
def test_a_source_option_without_uncertainty_is_a_usage_error(tmp_path, scan, option, value):
    r = cli("compensate", scan[0], tmp_path / "out.csv", option, value)
    assert r.exit_code == 2 and option in r.output and "--uncertainty" in r.output, r.output
    assert not (tmp_path / "out.csv").exists()
