"""Checks of a saved model and of a diagnosis against the runs they meet:
the machine configuration (kinematics) a run names, a run given twice to a
joint diagnosis, map-correction alternatives kept through a model file, a
model file's uncertainties, a single map used away from its temperature
inside a model, a calibrated bar length off by a unit slip and an
implausible stated reproducibility."""

from __future__ import annotations

import json
import logging
import math
import shutil
import warnings
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import cmmpose
from cmmpose.model import Model
from cmmpose.evaluation.observables import model_figures
from cmmpose.diagnosis import mapfamily as mf
from cmmpose.model.alternatives import Alternative
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import check_distinct, diagnose_jointly
from cmmpose.evaluation.observables import CALIBRATED_LENGTH_TOLERANCE, check_calibrated_length
from cmmpose.errors import InputError, MapTemperatureWarning
from cmmpose.evaluation.ballbar import evaluate
from cmmpose.evaluation.ballbar_uncertainty import evaluation_uncertainty
from cmmpose.run import Run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()
QUIET = Scanner(points_per_profile=96, noise=0.0)
QUICK = {"auto": False, "map_corrections": False, "patterns": False, "polish": False}
BRIDGE = {"kind": "bundled", "name": "thesis", "kinematics": "moving-bridge"}


def run_with(**kw):
    kw.setdefault("temperature", 22.5)
    return simulate_ballbar_run(scanner=kw.pop("scanner", QUIET), **kw)[0]


# -- 1. the machine configuration ------------------------------------------------


def test_a_model_for_another_configuration_is_refused_naming_the_run_and_both(tmp_path):
    run = run_with(seed=1)
    replace(run, maps=BRIDGE).save(tmp_path / "mb_run")
    mb = Run.load(tmp_path / "mb_run")
    thesis_model = Model(MAPS)
    for apply in (lambda: evaluate(mb, thesis_model), lambda: model_figures(thesis_model, mb),
                  lambda: cmmpose.diagnose(mb, thesis_model, **QUICK)):
        with pytest.raises(InputError, match=r"mb_run.*'moving-bridge'.*'thesis'"):
            apply()
    # Through a saved model file too (its maps.kinematics).
    thesis_model.save(tmp_path / "m.json")
    with pytest.raises(InputError, match="moving-bridge"):
        evaluate(mb, Model.load(tmp_path / "m.json"))
    # The same configuration applies; a run that names none is not checked.
    assert evaluate(mb, Model(MAPS.with_kinematics("moving-bridge"))).compensated is not None
    assert evaluate(replace(run, maps={}), thesis_model).compensated is not None


def test_the_default_diagnosis_starts_from_the_maps_on_the_runs_configuration():
    mb = replace(run_with(seed=1), maps=BRIDGE)
    assert cmmpose.diagnose(mb, **QUICK).model.maps.kinematics == "moving-bridge"


def test_a_joint_diagnosis_refuses_runs_of_different_configurations():
    thesis, mb = run_with(seed=1), replace(run_with(seed=2, temperature=23.5), maps=BRIDGE)
    with pytest.raises(InputError, match=r"a .*'thesis'.*b .*'moving-bridge'"):
        diagnose_jointly([thesis, mb], run_names=["a", "b"], **{k: v for k, v in QUICK.items() if k == "auto"})
    # A starting model on another configuration than both runs': refused too.
    with pytest.raises(InputError, match="moving-bridge"):
        diagnose_jointly([replace(thesis, maps=BRIDGE), mb], Model(MAPS), auto=False, map_corrections=False)
    # Unlike a run given twice: the same points on two configurations are not the same measurement.
    with pytest.raises(InputError, match="configured as"):
        diagnose_jointly([thesis, replace(thesis, maps=BRIDGE)], auto=False)


# -- 2. a run given twice to a joint diagnosis ------------------------------------


def test_a_joint_diagnosis_refuses_a_run_given_twice(tmp_path):
    run, other = run_with(seed=1), run_with(seed=2, temperature=23.5)
    with pytest.raises(InputError, match=r"run 1 and run 2 are the same run.*sqrt 2"):
        diagnose_jointly([run, run], auto=False, map_corrections=False)
    run.save(tmp_path / "sq")
    shutil.copytree(tmp_path / "sq", tmp_path / "copy")
    with pytest.raises(InputError, match=r"sq and .*sq are the same run directory"):
        diagnose_jointly([Run.load(tmp_path / "sq"), Run.load(tmp_path / "." / "sq")], auto=False)
    with pytest.raises(InputError, match=r"sq and .*copy are the same measurement"):
        diagnose_jointly([Run.load(tmp_path / "sq"), Run.load(tmp_path / "copy")], auto=False)
    with pytest.raises(InputError, match=r"second and third are the same measurement"):  # named as the caller names
        diagnose_jointly([other, Run.load(tmp_path / "sq"), Run.load(tmp_path / "copy")], auto=False,
                         run_names=["first", "second", "third"])
    check_distinct([run, other], ["a", "b"])  # two measurements pass


# -- 3. map-correction alternatives in a model file -------------------------------


def test_map_correction_alternatives_are_rebuilt_from_a_model_file(tmp_path, caplog):
    model = Model(MAPS).with_values("squareness", [0.0, 20.0, 0.0])
    spec = mf.make("ex(Z)", "poly", -450.0, -45.0)
    assert spec.kind == "python"  # saved with kind "python", like a user-defined effect
    alt = Alternative("squareness", spec, np.array([1.0, -2.0, 0.5]), 0.3, "aliased on this layout")
    replace(model, alternatives=(alt,)).save(tmp_path / "m.json")
    with caplog.at_level(logging.WARNING):
        back = Model.load(tmp_path / "m.json")
    assert [a.name for a in back.alternatives] == [spec.name]
    assert back.alternatives[0].spec == spec and np.array_equal(back.alternatives[0].values, alt.values)
    assert back.alternatives[0].in_sample_um == pytest.approx(0.3)
    assert "user-defined" not in caplog.text


# -- 4. a model file's uncertainties -----------------------------------------------


def _model_file(tmp_path, u_yz):
    model = replace(Model(MAPS).with_values("squareness", [0.0, 20.0, 0.0]),
                    uncertainty={"squareness": np.array([0.1, 0.2, 0.3])})
    path = model.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    doc["effects"][0]["uncertainty"]["yz"] = u_yz
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))  # json writes a NaN as NaN, which Python's reader takes
    return bad


@pytest.mark.parametrize("u", [math.nan, -5.0, "0.2", True])
def test_a_model_file_with_a_bad_uncertainty_is_refused_at_load(tmp_path, u):
    with pytest.raises(InputError, match=r"bad\.json: effect 'squareness': the uncertainty of parameter 'yz'"):
        Model.load(_model_file(tmp_path, u))


def test_a_null_uncertainty_stays_undetermined_and_zero_is_allowed(tmp_path):
    assert np.array_equal(Model.load(_model_file(tmp_path, None)).uncertainty["squareness"], [0.1, np.inf, 0.3])
    assert np.array_equal(Model.load(_model_file(tmp_path, 0.0)).uncertainty["squareness"], [0.1, 0.0, 0.3])


def test_the_budget_refuses_a_negative_uncertainty_of_a_model_in_memory():
    run = run_with(seed=2)
    model = replace(Model(MAPS).with_values("squareness", [0.0, 20.0, 0.0]),
                    uncertainty={"squareness": np.array([0.1, -0.2, 0.3])})
    ev = evaluate(run, model)
    with pytest.raises(InputError, match=r"squareness.*'yz'"):
        evaluation_uncertainty(run, ev, model)


# -- 5. a single map inside a model -------------------------------------------------


def _single_map_warnings(call) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        call()
    return [str(w.message) for w in caught if issubclass(w.category, MapTemperatureWarning)]


def test_a_single_map_inside_a_model_warns_once_as_the_map_alone_does():
    run = run_with(seed=3, temperature=28.0)
    single = cmmpose.ErrorMap.appendix_b()
    alone = _single_map_warnings(lambda: evaluate(run, single))
    assert len(alone) == 1 and "single map at 22 C" in alone[0]
    assert _single_map_warnings(lambda: evaluate(run, Model(single))) == alone
    assert _single_map_warnings(lambda: cmmpose.diagnose(run, Model(single), **QUICK)) == alone
    # The joint diagnosis names the run.
    said = _single_map_warnings(lambda: diagnose_jointly([run, run_with(seed=4, temperature=27.0)], Model(single),
                                                        auto=False, map_corrections=False))
    assert len(said) == 2 and said[0].startswith("run 1: a single map at 22 C")
    # A map at the run's temperature, or a set: no warning.
    assert _single_map_warnings(lambda: evaluate(run_with(seed=3, temperature=22.0), Model(single))) == []
    assert _single_map_warnings(lambda: evaluate(run, Model(MAPS))) == []


# -- 6. a calibrated bar length off by a slip, an implausible reproducibility ------


@pytest.mark.parametrize("factor, likely", [(10.0, "decimal-point slip"), (0.1, "decimal-point slip"),
                                            (25.4, "inches"), (1000.0, "metres"), (1.05, "typing slip")])
def test_a_calibrated_length_far_from_the_measured_one_is_refused(factor, likely):
    layout = SimpleNamespace(calibrated_length=404.2357 * factor, artefact=None)
    with pytest.raises(InputError, match=rf"cal: run.json's artefact.calibrated_length_mm .*{likely}"):
        check_calibrated_length(layout, np.full(20, 404.2357), "cal")


def test_a_calibrated_length_within_the_tolerance_passes():
    for rel in (-0.99 * CALIBRATED_LENGTH_TOLERANCE, 0.0, 0.99 * CALIBRATED_LENGTH_TOLERANCE):
        check_calibrated_length(SimpleNamespace(calibrated_length=404.2357 * (1 + rel), artefact=None),
                                np.full(20, 404.2357))
    check_calibrated_length(SimpleNamespace(calibrated_length=None, artefact=None), np.full(20, 1.0))


def test_a_diagnosis_refuses_a_calibrated_length_ten_times_the_bar(tmp_path):
    run = run_with(seed=5, calibrated=("length",))
    model_figures(Model(MAPS), run)  # the true calibrated length passes
    bad = replace(run, artefact={**run.artefact, "calibrated_length_mm": 10 * run.artefact["calibrated_length_mm"]})
    bad.save(tmp_path / "cal")
    bad = Run.load(tmp_path / "cal")
    for call in (lambda: cmmpose.diagnose(bad, **QUICK), lambda: model_figures(Model(MAPS), bad)):
        with pytest.raises(InputError, match=r"cal: run.json's artefact.calibrated_length_mm .* decimal-point slip"):
            call()


def test_an_implausible_stated_reproducibility_is_refused():
    problem = Problem(Model(MAPS), run_with(seed=6), {})
    with pytest.raises(InputError, match="reproducibility_um: 1e\\+06 um per axis is implausible"):
        problem.state_reproducibility(1e6)
    with pytest.raises(InputError, match="implausible"):
        problem.state_reproducibility(1000.5)
    problem.state_reproducibility(1000.0)  # a (generous) micrometre figure passes
    problem.state_reproducibility(3.0)


def test_the_command_line_names_its_reproducibility_option(tmp_path, simulated_run):
    from click.testing import CliRunner

    from cmmpose.cli import main

    run = simulated_run
    run.save(tmp_path / "run")
    res = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--reproducibility", "5000"])
    assert res.exit_code != 0 and "--reproducibility: 5000 um per axis is implausible" in res.output, res.output
    assert "reproducibility_um" not in res.output
