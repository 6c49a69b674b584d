"""Diagnosis of artefact runs (issue 24): ball plates and step gauges, alone
and jointly, with the effect library of the ballbar diagnosis. The
observables of an artefact run are each ball's centre per placement after the
placement's best-fit rigid transform (cmmpose.evaluation.artefact_layout)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cmmpose import artefacts
from cmmpose.cli import main
from cmmpose.diagnosis import diagnose
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.errors import InputError
from cmmpose.run import Run
from cmmpose.sim import Scale, Squareness
from cmmpose.sim.artefact_runs import simulate_artefact_run

SQUARENESS = (6.0, -4.0, 3.0)  # arc-seconds
SCALE = (8.0, -6.0, 5.0)  # ppm


def _strict_json(text: str):
    def refuse(c):
        raise AssertionError(f"not standard JSON: {c}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def hidden(plate):
    """KOBA 0420 in the three coordinate planes of the thesis machine with a
    squareness and a scale error the maps do not hold."""
    run, _ = simulate_artefact_run(plate, ["planes"], None, 20.0,
                                   [Squareness(*SQUARENESS), Scale(*SCALE)], seed=1)
    return run, diagnose(run, patterns=False)


def test_hidden_squareness_and_scale_are_found_within_their_uncertainty(hidden):
    _, d = hidden
    assert sorted(d.added) == ["scale", "squareness"]
    found = {x["name"]: x for x in d.decisions() if x["decision"] == "added"}
    for name, truth in (("squareness", SQUARENESS), ("scale", SCALE)):
        values, u = found[name]["values"], found[name]["uncertainty"]
        for (param, value), want in zip(values.items(), truth):
            assert 0 < u[param] < 1.0, (name, param, u[param])
            assert abs(value - want) < 3 * u[param], (name, param, value, want, u[param])
    first, last = d.steps[0].figures, d.steps[-1].figures
    assert first.deviation_rms > 3 * last.deviation_rms
    assert last.deviation_rms < 1e-3  # under 1 um once both are in the model


def test_a_plate_run_has_no_ballbar_lengths_and_counts_the_rigid_fits(hidden, plate):
    run, _ = hidden
    from cmmpose.model import Model
    from cmmpose.errormap import ErrorMapSet

    problem = Problem(Model(ErrorMapSet.thesis()), run, {})
    layout = problem.layout
    assert len(layout.positions) == 0  # balls 1 and 2 of a plate are not a bar
    assert layout.artefact.positions == (1, 2, 3)
    assert layout.sizes["length"] == 3 * 3 * plate.n_balls
    assert layout.artefact.fitted_dof == 18
    assert problem.n_eff[0] == 3 * 3 * plate.n_balls - 18
    assert problem.nuisance.shape[1] == 0  # calibrated centres and radius: nothing left to the run


def test_the_json_is_standard_and_names_the_deviation_figures(hidden):
    _, d = hidden
    doc = _strict_json(d.to_json())
    base = doc["steps"][0]
    assert base["rms_accuracy_error_um"] is None and base["b89_um"] is None
    assert base["rms_deviation_um"] > 1.0 and base["largest_deviation_um"] >= base["rms_deviation_um"]
    text = str(d)
    assert "rms deviation (um)" in text and "of deviations" in text


def test_a_noise_only_plate_run_adds_nothing(plate):
    run, _ = simulate_artefact_run(plate, ["planes"], None, 20.0, [], seed=2)
    d = diagnose(run, patterns=False)
    assert d.added == []
    assert d.steps[0].figures.deviation_rms < 1e-3


def test_a_step_gauge_counts_five_degrees_of_freedom_per_placement():
    gauge = artefacts.load_artefact("step-gauge-31x20")
    run, _ = simulate_artefact_run(gauge, ["xy@z=-400,rot=45"], None, 20.0, [Squareness(8.0, 0.0, 0.0)],
                                   seed=3)
    d = diagnose(run, patterns=False, auto=False)
    from cmmpose.model import Model
    from cmmpose.errormap import ErrorMapSet

    problem = Problem(Model(ErrorMapSet.thesis()), run, {})
    assert problem.layout.artefact.fitted_dof == 5
    ranking = {c.name: c for c in d.steps[0].ranking}
    sq = ranking["squareness"]
    assert sq.significant and abs(sq.values[0] - 8.0) < 3 * sq.uncertainty[0]
    # One bar-like artefact on one diagonal sees lengths along it only: a
    # squareness there is a roll there, and the diagnosis says so.
    assert "roll" in sq.aliases


def test_plate_and_step_gauge_jointly(hidden):
    plate_run, _ = hidden
    gauge = artefacts.load_artefact("step-gauge-31x20")
    gauge_run, _ = simulate_artefact_run(gauge, ["xy@z=-400,rot=45", "xz@y=500,rot=30"], None, 20.0,
                                         [Squareness(*SQUARENESS), Scale(*SCALE)], seed=4)
    d = diagnose_jointly([plate_run, gauge_run], same_artefact=False, run_names=["plate", "gauge"])
    assert sorted(d.added) == ["scale", "squareness"]
    sq = d.model.values("squareness")
    u = d.final_uncertainty["squareness"]
    assert np.all(np.abs(sq - SQUARENESS) < 3 * u), (sq, u)
    assert all(f.deviation_rms is not None for f in d.run_figures[0])
    assert "plate: rms deviation (um)" in str(d)
    _strict_json(d.to_json())


def test_a_scan_labelled_with_a_ball_the_artefact_lacks_is_an_error(plate):
    run, _ = simulate_artefact_run(plate, ["xy@z=-525"], None, 20.0, [], seed=5)
    scans = dict(run.scans)
    ball = scans["ball"].copy()
    ball[3] = 99
    scans["ball"] = ball
    bad = Run(run.points, scans, run.poses, run.temperatures, run.temperature_channels, run.artefact, run.maps,
              run.metadata, run.created)
    with pytest.raises(InputError, match="no ball 99"):
        diagnose(bad, patterns=False)


def test_cli_diagnose_plate_runs_alone_and_jointly(tmp_path):
    cli = CliRunner()
    a, b = tmp_path / "a", tmp_path / "b"
    r = cli.invoke(main, ["simulate", "--artefact", "koba-0420", "--placement", "planes", "--effect",
                          "squareness:xy=6", "-o", str(a)])
    assert r.exit_code == 0, r.output
    r = cli.invoke(main, ["simulate", "--artefact", "step-gauge-31x20", "--placement", "xy@z=-400,rot=45",
                          "--effect", "squareness:xy=6", "--seed", "3", "-o", str(b)])
    assert r.exit_code == 0, r.output
    r = cli.invoke(main, ["diagnose", str(a), "--json"])
    assert r.exit_code == 0, r.output
    doc = _strict_json(r.stdout)
    added = {x["name"]: x for x in doc["decisions"] if x["decision"] == "added"}
    assert abs(added["squareness"]["values"]["xy"] - 6.0) < 3 * added["squareness"]["uncertainty"]["xy"]
    r = cli.invoke(main, ["diagnose", str(a), str(b), "--joint", "--separate-artefacts"], env={"COLUMNS": "100"})
    assert r.exit_code == 0, r.output
    assert "rms deviation (um)" in r.output and "squareness" in r.output


def test_html_report_of_a_plate_run(hidden, tmp_path):
    pytest.importorskip("matplotlib")
    run, d = hidden
    path = d.write_report(tmp_path / "plate.html", run)
    text = path.read_text(encoding="utf-8")
    assert "rms deviation fell from" in text and "rms deviation (um)" in text
