"""Issue 33, sections 1 and 2: one way to apply a model, a check that never
refits, and a model that knows where it holds.

A found model (maps, a squareness, a periodic correction of the X scale) is
applied as saved to runs it was not fitted to, through every door: the
Python API (``cmmpose.evaluate``, ``check_model``, ``Model.compensate_run``,
``cmmpose.compensate``), ``cmmpose evaluate --model``, ``cmmpose diagnose
--model`` (with and without ``--no-auto``). The figures agree to the last
bit (``==`` on floats that went through the same arithmetic; JSON carries
Python's shortest round-trip repr, so the commands' figures compare exactly
too). The saved model is never refitted by its check. A model records its
domain (travel, poses by angle, temperatures, layouts) and parameter
covariance, saved and loaded; applied outside it, or where its correction
is as uncertain as itself, it warns naming what and how far; a model that
makes a run worse than its plain maps says so; ``--strict-model`` turns
those into exit status 1.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import Model
from cmmpose.cli import main
from cmmpose.diagnosis import verify
from cmmpose.errors import InputError, ModelDomainWarning
from cmmpose.evaluation.model_check import check_model
from cmmpose.model.domain import Domain
from cmmpose.model.mapshape import make
from cmmpose.sim import parse_effect, simulate_ballbar_run

MAPS = cmmpose.ErrorMapSet.thesis()
#: The machine's physics beyond the maps: a squareness the model knows.
TRUTH = (parse_effect("squareness:xy=4,yz=-3,zx=2"),)


def _found_model() -> Model:
    """A model as a diagnosis would save it: a squareness near the truth and a small periodic correction of the
    X position error (a map correction, the kind the old check refitted), with uncertainties."""
    ripple = make("dx(X)", "sine", 0.0, 900.0, 170.0)
    model = Model(MAPS).with_values("squareness", [3.8, -3.1, 2.2]).with_values(ripple, [0.8, -0.3])
    return dataclasses.replace(model, uncertainty={"squareness": np.array([0.3, 0.4, 0.4]),
                                                   ripple.name: np.array([0.2, 0.2])})


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    folder = tmp_path_factory.mktemp("applied")
    path = _found_model().save(folder / "m.json")
    runs = {}
    for name, kw in {"b89-21C": dict(temperature=21.0, seed=11),
                     "crossed-24C": dict(layout="crossed", temperature=24.0, seed=12),
                     "b89-27C": dict(temperature=27.0, seed=13, jitter=0.002)}.items():
        run, _ = simulate_ballbar_run(MAPS, effects=TRUTH, **kw)
        run.save(folder / name)
        runs[name] = cmmpose.Run.load(folder / name)
    return path, runs, folder


def test_every_door_gives_the_same_figure_to_the_last_bit(saved):
    path, runs, folder = saved
    model = Model.load(path)
    for name, run in runs.items():
        ev = cmmpose.evaluate(run, model)
        check = check_model(run, model)
        by_diagnosis = verify(model, run)
        assert check.model_um == ev.compensated.rms_accuracy_error * 1e3, name
        assert by_diagnosis["model_rms_um"] == check.model_um and by_diagnosis["plain_rms_um"] == check.plain_um
        res = CliRunner().invoke(main, ["evaluate", str(folder / name), "--model", str(path), "--json"])
        assert res.exit_code == 0, res.output
        doc = json.loads(res.output[res.output.index("{"):])
        assert doc["model_check"]["model_rms_um"] == check.model_um, name
        assert doc["model_check"]["change_um"] == check.change_um
        for extra in ([], ["--no-auto"]):
            res = CliRunner().invoke(main, ["diagnose", str(folder / name), "--model", str(path), "--json",
                                            "--no-map-corrections", "--max-effects", "0", *extra])
            assert res.exit_code == 0, res.output
            doc = json.loads(res.output[res.output.index("{"):])
            assert doc["verification"]["model_rms_um"] == check.model_um, (name, extra)
            assert doc["verification"]["plain_rms_um"] == check.plain_um


def test_points_of_a_run_compensate_alike_through_the_run_and_through_the_points(saved):
    """``Model.compensate_run`` (what evaluate applies) and ``cmmpose.compensate`` of the same points (what a
    point file gets), with the machine temperature per point: the same bits, pose by pose."""
    _, runs, _ = saved
    model = _found_model()
    run = runs["b89-21C"]
    xyz = model.compensate_run(run)
    inputs = model.inputs(run)
    for k, pose_id in enumerate(inputs.pose_ids):
        rows = np.flatnonzero(inputs.pose_index == k)
        pose, offset = run.pose(pose_id)
        got = cmmpose.compensate(run.uv[rows], run.scales[rows], model, pose, offset, inputs.temperature[rows])
        assert np.array_equal(got, xyz[rows]), pose_id


def test_the_check_of_a_model_never_refits_it(saved, tmp_path):
    """``diagnose RUN --model m.json --no-auto --save-model`` writes back the model as it was given: the map
    correction (a shape of the points within a scan) is not polished on the run it checks."""
    path, _, folder = saved
    out = tmp_path / "again.json"
    res = CliRunner().invoke(main, ["diagnose", str(folder / "b89-27C"), "--model", str(path), "--no-auto",
                                    "--no-map-corrections", "--save-model", str(out)])
    assert res.exit_code == 0, res.output
    given, back = Model.load(path), Model.load(out)
    assert given.names == back.names
    for name in given.names:
        assert np.array_equal(given.values(name), back.values(name)), name


def test_a_model_that_harms_a_run_says_so_and_strict_model_exits_1(saved, tmp_path):
    """A squareness the machine does not have (60 arc-seconds) makes a run worse than its plain maps: the
    check says WORSE in words and ``--strict-model`` gates on it; without the flag the command succeeds."""
    _, runs, folder = saved
    wrong = Model(MAPS).with_values("squareness", [60.0, 0.0, 0.0])
    wrong = dataclasses.replace(wrong, uncertainty={"squareness": np.array([0.2, 0.2, 0.2])})
    check = check_model(runs["b89-21C"], wrong)
    assert check.worse and check.change_um > 2 * check.change_u_um
    assert "WORSE" in check.verdict and check.verdict in check.warnings
    path = wrong.save(tmp_path / "wrong.json")
    ok = CliRunner().invoke(main, ["evaluate", str(folder / "b89-21C"), "--model", str(path)])
    assert ok.exit_code == 0, ok.output
    said = " ".join(ok.output.split())
    assert "model check: the model made this run WORSE" in said
    strict = CliRunner().invoke(main, ["evaluate", str(folder / "b89-21C"), "--model", str(path), "--strict-model"])
    assert strict.exit_code == 1, strict.output
    assert "--strict-model" in strict.output
    good = CliRunner().invoke(main, ["evaluate", str(folder / "b89-21C"), "--model", str(saved[0]),
                                     "--strict-model"])
    assert good.exit_code == 0, good.output  # the right physics passes the gate


def test_strict_model_needs_a_model(saved):
    _, _, folder = saved
    res = CliRunner().invoke(main, ["evaluate", str(folder / "b89-21C"), "--strict-model"])
    assert res.exit_code == 2 and "--strict-model" in res.output


def _narrow(model: Model) -> Model:
    """The model with a domain of an XY plate near the table's centre, at 20-21 C, one pose (not the runs')."""
    return dataclasses.replace(model, domain=Domain("thesis", ((0.0, 90.0, 0.0),),
                                                    ((380.0, 520.0), (200.0, 330.0), (-420.0, -380.0)), (20.0, 21.0),
                                                    ("ball_plate xy@x=450,y=265,z=-400",), 1))


def test_outside_the_domain_warns_naming_the_axis_and_the_distance(saved, tmp_path):
    _, runs, folder = saved
    model = _narrow(_found_model())
    run = runs["b89-27C"]
    with pytest.warns(ModelDomainWarning) as caught:
        model.compensate_run(run)
    text = " ".join(str(w.message) for w in caught)
    for axis in "XYZ":
        assert f"{axis} travel" in text
    assert "leaves the 380 to 520 mm the model was fitted on by up to" in text
    assert "machine temperature 2" in text and "leaves the 20.00 to 21.00 C" in text
    assert "at (90, 90, 0) deg is not a pose the model was fitted on (nearest: (0, 90, 0) deg, 90.0 deg away)" in text
    # by how much, in numbers a reader can check: the run's X readings against the trained range
    far = max(380.0 - run.scales[:, 0].min(), run.scales[:, 0].max() - 520.0)
    assert f"by up to {far:.0f} mm" in text
    # inside the domain: nothing said
    inside = dataclasses.replace(model, domain=Domain.of_runs([run], [model.inputs(run)], "thesis"))
    with np_warnings() as quiet:
        inside.compensate_run(run)
    assert not [w for w in quiet if issubclass(w.category, ModelDomainWarning) and "travel" in str(w.message)]
    # the command line prints it and gates on it
    path = model.save(tmp_path / "narrow.json")
    res = CliRunner().invoke(main, ["evaluate", str(folder / "b89-27C"), "--model", str(path), "--strict-model"])
    assert res.exit_code == 1 and "X travel" in " ".join(res.output.split()), res.output


class np_warnings:
    """Record every warning (a context manager)."""

    def __enter__(self):
        import warnings

        self._cm = warnings.catch_warnings(record=True)
        caught = self._cm.__enter__()
        warnings.simplefilter("always")
        return caught

    def __exit__(self, *exc):
        return self._cm.__exit__(*exc)


def test_a_correction_as_uncertain_as_itself_warns():
    """A periodic correction of 1 um whose parameters are known to +-3 um: its predicted uncertainty at the
    points (J C J^T through the kernel) exceeds the correction, so applying it warns; known to +-0.01 um: not."""
    run, _ = simulate_ballbar_run(MAPS, layout="crossed", temperature=21.0, seed=3)
    ripple = make("dx(X)", "sine", 0.0, 900.0, 170.0)
    shaky = dataclasses.replace(Model(MAPS).with_values(ripple, [0.8, 0.6]),
                                uncertainty={ripple.name: np.array([3.0, 3.0])})
    with pytest.warns(ModelDomainWarning, match="predicted standard uncertainty"):
        shaky.compensate_run(run)
    notes = shaky.domain_notes(run)
    assert len(notes) == 1 and "do not determine it here" in notes[0]
    firm = dataclasses.replace(shaky, uncertainty={ripple.name: np.array([0.01, 0.01])})
    assert firm.domain_notes(run) == []
    # an undetermined parameter that moves the points is named
    loose = dataclasses.replace(Model(MAPS).with_values("squareness", [0.0, 5.0, 0.0]),
                                uncertainty={"squareness": np.array([0.1, np.inf, 0.1])})
    assert any("squareness.yz_arcsec" in n or "squareness.yz" in n for n in loose.domain_notes(run))


def test_the_predicted_uncertainty_matches_a_monte_carlo_of_the_parameters():
    """The correction's predicted rms standard uncertainty against the spread of the corrections of models
    drawn from the parameters' covariance (500 draws: the sample sd is within 3 sd / sqrt(2 x 500) ~ 10 %)."""
    from cmmpose.model.domain import correction_uncertainty

    run, _ = simulate_ballbar_run(MAPS, layout="crossed", temperature=21.0, seed=4)
    cov = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, -0.5], [0.0, -0.5, 1.0]])  # arc-second^2
    model = dataclasses.replace(Model(MAPS).with_values("squareness", [2.0, -1.0, 0.5]),
                                uncertainty={"squareness": np.sqrt(np.diag(cov))},
                                covariance={"parameters": ["squareness.xy", "squareness.yz", "squareness.zx"],
                                            "matrix": cov})
    inputs = model.inputs(run)
    found = correction_uncertainty(model, inputs)
    rng = np.random.default_rng(1)
    sub = inputs.take(np.arange(0, len(inputs.uv), 7))
    base = model.compensate(sub)
    draws = np.array([model.with_values("squareness", v).compensate(sub) - base
                      for v in rng.multivariate_normal([2.0, -1.0, 0.5], cov, 500)])
    mc = float(np.sqrt(np.mean(np.sum(draws.var(axis=0), axis=1)))) * 1e3
    assert found["uncertainty_um"] == pytest.approx(mc, rel=0.12)


def test_a_diagnosis_saves_its_domain_and_covariance(tmp_path):
    run, _ = simulate_ballbar_run(MAPS, effects=TRUTH, temperature=22.0, seed=8)
    diag = cmmpose.diagnose(run, MAPS, add=["squareness"], auto=False, map_corrections=False, patterns=False)
    model = diag.model
    d = model.domain
    assert d is not None and d.kinematics == "thesis" and d.runs == 1 and d.layouts == ("ballbar b89",)
    for a in range(3):
        assert d.travel[a][0] == pytest.approx(run.scales[:, a].min()) and \
            d.travel[a][1] == pytest.approx(run.scales[:, a].max())
    assert sorted(d.poses) == sorted({tuple(round(float(x), 6) for x in run.pose(int(p))[0])
                                      for p in run.poses["pose_id"]})
    cov = np.asarray(model.covariance["matrix"])
    assert model.covariance["parameters"] == ["squareness.xy", "squareness.yz", "squareness.zx"]
    assert np.allclose(np.sqrt(np.diag(cov)), model.uncertainty["squareness"], rtol=1e-9)
    assert np.linalg.eigvalsh(cov).min() >= 0
    back = Model.load(model.save(tmp_path / "m.json"))
    assert back.domain == d
    assert np.array_equal(np.asarray(back.covariance["matrix"]), cov)
    assert model.domain_notes(run) == []  # its own run is inside its domain


@pytest.mark.parametrize("key, value, match", [
    ("covariance", {"parameters": ["squareness.xy"], "matrix": [[-1.0]]}, "positive semi-definite"),
    ("covariance", {"parameters": ["squareness.xy", "squareness.yz"], "matrix": [[1.0, 3.0], [3.0, 1.0]]},
     "positive semi-definite"),
    ("covariance", {"parameters": ["roll.x"], "matrix": [[1.0]]}, "covariance.parameters"),
    ("covariance", {"parameters": ["squareness.xy"], "matrix": [[float("nan")]]}, "finite"),
    ("domain", {"kinematics": "thesis", "poses_deg": [[90, 90, 0]], "temperature_C": [20, 21],
                "travel_mm": {"X": [0, 900], "Y": [0, 550], "Z": [-500, float("nan")]}}, "domain.travel_mm.Z"),
    ("domain", {"kinematics": "thesis", "poses_deg": [[90, 90, 0]], "temperature_C": [-300, 21],
                "travel_mm": {"X": [0, 900], "Y": [0, 550], "Z": [-500, 0]}}, "domain.temperature_C"),
    ("domain", {"kinematics": "thesis", "poses_deg": [[90, 90, 0]], "temperature_C": [22, 21],
                "travel_mm": {"X": [0, 900], "Y": [0, 550], "Z": [-500, 0]}}, "lower end is above"),
])
def test_a_bad_domain_or_covariance_in_a_model_file_is_named(tmp_path, key, value, match):
    doc = Model(MAPS).with_values("squareness", [1.0, 2.0, 3.0]).to_dict()
    doc[key] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc).replace("NaN", "NaN"))
    with pytest.raises(InputError, match=match) as err:
        Model.load(path)
    assert str(path) in str(err.value)


def test_an_undetermined_parameter_is_never_applied():
    """An XY-plane run cannot determine squareness yz and zx: the diagnosis's model holds them at zero (and
    says they are undetermined), so a model found on one plane moves no point through the other planes."""
    run, _ = simulate_ballbar_run(MAPS, layout="crossed", effects=(parse_effect("squareness:xy=6"),), seed=9)
    keep = np.isin(run.scans["position"], [0, 1, 2, 3])  # the crossed layout's XY-plane positions
    ids = run.scans["scan_id"][keep]
    kp = np.isin(run.points["scan_id"], ids)
    xy = cmmpose.Run({k: v[kp] for k, v in run.points.items()}, {k: v[keep] for k, v in run.scans.items()},
                     dict(run.poses), run.temperatures, run.temperature_channels, run.artefact, run.maps,
                     run.metadata, run.created)
    diag = cmmpose.diagnose(xy, MAPS, add=["squareness"], auto=False, map_corrections=False, patterns=False)
    u = diag.model.uncertainty["squareness"]
    values = diag.model.values("squareness")
    assert np.isfinite(u[0]) and abs(values[0] - 6.0) < 4 * u[0] + 1.0
    assert all(math.isinf(x) for x in u[1:]) and np.all(values[1:] == 0.0)
