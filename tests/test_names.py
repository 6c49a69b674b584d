"""Issue 26: one name per concept in the API (docs/conventions.md, "Names").
The maps argument is ``maps`` everywhere; lengths in mm carry no unit suffix;
other units do (``expansion_ppm_per_K``, ``u_length_certificate_um``). The old
keywords still work, warned, and a unit change is converted; giving both
spellings is an error."""

from __future__ import annotations

import inspect

import cmmpose
import numpy as np
import pytest
from cmmpose.calibration import alignment
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.standards import acceptance_test, interim_check, probing_test
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMap.appendix_b()
UV = np.array([[1.0, 2.0], [3.0, -4.0]])
SCALES = np.array([[300.0, 200.0, -300.0], [310.0, 210.0, -310.0]])
POSE, OFFSET = cmmpose.Pose(0.0, 0.0, 0.0), cmmpose.MountOffset(0.0, 0.0, -150.0)


def test_every_function_that_compensates_calls_its_maps_maps():
    for function in (cmmpose.compensate, cmmpose.compensate_file, cmmpose.evaluate, acceptance_test, interim_check,
                     alignment.alpha_beta_from_vernier, alignment.gamma_from_plane_scan,
                     alignment.reference_centre_reading, cmmpose.evaluation.evaluate_artefact, cmmpose.diagnose,
                     diagnose_jointly):
        params = inspect.signature(function).parameters
        assert "maps" in params and "error_map" not in params, function.__name__


def test_lengths_in_mm_carry_no_suffix_and_expansion_is_in_ppm_per_kelvin():
    for function in (cmmpose.evaluate, acceptance_test, interim_check, probing_test):
        params = inspect.signature(function).parameters
        assert not [p for p in params if p.endswith("_mm")], function.__name__
        assert "expansion" not in params, function.__name__
    for function in (cmmpose.evaluate, acceptance_test, interim_check):
        assert "expansion_ppm_per_K" in inspect.signature(function).parameters


def test_the_old_maps_keyword_still_works_warned():
    new = cmmpose.compensate(UV, SCALES, maps=MAPS, pose=POSE, offset=OFFSET)
    with pytest.warns(FutureWarning, match="error_map= is now maps="):
        old = cmmpose.compensate(UV, SCALES, error_map=MAPS, pose=POSE, offset=OFFSET)
    np.testing.assert_array_equal(old, new)
    with pytest.raises(cmmpose.InputTypeError, match="give maps= only"):
        cmmpose.compensate(UV, SCALES, maps=MAPS, error_map=MAPS, pose=POSE, offset=OFFSET)


def test_the_old_expansion_in_per_kelvin_is_converted():
    run, _ = simulate_ballbar_run(MAPS, 22.0, layout="crossed", scanner=Scanner(points_per_profile=64), seed=3)
    new = cmmpose.evaluate(run, MAPS, 22.0, expansion_ppm_per_K=11.5)
    with pytest.warns(FutureWarning, match="expansion= is now expansion_ppm_per_K="):
        old = cmmpose.evaluate(run, MAPS, 22.0, expansion=11.5e-6)
    assert old.compensated.expansion == new.compensated.expansion == pytest.approx(11.5e-6, rel=1e-15)
    np.testing.assert_array_equal(old.compensated.lengths_at_20c, new.compensated.lengths_at_20c)
