"""Honest words (issue 33, section 7): a rise is never called a fall, the
advice never asks for data the run already has, a local error is never
called periodic, and a joint diagnosis gives every run's figures.

Console text is read at an explicit width, never at the terminal's."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.diagnosis.console import as_text, verdict
from cmmpose.diagnosis.unexplained import periodic_errors, user_effect_skeleton
from cmmpose.diagnosis.wording import change_text, without_held_needs
from cmmpose.fitting import fit_spheres
from cmmpose.sim import effects as E
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()


def _flat(text: str) -> str:
    """Text with Rich's wrapping and table rules undone: words separated by single spaces."""
    return " ".join(re.sub(r"[│┃┏┓┗┛┡┩└┘┌┐├┤┬┴┼━─╇╈╋┳┻]", " ", text).split())


@pytest.fixture(scope="module")
def squareness_diagnosis(tmp_path_factory):
    folder = tmp_path_factory.mktemp("words") / "run"
    res = CliRunner().invoke(main, ["simulate", "--effect", "squareness:xy=20", "-o", str(folder)])
    assert res.exit_code == 0, res.output
    return cmmpose.diagnose(cmmpose.Run.load(folder))


def test_a_rise_is_never_called_a_fall():
    assert change_text("the rms", 4.34, 4.35) == "the rms rose from 4.34 um to 4.35 um"
    assert change_text("the rms", 4.35, 4.34) == "the rms fell from 4.35 um to 4.34 um"
    assert change_text("the rms", 4.340, 4.3449) == "the rms stayed at 4.34 um"
    said = change_text("the rms", 4.34, 4.35, u_um=0.3)
    assert said.startswith("the rms is unchanged within its uncertainty") and "+0.01 ± 0.30 um" in said
    assert "fell" not in said and "rose" not in said
    assert "rose" in change_text("the rms", 4.34, 7.30, u_um=0.3)


def test_a_diagnosis_whose_error_rose_says_it_rose(squareness_diagnosis, tmp_path):
    """The steps' figures swapped: the 'final' model's error is the larger. Neither the console's verdict nor
    the HTML report's says it fell."""
    d = squareness_diagnosis
    first, last = d.steps[0], d.steps[-1]
    worse = replace(d, steps=[replace(first, figures=last.figures), *d.steps[1:-1],
                              replace(last, figures=first.figures)])
    found = dict(verdict(worse))["found"]
    assert "rms accuracy error rose from" in found and "error fell" not in found, found
    from cmmpose.diagnosis.html_report import _verdict

    text = _verdict(worse, None, None)
    assert "rms accuracy error rose from" in text and "rms accuracy error fell" not in text, text


def test_no_advice_to_take_a_calibrated_length_the_run_has(tmp_path):
    res = CliRunner().invoke(main, ["simulate", "--calibrated", "--effect", "scale:x=10", "-o", str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    run = cmmpose.Run.load(tmp_path / "r")
    assert run.artefact.get("calibrated_length_mm") is not None
    d = cmmpose.diagnose(run)
    assert d.run_has["calibrated bar length"]
    doc = d.to_json()
    for text in (doc, str(d), as_text(d, verbose=False, width=100)):
        assert "needs: a calibrated bar length" not in text
        flat = _flat(text)
        assert not re.search(r"(scale|artefact-expansion): a calibrated bar length", flat), flat
    reasons = [x["reason"] for x in d.decisions() if x["name"] in ("scale", "artefact-expansion")]
    assert reasons and all("needs: a calibrated bar length" not in r for r in reasons)


def test_held_needs_are_rewritten_and_others_kept():
    reveal = "a calibrated bar length at 20 C, or runs at two temperatures"
    text = f"a typical x would stand only 0.1 sigma above the noise here; needs: {reveal}"
    said = without_held_needs(text, reveal, {"calibrated bar length": True})
    assert "needs:" not in said and "already has this (calibrated bar length)" in said
    assert without_held_needs(text, reveal, {"calibrated bar length": False}) == text
    assert without_held_needs(text, reveal, None) == text


TRUTH = [E.ArtefactExpansion(ppm_per_kelvin=11.5), E.Squareness(yz=12.0)]


@functools.lru_cache(maxsize=None)
def _joint_runs():
    return tuple(simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), t, TRUTH, jitter=0.0015, seed=s,
                                      scanner=Scanner(points_per_profile=256))[0] for t, s in ((21.0, 1), (27.0, 2)))


def test_a_joint_diagnosis_gives_every_runs_figures_at_every_step():
    from cmmpose.diagnosis.joint import diagnose_jointly

    d = diagnose_jointly(list(_joint_runs()), max_effects=3)
    assert len(d.steps) > 1
    for s, per_run in zip(d.steps, d.run_figures):
        assert s.run_figures is not None and len(s.run_figures) == 2
        assert [f.rms_accuracy_error for f in s.run_figures] == [f.rms_accuracy_error for f in per_run]
    doc = json.loads(d.to_json())
    for step in doc["steps"]:
        assert [r["run"] for r in step["runs"]] == ["run 1", "run 2"]
    second = [step["runs"][1]["rms_accuracy_error_um"] for step in doc["steps"]]
    assert second == pytest.approx([f[1].rms_accuracy_error * 1e3 for f in d.run_figures])
    assert second != [step["rms_accuracy_error_um"] for step in doc["steps"]]  # not the first run's again
    text = _flat(as_text(d, verbose=False, width=100))
    found = dict(verdict(d))["found"]
    for i, per_run in enumerate(zip(d.run_figures[0], d.run_figures[-1])):
        a, b = (f"{f.rms_accuracy_error * 1e3:.2f}" for f in per_run)
        assert f"run {i + 1}:" in found and a in found and b in found, found
        assert a in text and b in text
    assert len(as_text(d, verbose=False, width=100).rstrip("\n").splitlines()) <= 40


@functools.lru_cache(maxsize=None)
def _clean_run():
    run, _ = simulate_ballbar_run(MAPS, 22.5, [], jitter=0.0015, seed=4, scanner=Scanner(points_per_profile=256))
    return run


def _search(run):
    model = Model(MAPS)
    xyz = model.compensate(model.inputs(run))
    return periodic_errors(run, xyz, fit_spheres(xyz, run.points["scan_id"]))


def _with_reading(run, reading, shift_mm):
    pts = dict(run.points)
    pts[reading] = pts[reading] + shift_mm(pts[reading])
    return dataclasses.replace(run, points=pts)


@pytest.mark.parametrize("half_mm", [40.0, 80.0])
def test_a_local_ripple_is_called_local_not_periodic(half_mm, tmp_path):
    """A 12 mm ripple on a stretch of the X scale only (357 ± half_mm mm of a 170-730 mm travel): the search's
    sine fits it, but it does not repeat over the travel. It is reported local, where it sits, and never
    periodic; a ripple over the whole travel stays periodic."""
    run = _clean_run()
    centre = 357.5
    local = _with_reading(run, "D", lambda s: 0.003 * np.sin(2 * np.pi * s / 12.0) * (np.abs(s - centre) < half_mm))
    found = _search(local)
    assert found and found[0].kind == "local", [f.description for f in found]
    f = found[0]
    assert "periodic error" not in f.description and "not periodic" in f.description
    a, b = f.where_mm
    assert a < centre < b and b - a < 0.6 * (run.points["D"].max() - run.points["D"].min())
    assert json.loads(json.dumps(f.to_dict()))["where_mm"] == pytest.approx([a, b])
    # its draft is a bump where it sits, and loads as a user effect
    from cmmpose.model import load_user_effect

    path = tmp_path / "bump.py"
    path.write_text(user_effect_skeleton(f, name="bump"))
    effect = load_user_effect(str(path))
    s = np.linspace(150, 750, 61)
    inputs = {k: s for k in ("u", "v", "D", "E", "F", "t", "temperature", "x", "y", "z", "incidence")}
    corr = effect.correction(inputs, np.ones(effect.size))[:, 0]
    assert abs(corr[np.argmin(abs(s - (a + b) / 2))]) > 10 * abs(corr[0])
    whole = _search(_with_reading(run, "D", lambda s: 0.0015 * np.sin(2 * np.pi * s / 12.0)))
    assert whole and whole[0].kind == "periodic" and "a periodic error along x" in whole[0].description


def test_a_local_bump_is_not_called_periodic():
    """A 20 um bump 3 mm wide on the X scale: what the periodic search finds of it is local."""
    run = _clean_run()
    found = _search(_with_reading(run, "D", lambda s: 0.02 * np.exp(-((s - 357.5) / 3.0) ** 2)))
    assert all(f.kind != "periodic" and "periodic error" not in f.description for f in found), \
        [f.description for f in found]


def test_a_one_cycle_sine_correction_is_not_called_periodic():
    from cmmpose.diagnosis.mapfamily import parse

    one = parse("map:dx(Y):sine478[37,515]")  # one cycle over the travel: a shape, not shown to repeat
    many = parse("map:dx(Y):sine95.6[37,515]")
    assert "periodic" not in one.physics.replace("to call it periodic", "") and "sinusoidal" in one.physics
    assert "a periodic error of period 95.6 mm" in many.physics
