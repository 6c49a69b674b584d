"""The measurement run format (cmmpose.run, docs/formats.md "Measurement run"):
exact save/load round trip, truth kept out of Run.load, CSV fallback, and one
test per malformed case, each raising RunError with a message naming the
file or table, column and row."""

import builtins
import io
import json
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from cmmpose.errors import Error
from cmmpose.run import CHANNEL_ROLES, POINTS_COLUMNS, POSES_COLUMNS, SCANS_COLUMNS, Run, RunError, load_truth

CHANNELS = [
    {"name": "X1", "role": "x_scale"},
    {"name": "Y1", "role": "y_scale"},
    {"name": "air 1", "role": "air", "location": "above table"},
    {"name": "G_top", "role": "granite_top"},
]


def make_run(n_points=10_000, n_scans=6, n_poses=3, channels=CHANNELS, seed=0, grouped=False):
    """A random, valid run; t in s, lengths in mm, angles in degrees, temperatures in C."""
    rng = np.random.default_rng(seed)
    pose_ids = rng.permutation(np.arange(100, 100 + n_poses)).astype(np.int32)
    poses = {
        "pose_id": pose_ids,
        "alpha": rng.uniform(-180, 180, n_poses),
        "beta": rng.uniform(0, 180, n_poses),
        "gamma": rng.uniform(-180, 180, n_poses),
        "U1": rng.normal(0, 5, n_poses),
        "V1": rng.normal(260, 5, n_poses),
        "W1": rng.normal(130, 5, n_poses),
    }
    scan_ids = rng.permutation(np.arange(n_scans)).astype(np.int32) * 3 + 7
    scans = {
        "scan_id": scan_ids,
        "pose_id": pose_ids[np.arange(n_scans) % n_poses],
        "feature": np.array(["ball", "ball", "plane"] * n_scans)[:n_scans].astype(object),
        "position": rng.integers(1, 21, n_scans).astype(np.int32),
        "ball": np.array([1, 2, -1] * n_scans, dtype=np.int32)[:n_scans],
        "sweep_axis": np.array(["X", "Y", "Z"] * n_scans, dtype=object)[:n_scans],
        "sweep_direction": np.array([1, -1] * n_scans, dtype=np.int8)[:n_scans],
        "sweep_speed": rng.uniform(1, 50, n_scans),
    }
    sid = np.sort(rng.choice(scan_ids, n_points)) if grouped else rng.choice(scan_ids, n_points)
    t = np.sort(rng.uniform(0, 600, n_points))
    t[5:9] = t[5]  # equal times are allowed
    points = {
        "scan_id": sid.astype(np.int32),
        "t": t,
        "u": rng.uniform(-40, 40, n_points),
        "v": rng.uniform(100, 180, n_points),
        "D": rng.uniform(0, 900, n_points),
        "E": rng.uniform(0, 550, n_points),
        "F": rng.uniform(-500, 0, n_points),
    }
    points["u"][3] = -0.0  # bitwise exactness includes the sign of zero
    temperatures = None
    if channels:
        m = 61
        temperatures = {"t": np.linspace(0.0, 600.0, m)}
        for k, ch in enumerate(channels):
            temperatures[ch["name"]] = 20.0 + k * 0.1 + rng.normal(0, 0.05, m)
    return Run(
        points=points,
        scans=scans,
        poses=poses,
        temperatures=temperatures,
        temperature_channels=list(channels),
        artefact={"kind": "ballbar", "radius_mm": 38.125, "length_mm": 404.2},
        maps={"kind": "bundled", "name": "thesis"},
        metadata={"operator": "simulator", "seed": seed, "notes": ["a", 1.5, None, True], "nested": {"x": -0.0}},
        created="2025-01-31T12:00:00Z",
    )


def truth_of(run):
    rng = np.random.default_rng(1)
    arrays = {
        "xyz_true": rng.normal(size=(run.n_points, 3)),
        "ball_centres": rng.normal(size=(6, 3)).astype(np.float32),
        "flags": rng.integers(0, 2, 17).astype(bool),
        "labels": np.array(["a", "bc"]),
        "scalar": np.array(3.5),
    }
    return arrays, {"model": "rigid", "sigma_um": 0.5, "list": [1, 2, 3]}


def assert_bitwise_equal(a, b):
    assert a.keys() == b.keys()
    for c in a:
        assert a[c].dtype == b[c].dtype, c
        assert a[c].shape == b[c].shape, c
        if a[c].dtype == object:
            assert list(a[c]) == list(b[c]), c
            assert all(type(x) is str for x in b[c]), c
        else:
            assert a[c].tobytes() == b[c].tobytes(), c


@pytest.fixture(scope="module")
def big():
    return make_run()


@pytest.fixture(scope="module")
def small():
    return make_run(n_points=40, n_scans=3, n_poses=2, channels=CHANNELS[:2], seed=3)


@pytest.fixture
def saved(small, tmp_path):
    """A valid small run directory, for the malformed-file tests to damage."""
    d = tmp_path / "run"
    small.save(d)
    return d


def read_table(path):
    return {c: col.to_numpy(zero_copy_only=False) for c, col in zip(pq.read_table(path).column_names, pq.read_table(path).columns)}


def write_table(path, cols):
    pq.write_table(pa.table(cols), path)


def edit_table(run_dir, name, fn):
    """Rewrite ``name``.parquet with ``fn(columns)`` applied (fn edits in place or returns new columns)."""
    path = run_dir / f"{name}.parquet"
    cols = {c: np.array(a, copy=True) for c, a in read_table(path).items()}
    out = fn(cols)
    write_table(path, cols if out is None else out)


def edit_json(run_dir, fn):
    path = run_dir / "run.json"
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def load_error(run_dir, *fragments):
    with pytest.raises(RunError) as info:
        Run.load(run_dir)
    msg = str(info.value)
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"
    return msg


# -- round trip ----------------------------------------------------------------------
def test_round_trip_is_exact(big, tmp_path):
    assert big.n_points == 10_000 and len(big.scans["scan_id"]) == 6 and len(big.poses["pose_id"]) == 3
    arrays, info = truth_of(big)
    big.save(tmp_path / "r", truth=(arrays, info))
    back = Run.load(tmp_path / "r")
    assert back == big
    for table in ("points", "scans", "poses", "temperatures"):
        assert_bitwise_equal(getattr(big, table), getattr(back, table))
    assert back.temperature_channels == CHANNELS
    assert back.artefact == big.artefact and back.maps == big.maps and back.metadata == big.metadata
    assert back.created == "2025-01-31T12:00:00Z"
    assert np.signbit(back.points["u"][3]) and np.signbit(back.metadata["nested"]["x"])
    assert [str(a.dtype) for a in back.points.values()] == list(POINTS_COLUMNS.values())
    t_arrays, t_info = load_truth(tmp_path / "r")
    assert_bitwise_equal(arrays, t_arrays)
    assert t_info == info
    # and a second round trip of the loaded run is equal as well
    back.save(tmp_path / "r2")
    assert Run.load(tmp_path / "r2") == big


def test_round_trip_without_temperatures(tmp_path):
    run = make_run(n_points=50, channels=[])
    assert run.temperatures is None
    run.save(tmp_path / "r")
    assert not (tmp_path / "r" / "temperatures.parquet").exists()
    back = Run.load(tmp_path / "r")
    assert back == run and back.temperatures is None and back.temperature_channels == []


def test_equality_is_bitwise(small):
    pts = dict(small.points)
    u = pts["u"].copy()
    u[0] = np.nextafter(u[0], np.inf)
    pts["u"] = u
    other = Run(pts, small.scans, small.poses, small.temperatures, small.temperature_channels, small.artefact, small.maps, small.metadata, small.created)
    assert other != small
    same = Run(small.points, small.scans, small.poses, small.temperatures, small.temperature_channels, small.artefact, small.maps, small.metadata, small.created)
    assert same == small


def test_load_never_opens_truth(big, tmp_path, monkeypatch):
    d = tmp_path / "r"
    big.save(d, truth=truth_of(big))
    (d / "truth" / "truth.npz").write_bytes(b"not a zip file at all")
    (d / "truth" / "truth.json").write_text("{broken")
    opened = []
    real_open, real_load = io.open, np.load

    def spy_open(file, *args, **kwargs):
        opened.append(str(file))
        return real_open(file, *args, **kwargs)

    def spy_load(file, *args, **kwargs):
        opened.append(str(file))
        return real_load(file, *args, **kwargs)

    real_os_open = os.open

    def spy_os_open(file, *args, **kwargs):  # the one door in (cmmpose.errors.read_input) opens by descriptor
        opened.append(str(file))
        return real_os_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", spy_open)
    monkeypatch.setattr(io, "open", spy_open)
    monkeypatch.setattr(os, "open", spy_os_open)
    monkeypatch.setattr(np, "load", spy_load)
    back = Run.load(d)
    monkeypatch.undo()
    assert back == big
    assert any(p.endswith("run.json") for p in opened)
    assert not [p for p in opened if p.startswith(str(d / "truth"))]
    with pytest.raises(RunError, match=r"truth\.npz: not a readable \.npz file"):
        load_truth(d)


def test_load_truth_errors(small, tmp_path):
    small.save(tmp_path / "r")
    with pytest.raises(RunError, match=r"truth: missing \(the run has no truth\)"):
        load_truth(tmp_path / "r")
    small.save(tmp_path / "t", truth=({"a": np.arange(3)}, {}))
    (tmp_path / "t" / "truth" / "truth.json").write_text("[1, 2")
    with pytest.raises(RunError, match=r"truth\.json: not readable JSON"):
        load_truth(tmp_path / "t")
    (tmp_path / "t" / "truth" / "truth.json").unlink()
    with pytest.raises(RunError, match=r"truth\.json: missing"):
        load_truth(tmp_path / "t")


def test_truth_arguments_are_checked(small, tmp_path):
    with pytest.raises(RunError, match="expected a tuple"):
        small.save(tmp_path / "a", truth={"a": np.zeros(3)})
    with pytest.raises(RunError, match="dtype object"):
        small.save(tmp_path / "b", truth=({"a": np.array([1, None], dtype=object)}, {}))
    with pytest.raises(RunError, match="truth: info"):
        small.save(tmp_path / "c", truth=({"a": np.zeros(3)}, {"x": (1, 2)}))
    # names that would collide with np.savez keywords are fine
    small.save(tmp_path / "d", truth=({"file": np.zeros(2), "allow_pickle": np.ones(2)}, {}))
    arrays, _ = load_truth(tmp_path / "d")
    assert set(arrays) == {"file", "allow_pickle"}


# -- saving -----------------------------------------------------------------------------
def test_save_refuses_non_empty_directory_and_overwrite_replaces_run(big, small, tmp_path):
    d = tmp_path / "r"
    big.save(d, truth=truth_of(big))
    (d / "notes.txt").write_text("keep me")
    with pytest.raises(RunError, match="not empty.*overwrite=True"):
        small.save(d)
    no_temps = make_run(n_points=30, channels=[])
    no_temps.save(d, overwrite=True)
    assert Run.load(d) == no_temps
    assert not (d / "temperatures.parquet").exists() and not (d / "truth").exists()
    assert (d / "notes.txt").read_text() == "keep me"


def test_save_into_a_file_path(small, tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(RunError, match="not a directory"):
        small.save(tmp_path / "f")


def test_save_creates_parents_and_empty_directory_is_fine(small, tmp_path):
    (tmp_path / "empty").mkdir()
    small.save(tmp_path / "empty")
    small.save(tmp_path / "a" / "b" / "c")
    assert Run.load(tmp_path / "a" / "b" / "c") == small


def test_run_json_layout(small, tmp_path):
    small.save(tmp_path / "r")
    doc = json.loads((tmp_path / "r" / "run.json").read_text())
    assert list(doc) == ["schema", "schema_version", "created", "artefact", "maps", "temperature_channels", "metadata",
                         "rows"]
    assert doc["rows"] == {"points": 40, "scans": 3, "poses": 2, "temperatures": 61}  # checked on load
    assert doc["schema"] == "cmmpose-run" and doc["schema_version"] == 1
    schema = pq.read_schema(tmp_path / "r" / "scans.parquet")
    assert [str(schema.field(c).type) for c in SCANS_COLUMNS] == ["int32", "int32", "string", "int32", "int32", "string", "int8", "double"]


# -- the object ----------------------------------------------------------------------------
def test_constructor_copies_and_never_modifies_inputs():
    run = make_run(n_points=100, n_scans=3, n_poses=2)
    pts = {c: np.array(a) for c, a in run.points.items()}
    pts["scan_id"] = pts["scan_id"].astype(np.int64)  # converted
    pts["u"] = list(pts["u"])  # lists are fine
    before = {c: np.array(a, copy=True) for c, a in pts.items()}
    r = Run(pts, run.scans, run.poses, run.temperatures, run.temperature_channels)
    for c in pts:
        assert np.array_equal(np.asarray(pts[c]), before[c])
    assert pts["scan_id"].dtype == np.int64
    assert r.points["scan_id"].dtype == np.int32
    pts["t"][:] = -1.0
    assert r.points["t"][0] >= 0
    assert not r.points["t"].flags.writeable and not r.uv.flags.writeable
    with pytest.raises(ValueError):
        r.points["D"][0] = 1.0
    with pytest.raises(AttributeError):
        r.created = "x"
    meta = {"a": [1, 2]}
    r2 = Run(run.points, run.scans, run.poses, run.temperatures, run.temperature_channels, metadata=meta)
    meta["a"].append(3)
    assert r2.metadata == {"a": [1, 2]}


def test_string_columns_accept_str_arrays(small):
    scans = dict(small.scans)
    scans["feature"] = np.array(["ball", "ball", "plane"])  # <U5
    r = Run(small.points, scans, small.poses, small.temperatures, small.temperature_channels)
    assert r.scans["feature"].dtype == object and list(r.scans["feature"]) == ["ball", "ball", "plane"]


def test_created_defaults_to_now_utc():
    run = make_run(n_points=10, channels=[])
    fresh = Run(run.points, run.scans, run.poses)
    assert fresh.created.endswith("Z") and fresh.created[:2] == "20"


def test_uv_scales_cached_contiguous(big):
    uv, sc = big.uv, big.scales
    assert uv is big.uv and sc is big.scales
    assert uv.shape == (big.n_points, 2) and sc.shape == (big.n_points, 3)
    assert uv.dtype == np.float64 and sc.dtype == np.float64
    assert uv.flags.c_contiguous and sc.flags.c_contiguous
    assert np.array_equal(uv, np.column_stack([big.points["u"], big.points["v"]]))
    assert np.array_equal(sc, np.column_stack([big.points["D"], big.points["E"], big.points["F"]]))


@pytest.mark.parametrize("grouped", [False, True])
def test_scan_points(grouped):
    run = make_run(n_points=2000, grouped=grouped)
    total = 0
    for sid in run.scans["scan_id"]:
        got = run.scan_points(int(sid))
        mask = run.points["scan_id"] == sid
        assert got.keys() == run.points.keys()
        for c in got:
            assert np.array_equal(got[c], run.points[c][mask])
            assert not got[c].flags.writeable
        if grouped:  # contiguous scans: views of the points themselves
            assert np.shares_memory(got["u"], run.points["u"])
        total += len(got["t"])
    assert total == run.n_points
    a, b = run.scan_points(np.int32(run.scans["scan_id"][0])), run.scan_points(run.scans["scan_id"][0])
    assert np.shares_memory(a["t"], b["t"])  # views of one index computed once
    with pytest.raises(RunError, match="scan 999 is not in scans"):
        run.scan_points(999)


def test_scan_without_points_is_empty(small):
    pts = {c: a[small.points["scan_id"] != small.scans["scan_id"][0]] for c, a in small.points.items()}
    r = Run(pts, small.scans, small.poses, small.temperatures, small.temperature_channels)
    got = r.scan_points(int(small.scans["scan_id"][0]))
    assert all(len(a) == 0 for a in got.values())


def test_pose(big):
    for r, pid in enumerate(big.poses["pose_id"]):
        angles, offset = big.pose(int(pid))
        assert angles == tuple(float(big.poses[c][r]) for c in ("alpha", "beta", "gamma"))
        assert offset == tuple(float(big.poses[c][r]) for c in ("U1", "V1", "W1"))
    with pytest.raises(RunError, match="pose 5 is not in poses"):
        big.pose(5)


def test_run_error_is_a_cmmpose_error():
    assert issubclass(RunError, Error)


# -- CSV fallback --------------------------------------------------------------------------
def to_csv(run_dir, name):
    """Replace ``name``.parquet by ``name``.csv (17 significant digits: exact)."""
    path = run_dir / f"{name}.parquet"
    cols = read_table(path)
    lines = [",".join(cols)]
    n = len(next(iter(cols.values())))
    text = {c: [repr(float(x)) if a.dtype.kind == "f" else str(x) for x in a] for c, a in cols.items()}
    lines += [",".join(text[c][i] for c in cols) for i in range(n)]
    (run_dir / f"{name}.csv").write_text("\n".join(lines) + "\n")
    path.unlink()


def test_csv_fallback(big, tmp_path):
    d = tmp_path / "r"
    big.save(d)
    for name in ("points", "scans", "poses", "temperatures"):
        to_csv(d, name)
    assert not list(d.glob("*.parquet"))
    assert Run.load(d) == big


def test_csv_column_order_and_parquet_preferred(small, tmp_path):
    d = tmp_path / "r"
    small.save(d)
    to_csv(d, "poses")
    cols = (d / "poses.csv").read_text().splitlines()
    # reorder columns: W1 first
    rows = [line.split(",") for line in cols]
    (d / "poses.csv").write_text("\n".join(",".join([r[-1]] + r[:-1]) for r in rows) + "\n")
    assert Run.load(d) == small
    # with both present, the .parquet file wins (a broken CSV is never read)
    small.save(tmp_path / "s")
    (tmp_path / "s" / "poses.csv").write_text("garbage\n")
    assert Run.load(tmp_path / "s") == small


def test_csv_errors_name_line(saved):
    to_csv(saved, "points")
    lines = (saved / "points.csv").read_text().splitlines()
    fields = lines[3].split(",")
    fields[2] = "abc"  # u of data row 2
    lines[3] = ",".join(fields)
    (saved / "points.csv").write_text("\n".join(lines) + "\n")
    load_error(saved, "points.csv", "column 'u'", "'abc' at row 2 (line 4) is not a number")
    fields[2] = ""
    lines[3] = ",".join(fields)
    (saved / "points.csv").write_text("\n".join(lines) + "\n")
    load_error(saved, "points.csv", "column 'u'", "empty value at row 2 (line 4)")
    fields[2] = "nan"
    lines[3] = ",".join(fields)
    (saved / "points.csv").write_text("\n".join(lines) + "\n")
    load_error(saved, "points.csv", "column 'u'", "nan at row 2 (line 4); values must be finite")


def test_csv_integer_column_with_text(saved):
    to_csv(saved, "scans")
    text = (saved / "scans.csv").read_text().splitlines()
    f = text[2].split(",")
    f[3] = "1.5x"  # position of data row 1
    text[2] = ",".join(f)
    (saved / "scans.csv").write_text("\n".join(text) + "\n")
    load_error(saved, "scans.csv", "column 'position'", "'1.5x' at row 1 (line 3) is not an integer")


# -- malformed directories and run.json -------------------------------------------------------
def test_missing_directory(tmp_path):
    load_error(tmp_path / "nope", "nope: no such run directory")


def test_directory_is_a_file(tmp_path):
    (tmp_path / "f").write_text("")
    load_error(tmp_path / "f", "f: not a directory")


def test_missing_run_json(saved):
    (saved / "run.json").unlink()
    load_error(saved, "run.json: missing")


def test_invalid_json(saved):
    (saved / "run.json").write_text('{"schema": "cmmpose-run",\n  "schema_version": 1,,}')
    load_error(saved, "run.json:2:", "invalid JSON")


def test_json_not_an_object(saved):
    (saved / "run.json").write_text("[1, 2]")
    load_error(saved, "run.json: expected a JSON object, got list")


def test_json_nan_refused(saved):
    edit_json(saved, lambda d: d["metadata"].update(x=float("nan")))
    load_error(saved, "run.json: invalid JSON", "NaN is not allowed")


def test_wrong_schema_name(saved):
    edit_json(saved, lambda d: d.update(schema="cmmpose-map"))
    load_error(saved, "run.json: 'schema' is 'cmmpose-map', expected 'cmmpose-run'")


@pytest.mark.parametrize("version", [2, 0, "1", None, True])
def test_unknown_schema_version(saved, version):
    edit_json(saved, lambda d: d.update(schema_version=version))
    load_error(saved, f"unsupported schema_version {version!r}", "reads version 1")


def test_unknown_json_key(saved):
    edit_json(saved, lambda d: d.update(temperature_channel=[]))
    load_error(saved, "run.json: unknown key 'temperature_channel'")


def test_missing_created(saved):
    edit_json(saved, lambda d: d.pop("created"))
    load_error(saved, "run.json: missing key 'created'")


@pytest.mark.parametrize("created, fragment", [("yesterday", "not an ISO-8601 time"), ("2025-01-31T12:00:00", "not UTC"), ("2025-01-31T12:00:00+02:00", "not UTC")])
def test_bad_created(saved, created, fragment):
    edit_json(saved, lambda d: d.update(created=created))
    load_error(saved, "run.json: created:", fragment)


def test_optional_json_keys_default_empty(saved, small):
    edit_json(saved, lambda d: [d.pop(k) for k in ("artefact", "maps", "metadata")])
    run = Run.load(saved)
    assert run.artefact == {} and run.maps == {} and run.metadata == {}


def test_artefact_not_a_dict(saved):
    edit_json(saved, lambda d: d.update(artefact=[1]))
    load_error(saved, "run.json: artefact: expected a dict")


def test_unknown_channel_role(saved):
    edit_json(saved, lambda d: d["temperature_channels"][1].update(role="y_scales"))
    load_error(saved, "run.json: temperature_channels[1]: unknown role 'y_scales' of channel 'Y1'", "x_scale, y_scale")


@pytest.mark.parametrize(
    "channel, fragment",
    [({"role": "air"}, "'name' must be a non-empty string"), ({"name": "X9"}, "has no 'role'"), ({"name": "X1", "role": "air"}, "duplicate channel name 'X1'"), ({"name": "t", "role": "air"}, "may not be named 't'"), ("X9", "expected an object")],
)
def test_bad_channel_entries(saved, channel, fragment):
    edit_json(saved, lambda d: d["temperature_channels"].append(channel))
    load_error(saved, "temperature_channels[2]", fragment)


def test_all_roles_accepted():
    chans = [{"name": f"c{k}", "role": r} for k, r in enumerate(CHANNEL_ROLES)]
    run = make_run(n_points=20, channels=chans)
    assert [c["role"] for c in run.temperature_channels] == list(CHANNEL_ROLES)


# -- malformed tables ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["points", "scans", "poses"])
def test_missing_table_file(saved, name):
    (saved / f"{name}.parquet").unlink()
    load_error(saved, f"missing {name}.parquet (or {name}.csv)")


def test_missing_temperatures_file_with_channels(saved):
    (saved / "temperatures.parquet").unlink()
    load_error(saved, "missing temperatures.parquet (or temperatures.csv) (run.json lists temperature channels)")


def test_corrupt_parquet(saved):
    (saved / "poses.parquet").write_bytes(b"PAR1 but not really")
    load_error(saved, "poses.parquet: not a readable Parquet file")


@pytest.mark.parametrize("name, column", [("points", "F"), ("points", "scan_id"), ("scans", "sweep_speed"), ("poses", "W1"), ("temperatures", "t")])
def test_missing_column(saved, name, column):
    edit_table(saved, name, lambda c: {k: v for k, v in c.items() if k != column})
    load_error(saved, f"{name}.parquet: missing column {column!r}")


def test_unexpected_column(saved):
    edit_table(saved, "points", lambda c: c.update(intensity=np.zeros(len(c["u"]))))
    load_error(saved, "points.parquet: unexpected column 'intensity'")


def test_channel_column_missing_from_temperatures(saved):
    edit_table(saved, "temperatures", lambda c: {k: v for k, v in c.items() if k != "Y1"})
    load_error(saved, "temperatures.parquet: missing column 'Y1' (a channel listed in", "run.json: temperature_channels)")


def test_temperature_column_not_declared(saved):
    edit_table(saved, "temperatures", lambda c: c.update(Z1=c["X1"]))
    load_error(saved, "temperatures.parquet: unexpected column 'Z1'")


def test_wrong_dtype_strings_for_numbers(saved):
    edit_table(saved, "points", lambda c: c.update(v=np.array([f"{x:.3f}" for x in c["v"]])))
    load_error(saved, "points.parquet: column 'v': has type string, expected float64")


def test_wrong_dtype_numbers_for_strings(saved):
    edit_table(saved, "scans", lambda c: c.update(feature=np.arange(len(c["feature"]))))
    load_error(saved, "scans.parquet: column 'feature': has type int64, expected strings")


def test_wrong_dtype_bool(saved):
    edit_table(saved, "poses", lambda c: c.update(alpha=np.array([True, False])))
    load_error(saved, "poses.parquet: column 'alpha': has type bool, expected float64")


def test_non_integral_float_in_int_column(saved):
    edit_table(saved, "scans", lambda c: c.update(position=np.array([1.0, 2.5, 3.0])))
    load_error(saved, "scans.parquet: column 'position': 2.5 at row 1 is not an integer that fits in int32")


def test_int_out_of_range(saved):
    edit_table(saved, "scans", lambda c: c.update(ball=np.array([1, 2, 2**31], dtype=np.int64)))
    load_error(saved, "scans.parquet: column 'ball': 2147483648 at row 2 does not fit in int32")


def test_convertible_dtypes_are_converted(saved, small):
    edit_table(saved, "scans", lambda c: c.update(scan_id=c["scan_id"].astype(np.int64), position=c["position"].astype(np.float64), sweep_direction=c["sweep_direction"].astype(np.int32)))
    edit_table(saved, "poses", lambda c: c.update(alpha=c["alpha"].astype(np.float32)))
    run = Run.load(saved)
    assert run.scans["scan_id"].dtype == np.int32 and run.scans["sweep_direction"].dtype == np.int8
    assert_bitwise_equal(run.scans, small.scans)
    assert run.poses["alpha"].dtype == np.float64
    assert np.array_equal(run.poses["alpha"], small.poses["alpha"].astype(np.float32).astype(np.float64))


def test_int_column_into_float(saved, small):
    edit_table(saved, "poses", lambda c: c.update(alpha=np.array([90, -45], dtype=np.int64)))
    run = Run.load(saved)
    assert run.poses["alpha"].dtype == np.float64 and list(run.poses["alpha"]) == [90.0, -45.0]


@pytest.mark.parametrize("value, text", [(np.nan, "nan"), (np.inf, "inf"), (-np.inf, "-inf")])
def test_non_finite(saved, value, text):
    def damage(c):
        c["E"][7] = value
        c["E"][9] = value

    edit_table(saved, "points", damage)
    load_error(saved, "points.parquet: column 'E':", f"{text} at row 7; values must be finite")


def test_non_finite_temperature(saved):
    edit_table(saved, "temperatures", lambda c: c["X1"].__setitem__(4, np.nan))
    load_error(saved, "temperatures.parquet: column 'X1': nan at row 4")


def test_null_value(saved):
    def damage(c):
        u = pa.array(c["u"], mask=np.arange(len(c["u"])) == 5)
        return {**c, "u": u}

    edit_table(saved, "points", damage)
    load_error(saved, "points.parquet: column 'u': empty value at row 5")


def test_points_scan_not_in_scans(saved):
    edit_table(saved, "points", lambda c: c["scan_id"].__setitem__(slice(11, 13), 999))
    load_error(saved, "points.parquet: column 'scan_id': scan 999 at row 11 is not in", "scans.parquet")


def test_scan_pose_not_in_poses(saved):
    edit_table(saved, "scans", lambda c: c["pose_id"].__setitem__(2, 42))
    load_error(saved, "scans.parquet: column 'pose_id': pose 42 at row 2 is not in", "poses.parquet")


def test_duplicate_scan_id(saved):
    edit_table(saved, "scans", lambda c: c["scan_id"].__setitem__(2, c["scan_id"][0]))
    load_error(saved, "scans.parquet: duplicate scan_id", "at row 2 (first at row 0)")


def test_duplicate_pose_id(saved):
    edit_table(saved, "poses", lambda c: c["pose_id"].__setitem__(1, c["pose_id"][0]))
    load_error(saved, "poses.parquet: duplicate pose_id", "at row 1 (first at row 0)")


def test_t_decreasing_within_scan(saved, small):
    sid = small.points["scan_id"]
    rows = np.flatnonzero(sid == sid[10])
    later = int(rows[rows > 10][0])

    def damage(c):
        c["t"][later] = c["t"][10] - 1.0

    edit_table(saved, "points", damage)
    load_error(saved, f"points.parquet: column 't' decreases within scan {sid[10]} at row {later}", "at row 10)")


def test_t_may_decrease_between_scans(small):
    pts = {c: a.copy() for c, a in small.points.items()}
    order = np.argsort(pts["scan_id"], kind="stable")
    pts = {c: a[order] for c, a in pts.items()}  # per-scan order kept, times jump back at scan boundaries
    run = Run(pts, small.scans, small.poses, small.temperatures, small.temperature_channels)
    assert np.any(np.diff(run.points["t"]) < 0)


@pytest.mark.parametrize("dt", [0.0, -1.0])
def test_temperature_t_not_strictly_increasing(saved, dt):
    edit_table(saved, "temperatures", lambda c: c["t"].__setitem__(6, c["t"][5] + dt))
    load_error(saved, "temperatures.parquet: column 't' not strictly increasing at row 6")


@pytest.mark.parametrize("value", [0, 2, -2])
def test_sweep_direction(saved, value):
    edit_table(saved, "scans", lambda c: c["sweep_direction"].__setitem__(1, value))
    load_error(saved, "scans.parquet: column 'sweep_direction':", f"{value} at row 1; must be +1 or -1")


def test_sweep_axis(saved):
    edit_table(saved, "scans", lambda c: c.update(sweep_axis=np.array(["X", "x", "Z"])))
    load_error(saved, "scans.parquet: column 'sweep_axis': 'x' at row 1; must be 'X', 'Y' or 'Z'")


def test_duplicate_column_in_csv(saved):
    to_csv(saved, "poses")
    lines = (saved / "poses.csv").read_text().splitlines()
    (saved / "poses.csv").write_text("\n".join(line + "," + line.split(",")[1] for line in lines) + "\n")
    load_error(saved, "poses.csv: column 'alpha' appears more than once")


def test_empty_tables(tmp_path):
    run = make_run(n_points=10, n_scans=1, n_poses=1, channels=[])
    empty = Run({c: a[:0] for c, a in run.points.items()}, run.scans, run.poses)
    empty.save(tmp_path / "r")
    assert Run.load(tmp_path / "r") == empty and empty.n_points == 0 and empty.uv.shape == (0, 2)
    to_csv(tmp_path / "r", "points")
    assert Run.load(tmp_path / "r") == empty


# -- constructor messages name the table ------------------------------------------------------------
def test_constructor_errors_name_table(small):
    pts = dict(small.points)
    bad = pts["u"].copy()
    bad[3] = np.nan
    with pytest.raises(RunError, match=r"^points: column 'u': nan at row 3; values must be finite"):
        Run({**pts, "u": bad}, small.scans, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match=r"^points: missing column 'D'"):
        Run({c: a for c, a in pts.items() if c != "D"}, small.scans, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match=r"^points: columns have different lengths"):
        Run({**pts, "v": pts["v"][:-1]}, small.scans, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match=r"^points: column 'v': expected a 1-D array, got shape \(40, 1\)"):
        Run({**pts, "v": pts["v"][:, None]}, small.scans, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match=r"^scans: column 'feature': 3 at row 1 is not a string"):
        Run(pts, {**small.scans, "feature": np.array(["a", 3, "b"], dtype=object)}, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match=r"^temperatures: missing, but temperature_channels lists 2 channels"):
        Run(pts, small.scans, small.poses, None, small.temperature_channels)
    with pytest.raises(RunError, match=r"^temperature_channels\[0\]: unknown role 'floor'"):
        Run(pts, small.scans, small.poses, small.temperatures, [{"name": "X1", "role": "floor"}, small.temperature_channels[1]])
    with pytest.raises(RunError, match=r"^scans: expected a dict of column name"):
        Run(pts, [1, 2], small.poses)


def test_constructor_json_fields_must_round_trip(small):
    args = (small.points, small.scans, small.poses, small.temperatures, small.temperature_channels)
    with pytest.raises(RunError, match="^metadata: does not survive a JSON round trip"):
        Run(*args, metadata={"pair": (1, 2)})
    with pytest.raises(RunError, match="^artefact: does not survive"):
        Run(*args, artefact={1: "one"})
    with pytest.raises(RunError, match="^maps: not storable as JSON"):
        Run(*args, maps={"t": np.float32(1.0)})
    with pytest.raises(RunError, match="^metadata: not storable as JSON"):
        Run(*args, metadata={"x": float("inf")})
    with pytest.raises(RunError, match="^created: '2025' is not UTC|^created: '2025' is not an ISO"):
        Run(*args, created="2025")

