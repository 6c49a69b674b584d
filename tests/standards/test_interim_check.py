"""Interim check: three scale and three squareness values from one ballbar run."""

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.sim import parse_effect, simulate_ballbar_run
from cmmpose.sim.scanner import Scanner
from cmmpose.standards.interim import ARCSEC_PPM, _undetermined, interim_check

MAPS = cmmpose.ErrorMapSet.thesis()
SQUARENESS = {"squareness XY": 10.0, "squareness YZ": -6.0, "squareness ZX": 8.0}
SCALE = {"scale X": 5.0, "scale Y": -3.0, "scale Z": 2.0}


@pytest.fixture(scope="module")
def run():
    eff = [parse_effect("squareness:xy=10,yz=-6,zx=8"), parse_effect("scale:x=5,y=-3,z=2")]
    r, truth = simulate_ballbar_run(MAPS, 20.0, eff, jitter=0.001, calibrated=("length",),
                                    scanner=Scanner(points_per_profile=256), seed=2)
    return r


def test_recovers_hidden_squareness_and_scale(run):
    c = interim_check(run, MAPS, 20.0, u_temperature_K=0.05)
    assert c.absolute_scale and c.positions == 20 and c.label == "compensated"
    for name, truth in {**SQUARENESS, **SCALE}.items():
        v = c[name]
        assert abs(v.value - truth) <= 3 * v.u, (name, v)
        assert v.k == 2 and v.U == pytest.approx(2 * v.u)
    assert c["squareness XY"].um_per_m == pytest.approx(c["squareness XY"].value * ARCSEC_PPM)
    assert c["squareness XY"].u < 2.0  # arc-seconds: a 20-position run pins squareness well


def test_without_a_calibrated_length_scales_are_mismatches(run):
    c = interim_check(dataclasses.replace(run, artefact={"kind": "ballbar"}), MAPS, 20.0)
    assert not c.absolute_scale
    scales = np.array([c[k].value for k in SCALE])
    assert scales.sum() == pytest.approx(0.0, abs=1e-9)
    truth = np.array(list(SCALE.values()))
    assert np.all(np.abs(scales - (truth - truth.mean())) <= 3 * np.array([c[k].u for k in SCALE]))
    assert c["scale X"].words == "scale mismatch X" and any("mismatch" in n for n in c.notes)
    # Squareness does not need the reference length.
    ref = interim_check(run, MAPS, 20.0)
    assert c["squareness XY"].value == pytest.approx(ref["squareness XY"].value, rel=1e-4)  # y / mean vs / cal


def test_fit_against_the_model_written_again(run):
    """The least squares by hand: the same design from the fitted centres."""
    c = interim_check(run, MAPS, 20.0)
    ev = cmmpose.evaluate(run, MAPS, 20.0).compensated
    cen = {(s.position, s.ball): s.centre for s in ev.spheres}
    n = np.array([cen[(p, 2)] - cen[(p, 1)] for p in ev.positions.tolist()])
    n /= np.linalg.norm(n, axis=1)[:, None]
    k = np.pi / 648000 * 1e6
    a = np.column_stack([-n[:, 0] ** 2, -n[:, 1] ** 2, -n[:, 2] ** 2, k * n[:, 0] * n[:, 1], k * n[:, 1] * n[:, 2],
                         k * n[:, 2] * n[:, 0]])
    cal = run.artefact["calibrated_length_mm"]
    y = (ev.lengths_at_20c - cal) / cal * 1e6
    sol = np.linalg.lstsq(a, y, rcond=None)[0]
    np.testing.assert_allclose([v.value for v in c.values], sol, atol=1e-9)


def test_directions_that_do_not_determine_every_value():
    n = np.array([[1, 0, 0], [0, 1, 0], [np.sqrt(0.5), np.sqrt(0.5), 0], [np.sqrt(0.5), -np.sqrt(0.5), 0]] * 3)
    a = np.column_stack([-n[:, 0] ** 2, -n[:, 1] ** 2, -n[:, 2] ** 2, n[:, 0] * n[:, 1], n[:, 1] * n[:, 2],
                         n[:, 2] * n[:, 0]])
    assert _undetermined(a) == ["scale Z", "squareness YZ", "squareness ZX"]


def test_cli(run, tmp_path):
    run.save(tmp_path / "run")
    out = CliRunner().invoke(main, ["standards", "interim-check", str(tmp_path / "run"), "--temperature", "20", "--json"])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.stdout)
    assert [v["name"] for v in doc["values"]] == list(SCALE) + list(SQUARENESS)
    assert doc["values"][3]["words"] == "squareness XY" and doc["values"][0]["words"] == "scaling error X"
    rep = CliRunner().invoke(main, ["standards", "interim-check", str(tmp_path / "run"), "--temperature", "20", "--report",
                                    str(tmp_path / "rep")])
    assert rep.exit_code == 0, rep.output
    md = (tmp_path / "rep" / "interim-check.md").read_text()
    assert "| squareness XY | squareness XY |" in md
