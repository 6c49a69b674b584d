"""Thermal selection (issue 5, item 2): the thermocouple log checked, joined to
the points' time stamps by a stated policy, and checked against the maps."""

import re
import warnings

import numpy as np
import pytest

import cmmpose
from cmmpose import sim
from cmmpose.calibration.thermal import select_map_temperature
from cmmpose.temperature import (
    LogReport,
    ScanTemperatures,
    ThermalSummary,
    check_log,
    per_scan_temperature,
    temperatures_at,
)
from cmmpose.evaluation.ballbar import machine_temperature

CH = sim.CHANNELS
NOISE = 0.02  # K per sample, the simulator's default
# Machine mean of 9 axis channels, interpolated: noise at most NOISE / 3 per
# sample; 5 sigma of that is a safe bound for "within the noise".
WITHIN = 5 * NOISE / 3
TRAPEZOID = getattr(np, "trapezoid", None) or np.trapz  # numpy < 2 has only trapz
DRIFT = sim.temperature_series([0.0, 3600.0], [20.5, 23.5])  # 3 K/h room


def drifting_log(duration=3600.0, **kw):
    return sim.thermocouple_log(duration, DRIFT, rng=kw.pop("rng", 7), **kw)


def points(n=5000, lo=0.0, hi=3600.0, seed=3):
    return np.sort(np.random.default_rng(seed).uniform(lo, hi, n))


def drop(log, lo, hi):
    """The log without the samples with lo <= t < hi (a gap)."""
    keep = (log["t"] < lo) | (log["t"] >= hi)
    return {k: v[keep] for k, v in log.items()}


# -- check_log -----------------------------------------------------------------------
def test_clean_log_is_ok_and_prints_a_table():
    rep = check_log(drifting_log(), CH)
    assert isinstance(rep, LogReport)
    assert rep.ok and rep.problems == () and rep.clean.all()
    assert rep.clean.shape == (3601, 11)
    assert rep.max_gap == pytest.approx(5.0) and rep.median_spacing == pytest.approx(1.0)
    text = str(rep)
    assert "OK: no problems found" in text
    for name, role in CH:
        assert re.search(rf"^{name}\s+{role}\s+3601\s+0\s+-$", text, re.M)


def test_faults_are_found_with_channel_and_time():
    log = drifting_log(faults=(sim.Fault("X2", "stuck", at=600.0), sim.Fault("Y1", "open", at=1800.0)))
    log["Z3"][1000:1004] = np.nan
    log["GT"][2000] = 55.0  # implausible but not a burn-out value
    rep = check_log(log, CH)
    assert not rep.ok
    assert rep.bad_channels == ("X2", "Y1", "Z3", "GT")
    (stuck,) = rep.problems_of("X2")
    assert (stuck.kind, stuck.start, stuck.end, stuck.samples) == ("stuck", 599.0, 3600.0, 3002)
    (open_,) = rep.problems_of("Y1")
    assert (open_.kind, open_.start, open_.end, open_.samples) == ("open_circuit", 1800.0, 3600.0, 1801)
    (nan,) = rep.problems_of("Z3")
    assert (nan.kind, nan.start, nan.end, nan.samples) == ("nan", 1000.0, 1003.0, 4)
    (hot,) = rep.problems_of("GT")
    assert (hot.kind, hot.start, hot.samples) == ("implausible", 2000.0, 1)
    # the clean mask says exactly which samples are bad
    assert rep.clean_of("X2")[:599].all() and not rep.clean_of("X2")[599:].any()
    assert rep.clean_of("Y1").sum() == 1800
    assert rep.dropped == {"X1": 0, "X2": 3002, "X3": 0, "Y1": 1801, "Y2": 0, "Y3": 0, "Z1": 0, "Z2": 0,
                           "Z3": 4, "GT": 1, "GB": 0}
    text = str(rep)
    assert "X2: stuck from 599 s to 3600 s" in text
    assert "Y1: open circuit from 1800 s to 3600 s, 1801 samples (reads 999.9 C)" in text
    assert "Z3: NaN from 1000 s to 1003 s" in text
    assert "GT: implausible at 2000 s, 1 samples (reads 55 C, outside 0 to 50 C)" in text


def test_gap_is_reported_with_its_times():
    rep = check_log(drop(drifting_log(), 1000.0, 1060.0), CH)
    (gap,) = rep.gaps
    assert (gap.channel, gap.start, gap.end) == ("t", 999.0, 1060.0)
    assert "log: gap, no samples from 999 s to 1060 s (61 s > max_gap 5 s)" in str(rep)
    assert rep.clean.all()  # a gap removes no sample
    assert check_log(drop(drifting_log(), 1000.0, 1060.0), CH, max_gap=100.0).ok


def test_stuck_needs_a_long_window_while_others_vary():
    late = drifting_log(faults=(sim.Fault("Z1", "stuck", at=3500.0),))  # 100 s before the end
    assert check_log(late, CH).ok  # shorter than stuck_after (300 s)
    (p,) = check_log(late, CH, stuck_after=60.0).problems
    assert (p.channel, p.kind, p.start) == ("Z1", "stuck", 3499.0)
    # a noise-free, perfectly steady room: every channel constant, none stuck
    assert check_log(sim.thermocouple_log(1000, 20.0, noise=0.0), CH).ok
    # a lone channel that never changes is stuck
    lone = {"t": np.arange(1000.0), "A": np.full(1000, 21.0)}
    (p,) = check_log(lone, [("A", "air")]).problems
    assert (p.kind, p.start, p.end) == ("stuck", 0.0, 999.0)
    assert check_log(lone, [("A", "air")], stuck_after=None).ok


def test_many_short_problems_are_merged():
    log = drifting_log()
    log["X1"][100:400:2] = np.nan  # 150 one-sample dropouts
    (p,) = check_log(log, CH).problems
    assert (p.kind, p.runs, p.samples, p.start, p.end) == ("nan", 150, 150, 100.0, 398.0)
    assert "in 150 stretches" in str(p)


def test_check_log_accepts_run_channel_dicts():
    log = drifting_log(duration=100)
    dicts = [{"name": n, "role": r} for n, r in CH]
    assert check_log(log, dicts).channels == check_log(log, CH).channels


# -- temperatures_at ------------------------------------------------------------------
def test_machine_mean_recovers_a_steady_temperature():
    log = sim.thermocouple_log(1800, 22.5, rng=1)
    t = points(hi=1800.0)
    temps, info = temperatures_at(t, log, CH)
    assert temps.shape == t.shape
    assert np.max(np.abs(temps - 22.5)) < WITHIN
    assert abs(np.mean(temps) - 22.5) < 0.005
    assert isinstance(info, ThermalSummary)
    assert info.channels == info.channels_used == tuple(n for n, r in CH if r.endswith("_scale"))
    assert info.samples_dropped == 0 and info.channels_excluded == () and info.points == len(t)


def test_machine_mean_follows_a_drifting_room():
    t = points()
    temps, _ = temperatures_at(t, drifting_log(), CH)
    assert np.max(np.abs(temps - DRIFT(t))) < WITHIN


def test_faulty_channels_are_excluded_and_the_result_stays_right():
    log = drifting_log(faults=(sim.Fault("X2", "stuck", at=600.0), sim.Fault("Y1", "open", at=1800.0)))
    log["Z3"][1000:1004] = np.nan
    t = points()
    temps, info = temperatures_at(t, log, CH)
    assert np.max(np.abs(temps - DRIFT(t))) < WITHIN
    assert info.samples_dropped == 3002 + 1801 + 4
    assert info.dropped_by_channel["X2"] == 3002
    assert info.points_missing_channels == np.count_nonzero(t > 599.0)
    assert "samples dropped: 4807 (X2 3002, Y1 1801, Z3 4)" in str(info)
    # keeping the stuck channel would be wrong by (23.5 - 20.9) K / 9 at the end
    naive = np.mean([np.interp(t, log["t"], log[n]) for n, r in CH if r.endswith("_scale") and n != "Y1"], axis=0)
    assert np.nanmax(np.abs(naive - DRIFT(t))) > 0.25


def test_a_channel_broken_throughout_is_excluded():
    log = drifting_log(faults=(sim.Fault("Z2", "open", at=0.0),))
    temps, info = temperatures_at(points(), log, CH)
    assert info.channels_excluded == ("Z2",) and "Z2" not in info.channels_used
    assert "excluded (no clean reading where needed): Z2" in str(info)
    assert np.max(np.abs(temps - DRIFT(points()))) < WITHIN


def test_per_axis_returns_each_axis_offset():
    offsets = (0.3, -0.2, 0.5)
    log = sim.thermocouple_log(1200, 21.0, axis_offsets=offsets, rng=2)
    t = points(hi=1200.0)
    per_axis, info = temperatures_at(t, log, CH, policy="per_axis")
    assert per_axis.shape == (len(t), 3)
    assert np.max(np.abs(per_axis - (21.0 + np.array(offsets)))) < 5 * NOISE / np.sqrt(3)
    assert np.allclose(per_axis.mean(axis=0), 21.0 + np.array(offsets), atol=0.005)
    mean, _ = temperatures_at(t, log, CH)
    assert np.allclose(mean, per_axis.mean(axis=1))  # three channels per axis
    assert info.policy == "per_axis" and len(info.channels) == 9


def test_role_policy_is_one_axis_of_per_axis_and_drops_a_broken_channel():
    offsets = (0.3, -0.2, 0.5)
    log = sim.thermocouple_log(1200, 21.0, axis_offsets=offsets, faults=(sim.Fault("Y2", "open", at=0.0),), rng=2)
    t = points(hi=1200.0)
    per_axis, _ = temperatures_at(t, log, CH, policy="per_axis")
    for k, role in enumerate(("x_scale", "y_scale", "z_scale")):
        one, info = temperatures_at(t, log, CH, policy=f"role:{role}")
        assert one.shape == (len(t),) and np.array_equal(one, per_axis[:, k])
    assert info.policy == "role:z_scale"
    y, info = temperatures_at(t, log, CH, policy="role:y_scale")
    assert "Y2" in info.channels_excluded and np.max(np.abs(y - 20.8)) < 5 * NOISE
    with pytest.raises(cmmpose.InputError, match="no channel with role 'mount'"):
        temperatures_at(t, log, CH, policy="role:mount")


def test_one_channel_policy():
    log = sim.thermocouple_log(600, 21.0, granite_gradient=0.4, rng=3)
    t = np.array([10.0, 20.5, 599.0])
    top, info = temperatures_at(t, log, CH, policy="channel:GT")
    assert np.allclose(top, np.interp(t, log["t"], log["GT"]))
    assert info.channels_used == ("GT",)
    assert np.allclose(top, 21.2, atol=5 * NOISE)


def test_scalar_time_stamp():
    log = sim.thermocouple_log(600, 21.0, rng=3)
    temp, _ = temperatures_at(300.0, log, CH)
    assert np.shape(temp) == () and abs(temp - 21.0) < WITHIN
    per_axis, _ = temperatures_at(300.0, log, CH, policy="per_axis")
    assert per_axis.shape == (3,)


def test_run_input_agrees_with_the_evaluation_default(simulated_run):
    run = simulated_run
    t = run.points["t"][::50]
    temps, info = temperatures_at(t, run)
    assert np.allclose(temps, machine_temperature(run, t), atol=1e-12)
    assert info.report.ok
    scans = per_scan_temperature(run.points["t"], run.points["scan_id"], run)
    assert len(scans.scan_id) == len(run.scans["scan_id"])
    assert np.max(np.abs(scans.temperature - 22.5)) < WITHIN


def test_points_in_a_gap_are_refused_naming_row_and_time():
    log = drop(drifting_log(), 1000.0, 1060.0)
    t = np.array([10.0, 999.0, 1030.5, 1060.0, 1045.0])
    msg = ("point row 2 (t = 1030.5 s) falls in a gap of the temperature log: no samples from 999 s to 1060 s "
           "(61 s > max_gap 5 s); pass on_gap='interpolate'")
    with pytest.raises(cmmpose.InputError, match=re.escape(msg)):
        temperatures_at(t, log, CH)
    temps, info = temperatures_at(t, log, CH, on_gap="interpolate")
    assert info.points_across_gaps == 2
    assert "points interpolated across gaps wider than 5 s: 2" in str(info)
    assert np.max(np.abs(temps - DRIFT(t))) < WITHIN  # the room is linear, so interpolation is right
    # samples on both sides of the gap are fine
    temperatures_at(np.array([999.0, 1060.0]), log, CH)
    # a wider max_gap accepts it
    temperatures_at(t, log, CH, report=check_log(log, CH, max_gap=120.0))


def test_points_outside_the_log_are_refused_or_held():
    log = sim.thermocouple_log(600, 21.0, t0=100.0, rng=4)  # 100 .. 700 s
    t = np.array([150.0, 700.0, 701.5, 50.0])
    with pytest.raises(cmmpose.InputError,
                       match=re.escape("point row 2 (t = 701.5 s) is outside the temperature log (100 s to 700 s); "
                                       "2 points in all; pass out_of_range='hold'")):
        temperatures_at(t, log, CH)
    temps, info = temperatures_at(t, log, CH, out_of_range="hold")
    assert info.points_held == 2
    end, _ = temperatures_at(np.array([700.0, 100.0]), log, CH)
    assert temps[2] == end[0] and temps[3] == end[1]


def test_no_clean_channel_at_a_point():
    log = drifting_log()
    for n, r in CH:
        if r.endswith("_scale"):
            log[n][2000:2030] = np.nan  # every axis-scale channel out for 30 s
    t = np.array([100.0, 1500.0, 2015.0])
    with pytest.raises(cmmpose.InputError,
                       match=r"point row 2 \(t = 2015 s\): no clean axis-scale reading \(X1, X2, .*Z3\) within "
                             r"max_gap 5 s \[X1: NaN from 2000 s to 2029 s.*on_gap='interpolate'"):
        temperatures_at(t, log, CH)
    temps, info = temperatures_at(t, log, CH, on_gap="interpolate")
    assert info.points_across_gaps == 1
    assert np.max(np.abs(temps - DRIFT(t))) < WITHIN
    # a granite channel is still fine there
    temperatures_at(t, log, CH, policy="channel:GT")


def test_all_channels_broken():
    faults = tuple(sim.Fault(n, "open") for n, r in CH if r.endswith("_scale"))
    log = sim.thermocouple_log(600, 21.0, faults=faults, rng=5)
    with pytest.raises(cmmpose.InputError,
                       match=r"policy 'machine_mean': every axis-scale channel is unusable \(X1, .*Z3\): "
                             r"X1: open circuit from 0 s to 600 s, 601 samples \(reads 999.9 C\)"):
        temperatures_at([10.0], log, CH)
    with pytest.raises(cmmpose.InputError, match="every x_scale channel is unusable"):
        temperatures_at([10.0], log, CH, policy="per_axis")
    # the granite channels still work
    temperatures_at([10.0], log, CH, policy="channel:GB")
    # a dead axis after 300 s: points after it have no clean channel
    late = sim.thermocouple_log(600, 21.0, faults=tuple(sim.Fault(n, "open", at=300.0) for n, _ in CH), rng=5)
    with pytest.raises(cmmpose.InputError, match=r"point row 1 \(t = 400 s\): no clean axis-scale reading"):
        temperatures_at([100.0, 400.0], late, CH, on_gap="interpolate")


def test_unknown_policy_and_channel():
    log = sim.thermocouple_log(60, 21.0, rng=6)
    with pytest.raises(cmmpose.InputError, match=r"unknown policy 'mean'; expected one of 'machine_mean', 'per_axis', "
                                                 r"'role:ROLE', 'channel:NAME'"):
        temperatures_at([1.0], log, CH, policy="mean")
    with pytest.raises(cmmpose.InputError, match=r"policy 'channel:X9': no channel 'X9' in the log \(channels: X1, "):
        temperatures_at([1.0], log, CH, policy="channel:X9")
    with pytest.raises(cmmpose.InputError, match="policy: expected one of"):
        temperatures_at([1.0], log, CH, policy=None)
    granite = [(n, r) for n, r in CH if r.startswith("granite")]
    with pytest.raises(cmmpose.InputError, match="policy 'machine_mean': the log has no axis-scale channel"):
        temperatures_at([1.0], log, granite)
    no_z = [(n, r) for n, r in CH if r != "z_scale"]
    with pytest.raises(cmmpose.InputError, match="policy 'per_axis': the log has no channel with role 'z_scale'"):
        temperatures_at([1.0], log, no_z, policy="per_axis")
    with pytest.raises(cmmpose.InputError, match="on_gap: expected one of 'raise', 'interpolate', got 'skip'"):
        temperatures_at([1.0], log, CH, on_gap="skip")
    with pytest.raises(cmmpose.InputError, match="out_of_range: expected one of 'raise', 'hold', got 'clamp'"):
        temperatures_at([1.0], log, CH, out_of_range="clamp")


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda log: log.update(X1=log["X1"][:-1]), "column 'X1' has 60 samples but 't' has 61"),
        (lambda log: log.pop("Y2"), "no column for channel 'Y2'"),
        (lambda log: log.pop("t"), "no time column 't'"),
        (lambda log: log["t"].__setitem__(5, 4.0), r"column 't' not strictly increasing at row 5 \(t = 4 s after 4 s\)"),
        (lambda log: log["t"].__setitem__(3, np.nan), "column 't' is nan at row 3"),
        (lambda log: log.update(Z1=np.array(["a"] * 61)), "column 'Z1' cannot be read as numbers"),
        (lambda log: log.update(t=log["t"][:1], **{n: log[n][:1] for n, _ in CH}), "has 1 samples; a log needs at least 2"),
    ],
)
def test_malformed_logs(change, message):
    log = sim.thermocouple_log(60, 21.0, rng=6)
    change(log)
    with pytest.raises(cmmpose.InputError, match=message):
        check_log(log, CH)
    with pytest.raises(cmmpose.InputError, match=message):
        temperatures_at([1.0], log, CH)


@pytest.mark.parametrize(
    "channels, message",
    [
        ("X1", "channels: expected a list"),
        ([], "channels: empty"),
        ([("X1", "x_scale"), ("X1", "y_scale")], r"channels\[1\]: duplicate channel name 'X1'"),
        ([("X1", "scale")], r"channels\[0\]: unknown role 'scale' of channel 'X1'"),
        ([{"name": "t", "role": "air"}], r"channels\[0\]: name must be a non-empty string other than 't'"),
        ([42], r"channels\[0\]: expected \{'name': ..., 'role': ...\} or a \(name, role\) pair"),
    ],
)
def test_bad_channel_lists(channels, message):
    with pytest.raises(cmmpose.InputError, match=message):
        check_log(sim.thermocouple_log(60, 21.0, rng=6), channels)


def test_bad_options_and_time_stamps():
    log = sim.thermocouple_log(60, 21.0, rng=6)
    with pytest.raises(cmmpose.InputError, match="plausible: expected"):
        check_log(log, CH, plausible=(50.0, 0.0))
    with pytest.raises(cmmpose.InputError, match="max_gap: expected a positive time"):
        check_log(log, CH, max_gap=0.0)
    with pytest.raises(cmmpose.InputError, match="stuck_after: expected a positive time"):
        check_log(log, CH, stuck_after=-1.0)
    with pytest.raises(cmmpose.InputError, match="t: row 1 is nan; time stamps must be finite"):
        temperatures_at([1.0, np.nan], log, CH)
    with pytest.raises(cmmpose.InputError, match=r"t: expected one time stamp per point, shape \(N,\)"):
        temperatures_at(np.zeros((2, 2)), log, CH)
    with pytest.raises(cmmpose.InputError, match="report: made from a different log"):
        temperatures_at([1.0], log, CH, report=check_log(sim.thermocouple_log(30, 21.0), CH))
    with pytest.raises(cmmpose.InputError, match="temperatures: expected a dict"):
        temperatures_at([1.0], [1, 2, 3], CH)
    with pytest.raises(cmmpose.InputError, match="channels: required"):
        temperatures_at([1.0], log)


# -- per scan -------------------------------------------------------------------------
def test_per_scan_means_over_each_scan_duration():
    log = drifting_log()
    rng = np.random.default_rng(9)
    # three scans, points unevenly spread in time, shuffled
    t = np.concatenate([rng.uniform(100, 400, 500), 1000 + 500 * rng.uniform(0, 1, 300) ** 3,
                        rng.uniform(3000, 3010, 50)])
    sid = np.repeat([7, 2, 5], [500, 300, 50])
    order = rng.permutation(len(t))
    t, sid = t[order], sid[order]
    scans = per_scan_temperature(t, sid, log, CH)
    assert isinstance(scans, ScanTemperatures)
    assert list(scans.scan_id) == [2, 5, 7] and list(scans.n_points) == [300, 50, 500]
    for k, s in enumerate(scans.scan_id):
        a, b = t[sid == s].min(), t[sid == s].max()
        assert (scans.start[k], scans.end[k]) == (a, b)
        # a linear room: the mean over the duration is the temperature at mid-scan, not the mean over points
        assert abs(scans.temperature[k] - DRIFT(0.5 * (a + b))) < WITHIN
        # and exactly the time average of the policy temperature
        grid = np.linspace(a, b, 200001)
        dense, _ = temperatures_at(grid, log, CH)
        assert scans.temperature[k] == pytest.approx(TRAPEZOID(dense, grid) / (b - a), abs=1e-6)
    assert np.array_equal(scans.per_point, scans.temperature[np.searchsorted(scans.scan_id, sid)])
    # scan 2's points crowd its start, so the mean over points would be well off the duration mean
    at_points, _ = temperatures_at(t[sid == 2], log, CH)
    assert abs(at_points.mean() - scans.temperature[0]) > 0.05
    text = str(scans)
    assert re.search(r"^\s+2\s+1000\.\d+\s+14\d\d\.\d+\s+300\s+21\.\d{3}$", text, re.M)


def test_per_scan_per_axis_and_single_point_scans():
    offsets = (0.3, -0.2, 0.5)
    log = sim.thermocouple_log(600, 21.0, axis_offsets=offsets, rng=2)
    scans = per_scan_temperature([10.0, 20.0, 300.0], [0, 0, 1], log, CH, policy="per_axis")
    assert scans.temperature.shape == (2, 3) and scans.per_point.shape == (3, 3)
    assert np.allclose(scans.temperature, 21.0 + np.array(offsets), atol=5 * NOISE / np.sqrt(3))
    one, _ = temperatures_at(300.0, log, CH, policy="per_axis")
    assert np.allclose(scans.temperature[1], one)  # zero duration: the temperature at its time


def test_per_scan_refuses_a_scan_spanning_a_gap():
    log = drop(drifting_log(), 1000.0, 1060.0)
    t = np.array([100.0, 200.0, 990.0, 1100.0])  # scan 1 has points on both sides of the gap
    sid = np.array([0, 0, 1, 1])
    with pytest.raises(cmmpose.InputError,
                       match=re.escape("scan 1 (990 s to 1100 s) spans a gap of the temperature log: no samples from "
                                       "999 s to 1060 s")):
        per_scan_temperature(t, sid, log, CH)
    scans = per_scan_temperature(t, sid, log, CH, on_gap="interpolate")
    assert scans.scans_across_gaps == 1
    assert abs(scans.temperature[1] - DRIFT(1045.0)) < WITHIN


def test_per_scan_bad_inputs():
    log = sim.thermocouple_log(60, 21.0, rng=6)
    with pytest.raises(cmmpose.InputError, match="scan_id: has 2 entries but t has 3; one scan id per point"):
        per_scan_temperature([1.0, 2.0, 3.0], [0, 0], log, CH)
    with pytest.raises(cmmpose.InputError, match="scan_id: expected integers"):
        per_scan_temperature([1.0, 2.0], [0.5, 1.0], log, CH)
    with pytest.raises(cmmpose.InputError, match=r"point row 1 \(t = 99 s\) is outside the temperature log"):
        per_scan_temperature([1.0, 99.0], [0, 0], log, CH)
    with pytest.raises(cmmpose.InputError, match="t: no points"):
        per_scan_temperature([], [], log, CH)


# -- against the maps ---------------------------------------------------------------
MAPS = cmmpose.ErrorMapSet.thesis()  # 20, 25, 30 C


def test_temperatures_inside_the_maps_pass_unchanged():
    temps = np.array([20.0, 22.5, 30.0])
    out, clamped = select_map_temperature(temps, MAPS)
    assert np.array_equal(out, temps) and clamped == 0 and out is not temps


def test_out_of_range_temperatures_are_refused_naming_row_value_and_range():
    temps = np.array([21.0, 19.95, 30.5, 25.0])
    with pytest.raises(cmmpose.OutOfRangeError,
                       match=re.escape("row 1: temperature 19.95 C is outside the maps' range [20, 30] C "
                                       "(maps at 20, 25, 30 C; 2 of 4 rows outside); pass out_of_range='clamp'")):
        select_map_temperature(temps, MAPS)
    with pytest.raises(cmmpose.OutOfRangeError, match=r"^the temperature: temperature 31 C is outside"):
        select_map_temperature(31.0, MAPS)
    with pytest.raises(cmmpose.OutOfRangeError, match=r"row 1 \(Z axis\): temperature 30.2 C"):
        select_map_temperature([[21.0, 22.0, 23.0], [21.0, 22.0, 30.2]], MAPS)


def test_out_of_range_temperatures_are_clamped_on_request():
    temps = np.array([21.0, 19.95, 30.5, 25.0])
    with pytest.warns(cmmpose.ClampWarning, match=r"clamped 2 of 4 temperatures into the maps' range \[20, 30\] C"):
        out, clamped = select_map_temperature(temps, MAPS, out_of_range="clamp")
    assert clamped == 2 and np.array_equal(out, [21.0, 20.0, 30.0, 25.0])
    assert temps[1] == 19.95  # input untouched
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        select_map_temperature([22.0], MAPS, out_of_range="clamp")  # nothing to clamp: no warning


def test_select_map_temperature_bad_inputs():
    with pytest.raises(cmmpose.InputError, match="temperatures: row 2 is nan; temperatures must be finite"):
        select_map_temperature([21.0, 22.0, np.nan], MAPS)
    with pytest.raises(cmmpose.InputError, match="error_map_set: expected a cmmpose.ErrorMapSet, got ErrorMap"):
        select_map_temperature([21.0], MAPS.maps[0])
    with pytest.raises(cmmpose.InputError, match="out_of_range: expected one of 'raise', 'clamp', got 'hold'"):
        select_map_temperature([21.0], MAPS, out_of_range="hold")
    with pytest.raises(cmmpose.InputError, match="cannot be read as numbers"):
        select_map_temperature(["warm"], MAPS)


def test_log_to_compensation_end_to_end():
    """A log at 19.9-20.1 C against maps from 20 C: refused, then clamped on request."""
    log = sim.thermocouple_log(600, 20.0, noise=0.05, rng=8)
    temps, _ = temperatures_at(points(200, 0.0, 600.0), log, CH)
    assert temps.min() < 20.0
    with pytest.raises(cmmpose.OutOfRangeError):
        select_map_temperature(temps, MAPS)
    with pytest.warns(cmmpose.ClampWarning):
        ok, n = select_map_temperature(temps, MAPS, out_of_range="clamp")
    assert n == np.count_nonzero(temps < 20.0)
    xyz = cmmpose.compensate(np.zeros((200, 2)), np.tile([450.0, 275.0, -250.0], (200, 1)), MAPS,
                             cmmpose.Pose(90, 90, 0), cmmpose.MountOffset.thesis(), ok)
    assert np.isfinite(xyz).all()
