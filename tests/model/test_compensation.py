"""Issue 25, section 6: a found model is a compensation model. A model a
diagnosis saved compensates point files (``cmmpose.compensate``,
``compensate_file``, ``cmmpose compensate --model``) and evaluates runs
(``cmmpose.evaluate``, ``cmmpose evaluate --model``) with its effects; an
input its effects need that the data lack is an error naming it; its
parameters' uncertainties enter the evaluated figures' budgets."""

from __future__ import annotations

import json
import math

import cmmpose
import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose import Model
from cmmpose.errors import InputError
from cmmpose.evaluation.ballbar_uncertainty import evaluation_uncertainty
from cmmpose.filecompensation import compensate_file
from cmmpose.sim import parse_effect, simulate_ballbar_run

MAPS = cmmpose.ErrorMapSet.thesis()
ARCSEC = math.pi / 648000
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def _write_csv(path, columns: dict) -> None:
    names = list(columns)
    np.savetxt(path, np.column_stack([np.asarray(columns[c], float) for c in names]), delimiter=",",
               header=",".join(names), comments="", fmt="%.17g")


def _read_csv(path) -> dict:
    with open(path) as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {h: data[:, k] for k, h in enumerate(header)}


def _points(n=2000, seed=5):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(-25, 25, n), rng.uniform(115, 165, n)])
    scales = np.column_stack([rng.uniform(10, 890, n), rng.uniform(10, 540, n), rng.uniform(-490, -10, n)])
    return uv, scales, rng.uniform(20.5, 29.5, n)


def test_model_points_match_a_numpy_reference(tmp_path):
    """Squareness and scale offsets add e = (-E dS_xy - F dS_zx + D s_x, -F dS_yz + E s_y, F s_z) to the maps'
    compensation (docs/conventions.md, eqs. 11-13): written here from the readings alone, to rounding."""
    uv, scales, temps = _points()
    model = Model(MAPS).with_values("squareness", [7.0, -4.0, 3.0]).with_values("scale", [2.0, -6.0, 4.0])
    D, E, F = scales.T
    de = np.column_stack([(-E * 7.0 - F * 3.0) * ARCSEC + 2.0e-6 * D, -F * -4.0 * ARCSEC - 6.0e-6 * E, 4.0e-6 * F])
    reference = cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, temps) + de
    got = cmmpose.compensate(uv, scales, model, POSE, OFFSET, temps)
    np.testing.assert_allclose(got, reference, rtol=0, atol=1e-9)  # mm: linear terms, rounding only
    assert np.abs(de).max() > 5e-3  # the effects matter (um), so the check can fail
    # The same through a file, in chunks, with the file's other columns passed through.
    src, out = tmp_path / "in.csv", tmp_path / "out.csv"
    _write_csv(src, {"u": uv[:, 0], "v": uv[:, 1], "D": D, "E": E, "F": F, "T": temps, "intensity": np.arange(len(uv))})
    done = compensate_file(src, out, model, POSE, OFFSET, chunk=700)
    assert done.points == len(uv)
    cols = _read_csv(out)
    # The CSV writer keeps 1e-6 mm (docs/formats.md): half of that is the rounding.
    np.testing.assert_allclose(np.column_stack([cols["X"], cols["Y"], cols["Z"]]), reference, rtol=0, atol=5.1e-7)
    np.testing.assert_array_equal(cols["intensity"], np.arange(len(uv)))


def test_inputs_the_model_needs_are_named(tmp_path):
    uv, scales, temps = _points(50)
    src = tmp_path / "in.csv"
    _write_csv(src, {"u": uv[:, 0], "v": uv[:, 1], "D": scales[:, 0], "E": scales[:, 1], "F": scales[:, 2], "T": temps})
    latency = Model(MAPS).with_values("latency", [0.004])
    with pytest.raises(InputError, match=r"'latency' needs each point's time stamp.*column 't'"):
        compensate_file(src, tmp_path / "out.csv", latency, POSE, OFFSET)
    role = Model(MAPS).with_values("squareness-temperature@z_scale", [1.0])
    with pytest.raises(InputError, match=r"squareness-temperature@z_scale.*column 'T_z_scale'"):
        cmmpose.compensate(uv, scales, role, POSE, OFFSET, temps)
    with pytest.raises(InputError, match="machine temperature: a T column"):
        cmmpose.compensate(uv, scales, Model(MAPS), POSE, OFFSET)  # a map set needs one
    per_pose = Model(MAPS).with_values("alignment@2", [0.01, 0.0, 0.0])
    with pytest.raises(InputError, match="pose_id column"):
        cmmpose.compensate(uv, scales, per_pose, POSE, OFFSET, temps)
    assert not (tmp_path / "out.csv").exists()  # nothing left behind


@pytest.fixture(scope="module")
def runs():
    """One machine with a hidden squareness and Y scale error: a B89 run (to diagnose) and a crossed run (to apply
    the model to: positions and temperature it never saw)."""
    hidden = [parse_effect("squareness:xy=8"), parse_effect("scale:y=-6")]
    fit_run, _ = simulate_ballbar_run(MAPS, 21.0, hidden, seed=1, jitter=0.001)
    other, _ = simulate_ballbar_run(MAPS, 23.0, hidden, layout="crossed", seed=2, jitter=0.001)
    return fit_run, other


def test_run_lacking_a_thermocouple_role_is_refused(runs):
    _, other = runs
    model = Model(MAPS).with_values("mount-expansion", [10.0])
    with pytest.raises(InputError, match=r"'mount-expansion' needs thermocouples of role 'mount'"):
        cmmpose.evaluate(other, model)


def test_latency_from_time_stamps_matches_the_run(tmp_path, runs):
    """A model with latency on a point file reads each sweep's velocity from t and scan_id (sweeps split between
    chunks are kept whole) and gives the points the model gives on the run (velocity from the scans table)."""
    run, _ = runs
    model = Model(MAPS).with_values("latency", [0.004]).with_values("squareness", [5.0, 0.0, 0.0])
    inputs = model.inputs(run)
    expected = model.compensate(run)
    pose, offset = run.pose(int(run.poses["pose_id"][0]))
    assert len(run.poses["pose_id"]) == 1
    keep = run.points["scan_id"] < 5  # a few whole sweeps are enough
    src, out = tmp_path / "in.csv", tmp_path / "out.csv"
    _write_csv(src, {"u": run.uv[keep, 0], "v": run.uv[keep, 1], "D": run.scales[keep, 0], "E": run.scales[keep, 1],
                     "F": run.scales[keep, 2], "T": inputs.temperature[keep], "t": run.points["t"][keep],
                     "scan_id": run.points["scan_id"][keep]})
    compensate_file(src, out, model, pose, offset, chunk=7_001)
    cols = _read_csv(out)
    got = np.column_stack([cols["X"], cols["Y"], cols["Z"]])
    np.testing.assert_allclose(got, expected[keep], rtol=0, atol=1e-6)  # mm: the CSV's 1e-6 mm and the slope
    shift = np.abs(expected[keep] - Model(MAPS).with_values("squareness", [5.0, 0, 0]).compensate(run)[keep]).max()
    assert shift > 0.05  # 4 ms at 35 mm/s: 0.14 mm, so the velocity was really used


@pytest.mark.slow
def test_a_diagnosed_model_compensates_another_run(tmp_path, runs):
    """Diagnose one run, save the model, apply it to another run of the same machine: the error falls against the
    plain maps, and the model's parameter uncertainties are in the budgets."""
    fit_run, other = runs
    # One B89 layout cannot choose between the squareness and rolls of the carriages (issue 33, section 3): the
    # diagnosis adds neither and says so; the user chooses by name (or measures what the plan proposes).
    open_set = cmmpose.diagnose(fit_run, MAPS, patterns=False)
    assert "squareness" not in open_set.model.names
    assert any("squareness" in a.names for a in open_set.open_ambiguity)
    diag = cmmpose.diagnose(fit_run, MAPS, patterns=False, add=["squareness"])
    assert "squareness" in diag.model.names
    path = diag.model.save(tmp_path / "m.json")
    saved = json.loads(path.read_text())
    sq = next(e for e in saved["effects"] if e["name"] == "squareness")
    assert 0 < sq["uncertainty"]["xy"] < 2.0  # arc-seconds, as the diagnosis found them
    model = Model.load(path)
    plain = cmmpose.evaluate(other, MAPS)
    found = cmmpose.evaluate(other, model)
    before, after = plain.compensated.rms_accuracy_error, found.compensated.rms_accuracy_error
    assert after < 0.5 * before, (before, after)
    assert found.provenance["maps"]["kind"] == "model"
    unc = evaluation_uncertainty(other, found, model)
    rows = {i.name: i for i in unc["compensated"].budgets["rms accuracy error"].inputs}
    assert "model squareness: xy" in rows and rows["model squareness: xy"].standard_uncertainty == pytest.approx(
        sq["uncertainty"]["xy"])
    assert abs(rows["model squareness: xy"].sensitivity) > 0.1  # um per arc-second: it moves the crossed lengths
    assert unc["compensated"].rms_accuracy_error.u > unc["uncompensated"].rms_accuracy_error.u * 0  # present
    # The command line: the same figures.
    from cmmpose.cli import main

    other.save(tmp_path / "other")
    res = CliRunner().invoke(main, ["evaluate", str(tmp_path / "other"), "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output[res.output.index("{"):])
    rms = next(r for r in doc["results"] if r["label"] == "compensated")["rms_accuracy_error_mm"]
    assert rms == pytest.approx(after, abs=1e-5)


def test_command_line_compensate_with_a_model(tmp_path):
    uv, scales, temps = _points(300)
    src = tmp_path / "in.csv"
    _write_csv(src, {"u": uv[:, 0], "v": uv[:, 1], "D": scales[:, 0], "E": scales[:, 1], "F": scales[:, 2], "T": temps})
    model = Model(MAPS).with_values("squareness", [7.0, -4.0, 3.0])
    path = model.save(tmp_path / "m.json")
    from cmmpose.cli import main

    res = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / "out.csv"), "--model", str(path),
                                    "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"])
    assert res.exit_code == 0, res.output
    cols = _read_csv(tmp_path / "out.csv")
    expected = cmmpose.compensate(uv, scales, model, POSE, OFFSET, temps)
    np.testing.assert_allclose(np.column_stack([cols["X"], cols["Y"], cols["Z"]]), expected, rtol=0, atol=5.1e-7)
    path = model.with_values("latency", [0.004]).save(tmp_path / "latency.json")
    res = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / "out2.csv"), "--model", str(path)])
    assert res.exit_code == 1 and "'latency' needs each point's time stamp" in res.output and "column 't'" in res.output
    assert "Traceback" not in res.output and not (tmp_path / "out2.csv").exists()
    res = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / "out3.csv"), "--model", str(path),
                                    "--maps", "thesis"])
    assert res.exit_code == 2 and "not both" in res.output


def test_artefact_deviation_u_carries_the_model_parameters():
    """A model's squareness xy stated +-2 arc-seconds: every ball of an XY plate moves by -E dS in x (eqs. 11-12),
    and what its placement's rigid fit leaves of that move enters each deviation's variance."""
    from dataclasses import replace

    from cmmpose import artefacts
    from cmmpose.evaluation.artefact import evaluate_artefact
    from cmmpose.sim.artefact_runs import simulate_artefact_run

    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0420"), ["xy@z=-450,rot=30"], MAPS, 20.5, [], seed=1)
    plain = Model(MAPS).with_values("squareness", [0.0, 0.0, 0.0])
    stated = replace(plain, uncertainty={"squareness": np.array([2.0, 0.0, 0.0])})
    ua = np.array([b.u for b in evaluate_artefact(run, plain).compensated.placements[0].balls])
    res = evaluate_artefact(run, stated)
    balls = res.compensated.placements[0].balls
    ub = np.array([b.u for b in balls])
    y = np.array([b.measured[1] for b in balls])
    move = np.zeros((len(balls), 3))
    move[:, 0] = -y * 2.0 * ARCSEC  # mm: E differs from y by a constant, which the rigid fit takes
    c = np.array([b.measured for b in balls])
    c -= c.mean(axis=0)
    rigid = []
    for k in range(3):
        t = np.zeros_like(c)
        t[:, k] = 1.0
        rigid += [t.ravel(), np.cross(np.eye(3)[k], c).ravel()]
    q, _ = np.linalg.qr(np.column_stack(rigid))
    left = move.ravel() - q @ (q.T @ move.ravel())
    expected = left.reshape(-1, 3) ** 2
    assert np.sqrt(expected.max()) > 1e-4  # mm: the term is large enough to be seen
    np.testing.assert_allclose(ub ** 2 - ua ** 2, expected, rtol=0, atol=0.02 * expected.max())
    assert any("parameter uncertainties" in n for n in res.provenance["notes"])
