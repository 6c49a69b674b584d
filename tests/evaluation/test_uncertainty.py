"""Uncertainty: the GUM toolkit, the thesis's budgets (every figure of sections
5.3, 6.2.3, 6.3 and 6.4.1 to its printed digits), and Monte Carlo against the
linear law of propagation through compensation and fitting."""

import dataclasses
import json
import math

import numpy as np
import pytest

import cmmpose
from cmmpose import sim
from cmmpose.evaluation import uncertainty as unc
from cmmpose.evaluation.uncertainty import Budget, Input

MAPS = cmmpose.ErrorMapSet.thesis()
POSE = (90.0, 90.0, 0.0)
OFFSET = cmmpose.MountOffset.thesis()
T = 22.5  # inside the 20-25 C map interval, so +-5 sigma of 0.2 K stays inside the maps
SMALL = dict(u_noise=0.008, u_pose_deg=(0.01, 0.01, 0.01), u_offset=(0.02, 0.02, 0.02), u_temperature=0.2)
TRIALS = 2000  # sampling error of a Monte Carlo standard deviation: 1/sqrt(2(M-1)) = 1.6 %


def up(x, decimals=0):
    """Round up to ``decimals`` (the thesis mostly rounds uncertainties up, GUM 7.2.6)."""
    f = 10.0 ** decimals
    return math.ceil(x * f - 1e-9) / f


@pytest.fixture(scope="module")
def reference_scan():
    return sim.simulate_reference_scan(temperature=T, seed=3)


@pytest.fixture(scope="module")
def ballbar_scans():
    scanner = sim.Scanner(points_per_profile=256)
    balls = [sim.Sphere(c, sim.BALL_RADIUS) for c in ((450.0, 100.0, -420.0), (450.0, 500.0, -420.0))]
    return [sim.simulate_reference_scan(temperature=T, sphere=b, speed=35.0, scanner=scanner, seed=10 + i)
            for i, b in enumerate(balls)]


# --- toolkit ------------------------------------------------------------------------------------


def test_budget_combines_uncorrelated_inputs_and_prints():
    inputs = [Input("a", 1.0, 3.0, "um"), Input("b", 2.0, 2.0, "mm", sensitivity=-2.0, note="lever")]
    b = Budget("y", inputs, "um", source="test")
    assert b.inputs == tuple(inputs) and isinstance(inputs, list)  # stored as a tuple, input list untouched
    assert b.combined_standard_uncertainty == pytest.approx(5.0)  # sqrt(3^2 + (2*2)^2)
    assert b.expanded_uncertainty() == pytest.approx(10.0) and b.expanded_uncertainty(3) == pytest.approx(15.0)
    assert b.shares() == pytest.approx([0.36, 0.64])
    text = b.table()
    assert "a" in text and "lever" not in text and "u_c = 5 um" in text and "64.0 %" in text
    d = b.to_dict()
    assert json.loads(json.dumps(d))["combined_standard_uncertainty"] == pytest.approx(5.0)
    assert d["inputs"][1]["contribution"] == pytest.approx(4.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.unit = "mm"


@pytest.mark.parametrize("make", [
    lambda: Input("a", 0.0, -1.0, "um"),
    lambda: Input("a", 0.0, float("nan"), "um"),
    lambda: Input("a", "x", 1.0, "um"),
    lambda: Input("", 0.0, 1.0, "um"),
    lambda: Budget("y", (), "um"),
    lambda: Budget("y", (1.0,), "um"),
    lambda: Budget("y", (Input("a", 0.0, 1.0, "um"),), "um").expanded_uncertainty(0),
    lambda: unc.uncertainty_of_mean([1.0, 2.0], correlation=1.5),
    lambda: unc.uncertainty_of_mean([]),
    lambda: unc.uncertainty_of_mean([1.0, -2.0]),
])
def test_bad_toolkit_inputs_raise_input_error(make):
    with pytest.raises(cmmpose.InputError):
        make()


def test_uncertainty_of_mean():
    assert unc.uncertainty_of_mean([20.0] * 8) == pytest.approx(20 / math.sqrt(8))
    assert unc.uncertainty_of_mean([6.0, 10.0, 12.0], correlation=1.0) == pytest.approx(28 / 3)
    assert unc.uncertainty_of_mean([3.0, 4.0]) == pytest.approx(2.5)


# --- thesis section 5.3: mount offset -----------------------------------------------------------


def test_mount_offset_budgets_evaluate_eqs_22_to_24():
    b = unc.mount_offset_budgets()
    f = 100 / 3  # (10/sqrt(3))^2
    u2_d, u2_e, u2_f = 81 + f + 2 ** 2, 81 + f + 16.5 ** 2, 81 + f + 1 ** 2
    assert b["U1"].combined_standard_uncertainty == pytest.approx(math.sqrt((u2_e + u2_f) / 2), rel=1e-12)  # eq. 22
    assert b["V1"].combined_standard_uncertainty == pytest.approx(b["U1"].combined_standard_uncertainty)  # eq. 23
    assert b["W1"].combined_standard_uncertainty == pytest.approx(math.sqrt(5 / 4 * u2_d + u2_e / 4 + u2_f), rel=1e-12)  # eq. 24
    corrected = unc.mount_offset_budgets(model="corrected")["W1"]  # W1 = D1 - D3 - U1
    assert corrected.combined_standard_uncertainty == pytest.approx(math.sqrt(2 * u2_d + (u2_e + u2_f) / 2), rel=1e-12)
    assert len(b["U1"].inputs) == 12 and {i.sensitivity for i in b["U1"].inputs} == {0.5, -0.5}
    # With the thesis's rounded 5.8 um (line 1452) these are the values of the lines it substitutes into.
    t = unc.mount_offset_budgets(sphere_fit=5.8 * math.sqrt(3))
    assert round(t["U1"].combined_standard_uncertainty, 2) == 15.85  # sqrt(1/2((9^2+5.8^2+16.5^2)+(9^2+5.8^2+1^2)))
    assert round(t["W1"].combined_standard_uncertainty, 2) == 18.99  # 5/4(9^2+5.8^2+2^2)+1/4(..16.5^2)+(..1^2)


def test_printed_offset_figures_are_kept_but_do_not_follow_from_the_equations():
    # Lines 1467, 1473, 1481 print 35.1, 35.1, 39.9 um; eqs. 22-24 as printed give 15.8, 15.8, 19.0 um.
    b = unc.mount_offset_budgets()
    assert [b[k].printed for k in ("U1", "V1", "W1")] == [35.1, 35.1, 39.9]
    assert [round(b[k].combined_standard_uncertainty, 1) for k in ("U1", "V1", "W1")] == [15.8, 15.8, 19.0]
    assert "source prints u_c = 35.1 um" in b["U1"].table()


# --- thesis sections 6.2.3, 6.3, 6.4.1 -----------------------------------------------------------

# (budget, exact value in um, printed um, how the thesis rounded, where)
FIGURES = [
    (lambda: unc.sphere_centre_budget(), 13.454, 14, "up", "6.2.3 line 1637: centre sqrt(9^2+10^2)"),
    (lambda: unc.ballbar_length_budget(1), 19.026, 20, "up", "6.2.3 lines 1625, 1635, 1637: single length"),
    (lambda: unc.ballbar_length_budget(8), 6.727, 7, "nearest", "6.2.3 line 1637: 20/sqrt(8); 404.084 +- 0.007 (1681)"),
    (lambda: unc.ballbar_length_budget(20), 4.254, 5, "up", "6.3.1 '22 +- 5' (1661); Tables 19, 21 +-0.005 (1736-1738, 1763-1765); 404.073 +- 0.005 (1681)"),
    (lambda: unc.ballbar_length_budget(60), 2.456, 3, "up", "Table 19 all temperatures +-0.003 (1739); Table 21 404.238 +- 0.003 (1766); 6.4.2 '17 +- 3' (1770)"),
    (lambda: unc.ballbar_length_budget(1, False, temperature=20), 26.173, 26, "nearest", "6.4.1 line 1753 u20; 6.2.3 lines 1623, 1633"),
    (lambda: unc.ballbar_length_budget(1, False, temperature=25), 40.817, 41, "nearest", "6.4.1 line 1753 u25"),
    (lambda: unc.ballbar_length_budget(1, False, temperature=30), 51.971, 52, "nearest", "6.4.1 line 1753 u30"),
    (lambda: unc.ballbar_length_budget(20, False, temperature=20), 5.852, 6, "nearest", "Tables 19, 21 (1736, 1763); 6.4.1 '73 +- 6' (1730); 6.3.1 '71 +- 6' (1661)"),
    (lambda: unc.ballbar_length_budget(20, False, temperature=25), 9.127, 10, "up", "Tables 19, 21 (1737, 1764); 6.4.1 '62 +- 10' (1730)"),
    (lambda: unc.ballbar_length_budget(20, False, temperature=30), 11.621, 12, "nearest", "Tables 19, 21 (1738, 1765); 6.4.1 '66 +- 12' (1730)"),
]


@pytest.mark.parametrize("make, exact, printed, rounding, where", FIGURES, ids=[f[4][:40] for f in FIGURES])
def test_thesis_figures(make, exact, printed, rounding, where):
    b = make()
    u = b.combined_standard_uncertainty
    assert u == pytest.approx(exact, abs=5e-4)
    assert (up(u) if rounding == "up" else round(u)) == printed
    assert b.printed == printed and b.unit == "um"


def test_thesis_figures_from_its_own_rounded_intermediates():
    # The thesis carries rounded numbers forward: 14 um per centre -> 20 um -> 20/sqrt(8) = 7 um,
    # 0.005 mm / sqrt(3) = 0.003 mm (line 1772).
    centre = Input("centre", 0.0, 14.0, "um")
    length = Budget("L", (centre, dataclasses.replace(centre, name="centre 2")), "um")
    assert round(length.combined_standard_uncertainty) == 20
    assert round(unc.uncertainty_of_mean([20.0] * 8)) == 7
    assert round(unc.uncertainty_of_mean([5.0] * 3)) == 3


def test_uncompensated_all_temperature_figure():
    # Table 19/21 "All temperatures" +-0.009 mm (lines 1739, 1766), 6.4.2 "67 +- 9" (1770): the mean of the
    # three 20-position uncertainties, i.e. the three determinations taken as fully correlated (the same
    # scales). The thesis does not say; this is the reading that gives the printed figure.
    per_t = [unc.ballbar_length_budget(20, False, temperature=t).combined_standard_uncertainty for t in (20, 25, 30)]
    u = unc.uncertainty_of_mean(per_t, correlation=1.0)
    assert u == pytest.approx(8.867, abs=5e-4) and round(u) == 9
    assert round(unc.uncertainty_of_mean(per_t, correlation=0.0)) == 5  # independent: not what is printed


def test_length_budget_options_and_errors():
    custom = unc.ballbar_length_budget(4, False, scale=(3.0, 4.0, 0.0), digitizer=0.0, sphere_fit=0.0)
    assert custom.combined_standard_uncertainty == pytest.approx(2.5) and custom.printed is None
    assert unc.ballbar_length_budget(3).printed is None
    with pytest.raises(cmmpose.InputError, match="20, 25 and 30"):
        unc.ballbar_length_budget(1, False, temperature=22.0)
    for bad in (0, 1.5, True):
        with pytest.raises(cmmpose.InputError, match="n_positions"):
            unc.ballbar_length_budget(bad)
    with pytest.raises(cmmpose.InputError, match="model"):
        unc.mount_offset_budgets(model="other")


# --- Monte Carlo against the linear law of propagation ------------------------------------------


def _assert_agree(mc, lin, rtol=0.10):
    np.testing.assert_allclose(mc, lin, rtol=rtol)


def test_centre_noise_only_mc_matches_linearised_fit(reference_scan):
    d = reference_scan
    args = (d.uv, d.scales, MAPS, POSE, OFFSET, T)
    lin = unc.linear_sphere_centre_uncertainty(*args, u_noise=0.008)
    mc = unc.monte_carlo_sphere_centre(*args, u_noise=0.008, trials=TRIALS, rng=1)
    _assert_agree(mc.standard_uncertainty, lin.standard_uncertainty)
    assert np.all(mc.standard_uncertainty < 0.001)  # well under 1 um from 8 um noise on ~5000 points
    assert np.all(np.abs(mc.centre - lin.centre) < 5 * lin.standard_uncertainty / math.sqrt(TRIALS))


def test_centre_mc_matches_linear_for_small_uncertainties(reference_scan):
    d = reference_scan
    args = (d.uv, d.scales, MAPS, POSE, OFFSET, T)
    uv, scales = d.uv.copy(), d.scales.copy()
    lin = unc.linear_sphere_centre_uncertainty(*args, **SMALL)
    mc = unc.monte_carlo_sphere_centre(*args, **SMALL, trials=TRIALS, rng=2)
    np.testing.assert_array_equal(d.uv, uv)
    np.testing.assert_array_equal(d.scales, scales)  # inputs untouched
    _assert_agree(mc.standard_uncertainty, lin.standard_uncertainty)
    assert mc.trials.shape == (TRIALS, 3) and mc.n_trials == TRIALS and lin.n_trials == 0
    np.testing.assert_allclose(mc.covariance, np.cov(mc.trials, rowvar=False))
    # The linear covariance is the sum of the contributions; each axis's budget adds up to it.
    np.testing.assert_allclose(sum(lin.contributions.values()), lin.covariance)
    for j, axis in enumerate("xyz"):
        assert lin.budget(axis).combined_standard_uncertainty == pytest.approx(lin.standard_uncertainty[j], rel=1e-12)
    # W1 is along w = +X here: the centre moves by -1 mm per mm of W1 (X = ... - E313 l1).
    np.testing.assert_allclose(lin.sensitivities["W1"], [-1.0, 0.0, 0.0], atol=1e-3)
    lo, hi = mc.coverage_interval(0.95)
    assert np.all(lo < mc.centre) and np.all(mc.centre < hi)
    np.testing.assert_allclose(hi - lo, lin.coverage_interval(0.95)[1] - lin.coverage_interval(0.95)[0], rtol=0.1)
    with pytest.raises(cmmpose.InputError, match="Monte Carlo"):
        mc.budget("x")


def test_ballbar_mc_matches_linear(ballbar_scans):
    b1, b2 = ballbar_scans
    args = (b1.uv, b1.scales, b2.uv, b2.scales, MAPS, POSE, OFFSET, T)
    lin = unc.linear_ballbar_length_uncertainty(*args, **SMALL)
    mc = unc.monte_carlo_ballbar_length(*args, **SMALL, trials=TRIALS, rng=3)
    assert mc.standard_uncertainty == pytest.approx(lin.standard_uncertainty, rel=0.10)
    assert lin.length == pytest.approx(400.0, abs=0.002)
    assert abs(mc.length - lin.length) < 5 * lin.standard_uncertainty / math.sqrt(TRIALS)
    assert lin.budget().combined_standard_uncertainty == pytest.approx(lin.standard_uncertainty, rel=1e-12)
    # A common pose or offset error moves both balls alike: the length barely notices.
    assert lin.contributions["beta"] < 1e-3 * lin.standard_uncertainty ** 2
    assert lin.contributions["W1"] < 1e-3 * lin.standard_uncertainty ** 2
    assert mc.trials.shape == (TRIALS,) and mc.centres.shape == (2, 3)


def test_same_seed_same_trials(reference_scan):
    d = reference_scan
    args = (d.uv, d.scales, MAPS, POSE, OFFSET, T)
    a = unc.monte_carlo_sphere_centre(*args, **SMALL, trials=5, rng=7)
    b = unc.monte_carlo_sphere_centre(*args, **SMALL, trials=5, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.trials, b.trials)


def test_temperature_difference_is_one_sided_at_the_end_of_the_maps(reference_scan):
    d = reference_scan
    at_end = unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, 20.0, u_temperature=0.2)
    inside = unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, T, u_temperature=0.2)
    # The maps are linear in temperature from 20 to 25 C: the same slope at 20 C (forward difference) and
    # 22.5 C (central), up to the fit's own nonlinearity over 2.5 K (~5 um of centre motion on a 12.7 mm ball).
    np.testing.assert_allclose(at_end.sensitivities["temperature"], inside.sensitivities["temperature"], rtol=1e-3)
    with pytest.raises(cmmpose.OutOfRangeError, match="Monte Carlo trial"):
        unc.monte_carlo_sphere_centre(d.uv, d.scales, MAPS, POSE, OFFSET, 20.0, u_temperature=0.2, trials=50, rng=0)


def test_fixed_radius_and_single_map(reference_scan):
    d = reference_scan
    free = unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, T)
    fixed = unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, T, radius=12.7)
    # The scanner looks along machine Z here (v = +Z): a free radius trades off against the centre along it.
    assert fixed.standard_uncertainty[2] < 0.7 * free.standard_uncertainty[2]
    single = unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS.at(T), POSE, OFFSET, u_pose_deg=(0.01, 0, 0))
    assert "temperature" not in single.contributions
    mc = unc.monte_carlo_sphere_centre(d.uv, d.scales, MAPS.at(T), POSE, OFFSET, trials=3, rng=0)
    assert mc.trials.shape == (3, 3)


@pytest.mark.parametrize("kwargs, match", [
    (dict(u_noise=-1.0), "u_noise"),
    (dict(u_pose_deg=(0, 0)), "u_pose_deg"),
    (dict(u_offset=(0, -1, 0)), "standard uncertainties"),
    (dict(trials=1), "trials"),
    (dict(trials=2.5), "trials"),
    (dict(out_of_range="ignore"), "out_of_range"),
])
def test_bad_propagation_inputs_raise_input_error(reference_scan, kwargs, match):
    d = reference_scan
    with pytest.raises(cmmpose.InputError, match=match):
        unc.monte_carlo_sphere_centre(d.uv, d.scales, MAPS, POSE, OFFSET, T, **kwargs)


def test_bad_data_raise_input_error(reference_scan):
    d = reference_scan
    with pytest.raises(cmmpose.InputError, match="same number of rows"):
        unc.linear_sphere_centre_uncertainty(d.uv[:-1], d.scales, MAPS, POSE, OFFSET, T)
    with pytest.raises(cmmpose.InputError, match="required with an ErrorMapSet"):
        unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET)
    with pytest.raises(cmmpose.InputError, match="u_temperature"):
        unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS.at(T), POSE, OFFSET, u_temperature=0.1)
    with pytest.raises(cmmpose.InputError, match="step"):
        unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, T, step_pose_deg=0.0)
    with pytest.raises(cmmpose.InputError, match="p"):
        unc.linear_sphere_centre_uncertainty(d.uv, d.scales, MAPS, POSE, OFFSET, T).coverage_interval(1.5)
