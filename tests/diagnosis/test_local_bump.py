"""Issue 33, "Done when": where the physics is a shape of a map component, at least half of the unseen excess
error is removed. The case: a local Y straightness bump along X (benches/unseen_placements.py, ``bump``), a
plate at two XY placements, the model applied as saved to a third XY placement and an XZ one.

Two causes kept it below half: hat knots finer than the balls' pitch (a knot interval with no ball in it is
left to the prior, and the fit zig-zags between the training balls, where the unseen placement's balls lie),
and, with two runs, a map shape judged holding a whole run out (the run far from the bump tests nothing, and
the real shape failed)."""

import importlib.util
import math
import warnings

import numpy as np

from cmmpose.diagnosis.cv import MAP_RUNS_OUT, cv_groups, map_runs_out
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import JointProblem
from cmmpose.diagnosis.mapfamily import HAT_FRACTIONS, coverage_gap, hat_spacings
from cmmpose.model import Model
from repo import REPO

BENCH = REPO / "benches" / "unseen_placements.py"


def _bench():
    spec = importlib.util.spec_from_file_location("unseen_placements", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
