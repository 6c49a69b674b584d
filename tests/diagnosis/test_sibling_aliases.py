"""Issue 33, section 3: a map shape's siblings as competing explanations, and pose-out folds.

The map family searches each map component's shape on its own, so the same
shape on another component of the same carriage was never offered beside
the one chosen. A roll of X, ``ex(X)``, moves a point by ``eps x (x - D, y,
z)``: in Y by ``-eps z`` and in Z by ``eps y``. On a step gauge along X
near Y = 0 at one height, that is a Y straightness of X, ``dy(X)``, with
the same shape: the two are aliased, and differ by tens of um at other
heights. (On a ball plate spread over Y the roll's Z move, ``eps y``, tells
them apart: there the diagnosis takes the straightness.) The hidden physics
is a local Y straightness bump along X, made by what the Y scale reports
(docs/user-effects.md), as in benches/unseen_placements.py.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings

import numpy as np
import pytest

import cmmpose
from cmmpose.artefacts import load_artefact
from cmmpose.diagnosis import cv as cvmod
from cmmpose.diagnosis.console import verdict
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.diagnosis.mapfamily import make, parse, sibling_shapes
from cmmpose.errormap import data_path
from cmmpose.model import Model
from cmmpose.sim.artefact_runs import simulate_artefact_run
from cmmpose.sim.scanner import Scanner

GAUGE = load_artefact(data_path("artefacts", "step-gauge-31x20.toml"))
PLATE = load_artefact(data_path("artefacts", "koba-0420.toml"))
MAPS = cmmpose.ErrorMapSet.thesis()
JITTER = 0.0015
#: Two placements of the gauge along X, near Y = 0, at one height: one run.
ALONG_X = ("xy@x=450,y=15,z=-400", "xy@x=480,y=25,z=-400")

HIDDEN = {
    "bump": lambda D, E, F: (0 * D, 0.020 * np.exp(-((D - 450.0) / 60.0) ** 2), 0 * D),
    "periodic": lambda D, E, F: (0.012 * np.sin(2 * np.pi * D / 170.0), 0 * D, 0 * D),
}


def _shifted(run, case="bump"):
    pts = dict(run.points)
    for k, g in zip("DEF", HIDDEN[case](pts["D"], pts["E"], pts["F"])):
        pts[k] = pts[k] + g
    return dataclasses.replace(run, points=pts)


def _sim(artefact, placements, seed, case="bump"):
    return _shifted(simulate_artefact_run(artefact, list(placements), jitter=JITTER, seed=seed,
                                          scanner=Scanner(points_per_profile=96))[0], case)


@functools.cache
def gauge_run():
    return _sim(GAUGE, ALONG_X, 3)


def _quiet(f, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **k)


@functools.cache
def full():
    return _quiet(cmmpose.diagnose, gauge_run(), MAPS, max_effects=3, patterns=False)


def _x_carriage(names) -> set:
    return {n for n in names if n.startswith("map:") and parse(n).component[-2] == "X"}


def test_sibling_shapes_are_the_same_shape_on_the_carriages_other_components():
    spec = make("dy(X)", "hat", 275.0, 894.0, 51.6)
    sib = sibling_shapes(spec)
    assert [s.component for s in sib] == ["dx(X)", "dz(X)", "ex(X)", "ey(X)", "ez(X)"]
    for s in sib:
        assert (s.shape, s.lo, s.hi, s.scale_mm) == ("hat", 275.0, 894.0, 51.6)
        assert np.array_equal(s.knots(), spec.knots())
    sine = make("ez(Y)", "sine", 0.0, 550.0, 120.0, kinematics="moving-bridge", trials=40)
    sib = sibling_shapes(sine, "moving-bridge")
    assert {s.component for s in sib} == {"dx(Y)", "dy(Y)", "dz(Y)", "ex(Y)", "ey(Y)"}
    assert all(s.scale_mm == 120.0 and s.trials == 40 for s in sib)
    assert all(s.kinematics == "moving-bridge" for s in sib if s.kind_of_component == "rotational")
    assert sibling_shapes(make("sq(xy)", "const", 0.0, 550.0)) == []


def test_a_roll_chosen_alone_is_judged_beside_the_straightness_of_the_same_shape():
    """Only the roll is a candidate (a restricted list): the straightness of the same knots is offered beside it
    all the same, explains the gauge alike, and the roll is not added (before, it was)."""
    roll = parse("map:ex(X):hat51.6[275,894]")
    d = _quiet(cmmpose.diagnose, gauge_run(), MAPS, max_effects=3, patterns=False, candidates=[roll])
    assert d.added == []
    (a,) = d.open_ambiguity
    assert set(a.names) >= {roll.name, "map:dy(X):hat51.6[275,894]"}
    assert not a.agree and a.largest_difference_um > 5
    for m in a.members:  # parameters, cross-validated rms +- u, words
        assert m["values"] and m["cv_rms_um"] > 0 and m["cv_rms_u_um"] > 0 and m["physics"]
    words = {m["name"]: m["physics"] for m in a.members}
    assert "roll of X" in words[roll.name] and "straightness dy(X)" in words["map:dy(X):hat51.6[275,894]"]
    assert len(a.where["xyz_mm"]) == 3 and set(a.where["pair"]) <= set(a.names)
    assert any("X carriage" in w and "another height" in w for w in a.equivalences)
    # One run of two placements: the judge holds a whole placement out.
    assert a.split.startswith("leave one placement out") and not a.interpolation_only


def test_the_full_diagnosis_saves_neither_and_names_the_measurement_that_separates_them():
    d = full()
    assert not _x_carriage(d.model.names), d.added
    opened = [a for a in d.open_ambiguity if _x_carriage(a.names)]
    assert opened
    comps = {parse(n).component for a in opened for n in a.names if n.startswith("map:")}
    assert {"dy(X)", "ex(X)"} <= comps
    sep = d.separating
    assert sep is not None and sep["separates"]
    # Another plane or another height than the gauge's (XY at Z = -400).
    assert not (sep["placement"].startswith("xy@") and "z=-400" in sep["placement"]), sep["placement"]
    assert sep["placement"] in dict(verdict(d))["next"]
    doc = json.loads(d.to_json())
    assert any({m["name"] for m in s["members"]} >= set(opened[0].names) for s in doc["ambiguity_sets"])


def test_the_separating_placement_measured_resolves_it_to_the_straightness():
    d = full()
    new = _sim(GAUGE, [d.separating["placement"]], 4)
    joint = _quiet(diagnose_jointly, [gauge_run(), new], MAPS, max_effects=3)
    x = _x_carriage(joint.added)
    assert x and {parse(n).component for n in x} == {"dy(X)"}, joint.added
    assert not any(_x_carriage(a.names) for a in joint.open_ambiguity)
    # Applied as saved to a placement no run saw (a plate in the XZ plane): the error falls.
    held = _sim(PLATE, ["xz@x=430,y=300,z=-250"], 9)
    v = _quiet(cvmod.verify, joint.model, held)
    assert v["model_rms_um"] < v["plain_rms_um"] - 1.0, v


def test_on_a_plate_the_rolls_move_out_of_the_plane_tells_them_apart():
    """Two XY placements of a plate (benches/unseen_placements.py, bump, seed 2): the straightness explains the
    plate far better (-2 log L) than the roll with the same knots: it is taken, found by the search itself or
    as the sibling of the roll's knots the search chose (knots no finer than the ball pitch: the former)."""
    runs = [_sim(PLATE, [p], 200 + i) for i, p in enumerate(("xy@x=300,y=250,z=-400", "xy@x=560,y=300,z=-400"))]
    d = _quiet(diagnose_jointly, runs, MAPS, max_effects=3)
    assert [parse(n).component for n in _x_carriage(d.added)] == ["dy(X)"], d.added
    step = next(s for s in d.steps if any(c.name in d.added for c in s.ranking))
    taken = next(c for c in step.ranking if c.name in d.added)
    roll = next((c for c in step.ranking if c.name == taken.name.replace("dy(X)", "ex(X)")), None)
    assert "sibling component" in taken.cv["why"] or (roll is not None and roll.lr < taken.lr - 10), \
        (taken.cv["why"], roll and roll.lr, taken.lr)


def test_a_periodic_position_error_is_found_as_before_with_no_new_ambiguity():
    runs = [_sim(PLATE, [p], 100 + i, "periodic")
            for i, p in enumerate(("xy@x=300,y=250,z=-400", "xy@x=560,y=300,z=-400"))]
    d = _quiet(diagnose_jointly, runs, MAPS, max_effects=3)
    assert any(n.startswith("map:dx(X):sine") for n in d.added), d.added
    assert not any(_x_carriage(a.names) for a in d.ambiguity)


def test_a_periodic_x_error_on_a_ballbar_is_found_as_before_with_no_ambiguity():
    from cmmpose.sim.runs import simulate_ballbar_run

    run, _ = simulate_ballbar_run(seed=1, jitter=JITTER, scanner=Scanner(points_per_profile=256))
    d = _quiet(cmmpose.diagnose, _shifted(run, "periodic"), patterns=False)
    (name,) = d.added
    assert name.startswith("map:dx(X):sine") and abs(parse(name).scale_mm - 170.0) < 2.0
    assert d.ambiguity == []


# -- pose-out folds -------------------------------------------------------------------


def test_folds_hold_a_digitizer_pose_out_when_one_placement_was_scanned_from_several():
    run = simulate_artefact_run(PLATE, ["xy@x=430,y=270,z=-250"], jitter=JITTER, seed=7,
                                scanner=Scanner(points_per_profile=96))[0]
    poses = {tuple(np.round(run.pose(p)[0], 6)) for p in run.poses["pose_id"]}
    assert len(poses) == 2  # the pose library views some balls at -30 degrees, others at +30
    p = Problem(Model(MAPS), run)
    folds, items, split = cvmod.cv_groups(p, across=True)
    assert split.startswith("leave one digitizer pose out (2 poses") and "interpolation" not in split
    assert set(np.unique(folds[folds >= 0])) == {0, 1}
    # Each held-out ball goes with the pose that scanned it: the fold of every scan's radius row is its pose's.
    angles = cvmod.scan_pose_angles(p)
    at = p.layout.sizes["length"] + 3 * len(p.layout.repeated)
    radius_folds = folds[at:at + len(p.layout.labels)]
    for f in (0, 1):
        assert len({tuple(a) for a in angles[radius_folds == f]}) == 1
    assert len({tuple(a) for a in angles}) == 2
    # A valid design: every item (ball) inside one fold, and it scores.
    r0 = p.base_obs.residual
    X0, ridge0, target0 = cvmod.model_design(p, p.base)
    sigma = p.wls(r0, X0, ridge=ridge0, target=target0).sigma
    score = cvmod.CVDesign(p, r0, X0, ridge0, target0, sigma, (folds, items)).score_with()
    assert np.isfinite(score.rms_um) and np.isfinite(score.u_rms_um)
    # The selection's own split within the placement is unchanged; a one-pose placement keeps its split.
    assert "leave one ball out" in cvmod.cv_groups(p)[2]
    one = Problem(Model(MAPS), simulate_artefact_run(PLATE, ["xy@x=300,y=250,z=-400"], jitter=JITTER, seed=8,
                                                     scanner=Scanner(points_per_profile=96))[0])
    assert "judges interpolation only" in cvmod.cv_groups(one, across=True)[2]


def test_poses_are_told_apart_by_their_angles_not_their_ids():
    run = simulate_artefact_run(PLATE, ["xy@x=430,y=270,z=-250"], jitter=JITTER, seed=7,
                                scanner=Scanner(points_per_profile=96))[0]
    p = Problem(Model(MAPS), run)
    want = cvmod.cv_groups(p, across=True)
    # A third id with pose 0's angles, given to every other scan of pose 0: still two poses, the same folds.
    poses = {k: np.r_[np.asarray(v), np.asarray(v)[:1]] for k, v in run.poses.items()}
    poses["pose_id"][-1] = 7
    scans = dict(run.scans)
    pid = np.asarray(scans["pose_id"]).copy()
    zero = np.flatnonzero(pid == run.poses["pose_id"][0])
    pid[zero[::2]] = 7
    scans["pose_id"] = pid
    q = Problem(Model(MAPS), dataclasses.replace(run, poses=poses, scans=scans))
    assert len(q.inputs.pose_ids) == 3
    got = cvmod.cv_groups(q, across=True)
    assert got[2] == want[2] and "(2 poses" in got[2]
    assert np.array_equal(got[0], want[0])


def test_a_crossed_ballbar_layout_and_a_plate_beside_it_hold_a_pose_out():
    """The crossed layout scans its bars with the W axis along X and along Y (two poses): pose-out on its own,
    and, beside a plate scanned from two other poses (runs of different kinds), one pose out of every run."""
    from cmmpose.diagnosis.joint import JointProblem
    from cmmpose.sim.runs import simulate_ballbar_run

    bar, _ = simulate_ballbar_run(layout="crossed", seed=1, jitter=JITTER, scanner=Scanner(points_per_profile=64))
    p = Problem(Model(MAPS), bar)
    folds, items, split = cvmod.cv_groups(p, across=True)
    assert split.startswith("leave one digitizer pose out (2 poses") and "positions" in split
    n = p.layout.sizes["length"]
    assert set(np.unique(folds[:n])) == {0, 1}
    plate = simulate_artefact_run(PLATE, ["xy@x=430,y=270,z=-250"], jitter=JITTER, seed=7,
                                  scanner=Scanner(points_per_profile=64))[0]
    j = JointProblem(Model(MAPS), [bar, plate])
    folds, items, split = cvmod.cv_groups(j, across=True)
    assert split.startswith("leave one digitizer pose out of every run") and "differ in kind" in split
    per_run = np.split(folds, [len(j.parts[0].classes)])
    assert all(len(set(np.unique(f[f >= 0]))) >= 2 for f in per_run)
    r0 = j.base_obs.residual
    X0, ridge0, target0 = cvmod.model_design(j, j.base)
    sigma = j.wls(r0, X0, ridge=ridge0, target=target0).sigma
    assert np.isfinite(cvmod.CVDesign(j, r0, X0, ridge0, target0, sigma, (folds, items)).score_with().rms_um)
