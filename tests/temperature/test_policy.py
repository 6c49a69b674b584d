"""One temperature policy for every command and the API (cmmpose.policy,
docs/conventions.md): temperatures within the tolerance outside the maps
are held at the edge and counted; beyond it the user chooses (stop, clamp,
extrapolate) and the error says how in the words of the interface in use;
points just outside the thermocouple log (a recovered run) take its nearest
reading; a single map used at other temperatures says so."""

from __future__ import annotations

import dataclasses
import json
import pickle
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.errors import MapTemperatureWarning
from cmmpose.run import Run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner
from cmmpose.temperature import DEFAULT_POLICY, TemperaturePolicy, as_policy

MAPS = cmmpose.ErrorMapSet.thesis()
COARSE = Scanner(points_per_profile=128)


def simulate(temperature, seed=4):
    run, _ = simulate_ballbar_run(MAPS, temperature, layout="crossed", scanner=COARSE, seed=seed)
    return run


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.parametrize("t", [20.0, 30.0])
def test_runs_at_the_maps_ends_evaluate_and_diagnose_at_the_defaults(t):
    run = simulate(t)
    temps = cmmpose.evaluation.ballbar.machine_temperature(run, run.points["t"])
    assert (temps < 20.0).any() if t == 20.0 else (temps > 30.0).any()  # thermocouple noise crosses the edge
    ev = cmmpose.evaluate(run, MAPS)
    assert ev.compensated.rms_accuracy_error < 2e-3
    assert ev.provenance["points_held_at_maps_edge"] > 0 and ev.provenance["points_clamped"] == 0
    d = cmmpose.diagnose(run, MAPS, patterns=False, max_effects=1)
    assert d.steps[0].figures.rms_accuracy_error < 2e-3
    prov = json.loads(d.to_json())["provenance"]
    assert prov["policy"]["temperature_tolerance_K"] == 0.5 and prov["maps"]["kind"] == "set"


def test_cli_at_20_c_as_a_new_user_would(tmp_path):
    r = cli("simulate", "--layout", "crossed", "--temperature", 20, "-o", tmp_path / "r20")
    assert r.exit_code == 0, r.output
    r = cli("evaluate", tmp_path / "r20", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output[r.output.index("{"):])
    assert doc["provenance"]["policy"] == {"out_of_range": "raise", "temperature_tolerance_K": 0.5, "log_hold_s": 120.0}
    assert doc["provenance"]["points_held_at_maps_edge"] > 0


def test_beyond_the_tolerance_the_error_lists_the_choices_in_each_interface(tmp_path):
    run = simulate(20.0)
    run.save(tmp_path / "r")
    with pytest.raises(cmmpose.OutOfRangeError) as exc:
        cmmpose.evaluate(run, MAPS, temperature_tolerance=0.0)
    msg = str(exc.value)
    assert "outside the maps' range [20, 30] C" in msg and "out_of_range='clamp'" in msg
    assert "temperature_tolerance" in msg
    r = cli("evaluate", tmp_path / "r", "--temperature-tolerance", 0)
    assert r.exit_code != 0
    assert "--out-of-range clamp" in r.output and "--temperature-tolerance" in r.output
    assert "out_of_range=" not in r.output and "temperature_tolerance in K" not in r.output
    r = cli("diagnose", tmp_path / "r", "--temperature-tolerance", 0)
    assert r.exit_code != 0 and "--out-of-range extrapolate" in r.output


def test_extrapolation_reports_the_largest_distance():
    # Maps at 20 and 25 C only, a machine at 26 C.
    run = simulate(26.0)
    maps = cmmpose.ErrorMapSet(MAPS.maps[:2])
    with pytest.raises(cmmpose.OutOfRangeError, match=r"0\.[5-9].. K outside"):
        cmmpose.evaluate(run, maps)
    with pytest.warns(cmmpose.errors.ExtrapolationWarning, match=r"up to 1\.[0-9]+ K"):
        ev = cmmpose.evaluate(run, maps, out_of_range="extrapolate")
    assert 0 < ev.provenance["points_extrapolated"] <= run.n_points
    assert 0.9 < ev.provenance["max_extrapolation_K"] < 1.2
    with pytest.warns(cmmpose.ClampWarning, match="temperatures"):
        clamped = cmmpose.evaluate(run, maps, out_of_range="clamp")
    assert clamped.provenance["points_clamped"] > 0
    # Both stay near the noise floor here (the thesis maps are not linear in
    # temperature, so which is closer depends on the machine), and they differ.
    assert ev.compensated.rms_accuracy_error < 3e-3 and clamped.compensated.rms_accuracy_error < 3e-3
    assert np.abs(ev.compensated.lengths - clamped.compensated.lengths).max() > 1e-4


def _recovered(run: Run, cut_s: float) -> Run:
    """The run as recovered after the recorder stopped: the thermocouple log
    ends ``cut_s`` seconds before the last point."""
    log = dict(run.temperatures)
    keep = np.asarray(log["t"]) <= run.points["t"].max() - cut_s
    log = {k: np.asarray(v)[keep] for k, v in log.items()}
    return Run(points=run.points, scans=run.scans, poses=run.poses, temperatures=log,
               temperature_channels=run.temperature_channels, artefact=run.artefact, maps=run.maps,
               metadata=run.metadata)


def test_a_recovered_run_evaluates_and_diagnoses(tmp_path):
    run = simulate(22.5)
    short = _recovered(run, 60.0)
    ev = cmmpose.evaluate(short, MAPS)
    assert ev.compensated.rms_accuracy_error < 2e-3
    cmmpose.diagnose(short, MAPS, patterns=False, max_effects=0)
    long = _recovered(run, 200.0)
    with pytest.raises(cmmpose.InputError, match=r"outside the temperature log.*120 s held.*log_hold="):
        cmmpose.evaluate(long, MAPS)
    with pytest.raises(cmmpose.InputError, match="log_hold="):
        cmmpose.diagnose(long, MAPS, patterns=False, max_effects=0)
    assert cmmpose.evaluate(long, MAPS, log_hold=300.0).compensated is not None
    long.save(tmp_path / "long")
    r = cli("evaluate", tmp_path / "long")
    assert r.exit_code != 0 and "--log-hold" in r.output and "log_hold=" not in r.output
    assert cli("evaluate", tmp_path / "long", "--log-hold", 300).exit_code == 0


def test_a_single_map_at_another_temperature_is_never_silent(tmp_path):
    run = simulate(25.0)
    m20 = MAPS.maps[0]
    with pytest.warns(MapTemperatureWarning, match="single map at 20 C was used for points at 2[45]"):
        ev = cmmpose.evaluate(run, m20)
    assert any("single map at 20 C" in n for n in ev.provenance["notes"])
    with warnings.catch_warnings():  # at its own temperature (within the tolerance) a map is silent
        warnings.simplefilter("error", MapTemperatureWarning)
        cmmpose.evaluate(simulate(20.0), m20)
    m20.write(tmp_path / "map20.csv")
    run.save(tmp_path / "r25")
    r = cli("evaluate", tmp_path / "r25", "--maps", tmp_path / "map20.csv")
    assert r.exit_code == 0 and "single map at 20 C" in r.output
    pts = tmp_path / "p.csv"
    pts.write_text("u,v,D,E,F,T\n0,0,450,275,-250,25\n1,1,451,275,-250,25\n")
    r = cli("compensate", pts, tmp_path / "o.csv", "--maps", tmp_path / "map20.csv")
    assert r.exit_code == 0 and "single map at 20 C" in r.output


def test_simulating_beyond_the_maps_names_the_temperature_not_the_reading(tmp_path):
    r = cli("simulate", "--layout", "crossed", "--temperature", 35, "-o", tmp_path / "r35")
    assert r.exit_code != 0
    assert "temperature 35 C is outside the maps' 20..30 C" in r.output and "reading" not in r.output


def test_evaluation_json_carries_provenance_rounded_numbers_and_the_expansion(tmp_path):
    run = simulate(22.5)
    ev = cmmpose.evaluate(run, MAPS, expansion_ppm_per_K=11.5)
    doc = json.loads(ev.to_json())
    p = doc["provenance"]
    assert p["expansion_ppm_per_K"] == 11.5
    assert p["maps"]["kind"] == "set" and p["maps"]["temperatures_C"] == [20.0, 25.0, 30.0]
    assert p["cmmpose_version"] == cmmpose.__version__ and p["date_utc"].endswith("+00:00")
    assert "thermocouple log" in p["temperature"]["source"] and len(p["poses"]) == len(run.poses["pose_id"])
    row = doc["results"][1]["rows"][0]
    assert len(repr(row["length_mm"]).split(".")[1]) <= 5 and len(repr(row["deviation_um"]).split(".")[1]) <= 3
    assert "11.5 ppm/K" in str(ev)


def test_policy_arguments_are_checked():
    run = simulate(22.5)
    for kw in ({"out_of_range": "sometimes"}, {"temperature_tolerance": -1.0}, {"log_hold": float("nan")},
               {"temperature_tolerance": True}):
        with pytest.raises(cmmpose.InputError, match=next(iter(kw))):
            cmmpose.evaluate(run, MAPS, **kw)
        with pytest.raises(cmmpose.InputError, match=next(iter(kw))):
            Model(MAPS, **kw)


# -- one policy object: cmmpose.temperature.TemperaturePolicy ---------------------------------------
CLAMP = {"out_of_range": "clamp", "temperature_tolerance": 0.0}


def test_the_policy_is_frozen_hashable_picklable_and_checked():
    p = TemperaturePolicy(out_of_range="clamp", on_gap="interpolate", max_gap=30,
                          sensors={"x_scale": ["X2", "X3"], "mount": "T9"})
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.out_of_range = "raise"
    assert p.sensors == (("mount", ("T9",)), ("x_scale", ("X2", "X3")))  # one spelling, sorted
    assert p == TemperaturePolicy(out_of_range="clamp", on_gap="interpolate", max_gap=30.0,
                                  sensors=["x_scale=X2,X3", "mount=T9"])
    assert hash(p) == hash(pickle.loads(pickle.dumps(p))) and pickle.loads(pickle.dumps(p)) == p
    assert {p: 1}[dataclasses.replace(p)] == 1
    assert TemperaturePolicy.from_dict(json.loads(json.dumps(p.to_dict()))) == p
    assert TemperaturePolicy() == DEFAULT_POLICY and as_policy(None) is DEFAULT_POLICY
    assert as_policy(p, log_hold=5.0) == dataclasses.replace(p, log_hold=5.0)  # a keyword given wins
    for kw, name in (({"on_gap": "skip"}, "on_gap"), ({"broken_channels": "keep"}, "broken_channels"),
                     ({"max_gap": 0}, "max_gap"), ({"sensors": {"nowhere": "X1"}}, "sensors"),
                     ({"sensors": {"x_scale": "X1", "y_scale": "X1"}}, "sensors"), ({"log_hold": -1}, "log_hold")):
        with pytest.raises(cmmpose.InputError, match=name):
            TemperaturePolicy(**kw)


def test_every_function_has_the_same_default_policy():
    import inspect

    from cmmpose.model.inputs import RunInputs
    from cmmpose.filecompensation import compensate_file
    from cmmpose.scale import Compensator, compensate_array, compensate_dataframe, compensate_dataset
    from cmmpose.standards.acceptance import acceptance_test
    from cmmpose.standards.interim import interim_check

    for f in (cmmpose.compensate, cmmpose.evaluate, cmmpose.diagnose, acceptance_test, interim_check,
              compensate_file, compensate_array, compensate_dataframe, compensate_dataset, Compensator.make,
              RunInputs.from_run, cmmpose.evaluation.ballbar.machine_temperature):
        assert inspect.signature(f).parameters["temperature_policy"].default is None, f.__qualname__
    # None is TemperaturePolicy() everywhere; a new diagnosis model holds it too (diagnose once defaulted
    # out_of_range=None, 'the model's', while evaluate defaulted 'raise')
    assert Model(MAPS).policy == TemperaturePolicy()


def test_every_function_gives_the_old_keyword_paths_results():
    from cmmpose.model.inputs import RunInputs
    from cmmpose.standards.acceptance import acceptance_test
    from cmmpose.standards.interim import interim_check

    run, _ = simulate_ballbar_run(MAPS, 20.0, layout="b89", scanner=Scanner(points_per_profile=64), seed=4,
                                  calibrated=("length", "radius"))
    pol = TemperaturePolicy(**CLAMP, log_hold=60.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old = cmmpose.evaluate(run, MAPS, **CLAMP, log_hold=60.0)
        new = cmmpose.evaluate(run, MAPS, temperature_policy=pol)
        assert old.provenance["points_clamped"] > 0
        assert np.array_equal(old.compensated.lengths, new.compensated.lengths)
        assert old.provenance["policy"] == new.provenance["policy"]
        rows = run.points["scan_id"] == run.points["scan_id"][0]
        pose, offset = run.pose(int(run.poses["pose_id"][0]))
        t = cmmpose.evaluation.ballbar.machine_temperature(run, run.points["t"][rows])
        assert np.array_equal(
            cmmpose.compensate(run.uv[rows], run.scales[rows], MAPS, pose, offset, t, **CLAMP),
            cmmpose.compensate(run.uv[rows], run.scales[rows], MAPS, pose, offset, t, temperature_policy=pol))
        kw = {"mpe_form": 200, "mpe_size": 100, "mpe_length": "80+L/300"}
        a = acceptance_test(run, MAPS, out_of_range="clamp", **kw)
        b = acceptance_test(run, MAPS, temperature_policy=TemperaturePolicy(out_of_range="clamp"), **kw)
        assert [c.error_um for c in a.checks] == [c.error_um for c in b.checks]
        a = interim_check(run, MAPS, out_of_range="clamp")
        b = interim_check(run, MAPS, temperature_policy=TemperaturePolicy(out_of_range="clamp"))
        assert a.to_dict()["values"] == b.to_dict()["values"]
        d_old = cmmpose.diagnose(run, MAPS, auto=False, patterns=False, polish=False, **CLAMP)
        d_new = cmmpose.diagnose(run, MAPS, auto=False, patterns=False, polish=False, temperature_policy=pol.replace(
            log_hold=120.0))
        assert d_old.steps[0].figures.rms_accuracy_error == d_new.steps[0].figures.rms_accuracy_error
    i_old = RunInputs.from_run(run, log_hold=60.0)
    i_new = RunInputs.from_run(run, temperature_policy=TemperaturePolicy(log_hold=60.0))
    assert np.array_equal(i_old.temperature, i_new.temperature) and np.array_equal(i_old.gradient, i_new.gradient)


def test_the_scale_out_paths_take_the_policy():
    da = pytest.importorskip("dask.array")
    from cmmpose.scale import Compensator, compensate_array

    assert Compensator.make(MAPS, (90, 90, 0), (1, 2, 3), temperature_policy=TemperaturePolicy(**CLAMP)) == \
        Compensator.make(MAPS, (90, 90, 0), (1, 2, 3), **CLAMP)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-10, 10, (500, 2)), rng.uniform(100, 400, (500, 3)), np.full(500, 31.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = compensate_array(da.from_array(pts, chunks=(100, 6)), MAPS, (90, 90, 0), (1, 2, 3), **CLAMP).compute()
        b = compensate_array(da.from_array(pts, chunks=(100, 6)), MAPS, (90, 90, 0), (1, 2, 3),
                             temperature_policy=TemperaturePolicy(**CLAMP)).compute()
    assert np.array_equal(a, b)


def _command(path: str):
    import click

    cmd = main
    for name in path.split():
        cmd = cmd.get_command(click.Context(cmd), name)
    assert isinstance(cmd, click.Command)
    return cmd


@pytest.mark.parametrize("path,log", [("evaluate", True), ("diagnose", True), ("standards acceptance", True),
                                      ("standards interim-check", True), ("compensate", False)])
def test_every_command_offers_the_policys_flags_with_its_defaults_and_help(path, log):
    params = {p.name: p for p in _command(path).params}
    for f in dataclasses.fields(TemperaturePolicy):
        if not log and not f.metadata.get("map_side"):
            assert f.name not in params  # a command given temperatures has no log to read
            continue
        p = params[f.name]
        assert p.opts == [f.metadata["flag"]] and p.help == f.metadata["help"]
        assert p.default == f.default and p.multiple == bool(f.metadata.get("multiple"))
        if "choices" in f.metadata:
            assert tuple(p.type.choices) == f.metadata["choices"]


def test_the_cli_builds_the_policy_from_its_flags(tmp_path):
    run = simulate(22.5)
    run.save(tmp_path / "r")
    r = cli("evaluate", tmp_path / "r", "--json", "--on-gap", "interpolate", "--max-gap", 30,
            "--sensor", "x_scale=X2,X3", "--log-hold", 60)
    assert r.exit_code == 0, r.output
    log = json.loads(r.output)["provenance"]["temperature"]["log"]
    assert log["policy"] == {"log_hold_s": 60.0, "on_gap": "interpolate", "max_gap_s": 30.0,
                             "broken_channels": "drop", "sensors": {"x_scale": ["X2", "X3"]}}
    assert log["sensors"]["x_scale"]["read"] == ["X2", "X3"] and "X1" in log["moved"]
    r = cli("evaluate", tmp_path / "r", "--sensor", "x_scale=NOPE")
    assert r.exit_code == 1 and "NOPE" in r.output
    r = cli("evaluate", tmp_path / "r", "--sensor", "nowhere=X1")
    assert r.exit_code == 2 and "--sensor" in r.output


def test_the_kernel_takes_the_policy_whole_and_holds_no_default_of_its_own():
    """Issue 34, item 2: the binding reads the policy object's map side (out_of_range, temperature_tolerance)
    and has no default of its own (it once had 0.0 K against Python's 0.5 K): the one default is Python's."""
    from cmmpose import _core
    from cmmpose.pose import digitizer

    maps = cmmpose.ErrorMapSet.thesis()
    uv, scales = np.array([[0.0, 140.0]]), np.array([[450.0, 275.0, -250.0]])
    d = digitizer((90.0, 90.0, 0.0), (1.001, 264.505, 129.575))
    with pytest.raises(TypeError):
        _core.compensate(uv, scales, maps._core, d, temperature=30.3)  # no policy: no silent default
    # 30.3 C is 0.3 K beyond the set: held at the edge under the default policy (0.5 K), refused at 0.1 K
    xyz, report = _core.compensate(uv, scales, maps._core, d, cmmpose.TemperaturePolicy(), 30.3)
    assert report["held_temperature"] == 1
    with pytest.raises(cmmpose.OutOfRangeError):
        _core.compensate(uv, scales, maps._core, d, cmmpose.TemperaturePolicy(temperature_tolerance=0.1), 30.3)
    assert np.array_equal(xyz, cmmpose.compensate(uv, scales, maps, (90.0, 90.0, 0.0), (1.001, 264.505, 129.575),
                                                  30.3))
