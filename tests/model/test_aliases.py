"""Issue 25, sections 5 and 6: a saved model is honest about what its run
could not decide.

- Aliased choices stay aliased: the model keeps the effects the data could
  not tell from the one chosen (fitted in its place), and applying it where
  they predict differently warns (``AliasedChoiceWarning`` and a log line).
- Components the run cannot determine (an XY-plane run's squareness yz and
  zx) are saved as undetermined (inf, written null in strict JSON and named
  in ``non_finite``), and the evaluated budgets say so.
- ``cmmpose evaluate RUN... --model`` takes several runs."""

from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import replace

import cmmpose
import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose import Model
from cmmpose.model.alternatives import ALIAS_FLOOR_UM, Alternative, check_alternatives, points_difference_um
from cmmpose.model.names import resolve
from cmmpose.diagnosis.covariance import design_variances
from cmmpose.errors import AliasedChoiceWarning
from cmmpose.evaluation.ballbar import machine_coordinates
from cmmpose.evaluation.observables import figures_difference
from cmmpose.evaluation.ballbar_uncertainty import evaluation_uncertainty
from cmmpose.run import Run
from cmmpose.sim import parse_effect, simulate_ballbar_run

from tests.diagnosis.test_sensor_choice import simulate  # one warm axis: the sensor choice the run cannot make

MAPS = cmmpose.ErrorMapSet.thesis()
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)
#: B89 positions whose bars lie in the horizontal plane z ~ -614 mm (layouts.b89_positions).
XY_POSITIONS = (1, 2, 11, 12, 13, 14, 15, 16, 17, 18)


def _strict(text: str):
    """JSON that must hold no NaN or Infinity."""
    def refuse(token):
        raise AssertionError(f"not standard JSON: {token}")

    return json.loads(text, parse_constant=refuse)


# -- the numbers: variances of a badly scaled design -------------------------


def test_variances_of_a_badly_scaled_design_match_a_qr_reference():
    """Columns in mm and in typical magnitudes differ by 1e5: a pseudo-inverse of R^T R (condition squared)
    drops the weak directions and reads their variance near zero; the SVD of the normalised R does not."""
    rng = np.random.default_rng(3)
    R = rng.normal(size=(40, 5)) * np.array([2e4, 4e3, 8.0, 0.1, 0.08])
    R[:, 4] += 0.9 * R[:, 3] / 0.1 * 0.08  # correlated weak columns
    q, r = np.linalg.qr(R)
    ri = np.linalg.solve(r, np.eye(5))
    reference = np.sum(ri ** 2, axis=1)  # diag((R^T R)^-1) = row sums of R'^-1 squared
    var, free = design_variances(R)
    np.testing.assert_allclose(var, reference, rtol=1e-8)
    assert not free.any()
    old = np.diag(np.linalg.pinv(R.T @ R, rcond=1e-10))
    assert old[3] < 0.01 * reference[3]  # the old way: the weak direction lost (so the test can fail)
    # An exact alias (a repeated column) and an empty column are free: inf, the others unchanged in kind.
    R2 = np.column_stack([R[:, :3], R[:, 2], np.zeros(40)])
    var2, free2 = design_variances(R2)
    assert free2.tolist() == [False, False, True, True, True]


# -- undetermined components of an XY-plane run ------------------------------


def _xy_only(run: Run) -> Run:
    ks = np.isin(run.scans["position"], XY_POSITIONS)
    kp = np.isin(run.points["scan_id"], run.scans["scan_id"][ks])
    return Run({k: v[kp] for k, v in run.points.items()}, {k: v[ks] for k, v in run.scans.items()}, dict(run.poses),
               run.temperatures, run.temperature_channels, run.artefact, run.maps, run.metadata, run.created)


@pytest.fixture(scope="module")
def xy_model(tmp_path_factory):
    hidden = [parse_effect("squareness:xy=8")]
    run, _ = simulate_ballbar_run(MAPS, 22.0, hidden, seed=1, jitter=0.001)
    xy = _xy_only(run)
    assert np.ptp(machine_coordinates(xy, None, None)[:, 2]) < 60  # one plane (mm)
    d = cmmpose.diagnose(xy, MAPS, patterns=False, add=["squareness"], max_effects=0)
    path = d.model.save(tmp_path_factory.mktemp("xy") / "m.json")
    full, _ = simulate_ballbar_run(MAPS, 22.0, hidden, seed=2, jitter=0.001)
    return d, path, full


def test_an_xy_run_saves_squareness_yz_zx_as_undetermined(xy_model):
    d, path, _ = xy_model
    u = d.final_uncertainty["squareness"]
    assert 0 < u[0] < 2.0  # xy: determined, arc-seconds
    assert np.isinf(u[1]) and np.isinf(u[2])  # yz, zx: no number would be honest
    text = path.read_text()
    doc = _strict(text)  # standard JSON
    sq = next(e for e in doc["effects"] if e["name"] == "squareness")
    assert sq["uncertainty"]["xy"] == pytest.approx(u[0])
    assert sq["uncertainty"]["yz"] is None and sq["uncertainty"]["zx"] is None
    named = {f["key"]: f["value"] for f in doc["non_finite"]}  # as cmmpose._json states an infinity
    assert named == {"effects[0].uncertainty.yz": "inf", "effects[0].uncertainty.zx": "inf"}
    back = Model.load(path)
    np.testing.assert_array_equal(np.isinf(back.uncertainty["squareness"]), [False, True, True])
    assert back.uncertainty["squareness"][0] == pytest.approx(u[0])


@pytest.mark.slow
def test_the_budget_says_undetermined_not_a_tiny_number(xy_model):
    _, path, full = xy_model
    model = Model.load(path)
    ev = cmmpose.evaluate(full, model)
    unc = evaluation_uncertainty(full, ev, model)
    rows = {i.name: i for i in unc["compensated"].budgets["rms accuracy error"].inputs}
    assert "model squareness: xy" in rows
    assert "model squareness: yz" not in rows and "model squareness: zx" not in rows
    said = [s for s in unc.left_out if "undetermined" in s]
    assert said and "squareness.yz" in said[0] and "squareness.zx" in said[0]


# -- aliased choices ------------------------------------------------------------


@pytest.fixture(scope="module")
def sensor_model(tmp_path_factory):
    """One warm axis (z, +3 K): every thermocouple role departs from the mean in proportion, so the squareness
    change the run shows could follow any of them (tests/diagnosis/test_sensor_choice.py)."""
    run = simulate("z_scale", 26.0, 2, 3)
    d = cmmpose.diagnose(run, max_effects=3, patterns=False)
    path = d.model.save(tmp_path_factory.mktemp("sensor") / "m.json")
    other = simulate("z_scale", 24.0, 0, 2)  # the x axis warm instead: the roles now move differently
    return d, path, run, other


@pytest.mark.slow
def test_aliased_sensor_choice_is_saved_with_its_alternatives(sensor_model):
    d, path, _, _ = sensor_model
    chosen = [n for n in d.model.names if n.startswith("squareness-temperature@") or n == "squareness"]
    assert len(chosen) == 1
    doc = _strict(path.read_text())
    alts = [a for a in doc["alternatives"] if a["chosen"] == chosen[0]]
    names = {a["name"] for a in alts}
    group = next(g for g in d.ambiguous if chosen[0] in g)
    assert names == set(group) - {chosen[0]}  # every effect the run could not tell from it
    for a in alts:
        assert set(a["params"]) == set(a["units"]) and all(math.isfinite(v) for v in a["params"].values())
        assert a["warn_above_um"] == pytest.approx(max(ALIAS_FLOOR_UM, 2 * a["in_sample_difference_um"]))
    # On its own run, the alternatives fitted in the chosen one's place predict the lengths alike.
    assert all(a["in_sample_difference_um"] < 2 * ALIAS_FLOOR_UM for a in alts if a["name"] != "squareness")
    assert {a["name"] for a in _strict(d.to_json())["alternatives"]} == names  # the diagnosis's JSON says it too
    back = Model.load(path)
    assert {(a.chosen, a.name) for a in back.alternatives} == {(a["chosen"], a["name"]) for a in alts}
    for a in back.alternatives:
        want = next(x for x in alts if x["name"] == a.name)
        np.testing.assert_allclose(a.values, [want["params"][p] for p in a.spec.params], rtol=0, atol=0)


@pytest.mark.slow
def test_applying_an_aliased_choice_warns_where_the_alternatives_differ(sensor_model, caplog):
    _, path, run, other = sensor_model
    model = Model.load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", AliasedChoiceWarning)  # its own run: the alternatives agree, no warning
        cmmpose.evaluate(run, model)
    with caplog.at_level(logging.WARNING, logger="cmmpose.model.alternatives"), \
            pytest.warns(AliasedChoiceWarning, match="aliased choice") as caught:
        cmmpose.evaluate(other, model)
    text = str(next(w.message for w in caught if issubclass(w.category, AliasedChoiceWarning)))
    assert model.names[-1] in text or any(n in text for n in model.names)
    assert any("aliased choice" in r.getMessage() for r in caplog.records)
    # The comparison it warned on, by an independent route: each alternative in the choice's place.
    found = check_alternatives(model, model.inputs(other), "run", compare=figures_difference(other))
    big = [f for f in found if f["warned"]]
    assert big and all(f["difference_um"] > f["threshold_um"] for f in big)
    # The command line prints it, once per message, and still evaluates.
    from cmmpose.cli import main

    other.save(path.parent / "other")
    run.save(path.parent / "own")
    res = CliRunner().invoke(main, ["evaluate", str(path.parent / "own"), str(path.parent / "other"),
                                    "--model", str(path), "--json"])
    assert res.exit_code == 0, res.output
    assert "warning: other: run: the model's" in res.output and "warning: own:" not in res.output
    docs = _strict(res.output[res.output.index("\n[") + 1:])
    assert [sum("aliased choice" in w for w in d["warnings"]) for d in docs] == [0, 1]


def test_points_warn_only_beyond_a_rigid_motion(tmp_path):
    """On points, the alternatives are compared less the best rigid motion of the whole set: an alternative equal
    to the choice never warns; one that changes the scale does, by the amount a NumPy reference gives."""
    rng = np.random.default_rng(5)
    n = 3000
    uv = np.column_stack([rng.uniform(-25, 25, n), rng.uniform(115, 165, n)])
    scales = np.column_stack([rng.uniform(10, 890, n), rng.uniform(10, 540, n), rng.uniform(-490, -10, n)])
    temps = np.full(n, 22.0)
    base = Model(MAPS).with_values("squareness", [4.0, 0.0, 0.0])
    spec = base.effects[0][0]
    scale = Alternative("squareness", resolve("scale"), np.zeros(3), 0.1, "test")
    model = replace(base, alternatives=(scale,))
    assert Model.load(model.save(tmp_path / "m.json")).alternatives[0].name == "scale"
    with warnings.catch_warnings():
        warnings.simplefilter("error", AliasedChoiceWarning)
        # scale zero in place of squareness 4": a shear of E over 540 mm: 10 um, far above the floor -> warns
        with pytest.raises(AliasedChoiceWarning, match="differently"):
            cmmpose.compensate(uv, scales, model, POSE, OFFSET, temps)
    a = cmmpose.compensate(uv, scales, base, POSE, OFFSET, temps)
    b = cmmpose.compensate(uv, scales, Model(MAPS), POSE, OFFSET, temps)
    d = a - b
    # Reference: the shear d_x = -E * 4" less its best rigid motion, by a 6-column least squares.
    c = b - b.mean(axis=0)
    cols = []
    for k in range(3):
        t = np.zeros_like(c)
        t[:, k] = 1.0
        cols += [t.ravel(), np.cross(np.eye(3)[k], c).ravel()]
    A = np.column_stack(cols)
    left = d.ravel() - A @ np.linalg.lstsq(A, d.ravel(), rcond=None)[0]
    want = np.sqrt(np.max(np.sum(left.reshape(-1, 3) ** 2, axis=1))) * 1e3
    assert points_difference_um(a, b) == pytest.approx(want, rel=1e-6)
    assert want > ALIAS_FLOOR_UM
    # A rigid motion alone never counts.
    th = 1e-5
    rot = np.array([[1, -th, 0], [th, 1, 0], [0, 0, 1]])
    assert points_difference_um(b @ rot.T + 0.01, b) < 1e-3  # um: second order in the angle
    assert spec.name == "squareness"


def test_old_model_files_load_without_alternatives(tmp_path):
    model = Model(MAPS).with_values("squareness", [7.0, -4.0, 3.0])
    path = model.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert "alternatives" not in doc and "non_finite" not in doc  # nothing undetermined, nothing aliased
    back = Model.load(path)
    assert back == model and back.alternatives == ()
    # An alternative to an effect the model does not hold is refused, naming it.
    doc["alternatives"] = [{"chosen": "scale", "name": "squareness", "params": {"xy": 0, "yz": 0, "zx": 0}}]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(cmmpose.InputError, match=r"alternatives\[0\].*'scale'"):
        Model.load(tmp_path / "bad.json")


# -- cmmpose evaluate RUN... --model ------------------------------------------------


def test_evaluate_several_runs_with_a_model(tmp_path):
    hidden = [parse_effect("squareness:xy=6")]
    runs = [simulate_ballbar_run(MAPS, t, hidden, layout="crossed", seed=s, jitter=0.001)[0]
            for t, s in ((21.0, 1), (24.0, 2))]
    model = Model(MAPS).with_values("squareness", [6.0, 0.0, 0.0])
    path = model.save(tmp_path / "m.json")
    dirs = []
    for i, r in enumerate(runs):
        dirs.append(str(tmp_path / f"run{i}"))
        r.save(dirs[-1])
    from cmmpose.cli import main

    res = CliRunner().invoke(main, ["evaluate", *dirs, "--model", str(path), "--json", "--report",
                                    str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    docs = _strict(res.output[res.output.index("["):res.output.rindex("]") + 1])
    assert [d["run"] for d in docs] == dirs
    for d, r in zip(docs, runs):
        want = cmmpose.evaluate(r, model).compensated.rms_accuracy_error
        got = next(x for x in d["results"] if x["label"] == "compensated")["rms_accuracy_error_mm"]
        assert got == pytest.approx(want, abs=1e-5)  # mm: the JSON keeps 0.01 um
        assert d["uncertainty"]["results"]
    assert (tmp_path / "rep" / "run0" / "uncertainty.json").exists() and (tmp_path / "rep" / "run1").is_dir()
    res = CliRunner().invoke(main, ["evaluate", *dirs, "--model", str(path), "--scheduler", "threads"])
    assert res.exit_code == 2 and "--scheduler is for maps" in res.output


def test_compensate_command_prints_the_aliased_choice_once(tmp_path):
    """A point file compensated in chunks with a model whose alternative differs there: one warning, printed by
    the command (not also as a raw log line), and the points written."""
    from cmmpose.filecompensation import compensate_file

    rng = np.random.default_rng(7)
    n = 2500
    cols = {"u": rng.uniform(-25, 25, n), "v": rng.uniform(115, 165, n), "D": rng.uniform(10, 890, n),
            "E": rng.uniform(10, 540, n), "F": rng.uniform(-490, -10, n), "T": np.full(n, 22.0)}
    src = tmp_path / "in.csv"
    np.savetxt(src, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="",
               fmt="%.17g")
    base = Model(MAPS).with_values("squareness", [4.0, 0.0, 0.0])
    model = replace(base, alternatives=(Alternative("squareness", resolve("scale"), np.zeros(3), 0.1, "test"),))
    path = model.save(tmp_path / "m.json")
    with pytest.warns(AliasedChoiceWarning) as caught:
        compensate_file(src, tmp_path / "api.csv", Model.load(path), POSE, OFFSET, chunk=600)
    assert len([w for w in caught if issubclass(w.category, AliasedChoiceWarning)]) == 1  # once per file
    from cmmpose.cli import main

    res = CliRunner().invoke(main, ["compensate", str(src), str(tmp_path / "out.csv"), "--model", str(path),
                                    "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"])
    assert res.exit_code == 0, res.output
    assert res.output.count("aliased choice") == 1 and "warning:" in res.output
    assert (tmp_path / "out.csv").exists()


def test_an_artefact_evaluation_notes_undetermined_parameters():
    from cmmpose import artefacts
    from cmmpose.evaluation.artefact import evaluate_artefact
    from cmmpose.sim.artefact_runs import simulate_artefact_run

    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0420"), ["xy@z=-450,rot=30"], MAPS, 20.5, [], seed=1)
    model = replace(Model(MAPS).with_values("squareness", [1.0, 0.0, 0.0]),
                    uncertainty={"squareness": np.array([0.5, np.inf, np.inf])})
    notes = evaluate_artefact(run, model).provenance["notes"]
    said = [n for n in notes if "undetermined" in n]
    assert said and "squareness.yz, squareness.zx" in said[0]
    assert any("include the model's 1 parameter" in n for n in notes)  # xy alone enters the u
