"""Scaling out with Dask (cmmpose.scale): Parquet datasets, Dask arrays and
dataframes, and fleets of runs, on a LocalCluster of two worker processes and
on the default threads; results equal the in-process kernel bit for bit."""

import json
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import scale, sim
from cmmpose.cli import main
from cmmpose.errors import SchedulerError

distributed = pytest.importorskip("distributed")
da = pytest.importorskip("dask.array")

MAPS = cmmpose.ErrorMapSet.thesis()
POSE = (90.0, 90.0, 0.0)
OFFSET = cmmpose.MountOffset.thesis()


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(processes=True, n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as c:
        yield c


def _columns(n, seed):
    rng = np.random.default_rng(seed)
    return {"u": rng.uniform(-20, 20, n), "v": rng.uniform(-10, 10, n), "D": rng.uniform(100, 800, n),
            "E": rng.uniform(50, 500, n), "F": rng.uniform(-450, -50, n), "T": rng.uniform(20.5, 29.5, n),
            "scan_id": (np.arange(n) // 100).astype(np.int32), "intensity": rng.integers(0, 255, n).astype(np.uint8)}


def _reference(cols, maps=MAPS, temperature=None):
    t = cols["T"] if temperature is None else temperature
    return cmmpose.compensate(np.column_stack([cols["u"], cols["v"]]), np.column_stack([cols["D"], cols["E"], cols["F"]]),
                              maps, POSE, OFFSET, t if isinstance(maps, cmmpose.ErrorMapSet) else None)


def _same_bits(a, b):
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three files of different sizes, several row groups each."""
    d = tmp_path_factory.mktemp("dataset")
    files = {}
    for i, n in enumerate((5000, 12345, 1)):
        cols = _columns(n, i)
        pq.write_table(pa.table(cols), d / f"scan_{i:03d}.parquet", row_group_size=3000)
        files[f"scan_{i:03d}.parquet"] = cols
    (d / "notes.txt").write_text("not a point file")
    return d, files


def _xyz(path):
    t = pq.read_table(path)
    return t, np.column_stack([t[c].to_numpy() for c in ("X", "Y", "Z")])


def test_dataset_on_worker_processes_equals_the_kernel(client, dataset, tmp_path):
    src, files = dataset
    seen = []
    result = scale.compensate_dataset(src, tmp_path / "out", MAPS, POSE, OFFSET, scheduler=client, batch_rows=2048,
                                      progress=lambda done, total: seen.append((done, total)))
    assert [p.name for p in result.outputs] == sorted(files)
    assert result.points == sum(len(c["u"]) for c in files.values()) == result.report.points
    assert seen[-1] == (result.points, result.points) and all(a <= b for a, b in seen)
    assert len(seen) > len(files)  # batch by batch, not only at the end
    for name, cols in files.items():
        table, xyz = _xyz(tmp_path / "out" / name)
        assert table.column_names == ["X", "Y", "Z", "scan_id", "intensity"]
        assert table.schema.field("intensity").type == pa.uint8()
        assert _same_bits(xyz, _reference(cols))
        assert np.array_equal(table["scan_id"].to_numpy(), cols["scan_id"])
        assert np.array_equal(table["intensity"].to_numpy(), cols["intensity"])
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(files)  # no temporary file left


def test_dataset_threads_and_fixed_temperature(dataset, tmp_path):
    src, files = dataset
    result = scale.compensate_dataset(src, tmp_path / "out", MAPS, POSE, OFFSET, temperature=23.5)
    assert result.points == sum(len(c["u"]) for c in files.values())
    for name, cols in files.items():
        assert _same_bits(_xyz(tmp_path / "out" / name)[1], _reference(cols, temperature=23.5))


def test_dataset_without_overwrite_refuses_before_work_and_never_replaces_a_file_made_meanwhile(dataset, tmp_path,
                                                                                                   monkeypatch):
    from cmmpose.errors import OutputError

    src, files = dataset
    out = tmp_path / "out"
    out.mkdir()
    (out / "scan_001.parquet").write_text("an earlier result")
    with pytest.raises(OutputError, match="scan_001.parquet: exists.*overwrite=True"):
        scale.compensate_dataset(src, out, MAPS, POSE, OFFSET, temperature=23.5, overwrite=False)
    assert sorted(p.name for p in out.iterdir()) == ["scan_001.parquet"]  # nothing done
    assert (out / "scan_001.parquet").read_text() == "an earlier result"
    # A file another writer makes while the work runs: created exclusively, it is not replaced.
    (out / "scan_001.parquet").unlink()
    real = scale.dataset._plan_file

    def plan_then_another_writer(path, *args):
        (out / "scan_002.parquet").write_text("another writer's")
        return real(path, *args)

    monkeypatch.setattr(scale.dataset, "_plan_file", plan_then_another_writer)
    with pytest.raises(OutputError):
        scale.compensate_dataset(src, out, MAPS, POSE, OFFSET, temperature=23.5, overwrite=False)
    assert (out / "scan_002.parquet").read_text() == "another writer's"
    monkeypatch.setattr(scale.dataset, "_plan_file", real)
    result = scale.compensate_dataset(src, out, MAPS, POSE, OFFSET, temperature=23.5)  # the default replaces
    assert [p.name for p in result.outputs] == sorted(files)
    assert _same_bits(_xyz(out / "scan_002.parquet")[1], _reference(files["scan_002.parquet"], temperature=23.5))


def test_dataset_errors_name_the_file_and_column(tmp_path, dataset):
    src, files = dataset
    bad = tmp_path / "bad"
    bad.mkdir()
    cols = _columns(10, 1)
    del cols["T"]
    pq.write_table(pa.table(cols), bad / "a.parquet")
    with pytest.raises(cmmpose.InputError, match=r"a\.parquet: missing column 'T'"):
        scale.compensate_dataset(bad, tmp_path / "o", MAPS, POSE, OFFSET)
    cols["u"] = np.array(["x"] * 10)
    pq.write_table(pa.table(cols), bad / "a.parquet")
    with pytest.raises(cmmpose.InputError, match=r"a\.parquet: column 'u' has type string"):
        scale.compensate_dataset(bad, tmp_path / "o", MAPS, POSE, OFFSET, temperature=22.0)
    (bad / "a.parquet").write_bytes(b"PAR1 nonsense")
    with pytest.raises(cmmpose.InputError, match=r"a\.parquet: not a readable Parquet file"):
        scale.compensate_dataset(bad, tmp_path / "o", MAPS, POSE, OFFSET, temperature=22.0)
    (tmp_path / "o2").mkdir()
    with pytest.raises(cmmpose.InputError, match=r"o2: no Parquet files \(\.parquet, \.pq\)"):
        scale.compensate_dataset(tmp_path / "o2", tmp_path / "o", MAPS, POSE, OFFSET)
    with pytest.raises(cmmpose.InputError, match="the output folder is the input folder"):
        scale.compensate_dataset(src, src, MAPS, POSE, OFFSET)


def test_a_bad_row_names_the_file_and_rows_and_leaves_no_partial_output(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    cols = _columns(5000, 3)
    cols["D"][4100] = np.nan
    pq.write_table(pa.table(cols), src / "b.parquet")
    with pytest.raises(cmmpose.InputError, match=r"b\.parquet: rows 4096\.\.4999.*row"):
        scale.compensate_dataset(src, tmp_path / "out", MAPS, POSE, OFFSET, batch_rows=2048)
    assert list((tmp_path / "out").iterdir()) == []


def test_dask_array_and_dataframe_on_worker_processes(client):
    cols = _columns(20000, 7)
    ref = _reference(cols)
    points = da.from_array(np.column_stack([cols[c] for c in ("u", "v", "D", "E", "F", "T")]), chunks=(3000, 3))
    lazy = scale.compensate_array(points, MAPS, POSE, OFFSET)
    graph = dict(lazy.__dask_graph__())
    shared = [k for k in graph if str(k if isinstance(k, str) else k[0]).startswith("Compensator-")]
    assert len(shared) == 1  # the maps are one key, which every block depends on
    assert _same_bits(client.compute(lazy).result(), ref)

    dd = pytest.importorskip("dask.dataframe")
    pd = pytest.importorskip("pandas")
    frame = dd.from_pandas(pd.DataFrame(cols), npartitions=5)
    out = client.compute(scale.compensate_dataframe(frame, MAPS, POSE, OFFSET)).result()
    assert list(out.columns) == ["X", "Y", "Z", "scan_id", "intensity"]
    assert _same_bits(out[["X", "Y", "Z"]].to_numpy(), ref)
    with pytest.raises(cmmpose.InputError, match="missing column 'T'"):
        scale.compensate_dataframe(frame.drop(columns="T"), MAPS, POSE, OFFSET)


def test_scheduler_specs_and_the_missing_extra(monkeypatch):
    with pytest.raises(SchedulerError, match="'threads', 'processes' or an address.*'gpu'"):
        with scale.scheduler_client("gpu"):
            pass
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(SchedulerError, match=r"pip install 'cmmpose\[dask\]'"):
        with scale.scheduler_client("threads"):
            pass


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    dirs = []
    for i, t in enumerate((21.0, 23.0, 25.5)):
        run, truth = sim.simulate_ballbar_run(MAPS, t, layout="crossed", scanner=sim.Scanner(points_per_profile=48),
                                              seed=10 + i)
        run.save(d / f"run{i}", truth)
        dirs.append(d / f"run{i}")
    return dirs


def test_fleet_evaluation_on_worker_processes_equals_one_by_one(client, runs):
    evs = scale.evaluate_runs(runs, scheduler=client)
    evs_map = scale.evaluate_runs(runs, MAPS, scheduler=client, expansion_ppm_per_K=11.5)
    for r, ev, ev_map in zip(runs, evs, evs_map):
        one = cmmpose.evaluate(cmmpose.Run.load(r), MAPS)
        assert _same_bits(ev.compensated.lengths, one.compensated.lengths)
        assert _same_bits(ev.uncompensated.lengths, one.uncompensated.lengths)
        assert _same_bits(ev_map.compensated.lengths, one.compensated.lengths)
        assert ev_map.uncompensated.expansion == 11.5e-6
    rows = scale.fleet_summary(runs, evs)
    assert [r.temperature for r in rows] == pytest.approx([21.0, 23.0, 25.5], abs=0.1)
    assert all(r.rms_compensated < r.rms_uncompensated for r in rows)
    assert rows[0].created == cmmpose.Run.load(runs[0]).created


def test_fleet_diagnosis_on_worker_processes(client, runs):
    diags = scale.diagnose_runs(runs[:2], scheduler=client, auto=False, patterns=False)
    for r, d in zip(runs, diags):
        one = cmmpose.diagnose(cmmpose.Run.load(r), auto=False, patterns=False)
        assert d.steps[0].figures.rms_accuracy_error == one.steps[0].figures.rms_accuracy_error
        assert _same_bits(d.steps[0].figures.lengths, one.steps[0].figures.lengths)
        assert [c.spec.name for c in d.steps[0].ranking] == [c.spec.name for c in one.steps[0].ranking]


def test_a_fleet_error_names_the_run(client, runs, tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(cmmpose.RunError, match="empty"):
        scale.evaluate_runs([runs[0], tmp_path / "empty"], scheduler=client)


def test_cli_dataset_on_an_address_equals_threads(client, dataset, tmp_path):
    src, files = dataset
    runner = CliRunner()
    a = runner.invoke(main, ["compensate", str(src), str(tmp_path / "a"), "--maps", "thesis", "--pose", "90,90,0",
                             "--scheduler", client.scheduler.address])
    assert a.exit_code == 0, a.output
    assert "17,346" in a.output and "files" in a.output
    b = runner.invoke(main, ["compensate", str(src), str(tmp_path / "b"), "--maps", "thesis", "--pose", "90,90,0"])
    assert b.exit_code == 0, b.output
    for name, cols in files.items():
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
        assert _same_bits(_xyz(tmp_path / "a" / name)[1], _reference(cols))
    c = runner.invoke(main, ["compensate", str(src / "scan_000.parquet"), str(tmp_path / "c.parquet"),
                             "--scheduler", "processes"])
    assert c.exit_code != 0 and "--scheduler is for a folder" in c.output
    d = runner.invoke(main, ["compensate", str(src), str(tmp_path / "d"), "--maps", "appendix-b", "--pose", "90,90,0",
                             "--scheduler", "processes"])  # a local cluster of its own, one kernel thread per worker
    assert d.exit_code == 0, d.output
    lo = min(float(c["T"].min()) for c in files.values())
    assert f"a single map at 22 C was used for points at {lo:.2f}.." in d.output.replace("\n", " ")
    for name, cols in files.items():
        assert _same_bits(_xyz(tmp_path / "d" / name)[1], _reference(cols, cmmpose.ErrorMap.appendix_b()))


def test_cli_evaluate_fleet(client, runs, tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["evaluate", *map(str, runs), "--scheduler", client.scheduler.address,
                               "--report", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert "3 runs" in res.output and "run2" in res.output
    summary = (tmp_path / "rep" / "summary.csv").read_text().splitlines()
    assert summary[0].startswith("run,created,temperature,rms_uncompensated") and len(summary) == 4
    assert (tmp_path / "rep" / "trend.png").stat().st_size > 0
    assert (tmp_path / "rep" / "run1" / "evaluation.json").is_file()
    res = runner.invoke(main, ["evaluate", *map(str, runs[:2]), "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.output[res.output.index("["):])
    assert [r["run"] for r in rows] == [str(r) for r in runs[:2]]
    # The table across runs has no uncertainties: their options are refused, not ignored.
    res = runner.invoke(main, ["evaluate", *map(str, runs[:2]), "--u-temperature", "0.3"])
    assert res.exit_code == 2 and "--u-temperature takes one run" in res.output


def test_cli_diagnose_fleet(client, runs, tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["diagnose", *map(str, runs[:2]), "--scheduler", client.scheduler.address,
                               "--no-auto", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert list(doc) == [str(r) for r in runs[:2]]
    one = cmmpose.diagnose(cmmpose.Run.load(runs[1]), auto=False)
    assert doc[str(runs[1])]["steps"][0]["rms_accuracy_error_um"] == pytest.approx(
        one.steps[0].figures.rms_accuracy_error * 1e3, rel=1e-12)
    res = runner.invoke(main, ["diagnose", *map(str, runs[:2]), "--max-effects", "1"])
    assert res.exit_code == 0 and "diagnosis of 2 runs" in res.output, res.output
    res = runner.invoke(main, ["diagnose", *map(str, runs[:2]), "--report", str(tmp_path / "r")])
    assert res.exit_code != 0 and "--report takes one run" in res.output


def test_fleet_diagnosis_keeps_the_temperature_and_policy(runs):
    (d,) = scale.diagnose_runs(runs[:1], auto=False, patterns=False, temperature=22.0, temperature_tolerance=1.5)
    assert d.steps[0].model.temperature == 22.0 and d.steps[0].model.temperature_tolerance == 1.5
    res = CliRunner().invoke(main, ["diagnose", *map(str, runs[:2]), "--maps", "none"])
    assert res.exit_code != 0 and "'none' is not a model" in res.output


def test_a_single_map_on_a_dataset_is_said_by_the_library(dataset, tmp_path):
    # Issue 26: the choice of the map-set temperature (and the note when one map meets other temperatures) lives in
    # compensate_dataset, not in the command line: the T columns' range is read from the files' statistics.
    src, files = dataset
    with pytest.warns(cmmpose.MapTemperatureWarning, match="a single map at 22 C was used for points at"):
        scale.compensate_dataset(src, tmp_path / "out", cmmpose.ErrorMap.appendix_b(), (90.0, 90.0, 0.0),
                                 cmmpose.MountOffset.thesis(), scheduler="threads")


def test_dataset_files_take_every_parquet_suffix_in_any_case_and_name_the_rest(tmp_path, caplog):
    # B.PARQUET and c.pq were skipped in silence (only "*.parquet" was taken): their points never compensated.
    folder = tmp_path / "in"
    folder.mkdir()
    t = pa.table({"u": [0.0], "v": [0.0], "D": [400.0], "E": [300.0], "F": [-200.0]})
    for name in ("a.parquet", "B.PARQUET", "c.pq"):
        pq.write_table(t, folder / name)
    for name in ("notes.txt", "_SUCCESS", ".hidden"):
        (folder / name).write_text("x")
    with caplog.at_level("WARNING", logger="cmmpose"):
        files = scale.dataset_files(folder)
    assert [p.name for p in files] == ["B.PARQUET", "a.parquet", "c.pq"]
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "notes.txt" in said and "not compensated" in said and "_SUCCESS" not in said and ".hidden" not in said
    res = CliRunner().invoke(main, ["compensate", str(folder), str(tmp_path / "out"), "--temperature", "22"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["B.PARQUET", "a.parquet", "c.pq"]
