"""Pinned numerical outputs: today's results, stored before the effects/kernel
redesign, recomputed and compared so the refactor can prove nothing moved.

Pinned (computed by ``tests/pinned/make_pinned.py``, whose functions this
module imports; regenerate with ``PYTHONPATH=python python tests/pinned/make_pinned.py``
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
Gauss-Newton through finite-difference sensitivities, which amplify such ulps,
hence its fitted values and rms to a relative 1e-9.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

PINNED = Path(__file__).resolve().parent / "pinned"


def _load_make_pinned():
    spec = importlib.util.spec_from_file_location("make_pinned", PINNED / "make_pinned.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


mp = _load_make_pinned()

ATOL = 1e-12  # see the module docstring
DIAG_RTOL = 1e-9


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
        np.testing.assert_allclose(g["values"], w["values"], rtol=DIAG_RTOL, atol=0, err_msg=g["name"])
    np.testing.assert_allclose(got["rms_accuracy_error_mm"], want["rms_accuracy_error_mm"], rtol=DIAG_RTOL, atol=0)
