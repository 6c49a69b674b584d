"""Issue 25: a diagnosis that holds out of sample.

Hidden physics the library does not name, made in the test by what the
machine's scales report (the simulator's runs, their readings shifted as a
scale or a guide would: ``what the scale reports is not where the carriage
is``, docs/user-effects.md): a periodic X scale error (12 um, 170 mm pitch),
a local bump in the Y straightness of X, a twisted table (Z error ~ x*y) and
nothing at all. A ball plate measured at three placements: the model is found
jointly on two and judged on the third, which no step used. Acceptance (the
issue's "Done when"): on the held-out placement a map-shape case removes at
least half of the excess error over the truth model; no case raises the
error by more than 5 % + 0.3 um; noise-only adds nothing; an error of two
axes at once that no effect holds is reported as unexplained, with its axes.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings

import cmmpose
from cmmpose.diagnosis.floor import FIT_SCATTER, NO_FLOOR
import numpy as np
import pytest
from cmmpose.artefacts import load_artefact
from cmmpose.model import Model, UserEffect
from cmmpose.diagnosis import cv as cvmod
from cmmpose.diagnosis import mapfamily as mf
from cmmpose.diagnosis.diagnose import _step
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.diagnosis.patterns import _LENGTH_HINTS, _POINT_HINTS
from cmmpose.diagnosis.unexplained import Finding, user_effect_skeleton
from cmmpose.errormap import data_path
from cmmpose.errors import ModelDomainWarning
from cmmpose.evaluation.model_check import check_model
from cmmpose.sim.artefact_runs import simulate_artefact_run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

PLATE = load_artefact(data_path("artefacts", "koba-0420.toml"))
PLACEMENTS = ("xy@x=300,y=250,z=-400", "xy@x=560,y=300,z=-400", "xy@x=430,y=270,z=-400")
JITTER = 0.0015  # mm per axis per scan

# What each scale reports beyond the truth, mm, as a function of the readings (D, E, F mm).
HIDDEN = {
    "periodic": lambda D, E, F: (0.012 * np.sin(2 * np.pi * D / 170.0), 0 * D, 0 * D),
    "bump": lambda D, E, F: (0 * D, 0.020 * np.exp(-((D - 450.0) / 60.0) ** 2), 0 * D),
    "twist": lambda D, E, F: (0 * D, 0 * D, 0.050 * (D - 450.0) / 450.0 * (E - 275.0) / 275.0),
    "noise": lambda D, E, F: (0 * D, 0 * D, 0 * D),
}


def _shifted(run, case):
    pts = dict(run.points)
    for k, g in zip("DEF", HIDDEN[case](pts["D"], pts["E"], pts["F"])):
        pts[k] = pts[k] + g
    return dataclasses.replace(run, points=pts)


@functools.cache
def plate_runs(case):
    return tuple(_shifted(simulate_artefact_run(PLATE, [p], jitter=JITTER, seed=40 + i,
                                                scanner=Scanner(points_per_profile=96))[0], case)
                 for i, p in enumerate(PLACEMENTS))


def truth_model(case):
    """The plain maps plus the exact correction of the hidden readings (to first order)."""
    def correction(inputs, on):
        return -on * np.column_stack(HIDDEN[case](inputs["D"], inputs["E"], inputs["F"]))

    effect = UserEffect.create(f"truth-{case}", correction, {"on": ("1", 1.0)})
    return Model(cmmpose.ErrorMapSet.thesis()).with_values(effect, [1.0])


@functools.cache
def found(case):
    runs = plate_runs(case)
    joint = diagnose_jointly(list(runs[:2]), max_effects=3)
    held = runs[2]
    return joint, cvmod.verify(joint.model, held), cvmod.verify(truth_model(case), held)


@pytest.mark.parametrize("case", ["periodic", "bump"])
def test_a_map_shape_found_on_two_placements_holds_on_the_third(case):
    joint, v, truth = found(case)
    assert any(n.startswith("map:") for n in joint.added), joint.added
    plain, model, best = v["plain_rms_um"], v["model_rms_um"], truth["model_rms_um"]
    assert plain - model >= 0.5 * (plain - best), (case, plain, model, best)
    assert model <= 1.05 * plain + 0.3
    assert v["holds"] and "holds" in v["verdict"]
    # The cross-validated rms stands beside the in-sample one, in the table's data and the JSON.
    doc = json.loads(joint.to_json())
    for s in doc["steps"]:
        cv = s["cross_validation"]
        assert cv["cv_rms_um"] > 0 and cv["in_sample_rms_um"] > 0 and "within each run: leave one ball out" in cv["split"]
    assert doc["steps"][-1]["cross_validation"]["cv_rms_um"] < doc["steps"][0]["cross_validation"]["cv_rms_um"]


def test_the_periodic_search_finds_the_pitch_with_its_uncertainty():
    joint, _, _ = found("periodic")
    spec = next(s for s, _ in joint.model.effects if s.name.startswith("map:dx(X):sine"))
    amp = float(np.hypot(*joint.model.values(spec.name)))
    assert abs(spec.scale_mm - 170.0) < max(3 * spec.scale_u_mm, 2.0), (spec.scale_mm, spec.scale_u_mm)
    assert 0 < spec.scale_u_mm < 20
    unc = next(d for d in joint.decisions() if d["name"] == spec.name)["uncertainty"]
    u_amp = float(np.hypot(*unc.values()))
    assert abs(amp - 12.0) < 4 * u_amp + 1.0, (amp, u_amp)


def test_noise_and_the_twist_never_raise_the_error_on_the_held_out_placement():
    for case in ("noise", "twist"):
        joint, v, _ = found(case)
        assert v["model_rms_um"] <= 1.05 * v["plain_rms_um"] + 0.3, (case, joint.added, v)
    joint, v, _ = found("noise")
    assert joint.added == [] and not joint.two_axis


@functools.cache
def b89(case, seed=1):
    run, _ = simulate_ballbar_run(temperature=22.5, jitter=JITTER, seed=seed, scanner=Scanner(points_per_profile=128))
    return _shifted(run, case)


def test_a_twisted_table_on_a_ballbar_is_found_as_a_cross_axis_twist_with_its_size():
    """Issue 33, section 6: a twisted table (a z error ~ x*y, outside every one-axis map component) is offered as
    a cross-axis candidate and found with its size; without the cross-axis family (only the library's named
    effects) it is reported unexplained, with its axes."""
    d = cmmpose.diagnose(b89("twist"), patterns=False, reproducibility_um=1.5)
    assert [n.split("[")[0] for n in d.added] == ["cross:z(XY):twist"], d.added
    spec = next(s for s, _ in d.model.effects if s.name == d.added[0])
    (lo_a, hi_a), (lo_b, hi_b) = spec.travel
    # The hidden reading shift is 50 um * (D-450)/450 * (E-275)/275: at the corners of the travel the run used
    # (half-spans (hi-lo)/2 about the centres), the correction is minus its value there.
    want = -50.0 * (hi_a - lo_a) / 2 / 450.0 * (hi_b - lo_b) / 2 / 275.0
    c, u = d.model.values(spec.name)[0], d.model.uncertainty[spec.name][0]
    assert abs(c - want) < 3 * u + 1.0, (c, u, want)
    assert not d.two_axis and d.noise["noise"]
    assert "twisted table" in spec.describe([c])
    plain = cmmpose.diagnose(b89("twist"), patterns=False, reproducibility_um=1.5, map_corrections=False)
    assert not any(n.startswith(("map:", "cross:")) for n in plain.added), plain.added
    assert plain.two_axis and plain.two_axis[0]["direction"] == "z" and plain.two_axis[0]["axes"] == "XY"
    # The table spans about 280 x 240 mm of the 900 x 550: 50 um scaled to the corners used.
    assert 15 < plain.two_axis[0]["size_um"] < 45
    doc = json.loads(plain.to_json())
    assert doc["two_axis"][0]["axes"] == "XY" and doc["noise_floor"]["floor_um"] > 0


def test_a_noise_only_ballbar_adds_nothing_and_its_residuals_look_like_noise():
    d = cmmpose.diagnose(b89("noise"), patterns=False, reproducibility_um=1.5)
    assert d.added == [] and d.two_axis == []
    assert d.noise["noise"] and d.noise["verdict"].startswith("the residuals look like noise")
    # Without repeated scans or a stated reproducibility there is no floor, and the diagnosis says so first;
    # the floor tested against is the spheres' fit scatter (issue 33, section 4).
    bare = cmmpose.diagnose(b89("noise"), patterns=False).noise
    assert bare["source"] == FIT_SCATTER and not bare["floor_stated_or_measured"]
    assert bare["verdict"].startswith(NO_FLOOR)


# -- the cross-validation arithmetic against a brute-force refit ----------------------


def test_leave_one_group_out_matches_an_explicit_refit():
    run = b89("noise", 2)
    model = Model(cmmpose.ErrorMapSet.thesis())
    problem = Problem(model, run, {n: s for n, s in cmmpose.model.LIBRARY.items() if n in ("squareness",)})
    step = _step("base", model, problem)
    r0 = step.residual
    J = problem.columns["squareness"]
    X = np.column_stack([problem.nuisance, J])
    ridge = np.r_[np.zeros(problem.nuisance.shape[1]), np.full(J.shape[1], 0.3)]
    target = np.zeros(X.shape[1])
    sigma = problem.wls(r0, problem.nuisance).sigma
    folds, items, _ = cvmod.cv_groups(problem)
    score = cvmod.cv_score(problem, r0, X, ridge, target, sigma, folds, items)
    s = sigma[problem.classes]
    head = problem.classes == 0
    e = []
    for g in np.unique(folds[folds >= 0]):
        train = folds != g
        A = np.vstack([X[train] / s[train, None], np.diag(ridge)])
        b = np.r_[-r0[train] / s[train], ridge * target]
        beta = np.linalg.lstsq(A, b, rcond=None)[0]
        held = (folds == g) & head
        e.append(float(np.sum((r0[held] + X[held] @ beta) ** 2)))
    want = np.sqrt(np.sum(e) / head.sum()) * 1e3
    assert score.rms_um == pytest.approx(want, rel=1e-6)
    assert len(score.n_head) == len(run_positions := problem.layout.positions) and len(run_positions) == 20


# -- map corrections: sensitivities, files, corrected maps -----------------------------


def test_corrected_maps_compensate_as_the_model_does_and_the_model_file_keeps_them(tmp_path):
    run = b89("noise")
    base = Model(cmmpose.ErrorMapSet.thesis())
    lo, hi = run.scales.min(axis=0) - 1, run.scales.max(axis=0) + 1
    x0 = base.compensate(run)
    for comp in ("dx(X)", "dy(X)", "dz(Y)", "dx(Z)"):
        a = mf.COMPONENTS[comp][0]
        m = base.with_values(mf.make(comp, "poly", float(lo[a]), float(hi[a])), [5.0, -3.0])
        x1 = m.compensate(run)
        x2 = Model(mf.corrected_maps(m)).compensate(run)
        # The same correction (um) one map node (25 mm) inside the travel the shape spans: the shape
        # is held flat beyond it, and the maps interpolate linearly across the node interval at its end.
        assert np.abs(x1 - x0).max() > 3e-3
        d = np.abs(x2 - x1).max(axis=1)
        inside = (run.scales[:, a] > lo[a] + 25) & (run.scales[:, a] < hi[a] - 25)
        assert d[inside].max() < 1e-4 and d.max() < 1e-3, comp
        m.save(tmp_path / "m.json")
        back = Model.load(tmp_path / "m.json")
        assert back.names == m.names and np.allclose(back.compensate(run), x1)
    path = tmp_path / "corrected.csv"
    mf.corrected_maps(m).maps[0].write(path)
    assert cmmpose.ErrorMap.read(path) is not None


def test_centre_level_sensitivities_agree_with_the_compensation():
    run = b89("noise")
    model = Model(cmmpose.ErrorMapSet.thesis())
    lo, hi = run.scales[:, 0].min(), run.scales[:, 0].max()
    spec = mf.make("dx(X)", "sine", float(lo), float(hi), 170.0)
    problem = Problem(model, run, {spec.name: spec})
    analytic = problem.columns[spec.name]
    moved = problem.observe(model.with_values(spec, [3.0, 0.0])).residual  # one prior magnitude of sin_um
    fd = moved - problem.base_obs.residual
    L = problem.classes == 0
    # Lengths: the same to a few percent of the change (centre level against the sphere fits).
    assert np.abs(fd[L] - analytic[L, 0]).max() < 0.05 * np.abs(fd[L]).max() + 2e-5


def test_component_report_names_what_the_run_determines_and_what_it_cannot_see():
    run = b89("noise")
    model = Model(cmmpose.ErrorMapSet.thesis())
    problem = Problem(model, run, {})
    rep = mf.component_report(problem)
    assert set(rep) == set(mf.COMPONENTS) | set(mf.SQUARENESS)
    assert rep["dx(X)"]["status"] in ("determined", "aliased") and rep["dx(X)"]["shapes_determined"] > 0
    for r in rep.values():
        assert r["status"] in ("determined", "aliased", "invisible")
        assert (r["status"] == "aliased") == bool(r["aliased_with"])


# -- honesty ------------------------------------------------------------------------


QUANTITIES = sorted(set(_LENGTH_HINTS) | set(_POINT_HINTS) | {"pose", "sweep direction", "sweep axis", "position",
                                                               "sweep speed", "dx*dy", "dy*dz", "dz*dx", "dx^2"})


@pytest.mark.parametrize("quantity", QUANTITIES)
def test_every_drafted_skeleton_runs_as_written(quantity):
    f = Finding("pattern", quantity, f"a pattern against {quantity}", 1.0, 1e-6, 1e-4)
    ns = {}
    exec(compile(user_effect_skeleton(f, "drafted"), "draft.py", "exec"), ns)  # noqa: S102 - our own text
    rng = np.random.default_rng(0)
    n = 50
    inputs = {k: rng.normal(size=n) for k in ("u", "v", "D", "E", "F", "t", "temperature", "x", "y", "z",
                                              "incidence")}
    inputs["scan_id"] = np.repeat(np.arange(5), 10)
    inputs["pose_id"] = np.zeros(n, int)
    out = ns["EFFECT"].correction(inputs, np.ones(ns["EFFECT"].size))
    assert out.shape == (n, 3) and np.all(np.isfinite(out))


def test_report_values_carry_the_declared_unit():
    from cmmpose.diagnosis.html_report import _values_text

    text = _values_text(("gain",), [4.75e-2], [0.35], ("1",))
    assert "ppm" not in text


def test_the_named_jacobian_for_other_tools():
    from cmmpose.diagnosis import jacobian

    run = b89("noise")
    problem = Problem(Model(cmmpose.ErrorMapSet.thesis()), run)
    jac = jacobian(problem)
    assert jac["J"].shape == (len(problem.classes), len(jac["names"])) == (len(jac["classes"]), len(jac["prior"]))
    assert "squareness.xy" in jac["names"] and any(n.startswith("map:dx(X):sine") for n in jac["names"])
    i = jac["names"].index("squareness.xy")
    assert np.array_equal(jac["J"][:, i], problem.columns["squareness"][:, 0])
    assert len(jac["singular_values"]) and np.all(np.diff(jac["singular_values"]) <= 1e-12)


def test_a_periodic_error_found_on_a_b89_run_runs_on_beyond_its_travel():
    """A 12 um, 170 mm periodic X error found on a B89 run (X 169-729 mm) and applied, as saved, to a crossed
    layout reaching X 56-854 mm: the sine runs on past the travel it was fitted on (a scale's periodic error
    repeats along it), so the bars that reach beyond are corrected too. Held at its end values instead, the
    model raised that run's error from 2.70 to 6.30 um (truth 1.53 um); running on, it removes at least half
    of the excess, and the run is still said to leave the model's domain."""
    def run(layout, seed):
        r, _ = simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 21.0, [], layout=layout, jitter=0.0015, seed=seed)
        return _shifted(r, "periodic")

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = cmmpose.diagnose(run("b89", 10), max_effects=3)
    (sine,) = [s for s, _ in d.model.effects if s.name.startswith("map:dx(X):sine")]
    assert 165 < sine.scale_mm < 175 and sine.hi < 760
    crossed = run("crossed", 16)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check = check_model(crossed, d.model)
    assert any(issubclass(w.category, ModelDomainWarning) and "X travel" in str(w.message) for w in caught)
    best = check_model(crossed, truth_model("periodic")).model_um
    assert check.plain_um - check.model_um >= 0.5 * (check.plain_um - best), (check.plain_um, check.model_um, best)
