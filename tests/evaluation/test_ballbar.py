"""Ballbar evaluation: the thesis's own numbers (Appendix C -> Tables 19 and 20),
and the evaluation of simulated runs end to end."""

import json

import numpy as np
import pytest

import cmmpose
from cmmpose import layouts, sim

MAPS = cmmpose.ErrorMapSet.thesis()


@pytest.mark.parametrize(
    "state, mean, rms, b89",
    [("uncompensated", 404.2051, 0.0732, 0.186), ("compensated", 404.2357, 0.0128, 0.024)],
)
def test_appendix_c_reproduces_tables_19_and_20(state, mean, rms, b89):
    printed = layouts.appendix_c_lengths(state)
    centres = layouts.appendix_c_centres(state)
    from_centres = np.linalg.norm(centres[:, 1] - centres[:, 0], axis=1)
    for lengths in (printed, from_centres):
        assert round(float(np.mean(lengths)), 4) == mean
        assert round(cmmpose.rms_accuracy_error(lengths), 4) == rms
        assert round(cmmpose.b89_value(lengths), 3) == b89


def test_improvement_and_length_at_20c():
    # Table 19 at 20 C prints 82 % for 73.2 -> 12.8 um (82.5 %, truncated); Table 20: 186 -> 24 um is 87 %.
    assert cmmpose.improvement(0.0732, 0.0128) == pytest.approx(0.8251, abs=1e-4)
    assert round(cmmpose.improvement(0.186, 0.024), 2) == 0.87
    # Steel, 12e-6 /K: a 404.2357 mm bar at 25 C is 404.2115 mm at 20 C.
    assert cmmpose.length_at_20c(404.2357, 25.0) == pytest.approx(404.2357 / (1 + 12e-6 * 5))
    with pytest.raises(cmmpose.InputError):
        cmmpose.rms_accuracy_error([404.0])
    with pytest.raises(cmmpose.InputError, match="position 1"):
        cmmpose.b89_value([404.0, np.nan, 404.1])


@pytest.fixture(scope="module")
def run_22():
    return sim.simulate_ballbar_run(MAPS, 22.5, seed=21)


def test_evaluate_simulated_run(run_22):
    run, (truth, _) = run_22
    ev = cmmpose.evaluate(run, MAPS)  # temperatures from the run's thermocouple log
    assert 0.060 < ev.uncompensated.rms_accuracy_error < 0.080
    assert ev.compensated.rms_accuracy_error < 0.001
    assert ev.improvement_rms > 0.98
    np.testing.assert_allclose(ev.compensated.lengths, truth["true_lengths"], atol=0.002)
    np.testing.assert_array_equal(ev.compensated.positions, np.arange(1, 21))
    assert len(ev.compensated.spheres) == 40
    s = ev.compensated.spheres[0]
    assert abs(s.ps) < 0.002 and 0.02 < s.pf < 0.08 and 0.006 < s.rms < 0.010
    np.testing.assert_allclose(ev.compensated.temperatures, 22.5, atol=0.02)
    text = str(ev)
    assert "rms accuracy error" in text and "improvement" in text
    d = json.loads(ev.to_json())
    assert d["results"][1]["label"] == "compensated" and len(d["results"][1]["rows"]) == 20
    df = ev.to_pandas()
    assert df.shape[0] == 40 and {"length_mm", "ball2_radius_mm"} <= set(df.columns)


def test_uncompensated_only_and_fixed_temperature(run_22):
    run, _ = run_22
    ev = cmmpose.evaluate(run)
    assert ev.compensated is None and ev.improvement_rms is None
    ev2 = cmmpose.evaluate(run, MAPS, 22.5)
    assert ev2.compensated.rms_accuracy_error < 0.001


def test_evaluate_bad_runs(run_22, tmp_path):
    run, _ = run_22
    with pytest.raises(cmmpose.InputError, match="expected a cmmpose.Run"):
        cmmpose.evaluate("not a run")
    no_log = cmmpose.Run(points=run.points, scans=run.scans, poses=run.poses, artefact=run.artefact)
    with pytest.raises(cmmpose.InputError, match="no temperature log"):
        cmmpose.evaluate(no_log, MAPS)
    one = {k: v[:2] for k, v in run.scans.items()}
    keep = np.isin(run.points["scan_id"], one["scan_id"])
    single = cmmpose.Run(points={k: v[keep] for k, v in run.points.items()}, scans=one, poses=run.poses)
    with pytest.raises(cmmpose.InputError, match="at least 2 positions"):
        cmmpose.evaluate(single)


def test_open_thermocouple_is_left_out_of_the_machine_mean(run_22):
    run, _ = run_22
    temps = dict(run.temperatures)
    temps["X1"] = np.full_like(temps["X1"], sim.OPEN_CIRCUIT_READING)
    broken = cmmpose.Run(points=run.points, scans=run.scans, poses=run.poses, temperatures=temps,
                         temperature_channels=run.temperature_channels)
    t = cmmpose.evaluation.ballbar.machine_temperature(broken, run.points["t"][:100])
    np.testing.assert_allclose(t, 22.5, atol=0.05)
