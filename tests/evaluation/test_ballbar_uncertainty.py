"""Uncertainties of the ballbar figures (cmmpose.evaluation.ballbar_uncertainty): the
budget's arithmetic, the temperature sensitivity against evaluate itself, and
coverage over simulated runs with per-scan reproducibility."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.evaluation.ballbar_uncertainty import default_map_ppm, evaluation_uncertainty
from cmmpose.sim import parse_effect, simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()
SCANNER = Scanner(points_per_profile=256)


@pytest.fixture(scope="module")
def sim():
    run, truth = simulate_ballbar_run(MAPS, 22.5, jitter=0.003, scanner=SCANNER, seed=3)
    ev = cmmpose.evaluate(run, MAPS, 22.5)
    return run, truth, ev, evaluation_uncertainty(run, ev, MAPS, 22.5, u_model_ppm=0.5)


def test_budget_arithmetic(sim):
    run, _, ev, unc = sim
    r = unc["compensated"]
    res = ev.compensated
    P = len(res.lengths)
    s = np.std(res.lengths, ddof=1) * 1e3
    assert r.s_lengths_um == pytest.approx(s)
    for fig in r.lengths:
        rows = {i.name: i.contribution for i in fig.budget.inputs}
        # Type A and fit shares add up to the spread of the lengths on average:
        # u_between^2 = s^2 - mean u_fit^2.
        assert rows["Type A: scan-to-scan reproducibility"] > 0
        assert fig.u == pytest.approx(math.sqrt(sum(v ** 2 for v in rows.values())))
        # Residual model error: 0.5 ppm of the length.
        assert rows["residual model error"] == pytest.approx(0.5e-6 * fig.value * 1e3)
        assert fig.k == 2 and fig.U == pytest.approx(2 * fig.u)
    fit2 = np.mean([{i.name: i.contribution for i in f.budget.inputs}["scanner noise (u and v) via the sphere fits"] ** 2
                    for f in r.lengths])
    between = {i.name: i.contribution for i in r.lengths[0].budget.inputs}["Type A: scan-to-scan reproducibility"]
    assert between ** 2 + fit2 == pytest.approx(s ** 2)
    # The mean: the random terms divided by sqrt(P), the common ones not.
    mean_rows = {i.name: i.contribution for i in r.mean.budget.inputs}
    assert mean_rows["Type A: scan-to-scan reproducibility"] == pytest.approx(between / math.sqrt(P))
    assert mean_rows["residual model error"] == pytest.approx(0.5e-6 * res.mean_length * 1e3)
    # The rms accuracy error: s / sqrt(2 (P - 1)).
    assert r.rms_accuracy_error.u == pytest.approx(s / math.sqrt(2 * (P - 1)))
    assert r.rms_accuracy_error.value == pytest.approx(s)
    assert r.b89.value == pytest.approx(res.b89 * 1e3)
    assert 0.2 * s < r.b89.u < s
    # The map term: a scale error e on every axis changes a length by e L (sum dL_j^2 / L = L),
    # so with independent axes the length's term lies between L u / sqrt(3) and L u.
    u_map = {i.name: i.contribution for i in r.lengths[0].budget.inputs}["error maps: scale of each axis"]
    L_um = r.lengths[0].value * 1e3
    assert L_um * default_map_ppm() * 1e-6 / math.sqrt(3) - 1e-9 <= u_map <= L_um * default_map_ppm() * 1e-6 + 1e-9
    assert any("certificate" in x for x in unc.left_out)


def test_temperature_sensitivity_agrees_with_evaluate(sim):
    run, _, ev, unc = sim
    up = cmmpose.evaluate(run, MAPS, 23.0).compensated.lengths
    down = cmmpose.evaluate(run, MAPS, 22.0).compensated.lengths
    c = (up - down) * 1e3  # um per K
    rows = [{i.name: i for i in f.budget.inputs}["machine temperature reading (through the maps)"]
            for f in unc["compensated"].lengths]
    np.testing.assert_allclose([i.sensitivity for i in rows], c, rtol=1e-6, atol=1e-6)
    assert unc["compensated"].temperature_sensitivity_um_per_K == pytest.approx(np.mean(c), abs=1e-6)


def test_uncompensated_has_no_map_terms(sim):
    run, _, ev, _ = sim
    unc = evaluation_uncertainty(run, cmmpose.evaluate(run, None, 22.5), None, 22.5)
    names = {i.name for i in unc["uncompensated"].lengths[0].budget.inputs}
    assert names == {"Type A: scan-to-scan reproducibility", "scanner noise (u and v) via the sphere fits"}
    with pytest.raises(KeyError):
        unc["compensated"]


def test_a_mismatched_evaluation_is_refused(sim):
    run, _, ev, _ = sim
    with pytest.raises(cmmpose.InputError, match="not those of run"):
        evaluation_uncertainty(run, ev, MAPS, 25.0)
    with pytest.raises(cmmpose.InputError, match="u_temperature_K"):
        evaluation_uncertainty(run, ev, MAPS, 22.5, u_temperature_K=-1)


def test_coverage_over_simulated_runs():
    """40 runs with 3 um per-scan reproducibility and the budget's inputs drawn
    at their stated uncertainties (benches/evaluation_coverage.py does 1000)."""
    inside_l, inside_m, z_fit_only = [], [], []
    for i in range(40):
        rng = np.random.default_rng([17, i])
        d_t = float(rng.normal(0, 0.2))
        e = [float(x) for x in rng.normal(0, default_map_ppm(), 3)]
        run, truth = simulate_ballbar_run(MAPS, 22.5, [parse_effect(f"scale:x={e[0]},y={e[1]},z={e[2]}")],
                                          jitter=0.003, scanner=SCANNER, seed=100 + i)
        ev = cmmpose.evaluate(run, MAPS, 22.5 + d_t)
        r = evaluation_uncertainty(run, ev, MAPS, 22.5 + d_t)["compensated"]
        err = (ev.compensated.lengths - truth[0]["true_lengths"]) * 1e3
        u = np.array([f.u for f in r.lengths])
        inside_l.append(np.abs(err) <= 2 * u)
        inside_m.append(abs(err.mean()) <= 2 * r.mean.u)
        fit_only = np.array([{i.name: i.contribution for i in f.budget.inputs}
                             ["scanner noise (u and v) via the sphere fits"] for f in r.lengths])
        z_fit_only.append(np.abs(err) <= 2 * fit_only)
    assert 0.90 <= np.mean(inside_l) <= 0.99
    assert 0.85 <= np.mean(inside_m) <= 1.0
    # The fits' share alone (what the old propagation had, noise only) covers far too little.
    assert np.mean(z_fit_only) < 0.3


def test_cli_evaluate_prints_u_and_budget(tmp_path):
    run, truth = simulate_ballbar_run(MAPS, 22.5, jitter=0.003, scanner=SCANNER, seed=4)
    run.save(tmp_path / "run", truth=truth)
    out = CliRunner().invoke(main, ["evaluate", str(tmp_path / "run"), "--temperature", "22.5", "--json",
                                    "--u-temperature", "0.1", "--u-model", "0.3"])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.stdout)
    u = doc["uncertainty"]
    assert u["inputs"]["u_temperature_K"] == 0.1 and u["inputs"]["u_model_ppm"] == 0.3
    comp = [r for r in u["results"] if r["label"] == "compensated"][0]
    assert len(comp["lengths"]) == 20 and all(f["k"] == 2 and f["U_um"] > 0 for f in comp["lengths"])
    assert [f["name"] for f in comp["figures"]] == ["mean length", "mean length at 20 C", "rms accuracy error", "B89"]
    assert "left_out" in u and doc["results"][1]["label"] == "compensated"
    table = CliRunner().invoke(main, ["evaluate", str(tmp_path / "run"), "--temperature", "22.5", "--report",
                                      str(tmp_path / "rep"), "--verbose"])  # the budgets: behind --verbose
    assert table.exit_code == 0
    assert "Uncertainty budget: mean length" in table.stdout and "left out:" in table.stdout
    assert json.loads((tmp_path / "rep" / "uncertainty.json").read_text())["coverage_factor"] == 2
    md = (tmp_path / "rep" / "uncertainty.md").read_text()
    assert "| compensated | mean length |" in md and "Left out:" in md


def test_temperature_sensitivity_at_the_maps_edge_is_one_sided():
    run, _ = simulate_ballbar_run(MAPS, 30.0, jitter=0.003, scanner=Scanner(points_per_profile=128), seed=6)
    ev = cmmpose.evaluate(run, MAPS, 30.0)
    unc = evaluation_uncertainty(run, ev, MAPS, 30.0)  # 30.5 C is outside the maps: 29.5 C only
    c = (ev.compensated.lengths - cmmpose.evaluate(run, MAPS, 29.5).compensated.lengths) / 0.5 * 1e3
    rows = [{i.name: i for i in f.budget.inputs}["machine temperature reading (through the maps)"]
            for f in unc["compensated"].lengths]
    np.testing.assert_allclose([i.sensitivity for i in rows], c, rtol=1e-6, atol=1e-6)
