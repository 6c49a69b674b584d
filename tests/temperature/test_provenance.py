"""Every command that turns a thermocouple log into temperatures says, in its
printed output and its JSON (and a saved diagnosis model), which channels it
dropped as broken and why, which points it held past the log's end and for
how long, and which channels each role read (issue 23; cmmpose.temperature)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner
from cmmpose.standards.acceptance import acceptance_test
from cmmpose.standards.interim import interim_check
from cmmpose.temperature import TemperaturePolicy, run_sensor_temperatures, run_temperatures

MAPS = cmmpose.ErrorMapSet.thesis()
SHORT_S = 5.0  # the logger stops this long before the last point


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def clean():
    run, _ = simulate_ballbar_run(MAPS, 22.5, layout="b89", scanner=Scanner(points_per_profile=64), seed=7,
                                  calibrated=("length", "radius"))
    return run


def broken(run, *, value=1e6, short=True):
    """X1 reads ``value`` throughout; the log ends SHORT_S before the last point."""
    log = {k: np.array(v, dtype=float, copy=True) for k, v in run.temperatures.items()}
    log["X1"][:] = value
    if short:
        keep = log["t"] <= float(np.max(run.points["t"])) - SHORT_S
        log = {k: v[keep] for k, v in log.items()}
    return dataclasses.replace(run, temperatures=log)


@pytest.fixture(scope="module")
def bad(clean):
    return broken(clean)


def check_log(log: dict, run) -> None:
    """The provenance of ``broken(run)``, checked against the run itself."""
    (x1,) = log["channels_dropped"]
    assert x1["channel"] == "X1" and x1["role"] == "x_scale"
    assert x1["why"] == ["open circuit (a burn-out reading)"] and "1e+06" in " ".join(x1["problems"])
    assert x1["samples_dropped"] == x1["samples"] == len(run.temperatures["t"])
    assert log["sensors"]["x_scale"] == {"read": ["X2", "X3"], "left_out": ["X1"]}
    assert log["sensors"]["y_scale"]["read"] == ["Y1", "Y2", "Y3"]
    held = log["held"]
    last = float(np.max(run.points["t"]))
    assert held["points"] == int(np.sum(run.points["t"] > run.temperatures["t"][-1])) > 0
    assert held["after_log_s"] == pytest.approx(last - float(run.temperatures["t"][-1]), abs=1e-3)
    assert held["before_log_s"] == 0.0 and held["max_s"] == held["after_log_s"] and held["log_hold_s"] == 120.0
    assert SHORT_S <= held["after_log_s"] < SHORT_S + 2 * np.median(np.diff(run.temperatures["t"]))
    assert log["policy"]["broken_channels"] == "drop"


def test_the_machine_temperature_is_the_mean_of_the_channels_read(clean, bad):
    """Independent reference: the mean of the eight other axis-scale columns,
    each interpolated linearly in time (np.interp holds the ends)."""
    t = clean.points["t"]
    temps, log = run_temperatures(bad, t)
    names = [f"{a}{k}" for a in "XYZ" for k in (1, 2, 3) if f"{a}{k}" != "X1"]
    want = np.mean([np.interp(t, bad.temperatures["t"], bad.temperatures[n]) for n in names], axis=0)
    assert np.allclose(temps, want, atol=1e-12, rtol=0)
    check_log(log, bad)
    # the same channels chosen by the policy on the clean log give the same temperatures
    chosen, log2 = run_temperatures(clean, t, TemperaturePolicy(sensors={"x_scale": ("X2", "X3")}))
    full = np.mean([np.interp(t, clean.temperatures["t"], clean.temperatures[n]) for n in names], axis=0)
    assert np.allclose(chosen, full, atol=1e-12, rtol=0)
    assert log2["moved"] == {"X1": {"log_role": "x_scale", "read_as": None}}
    assert log2["sensors"]["x_scale"]["read"] == ["X2", "X3"] and log2["channels_dropped"] == []


def test_evaluate_states_the_dropped_channel_and_the_hold(bad):
    ev = cmmpose.evaluate(bad, MAPS)
    doc = json.loads(ev.to_json())
    check_log(doc["provenance"]["temperature"]["log"], bad)
    notes = " ".join(doc["provenance"]["notes"])
    assert "thermocouple X1 (x_scale): left out of the machine temperature entirely" in notes
    assert "does not cover" in notes and "thermocouples read: x_scale X2, X3;" in notes
    assert "thermocouple X1" in str(ev)


def test_a_constant_in_range_channel_is_dropped_as_constant(clean):
    run = broken(clean, value=21.0, short=False)
    _, log = run_temperatures(run, run.points["t"])
    (x1,) = log["channels_dropped"]
    assert x1["channel"] == "X1" and x1["why"] == ["constant (stuck while the others vary)"]
    assert log["held"] is None


def test_broken_channels_raise_names_the_channel(bad, tmp_path):
    with pytest.raises(cmmpose.InputError, match=r"thermocouple X1: broken.*1e\+06.*broken_channels='drop'"):
        cmmpose.evaluate(bad, MAPS, temperature_policy=TemperaturePolicy(broken_channels="raise"))
    bad.save(tmp_path / "run")
    r = cli("evaluate", tmp_path / "run", "--broken-channels", "raise")
    assert r.exit_code == 1 and "X1" in r.output and "--broken-channels drop" in r.output
    assert "broken_channels=" not in r.output


def test_diagnose_states_it_and_the_saved_model_keeps_it(bad, tmp_path):
    d = cmmpose.diagnose(bad, MAPS, auto=False, patterns=False, polish=False)
    prov = json.loads(d.to_json())["provenance"]
    check_log(prov["temperature_log"], bad)
    assert prov["temperature_policy"] == TemperaturePolicy().to_dict()
    assert prov["temperature_log"]["sensors"]["granite_top"]["read"] == ["GT"]
    path = d.model.save(tmp_path / "m.json")
    saved = json.loads(path.read_text())
    check_log(saved["temperature_log"], bad)
    back = Model.load(path)
    assert back.thermal == saved["temperature_log"] and back.policy == TemperaturePolicy()


def test_the_diagnosis_reads_each_role_through_the_policy(clean):
    read = run_sensor_temperatures(clean, clean.points["t"])
    t = clean.points["t"]
    want = np.mean([np.interp(t, clean.temperatures["t"], clean.temperatures[f"{a}{k}"])
                    for a in "XYZ" for k in (1, 2, 3)], axis=0)
    assert np.allclose(read.temperature, want, atol=1e-12, rtol=0)
    assert set(read.sensors) == {"x_scale", "y_scale", "z_scale", "granite_top", "granite_bottom"}
    assert read.provenance["channels_dropped"] == [] and read.provenance["held"] is None
    # a role whose only channel the policy moves elsewhere is no longer offered
    moved = run_sensor_temperatures(clean, t, TemperaturePolicy(sensors={"granite_bottom": ("GT", "GB")}))
    assert "granite_top" not in moved.sensors and moved.gradient is None
    assert moved.provenance["moved"]["GT"] == {"log_role": "granite_top", "read_as": "granite_bottom"}


def test_the_standards_state_it(bad):
    acc = acceptance_test(bad, MAPS, mpe_form=200, mpe_size=100, mpe_length="80+L/300")
    check_log(json.loads(acc.to_json())["temperature_log"], bad)
    assert any("thermocouple X1" in n for n in acc.notes) and any("does not cover" in n for n in acc.notes)
    ic = interim_check(bad, MAPS)
    check_log(ic.to_dict()["temperature_log"], bad)
    assert any("thermocouple X1" in n for n in ic.notes)


def test_the_command_line_prints_and_writes_it(bad, tmp_path):
    bad.save(tmp_path / "run")
    for args, get in ((("evaluate",), lambda d: d["provenance"]["temperature"]["log"]),
                      (("diagnose", "--no-auto"), lambda d: d["provenance"]["temperature_log"]),
                      (("standards acceptance", "--mpe-form", 200, "--mpe-size", 100, "--mpe-length", "80+L/300"),
                       lambda d: d["temperature_log"]),
                      (("standards interim-check",), lambda d: d["temperature_log"])):
        r = cli(*args[0].split(), tmp_path / "run", *args[1:])
        out = " ".join(r.output.split())
        assert r.exit_code in (0, 1), r.output
        assert "thermocouple X1" in out and "does not cover" in out, (args[0], r.output[-2000:])
        r = cli(*args[0].split(), tmp_path / "run", *args[1:], "--json")
        check_log(get(json.loads(r.output[r.output.index("{"):])), bad)
