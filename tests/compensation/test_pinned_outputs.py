"""Pinned numerical outputs: today's results, stored before the effects/kernel
redesign, recomputed and compared so the refactor can prove nothing moved.

Pinned (computed by ``tests/support/pinned/make_pinned.py``, whose functions this
module imports; regenerate with ``PYTHONPATH=python python tests/support/pinned/make_pinned.py``
only for an intended change of results):

a. the ``cmmpose demo`` run (thesis maps, 22.5 C, seed 0, 3 um jitter): a subset of the
   recorded points, per-position lengths uncompensated and compensated, rms;
b. ``data/examples/sphere_scan.csv`` compensated as the CI's ``cmmpose compensate`` line;
c. ``diagnosis.Model`` compensation with each library effect (kernel, pose,
   length) alone at its prior, and the thesis model, with the lengths at 20 C;
d. simulator truth with every simulator effect switched on;
e. one ``cmmpose.diagnose`` (hidden squareness offset): effects and fitted values.

Tolerances: a refactor may reorder floating-point sums, which moves results
by a few ulps (~1e-13 mm), far below any metrological meaning; so cases a-d
are compared to an absolute 1e-12 (mm for coordinates and lengths, the same
absolute value for u, v in mm and t in s), rtol 0. The diagnosis fits by
Gauss-Newton through finite-difference sensitivities and a least-squares solve
whose summation order depends on the CPU's BLAS kernel (AVX2, AVX-512), which
amplify such ulps: on an AVX-512 CPU a squareness of -0.16 arcsec moved by
2.3e-10 arcsec (relative 1.4e-9, so a relative tolerance near zero fails). Its
fitted values are therefore compared absolutely, to 1e-6 in each parameter's
own unit (arc-seconds here: 1e-6 arcsec turns a 1 m arm by 5 pm, four
thousand times the CPU-to-CPU spread and a million times below the fit's own
uncertainty of about 0.3 arcsec), and the rms to 1e-9 mm (1 pm). CI runs the
suite twice, with OpenBLAS's default kernel and with OPENBLAS_CORETYPE=Haswell.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from repo import PINNED
from repo_scripts import load_script



def _load_make_pinned():
    return load_script(PINNED / "make_pinned.py")


mp = _load_make_pinned()

ATOL = 1e-12  # see the module docstring
DIAG_ATOL = 1e-6  # in each fitted parameter's unit (arc-seconds, ppm, ...): see the module docstring
DIAG_RMS_ATOL_MM = 1e-9


@pytest.fixture(scope="module")
def stored():
    with np.load(mp.OUTPUTS) as z:
        return {k: z[k] for k in z.files}


def _compare(stored, fresh, prefix):
    want = sorted(k for k in stored if k.startswith(prefix + "__"))
    assert sorted(fresh) == want, "the set of pinned arrays changed"
    for key in want:
        assert fresh[key].shape == stored[key].shape, key
        np.testing.assert_allclose(fresh[key], stored[key], rtol=0, atol=ATOL, err_msg=key)


def test_demo_run_and_evaluation(stored):
    _compare(stored, mp.case_demo(), "demo")


def test_example_scan_compensation(stored):
    _compare(stored, mp.case_example_scan(), "scan")


def test_model_with_each_library_effect(stored):
    names = {s.name for s in mp.model_effect_specs()}
    assert names >= {"squareness", "scale", "roll", "axis-temperature", "granite-gradient", "latency",
                     "scanner-scale", "incidence", "alignment", "mount-offset", "artefact-expansion"}
    _compare(stored, mp.case_model_effects(), "model")


def test_simulator_truth_with_every_effect(stored):
    _compare(stored, mp.case_sim_effects(), "simfx")


def test_one_diagnosis():
    want = json.loads(mp.DIAGNOSIS.read_text())
    got = mp.case_diagnosis()
    assert got["added"] == want["added"]
    assert got["steps"] == want["steps"]
    assert [e["name"] for e in got["effects"]] == [e["name"] for e in want["effects"]]
    for g, w in zip(got["effects"], want["effects"]):
        assert g["params"] == w["params"]
        np.testing.assert_allclose(g["values"], w["values"], rtol=0, atol=DIAG_ATOL, err_msg=g["name"])
    np.testing.assert_allclose(got["rms_accuracy_error_mm"], want["rms_accuracy_error_mm"], rtol=0, atol=DIAG_RMS_ATOL_MM)
