"""Residual patterns (issue 6, item 2): a hidden effect in a simulated B89 run
must show as the pattern its physics predicts; noise must show nothing."""

import dataclasses
import functools
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cmmpose
from cmmpose.diagnosis.pattern_results import Patterns
from cmmpose.diagnosis.patterns import f_test_p_value, find_patterns
from cmmpose.evaluation.ballbar import machine_coordinates, machine_temperature
from cmmpose.fitting import fit_spheres
from cmmpose.sim.effects import Incidence, Latency, Scale, ScannerScale, Squareness
from cmmpose.sim.runs import simulate_ballbar_run

MAPS = cmmpose.ErrorMapSet.thesis()
ARCSEC = math.pi / 180 / 3600
SPEED = 35.0  # mm/s, the simulator's default sweep speed


@functools.lru_cache(maxsize=None)
def _measured(effects: tuple = (), seed: int = 1, bidirectional: bool = False):
    """A simulated B89 run at 22.5 C, compensated with the thesis maps (which
    know none of ``effects``) at the logged machine temperature, and fitted."""
    run, truth = simulate_ballbar_run(MAPS, 22.5, list(effects), seed=seed, bidirectional=bidirectional)
    temp = machine_temperature(run, run.points["t"])
    xyz = machine_coordinates(run, MAPS, temp)
    fits = fit_spheres(xyz, run.points["scan_id"])
    return run, truth, xyz, fits, temp


@functools.lru_cache(maxsize=None)
def _patterns(effects: tuple = (), seed: int = 1, bidirectional: bool = False, calibrated: bool = True) -> Patterns:
    run, _, xyz, fits, temp = _measured(effects, seed, bidirectional)
    radius = run.artefact["ball_radius_mm"] if calibrated else None
    return find_patterns(run, xyz, fits, temperature=temp, nominal_radius=radius)


# -- hidden effects -------------------------------------------------------------------------
@pytest.mark.parametrize(("effect", "quantity", "hint"), [
    (Squareness(xy=15.0), "dx*dy", "squareness xy"),
    (Squareness(yz=15.0), "dy*dz", "squareness yz"),
    (Squareness(zx=-15.0), "dz*dx", "squareness zx"),
])
def test_hidden_squareness_is_the_strongest_pattern_against_its_direction_product(effect, quantity, hint):
    pats = _patterns((effect,))
    s = pats.strongest
    assert s is not None and s.significant
    assert (s.level, s.observable, s.quantity) == ("length", "ballbar length deviation", quantity)
    assert s.r2 > 0.95
    # A squareness S changes a bar of length L by about L S dx dy: over the
    # layout's dx dy from -0.5 to 0.5 that is L S peak to peak.
    bar = float(np.mean(pats.lengths["length_mm"]))
    expected_um = bar * 15.0 * ARCSEC * 1e3
    assert s.amplitude_um == pytest.approx(expected_um, rel=0.15)
    assert hint in s.hint
    assert f"strongest pattern: ballbar length deviation vs {quantity}" in pats.summary()
    assert hint in pats.summary()


def test_hidden_axis_scale_error_shows_against_the_squared_direction_cosine():
    pats = _patterns((Scale(x=10.0),))
    s = pats.strongest
    assert (s.level, s.quantity) == ("length", "dx^2")
    assert "scale error x" in s.hint
    bar = float(np.mean(pats.lengths["length_mm"]))
    assert s.amplitude_um == pytest.approx(10e-6 * bar * 1e3, rel=0.25)  # dx^2 spans 0..1


@pytest.mark.parametrize(("effect", "expected"), [
    (ScannerScale(depth=2e-3), {"v", "incidence"}),
    (ScannerScale(lateral=2e-3), {"u"}),
    (Incidence(per_degree=3e-4), {"incidence", "v"}),
])
def test_scanner_effects_make_the_matching_point_pattern_strongest(effect, expected):
    pats = _patterns((effect,))
    points = pats.level("point")
    top = points[0]
    assert top.quantity in expected, [(p.quantity, p.r2, p.amplitude_um) for p in points]
    assert top.significant and top.amplitude_um > 1.0
    assert any(h in top.hint for h in ("depth scale", "lateral scale", "incidence-angle"))
    # incidence is measured from the beam (pose v axis): the simulated scanner
    # sees surfaces up to 70 degrees from it, and the top of the ball at ~0
    incidence = pats.find("point fit residual", "incidence")
    assert 0.0 < incidence.x.min() < 12.0 and 58.0 < incidence.x.max() < 70.0
    # the sphere radius is biased too, seen against the calibrated radius
    radius = pats.find("sphere radius deviation from nominal", "(all scans)")
    assert radius is not None and radius.significant and radius.amplitude_um > 5.0


def test_depth_scale_pattern_is_quadratic_in_v_with_bins_that_follow_the_model():
    p = _patterns((ScannerScale(depth=2e-3),)).find("point fit residual", "v")
    assert p.model == "quadratic" and p.n > 100_000
    assert p.counts.sum() == p.n and len(p.x) >= 20
    # the model explains the bin means, not just the noise-dominated points
    ss = np.sum(p.counts * (p.y - np.average(p.y, weights=p.counts)) ** 2)
    assert 1 - np.sum(p.counts * (p.y - p.fitted) ** 2) / ss > 0.9


def test_without_a_calibrated_radius_no_radius_offset_is_tested():
    pats = _patterns((ScannerScale(depth=2e-3),), calibrated=False)
    assert pats.find("sphere radius deviation", "(all scans)") is None
    assert all("from mean" in p.observable for p in pats if p.observable.startswith("sphere radius"))


def test_latency_with_alternating_sweeps_shows_in_lengths_along_the_sweep_axis():
    seconds = 0.002
    pats = _patterns((Latency(seconds=seconds),), bidirectional=True)
    s = pats.strongest
    assert (s.level, s.quantity) == ("length", "dx")
    assert "latency" in s.hint
    # ball 1 forward, ball 2 reversed: the bar gains 2 v tau along X, so the
    # length changes by 2 v tau dx, 4 v tau peak to peak over dx in [-1, 1]
    assert s.amplitude_um == pytest.approx(4 * SPEED * seconds * 1e3, rel=0.1)


def test_latency_with_sweeps_in_one_direction_cancels_in_lengths():
    # the same shift for both balls: nothing at the length level to see (the
    # measurement that would reveal it is a reversed sweep, tested below)
    pats = _patterns((Latency(seconds=0.002),))
    assert not [p for p in pats.level("length") if p.significant]


def _merged_run(first, second):
    """Two runs of the same layout as one run: every ball scanned twice."""
    run1, run2 = first[0], second[0]
    shift = int(run1.scans["scan_id"].max()) + 1
    points = {k: np.concatenate([run1.points[k], run2.points[k] + (shift if k == "scan_id" else 0)])
              for k in run1.points}
    scans = {k: np.concatenate([run1.scans[k], run2.scans[k] + shift if k == "scan_id" else run2.scans[k]]) for k in run1.scans}
    run = cmmpose.Run(points=points, scans=scans, poses={k: np.asarray(v) for k, v in run1.poses.items()})
    xyz = np.concatenate([first[2], second[2]])
    return run, xyz


def test_repeated_scans_in_both_directions_reveal_latency_in_the_sphere_centres():
    effect = (Latency(seconds=0.002),)
    run, xyz = _merged_run(_measured(effect, 1, False), _measured(effect, 2, True))
    pats = find_patterns(run, xyz, fit_spheres(xyz, run.points["scan_id"]))
    centre = [p for p in pats if p.observable.startswith("sphere centre")]
    assert centre, "balls scanned twice must give centre deviations"
    top = max(centre, key=lambda p: p.score)
    assert (top.observable, top.quantity) == ("sphere centre deviation x", "sweep direction")
    assert top.significant and "latency" in top.hint
    # Forward and reverse scans of ball 2 sit at -/+ v tau from their mean;
    # ball 1 is swept forward both times (deviation 0). Group means: forward
    # (40 x 0 - 20 v tau) / 60 = -v tau / 3, reverse + v tau: 4/3 v tau apart.
    assert top.amplitude_um == pytest.approx(4 / 3 * SPEED * 0.002 * 1e3, rel=0.1)
    # without latency the same design shows no centre pattern
    quiet_run, quiet_xyz = _merged_run(_measured((), 1, False), _measured((), 2, True))
    quiet = find_patterns(quiet_run, quiet_xyz, fit_spheres(quiet_xyz, quiet_run.points["scan_id"]))
    assert not [p for p in quiet if p.observable.startswith("sphere centre") and p.significant]


# -- noise only -------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_noise_only_run_has_no_significant_pattern(seed):
    # criterion: no pattern with p < 1e-3 / (number of patterns tested), Bonferroni
    pats = _patterns((), seed=seed)
    assert pats.alpha == 1e-3 and pats.threshold == pytest.approx(1e-3 / pats.tested)
    assert pats.tested >= 20
    assert pats.significant == ()
    assert pats.strongest is None
    assert "no significant pattern" in pats.summary()
    # and what is there is small: sub-micrometre patterns on 6 um noise
    assert all(p.r2 < 1e-3 and p.amplitude_um < 0.5 for p in pats.level("point"))
    assert all(p.amplitude_um < 3.0 for p in pats.level("length"))


def test_f_test_p_values_are_uniform_under_the_null():
    # seeded check of the whole pattern fit: random y against fixed x, 20 observations
    from cmmpose.diagnosis.patterns import continuous_pattern

    rng = np.random.default_rng(7)
    x = np.linspace(-1.0, 1.0, 20)
    p_lin = np.array([continuous_pattern("length", "y", "x", "1", x, rng.normal(size=20), "", shape=True).p_value
                      for _ in range(1500)])
    p_quad = np.array([continuous_pattern("length", "y", "x", "mm", x, rng.normal(size=20), "").p_value for _ in range(1500)])
    for p in (p_lin, p_quad):
        assert np.mean(p < 0.05) == pytest.approx(0.05, abs=0.017)
        assert np.mean(p < 0.5) == pytest.approx(0.5, abs=0.05)


@settings(max_examples=60, deadline=None)
@given(f=st.floats(0.0, 500.0), df1=st.integers(1, 30), df2=st.integers(1, 600_000))
def test_f_test_p_value_matches_scipy(f, df1, df2):
    scipy_stats = pytest.importorskip("scipy.stats")
    expected = float(scipy_stats.f.sf(f, df1, df2))
    assert f_test_p_value(f, df1, df2) == pytest.approx(expected, rel=1e-6, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(1e-3, 1e3), offset=st.floats(-1e3, 1e3), seed=st.integers(0, 2**31))
def test_strength_does_not_depend_on_units_or_offsets(scale, offset, seed):
    from cmmpose.diagnosis.patterns import continuous_pattern

    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, 30)
    y = 3 * x**2 + rng.normal(size=30)
    a = continuous_pattern("length", "y", "x", "mm", x, y, "")
    b = continuous_pattern("length", "y", "x", "mm", x * scale + offset, y * scale + offset, "")
    assert b.r2 == pytest.approx(a.r2, rel=1e-6, abs=1e-9)
    assert b.amplitude_um == pytest.approx(a.amplitude_um * scale, rel=1e-6)


# -- the result object ----------------------------------------------------------------------
def test_ranking_json_and_summary_table():
    pats = _patterns((Squareness(xy=15.0),))
    keys = [(not p.significant, -p.score) for p in pats]
    assert keys == sorted(keys)
    assert {p.level for p in pats} == {"length", "scan", "point"}
    d = pats.to_dict()
    text = json.dumps(d, allow_nan=False)  # JSON-safe: no NaN, no numpy types
    assert json.loads(text)["strongest"]["quantity"] == "dx*dy"
    assert d["tested"] == len(d["patterns"]) == len(pats)
    assert len(d["lengths"]["position"]) == 20
    s = str(pats)
    assert "strongest pattern: ballbar length deviation vs dx*dy" in s
    assert "squareness xy" in s and "Residual patterns" in s


def test_temperature_quantities_appear_only_with_temperatures():
    run, _, xyz, fits, _ = _measured((), 1)
    pats = find_patterns(run, xyz, fits)
    assert pats.find("ballbar length deviation", "temperature") is None
    assert pats.find("point fit residual", "temperature") is None
    with_t = find_patterns(run, xyz, fits, temperature=22.5 + run.points["t"] * 1e-4)
    assert with_t.find("ballbar length deviation", "temperature") is not None
    assert with_t.find("point fit residual", "temperature") is not None


# -- bad input --------------------------------------------------------------------------------
def test_bad_input_raises_clear_errors():
    run, _, xyz, fits, temp = _measured((), 1)
    with pytest.raises(cmmpose.InputError, match=r"xyz: expected shape \(\d+, 3\)"):
        find_patterns(run, xyz[:, :2], fits)
    with pytest.raises(cmmpose.InputError, match=r"xyz: expected shape"):
        find_patterns(run, xyz[:-1], fits)
    bad = xyz.copy()
    bad[17, 1] = np.nan
    with pytest.raises(cmmpose.InputError, match="xyz: row 17 is not finite"):
        find_patterns(run, bad, fits)
    missing = {k: v for k, v in fits.items() if k != 5}
    with pytest.raises(cmmpose.InputError, match="no sphere fit for scan 5"):
        find_patterns(run, xyz, missing)
    failed = {**fits, 3: cmmpose.GeometryError("cap too small")}
    with pytest.raises(cmmpose.InputError, match="scan 3 could not be fitted"):
        find_patterns(run, xyz, failed)
    shifted = {**fits, 1: dataclasses.replace(fits[1], residuals=fits[1].residuals[:-1])}
    with pytest.raises(cmmpose.InputError, match="scan 1: .* residuals for"):
        find_patterns(run, xyz, shifted)
    with pytest.raises(cmmpose.InputError, match="fits: expected a dict"):
        find_patterns(run, xyz, list(fits.values()))
    t = temp.copy()
    t[3] = np.nan
    with pytest.raises(cmmpose.InputError, match="temperature: row 3 is not finite"):
        find_patterns(run, xyz, fits, temperature=t)
    with pytest.raises(cmmpose.InputError, match="temperature: expected one value or shape"):
        find_patterns(run, xyz, fits, temperature=temp[:10])
    with pytest.raises(cmmpose.InputError, match="nominal_radius"):
        find_patterns(run, xyz, fits, nominal_radius=-38.1)
    with pytest.raises(cmmpose.InputError, match="run: expected a cmmpose.Run"):
        find_patterns({"points": {}}, xyz, fits)
    with pytest.raises(cmmpose.InputError, match="alpha"):
        find_patterns(run, xyz, fits, alpha=1.5)
    with pytest.raises(cmmpose.InputError, match="degrees of freedom"):
        f_test_p_value(1.0, 0, 10)


def test_pattern_hints_come_from_the_effect_files():
    # Issue 26: which effect could make a pattern is declared in the effect's own file (Effect.hints); the pattern
    # tables only add the causes outside the library. Every declared quantity is one the patterns draw.
    from cmmpose import effects
    from cmmpose.diagnosis import patterns

    tables = {"length": patterns._LENGTH_TEMPLATES, "point": patterns._POINT_TEMPLATES}
    for name, cls in effects.available().items():
        for kind, declared in cls.hints.items():
            assert set(declared) <= set(tables[kind]), (name, kind, set(declared) - set(tables[kind]))
            built = patterns._hints(kind, tables[kind])
            for quantity, phrase in declared.items():
                assert phrase in built[quantity], (name, quantity)
    assert patterns._LENGTH_HINTS["dx*dy"] == "squareness xy"
    assert patterns._LENGTH_HINTS["dy*dz"] == "squareness yz or granite gradient"
