"""Structure no library effect explains (issue 16): the periodic search finds a
ripple on any axis with its period, amplitude and phase, stays silent on
noise, and the drafted user effects are valid Python that the diagnosis takes."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.diagnosis.pattern_results import Pattern, Patterns
from cmmpose.diagnosis.unexplained import Finding, periodic_errors, unexplained_findings, user_effect_skeleton
from cmmpose.fitting import fit_spheres
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()


@functools.lru_cache(maxsize=None)
def clean_run(layout="b89", seed=3):
    run, _ = simulate_ballbar_run(MAPS, 22.5, [], layout=layout, jitter=0.0015, seed=seed,
                                  scanner=Scanner(points_per_profile=256))
    return run


def rippled(run, reading, amplitude_mm, period_mm, phase=0.0):
    pts = dict(run.points)
    pts[reading] = pts[reading] + amplitude_mm * np.sin(2 * np.pi * pts[reading] / period_mm + phase)
    return dataclasses.replace(run, points=pts)


def search(run):
    model = Model(MAPS)  # the run's poses and temperatures, as the diagnosis compensates
    xyz = model.compensate(model.inputs(run))
    return periodic_errors(run, xyz, fit_spheres(xyz, run.points["scan_id"]))


# A reading varies within a scan only along the sweep: B89 sweeps along X, the
# crossed layout along X and Y. A ripple on an axis no scan sweeps moves whole
# scans and is taken up by the sphere fits (docs/user-effects.md).
@pytest.mark.parametrize("layout, reading, axis, period, phase", [("b89", "D", "x", 12.0, 0.0),
                                                                  ("crossed", "E", "y", 25.0, 1.0),
                                                                  ("crossed", "D", "x", 30.0, -2.0)])
def test_a_ripple_is_found_with_its_period_amplitude_and_phase(layout, reading, axis, period, phase):
    found = search(rippled(clean_run(layout, 4), reading, 0.0015, period, phase))
    assert found and found[0].axis == axis and found[0].input == reading, [f.description for f in found]
    f = found[0]
    assert f.period_mm == pytest.approx(period, rel=2e-3)
    assert f.size_um == pytest.approx(1.5, abs=0.25)
    # a sin(w s + phase) = (a cos phase) sin(w s) + (a sin phase) cos(w s)
    np.testing.assert_allclose(f.phase, [1.5 * np.cos(phase), 1.5 * np.sin(phase)], atol=0.35)
    assert f.p_value < f.threshold


def test_noise_and_small_ripples_raise_nothing():
    for layout, seed in (("b89", 3), ("crossed", 4), ("b89", 5)):
        assert search(clean_run(layout, seed)) == []
    # below the 0.2 um floor: not reported even where significant
    assert search(rippled(clean_run(), "D", 0.0001, 12.0)) == []
    # shorter than two profile spacings (5.3 mm here): aliased, not searched, so not misreported
    assert all(f.period_mm > 11.0 for f in search(rippled(clean_run(), "D", 0.0015, 4.0)))


def test_patterns_become_findings_that_say_what_the_model_holds():
    p = Pattern("point", "point fit residual", "v", "mm", "quadratic", 0.01, 1e-12, (2, 9000), 9000, 0.18,
                "scanner depth scale", significant=True)
    q = dataclasses.replace(p, quantity="t in scan", hint="drift", significant=False)
    pats = Patterns((p, q), 1e-3, 1e-5)
    (f,) = unexplained_findings(pats, [], ["scanner-scale"])
    assert f.kind == "pattern" and f.input == "v" and f.in_model == ("scanner-scale",)
    assert "in the model already" in f.description
    (f,) = unexplained_findings(pats, [], [])
    assert "consistent with scanner depth scale" in f.description and f.in_model == ()
    assert unexplained_findings(None, [], []) == []


def test_drafts_are_valid_user_effects(tmp_path):
    from cmmpose.model.spec import load_user_effect as _load_user_effect

    periodic = Finding("periodic", "E", "a ripple", 1.0, 1e-9, 1e-6, period_mm=7.5, phase=(1.0, 0.0), axis="y")
    pattern = Finding("pattern", "incidence", "point fit residual vs incidence", 0.5, 1e-9, 1e-6)
    n = 50
    inputs = {k: np.linspace(0, 100, n) for k in ("u", "v", "D", "E", "F", "t", "temperature", "x", "y", "z",
                                                  "incidence")}
    for k, f in enumerate((periodic, pattern)):
        path = tmp_path / f"draft{k}.py"
        path.write_text(user_effect_skeleton(f, name=f"draft-{k}"))
        effect = _load_user_effect(str(path))
        zero = effect.correction(inputs, np.zeros(effect.size))
        assert zero.shape == (n, 3) and np.all(zero == 0)
        one = effect.correction(inputs, np.ones(effect.size))
        assert np.any(one != 0)
    # the periodic draft acts along its axis only
    one = _load_user_effect(str(tmp_path / "draft0.py")).correction(inputs, np.ones(2))
    assert np.all(one[:, [0, 2]] == 0) and np.any(one[:, 1] != 0)


def test_bad_user_effect_files_are_clear(tmp_path):
    run_dir = tmp_path / "run"
    clean_run().save(run_dir)
    for text, words in (("x = 1\n", "must define EFFECT"), ("raise ValueError('boom')\n", "ValueError: boom"),
                        ("import numpy\nEFFECT = 3\n", "must define EFFECT")):
        path = tmp_path / "effect.py"
        path.write_text(text)
        res = CliRunner().invoke(main, ["diagnose", str(run_dir), "--user-effect", str(path)])
        assert res.exit_code != 0 and words in res.output and "effect.py" in res.output, res.output
        assert "Traceback" not in res.output


def test_two_hidden_effects_both_found_and_no_invented_structure():
    """The issue's case: squareness yz and a lateral scanner scale. Both are
    found; the final model's own parameter imprecision (a depth scale fitted
    on 400 points per scan) no longer shows up as a 'consistent with depth
    scale' pattern on every point, since the scanner effects are refitted on
    POLISH_POINTS_PER_SCAN points."""
    from cmmpose.sim import effects as E

    # `cmmpose simulate --effect squareness:yz=20 --effect scanner-scale:lateral=0.0006`: the CLI's defaults
    run, _ = simulate_ballbar_run(MAPS, 20.0, [E.Squareness(yz=20.0), E.ScannerScale(lateral=6e-4)], seed=0)
    unpolished = cmmpose.diagnose(run, max_effects=3, polish=False)
    assert {f.input for f in unpolished.unexplained} == {"v", "incidence"}  # what the issue saw
    d = cmmpose.diagnose(run, max_effects=3)
    assert sorted(d.added) == ["scanner-scale", "squareness"]
    assert d.unexplained == [], [f.description for f in d.unexplained]
    assert not [p.title for p in d.patterns if p.significant]
    lat = next(x for x in d.decisions() if x["name"] == "scanner-scale")
    assert abs(lat["values"]["lateral"] - 6e-4) < 4 * lat["uncertainty"]["lateral"]
    assert abs(lat["values"]["depth"]) < 4 * lat["uncertainty"]["depth"]


def test_a_joint_diagnosis_says_what_each_run_leaves_unexplained():
    """Issue 33, section 6 and "every other case reported as ambiguous or unexplained": the joint diagnosis looks
    in each run's residuals as the single-run one does (each family at ALPHA over the runs together), and names
    the run of each finding; clean runs give none."""
    from cmmpose.diagnosis.joint import diagnose_jointly

    runs = [rippled(clean_run("b89", s), "D", 0.0015, 12.0) for s in (3, 5)]
    d = diagnose_jointly(runs, MAPS, max_effects=2, run_names=["left", "right"])
    periodic = [f for f in d.unexplained if f.kind in ("periodic", "local")]
    assert {f.description.split(":")[0] for f in periodic} == {"left", "right"}, [f.description for f in d.unexplained]
    assert all(f.input == "D" and f.period_mm == pytest.approx(12.0, rel=5e-3) for f in periodic)
    assert d.claims["unexplained"]
    clean = diagnose_jointly([clean_run("b89", 3), clean_run("b89", 5)], MAPS, max_effects=2)
    assert clean.unexplained == [], [f.description for f in clean.unexplained]
    assert diagnose_jointly(runs, MAPS, max_effects=2, patterns=False).unexplained == []
