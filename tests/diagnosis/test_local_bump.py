"""Issue 33, "Done when": where the physics is a shape of a map component, at least half of the unseen excess
error is removed. The case: a local Y straightness bump along X (benches/unseen_placements.py, ``bump``), a
plate at two XY placements, the model applied as saved to a third XY placement and an XZ one.

Two causes kept it below half: hat knots finer than the balls' pitch (a knot interval with no ball in it is
left to the prior, and the fit zig-zags between the training balls, where the unseen placement's balls lie),
and, with two runs, a map shape judged holding a whole run out (the run far from the bump tests nothing, and
the real shape failed)."""

import math
import warnings

import numpy as np
import pytest

from cmmpose.diagnosis.cv import MAP_RUNS_OUT, cv_groups, map_runs_out
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import JointProblem
from cmmpose.diagnosis.mapfamily import HAT_FRACTIONS, coverage_gap, hat_spacings
from cmmpose.model import Model
from repo_scripts import bench



def _bench():
    return bench("unseen_placements")


def test_no_knot_spacing_finer_than_the_gaps_between_the_scans():
    span = 613.0
    assert hat_spacings(span, 0.5) == sorted({round(span * f, 1) for f in HAT_FRACTIONS}, reverse=True)
    got = hat_spacings(span, 83.0)
    assert min(got) >= 83.0 and round(span / 7, 1) in got  # the finest whole division the coverage supports
    assert hat_spacings(span, 400.0) == [round(span * HAT_FRACTIONS[0], 1)]  # always one to try
    assert hat_spacings(span, math.inf) == [round(span * HAT_FRACTIONS[0], 1)]


def test_a_plates_coverage_is_its_ball_pitch_and_two_runs_are_judged_within_each():
    bench = _bench()
    runs = [bench.plate_run("noise", p, 1 + i, 24) for i, p in enumerate(bench.TRAIN)]
    one = Problem(Model(bench.MAPS), runs[0])
    assert 80.0 < coverage_gap(one, 0) < 86.0  # KOBA 0420: balls every 83 mm
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        joint = JointProblem(Model(bench.MAPS), runs)
    assert MAP_RUNS_OUT == 3 and map_runs_out(joint) is False and map_runs_out(one) is None
    assert "leave one run out" not in cv_groups(joint, by_run=map_runs_out(joint))[2]


def test_a_local_bump_loses_at_least_half_its_unseen_excess():
    bench = _bench()
    for seed in (1, 3):  # seed 3 added nothing before (the held-out run far from the bump failed it)
        r = bench.one("bump", seed, 48, None)
        assert any(n.startswith("map:dy(X):hat") for n in r["added"]), r["added"]
        same = next(u for u in r["unseen"] if u["where"] == "same plane")
        assert same["removed"] >= 0.5, (seed, same)
        assert all(u["model"] < u["plain"] for u in r["unseen"]), r["unseen"]
        assert not any(u["harm"] and not u["warned"] for u in r["unseen"])


def test_knots_determined_only_in_combination_warn_by_the_combinations_uncertainty():
    """A hat-knot correction is applied as the combination the training runs determine (the rigid fits' null
    directions projected out), so its knots, each undetermined alone, are judged by the pseudo-inverse
    covariance of that combination: no knot is called "not determined ... moves these points"; the covariance
    covers every knot, is positive semi-definite, and holds the applied values in its range (what is applied
    has a finite uncertainty); and the correction's predicted uncertainty at an unseen placement is finite and
    smaller than the correction."""
    from cmmpose.diagnosis.joint import diagnose_jointly
    from cmmpose.model.domain import correction_uncertainty

    bench = _bench()
    train = [bench.plate_run("bump", p, 100 + i, 48) for i, p in enumerate(bench.TRAIN)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = diagnose_jointly(train, bench.MAPS, max_effects=3).model
    hats = [(s, v) for s, v in model.effects if s.name.startswith("map:dy(X):hat")]
    assert hats, [s.name for s, _ in model.effects]
    spec, values = hats[0]
    u = np.ravel(model.uncertainty[spec.name])
    assert np.isinf(u).any()  # some knots alone are not determined: the case this test is about
    names = [f"{spec.name}.{p}" for p in spec.params]
    assert set(names) <= set(model.covariance["parameters"])
    C = model.parameter_covariance(names)
    assert np.linalg.eigvalsh(C).min() >= -1e-9 * np.abs(C).max()
    # The applied values lie in the covariance's range: none of them sits on a direction the data never saw.
    v = np.asarray(values, float)
    np.testing.assert_allclose(C @ np.linalg.pinv(C, rcond=1e-10) @ v, v, atol=1e-6 * np.abs(v).max())
    unseen = bench.plate_run("bump", bench.UNSEEN["same plane"], 107, 48)
    found = correction_uncertainty(model, model.inputs(unseen))
    assert found["undetermined"] == []
    assert 0 < found["uncertainty_um"] < found["correction_um"]
    assert not [n for n in model.domain_notes(unseen) if "was not determined" in n]


def test_the_combinations_predicted_uncertainty_matches_refits_on_fresh_noise():
    """The predicted standard uncertainty of a hat-knot correction at an unseen placement (J C J^T, C the
    pseudo-inverse covariance of the applied combination) against the spread of the same correction refitted
    on 20 training pairs with fresh scanner noise: the rms sd of 20 draws has a relative standard error of about
    1 / sqrt(2 x 19) = 16 %, so the two agree within 35 % (more than two of those; the noise level itself is
    estimated from each run). Measured: 0.71 against 0.75 um."""
    from cmmpose.diagnosis.joint import diagnose_jointly
    from cmmpose.model.domain import correction_uncertainty

    bench = _bench()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        train = [bench.plate_run("bump", p, 100 + i, 48) for i, p in enumerate(bench.TRAIN)]
        model = diagnose_jointly(train, bench.MAPS, max_effects=3).model
        name = next(s.name for s, _ in model.effects if s.name.startswith("map:dy(X):hat"))
        unseen = bench.plate_run("bump", bench.UNSEEN["same plane"], 107, 48)
        inputs = model.inputs(unseen)
        sub = inputs.take(np.arange(0, len(inputs.uv), 50))
        predicted = correction_uncertainty(model, sub)["uncertainty_um"]
        plain = model.without_effects().compensate(sub)
        draws = []
        for s in range(20):
            fresh = [bench.plate_run("bump", p, 1000 + 10 * s + i, 48) for i, p in enumerate(bench.TRAIN)]
            refit = diagnose_jointly(fresh, bench.MAPS, add=[name], auto=False).model
            draws.append(refit.compensate(sub) - plain)
    spread = float(np.sqrt(np.mean(np.sum(np.var(draws, axis=0, ddof=1), axis=1)))) * 1e3
    assert 0.3 < predicted < 3.0  # um: a real uncertainty, neither nothing nor everything
    assert spread == pytest.approx(predicted, rel=0.35)
