"""Pickling of what a Dask worker is sent: maps, poses, offsets, models and
runs come back equal, and compensate to the same bits."""

import pickle

import numpy as np
import pytest

import cmmpose
from cmmpose import _core
from cmmpose.model import Model

MAPS = cmmpose.ErrorMapSet.thesis()
POSE = cmmpose.Pose(90.0, 90.0, 10.0)
OFFSET = cmmpose.MountOffset.thesis()


def _again(obj):
    return pickle.loads(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL))


def _points(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-10, 10, n)])
    scales = np.column_stack([rng.uniform(100, 800, n), rng.uniform(50, 500, n), rng.uniform(-450, -50, n)])
    return uv, scales, rng.uniform(20.5, 29.5, n)


def _same_bits(a, b):
    return a.shape == b.shape and np.array_equal(np.asarray(a).view(np.uint64), np.asarray(b).view(np.uint64))


@pytest.mark.parametrize("make", [
    lambda: MAPS.maps[0],
    lambda: MAPS.at(23.37),  # a blend: its kernel-unit tables are not the table-unit rows converted
    lambda: cmmpose.ErrorMap.appendix_b().with_kinematics("gantry"),
    lambda: cmmpose.ErrorMap.zero(temperature=21.0),
], ids=["file", "blend", "appendix-b-gantry", "zero"])
def test_error_map_round_trip_is_exact(make):
    m = make()
    back = _again(m)
    assert isinstance(back, cmmpose.ErrorMap)
    assert back == m and back._core == m._core
    assert back.source == m.source and back.kinematics == m.kinematics and back.temperature == m.temperature
    for c in cmmpose.CARRIAGES:
        assert _same_bits(back.table(c), m.table(c))
    uv, scales, _ = _points()
    assert _same_bits(cmmpose.compensate(uv, scales, back, POSE, OFFSET),
                      cmmpose.compensate(uv, scales, m, POSE, OFFSET))


def test_error_map_set_round_trip_is_exact():
    for s in (MAPS, MAPS.with_kinematics("horizontal-arm")):
        back = _again(s)
        assert isinstance(back, cmmpose.ErrorMapSet)
        assert back.temperatures == s.temperatures and back.kinematics == s.kinematics
        assert back._core == s._core and [m.source for m in back.maps] == [m.source for m in s.maps]
        uv, scales, t = _points()
        assert _same_bits(cmmpose.compensate(uv, scales, back, POSE, OFFSET, t),
                          cmmpose.compensate(uv, scales, s, POSE, OFFSET, t))
        assert back.at(24.1) == s.at(24.1)


def test_a_tampered_map_state_is_refused_naming_what():
    rebuild, (state,) = MAPS.maps[0]._core.__reduce__()
    tables = list(state[0])
    positions, values, slopes, inv_pitch, rows = tables[1]
    tables[1] = (positions, values, slopes[:-1], inv_pitch, rows)
    with pytest.raises(cmmpose.MapError, match="Y carriage table.*slopes"):
        rebuild((tuple(tables), *state[1:]))
    with pytest.raises(cmmpose.InputError, match="'probe' or 'part'"):
        rebuild((state[0], *state[1:4], None, [(0, "probe"), (1, "side"), (2, "probe")]))


def test_pose_offset_and_digitizer_pickle():
    assert _again(POSE) == POSE
    assert _again(OFFSET) == OFFSET and isinstance(_again(OFFSET), cmmpose.MountOffset)
    d = _core.Digitizer(alpha=12.5, beta=33.0, gamma=-4.0, offset=(1.0, 2.5, 3.0))
    back = _again(d)
    assert (back.alpha, back.beta, back.gamma, back.offset) == (d.alpha, d.beta, d.gamma, d.offset)


def test_run_round_trip_is_equal_and_read_only(simulated_run):
    simulated_run.uv, simulated_run.scales  # cached stacks are not sent  # noqa: B018
    data = pickle.dumps(simulated_run)
    back = pickle.loads(data)
    assert back == simulated_run and back.created == simulated_run.created
    assert "uv" not in back.__dict__ and "scales" not in back.__dict__
    for table in ("points", "scans", "poses", "temperatures"):
        for name, col in getattr(back, table).items():
            assert not col.flags.writeable, f"{table}.{name}"
    assert _same_bits(back.uv, simulated_run.uv) and _same_bits(back.scales, simulated_run.scales)
    assert back.scan_points(int(simulated_run.scans["scan_id"][3]))["t"].tolist() == \
        simulated_run.scan_points(int(simulated_run.scans["scan_id"][3]))["t"].tolist()
    a, b = cmmpose.evaluate(back, MAPS), cmmpose.evaluate(simulated_run, MAPS)
    assert _same_bits(a.compensated.lengths, b.compensated.lengths)


def test_model_round_trip_compensates_the_same_and_holds_no_run(simulated_run):
    model = Model(MAPS).with_values("squareness", [3.0, -2.0, 1.5]).with_values("scanner-scale", [2e-4, -1e-4])
    xyz = model.compensate(simulated_run)
    back = _again(model)
    assert back.maps._core == model.maps._core and back.names == model.names
    for name in model.names:
        assert _same_bits(back.values(name), model.values(name))
    assert (back.temperature, back.out_of_range, back.temperature_tolerance, back.log_hold) == \
        (model.temperature, model.out_of_range, model.temperature_tolerance, model.log_hold)
    assert _same_bits(back.compensate(simulated_run), xyz)
    assert len(pickle.dumps(model)) < len(pickle.dumps(simulated_run)) / 2  # the run is not sent along
