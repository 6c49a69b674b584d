"""The diagnosis model: its effects inside the Rust kernel against
independent references (the exact rigid-body truth machine of the
simulator, and maps edited by hand), files, user-defined effects, the CLI
and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.pose import digitizer
from cmmpose import _core
from cmmpose.calibration import STANDARD_POSES
from cmmpose.cli import main
from cmmpose.model import LIBRARY, Model, UserEffect
from cmmpose.diagnosis import fit_effect
from cmmpose.evaluation.observables import model_figures
from cmmpose.model.spec import library
from cmmpose.evaluation.ballbar import machine_coordinates, machine_temperature
from cmmpose.run import load_truth
from cmmpose.sim import effects as E
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()
QUIET = Scanner(points_per_profile=96, noise=0.0)


def run_with(effects=(), **kw):
    kw.setdefault("temperature", 22.5)
    return simulate_ballbar_run(effects=effects, scanner=kw.pop("scanner", QUIET), **kw)


def test_no_effects_is_the_thesis_compensation():
    run, _ = run_with(seed=1)
    want = machine_coordinates(run, MAPS, machine_temperature(run, run.points["t"]))
    got = Model(MAPS).compensate(run)
    assert np.abs(got - want).max() < 1e-9


def test_machine_terms_equal_maps_edited_by_hand():
    """Scale error, roll and squareness added in the kernel equal the same
    terms written into the map tables (linear in position, so the tables'
    linear interpolation holds them exactly) and compensated by the thesis
    kernel: an independent path through the map reader and the old kernel."""
    run, _ = run_with(seed=2)
    ppm, roll, sq = np.array([7.0, -4.0, 11.0]), np.array([25.0, -15.0, 30.0]), np.array([3.0, -6.0, 9.0])
    edited = []
    for m in MAPS.maps:
        tables = []
        for k, c in enumerate("XYZ"):
            t = m.table(c).copy()
            t[:, 1 + k] += ppm[k] * 1e-6 * t[:, 0] * 1e3  # um
            t[:, 4 + k] += roll[k] * t[:, 0] / 1000.0  # arc-second
            tables.append(t)
        edited.append(cmmpose.ErrorMap(*tables, tuple(np.add(m.squareness, sq)), m.temperature))
    want = machine_coordinates(run, cmmpose.ErrorMapSet(edited), machine_temperature(run, run.points["t"]))
    model = Model(MAPS).with_values("scale", ppm).with_values("roll", roll).with_values("squareness", sq)
    assert np.abs(model.compensate(run) - want).max() < 1e-9


# effect in the simulator, the same physics as model values, run options,
# tolerance (mm). The truth machine's own round trip leaves 0.002 um; where
# the model needs the thermocouple log (0.02 K noise per channel) the floor
# is 0.13 um, so those take the log's temperatures and a looser tolerance;
# the others take the exact machine temperature.
INVERSIONS = [
    (E.Squareness(xy=12.0, yz=-8.0, zx=5.0), "squareness", [12.0, -8.0, 5.0], {}, 2e-5),
    (E.Scale(x=9.0, y=-6.0, z=12.0), "scale", [9.0, -6.0, 12.0], {}, 2e-5),
    (E.Roll(x=30.0, y=-20.0, z=40.0), "roll", [30.0, -20.0, 40.0], {}, 2e-5),
    (E.AxisTemperature(x=2.0, y=-1.5, z=1.0), "axis-temperature", [1.0], {"temperature": 25.0, "log": True}, 5e-4),
    (E.GraniteGradient(kelvin=1.0, xy=5.0, yz=12.0, zx=-9.0), "granite-gradient", [5.0, 12.0, -9.0],
     {"log": True}, 5e-4),
    (E.Latency(0.01), "latency", [0.01], {"bidirectional": True}, 2e-5),
    (E.ScannerScale(lateral=8e-4, depth=-6e-4), "scanner-scale", [8e-4, -6e-4], {}, 2e-5),
    # Incidence angles come from sphere fits, not the truth.
    (E.Incidence(per_degree=2e-4, per_degree_mm=3e-6), "incidence", [2e-4, 3e-6], {}, 1e-4),
    (E.Alignment(alpha=0.02, beta=-0.015, gamma=0.01), "alignment", [0.02, -0.015, 0.01], {}, 2e-5),
    (E.MountOffset(0.03, -0.02, 0.04), "mount-offset", [0.03, -0.02, 0.04],
     {"reference_poses": STANDARD_POSES}, 2e-5),
]


@pytest.mark.parametrize("effect, name, values, options, tol", INVERSIONS, ids=[i[1] for i in INVERSIONS])
def test_model_with_the_true_values_inverts_the_truth_machine(effect, name, values, options, tol):
    options = dict(options)
    from_log = options.pop("log", False)
    run, (truth, _) = run_with([effect], seed=3, **options)
    base = Model(MAPS, temperature=None if from_log else options.get("temperature", 22.5))
    thesis = base.compensate(run) - truth["true_xyz"]
    model = base.with_values(name, values).compensate(run) - truth["true_xyz"]
    assert np.abs(thesis).max() > 5 * tol, "the effect must matter for the test to mean anything"
    assert np.abs(model).max() < tol, np.abs(model).max()


def test_artefact_expansion_acts_on_the_predicted_length():
    run, _ = run_with([E.ArtefactExpansion(11.5)], seed=4, calibrated=("length",))
    base = model_figures(Model(MAPS), run)
    fixed = model_figures(Model(MAPS).with_values("artefact-expansion", [11.5]), run)
    assert abs(base.length_error * 1e3 - 11.5e-6 * 2.5 * 404.2 * 1e3) < 0.5  # um: L a (T - 20)
    assert abs(fixed.length_error) < 0.5e-3


def test_user_effect_is_fitted_like_a_library_one():
    def y_scale(inputs, ppm):
        out = np.zeros((len(inputs["u"]), 3))
        out[:, 1] = ppm * 1e-6 * inputs["E"]
        return out

    user = UserEffect.create("my-y-scale", y_scale, {"ppm": ("ppm", 5.0)}, physics="Y scale by hand")
    run, _ = run_with([E.Scale(y=25.0)], seed=5, jitter=0.0015, scanner=Scanner(points_per_profile=256),
                      calibrated=("length",))
    d = cmmpose.diagnose(run, candidates=["squareness", user], patterns=False)
    assert d.added == ["my-y-scale"]
    assert abs(d.model.values("my-y-scale")[0] - 25.0) < 0.25 * 25.0


def test_save_and_load_reproduce_the_model(tmp_path):
    run, _ = run_with(seed=6)
    m = Model(MAPS).with_values("squareness", [1.0, 2.0, 3.0]).with_values("latency", [0.004])
    m.save(tmp_path / "m.json")
    back = Model.load(tmp_path / "m.json")
    assert back.names == m.names
    assert np.array_equal(back.compensate(run), m.compensate(run))
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(cmmpose.InputError, match="bad.json"):
        Model.load(tmp_path / "bad.json")
    doc = json.loads((tmp_path / "m.json").read_text())
    doc["effects"][0]["params"] = {"xy": 1.0}
    (tmp_path / "short.json").write_text(json.dumps(doc))
    with pytest.raises(cmmpose.InputError, match="short.json.*squareness"):
        Model.load(tmp_path / "short.json")


def test_bad_input_is_named():
    run, _ = run_with(seed=7)
    m = Model(MAPS)
    with pytest.raises(cmmpose.InputError, match="unknown"):
        fit_effect(m, "no-such-effect", run)
    with pytest.raises(cmmpose.InputError, match="squareness.*3 finite"):
        m.with_values("squareness", [1.0, 2.0])
    with pytest.raises(cmmpose.InputError, match="squareness.*3 finite"):
        m.with_values("squareness", [1.0, np.nan, 2.0])
    with pytest.raises(cmmpose.InputTypeError, match="a cmmpose.Run to fit"):
        fit_effect(m, "squareness", None)
    with pytest.raises(cmmpose.InputError, match="maps"):
        Model("thesis")
    with pytest.raises(cmmpose.InputError, match="prior"):
        UserEffect.create("u", lambda i, a: 0, {"a": ("mm", 0.0)})
    bad = UserEffect.create("u", lambda inputs, a: np.zeros((3, 3)), {"a": ("mm", 1.0)})
    with pytest.raises(cmmpose.InputError, match="u.*\\(N, 3\\)|shape"):
        m.with_values(bad, [1.0]).compensate(run)
    inp = m.inputs(run)
    digitizers = [digitizer(p[:3], p[3:]) for p in m.poses(inp)]

    def call(uv=inp.uv, pose_index=inp.pose_index, temperature=inp.temperature, effects=None):
        return _core.compensate_model(uv, inp.scales, MAPS._core, digitizers, cmmpose.TemperaturePolicy(),
                                      pose_index=pose_index,
                                      inputs={"temperature": temperature}, effects=effects)

    with pytest.raises(cmmpose.InputError, match="unknown term"):
        call(effects={"warp": [1.0]})
    with pytest.raises(cmmpose.InputError, match="latency.*1 finite"):
        call(effects={"latency": [1.0, 2.0]})
    with pytest.raises(cmmpose.OutOfRangeError, match="row 0"):
        call(temperature=inp.temperature + 20.0)
    with pytest.raises(cmmpose.InputError, match="velocity"):
        call(effects={"latency": 0.01})
    with pytest.raises(cmmpose.InputError, match="pose_index"):
        call(pose_index=inp.pose_index + 5)
    nan = inp.uv.copy()
    nan[10, 1] = np.nan
    with pytest.raises(cmmpose.InputError, match="uv.*10|10.*uv"):
        call(uv=nan)
    with pytest.raises(cmmpose.InputError, match="inputs.*float64"):
        _core.compensate_model(inp.uv, inp.scales, MAPS._core, digitizers, cmmpose.TemperaturePolicy(),
                               inputs={"temperature": [20.0]})


def test_library_lists_per_pose_alignment_only_with_several_poses():
    # An effect that follows a sensor is a candidate per thermocouple role only.
    followers = {n for n, s in LIBRARY.items() if s.sensor_input}
    assert followers == {"squareness-temperature"}
    assert set(library([0])) == set(LIBRARY) - followers
    assert {"alignment@0", "alignment@3"} <= set(library([0, 3]))
    assert set(library([0], ["x_scale", "mount"])) == set(LIBRARY) - followers | {
        "squareness-temperature@x_scale", "squareness-temperature@mount"}
    for spec in LIBRARY.values():
        assert spec.physics and spec.reveal and len(spec.params) == len(spec.units) == len(spec.prior)


def test_cli_diagnose_writes_tables_report_json_and_a_reusable_model(tmp_path):
    run, truth = run_with([E.Squareness(xy=25.0)], seed=8, jitter=0.0015, scanner=Scanner(points_per_profile=256))
    run.save(tmp_path / "run", truth=truth)
    # One B89 layout cannot choose between a squareness and rolls of the carriages (issue 33, section 3: their
    # cross-validated rms within one standard uncertainty, -2 log L within 10), whose corrections differ by tens
    # of um at the corners of the travel: the diagnosis adds neither and says so; the user chooses by name.
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--report", str(tmp_path / "r"),
                                  "--save-model", str(tmp_path / "open.json")], env={"COLUMNS": "100"})
    assert r.exit_code == 0, r.output
    assert "cannot choose between squareness, roll" in " ".join(r.output.split())
    assert Model.load(tmp_path / "open.json").names == ()
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--add", "squareness", "--report",
                                  str(tmp_path / "r"), "--save-model", str(tmp_path / "m.json"), "--overwrite"],
                           env={"COLUMNS": "100"})  # the report replaces the first one
    assert r.exit_code == 0, r.output
    assert "squareness" in r.output and "The error falling" in r.output
    html = (tmp_path / "r" / "diagnose.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and "squareness" in html
    model = Model.load(tmp_path / "m.json")
    assert model.names == ("squareness",) and abs(model.values("squareness")[0] - 25.0) < 5.0
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--json", "--no-auto", "--add", "latency"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert [s["label"] for s in doc["steps"]] == ["base", "+ latency"] and doc["steps"][1]["forced"]
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--add", "warp"])
    assert r.exit_code != 0 and "warp" in r.output
    # The truth folder was never read: the diagnosis works without it.
    assert load_truth(tmp_path / "run")[1]["effects"][0]["name"] == "squareness"


def test_models_and_map_sets_compare_by_value():
    # Equal when the maps, temperature policy, effects and values are; an
    # effect's values are arrays, so equality must not ask an array for truth.
    a = Model(cmmpose.ErrorMapSet.thesis()).with_values("squareness", [1.0, 2.0, 3.0])
    b = Model(cmmpose.ErrorMapSet.thesis()).with_values("squareness", [1.0, 2.0, 3.0])
    assert a == b and a.maps == b.maps
    assert a != b.with_values("squareness", [1.0, 2.0, 3.5])
    assert a != Model(cmmpose.ErrorMapSet.thesis())
    assert a != Model(a.maps.at(22.0)).with_values("squareness", [1.0, 2.0, 3.0])
    assert cmmpose.ErrorMapSet.thesis() != cmmpose.ErrorMapSet(cmmpose.ErrorMapSet.thesis().maps[:2])
    assert cmmpose.ErrorMapSet.thesis() != cmmpose.ErrorMapSet.thesis().with_kinematics("moving-bridge")
    assert a != "a model"
