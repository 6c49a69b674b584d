"""Sensitivities of an artefact run's observables to the machine's effects
(issue 24, "Speed"): for the kernel effects of the machine (squareness,
scale, roll, thermal, latency, the artefact's expansion) the diagnosis takes them from linearised
sphere fits of a sample of each scan's points through the kernel
(``cmmpose.evaluation.artefact_layout.artefact_columns``), not from refitting every
point of the run once per parameter. They must be the finite differences'
columns: on the balls' deviations, which these effects move by micrometres,
to a fraction of a per cent; on the radii and point residuals, which they
barely move (nanometres), to the few per cent that the finite differences'
own refits resolve."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from cmmpose import artefacts
from cmmpose.model import Model
from cmmpose.diagnosis import diagnose, identify
from cmmpose.diagnosis.artefact import artefact_columns, linearised_columns
from cmmpose.errormap import ErrorMapSet
from cmmpose.sim import Scale, Squareness
from cmmpose.sim.artefact_runs import simulate_artefact_run

#: Finite differences with steps ten times the library's: the effects are
#: linear in their parameters, and the refits' convergence noise (about a
#: nanometre) is then well below the change they measure.
STEP = 10.0


@pytest.fixture(scope="module")
def problem():
    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0320"), ["planes"], None, 20.0,
                                   [Squareness(6.0, -4.0, 3.0), Scale(8.0, -6.0, 5.0)], seed=4)
    model = Model(ErrorMapSet.thesis(), temperature=20.0)
    return identify.Problem(model, run), model, run


@pytest.mark.parametrize("name", ["squareness", "scale", "roll"])
def test_linearised_columns_are_the_finite_differences(problem, name, monkeypatch):
    prob, model, _ = problem
    spec = prob.candidates[name]
    assert linearised_columns(spec)
    big = dataclasses.replace(spec, step=tuple(float(s) * STEP for s in spec.steps))
    fast = artefact_columns(prob, model, big, np.zeros(spec.size), prob.base_obs)
    monkeypatch.setattr(identify, "linearised_columns", lambda s: False)
    slow = prob._columns(model, big, np.zeros(spec.size), prob.base_obs)
    first = prob.layout.sizes["length"]
    norm = np.linalg.norm(slow[:first], axis=0)
    seen = norm > 1e-4  # mm per prior: the parameters the placements show
    assert seen.any()
    err = np.linalg.norm(fast[:first] - slow[:first], axis=0)
    assert np.all(err[seen] < 5e-3 * norm[seen]), (name, err / norm)
    rest = np.linalg.norm(slow[first:], axis=0)
    assert np.all(np.linalg.norm(fast[first:] - slow[first:], axis=0) <= 0.1 * rest + 1e-6), name
    # and a wrong model (another effect's columns) is nowhere near
    other = prob.columns["scale" if name != "scale" else "squareness"]
    assert np.linalg.norm(other[:first] - slow[:first]) > 0.3 * np.linalg.norm(slow[:first])


def test_scanner_effects_keep_the_finite_differences(problem):
    """The scanner's and the pose's effects reshape each ball: a sample does
    not carry their small centre shifts, so they are refitted point by point."""
    prob, _, _ = problem
    for name in ("scanner-scale", "incidence", "alignment", "mount-offset"):
        assert not linearised_columns(prob.candidates[name])
    assert linearised_columns(prob.candidates["artefact-expansion"])


def test_the_diagnosis_is_the_same_either_way(problem, monkeypatch):
    _, model, run = problem
    fast = diagnose(run, model, patterns=False, map_corrections=False)
    monkeypatch.setattr(identify, "linearised_columns", lambda s: False)
    slow = diagnose(run, model, patterns=False, map_corrections=False)
    assert fast.added == slow.added and "scale" in fast.added
    for name in fast.added:
        u = fast.final_uncertainty[name]
        assert np.all(np.abs(fast.steps[-1].model.values(name) - slow.steps[-1].model.values(name)) < 0.1 * u)
