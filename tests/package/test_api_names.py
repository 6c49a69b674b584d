"""Issue 26: one name per concept in the API (docs/conventions.md, "Names").
The maps argument is ``maps`` everywhere; lengths in mm carry no unit suffix;
other units do (``expansion_ppm_per_K``, ``u_length_certificate_um``)."""

from __future__ import annotations

import inspect

import cmmpose
from cmmpose.calibration import alignment
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.standards import acceptance_test, interim_check, probing_test


def test_every_function_that_compensates_calls_its_maps_maps():
    for function in (cmmpose.compensate, cmmpose.compensate_file, cmmpose.evaluate, acceptance_test, interim_check,
                     alignment.alpha_beta_from_vernier, alignment.gamma_from_plane_scan,
                     alignment.reference_centre_reading, cmmpose.evaluation.evaluate_artefact, cmmpose.diagnose,
                     diagnose_jointly):
        params = inspect.signature(function).parameters
        assert "maps" in params and not {"error_map", "model"} & set(params), function.__name__


def test_lengths_in_mm_carry_no_suffix_and_expansion_is_in_ppm_per_kelvin():
    for function in (cmmpose.evaluate, acceptance_test, interim_check, probing_test):
        params = inspect.signature(function).parameters
        assert not [p for p in params if p.endswith("_mm")], function.__name__
        assert "expansion" not in params, function.__name__
    for function in (cmmpose.evaluate, acceptance_test, interim_check):
        assert "expansion_ppm_per_K" in inspect.signature(function).parameters
