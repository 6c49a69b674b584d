"""A noise floor at the defaults (issue 33, section 4): a machine file states
the machine's per-scan reproducibility, a command estimates it from runs that
repeat scans and writes it into a machine file, simulated runs and plans can
repeat scans, the joint diagnosis takes --reproducibility, and without any
floor the verdict says so first and the selection takes the spheres' fit
scatter as a conservative floor."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.diagnosis.floor import FIT_SCATTER, NO_FLOOR, fit_scatter_um, repeats_scans, reproducibility_from_runs
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.errors import InputError
from cmmpose.machine import Machine, example_text, load_machine, with_reproducibility
from cmmpose.sim import Scanner
from cmmpose.sim.runs import simulate_ballbar_run

JITTER = 3e-3  # mm per axis, the simulator's realistic per-scan reproducibility


def _run(repeat_scans=0, seed=4, layout="crossed"):
    return simulate_ballbar_run(temperature=22.5, jitter=JITTER, seed=seed, layout=layout, repeat_scans=repeat_scans,
                                scanner=Scanner(points_per_profile=128))[0]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two small crossed-layout runs (16 sweeps): one repeating 8 scans, one repeating none; saved."""
    folder = tmp_path_factory.mktemp("floor")
    rep, bare = _run(8, seed=4), _run(0, seed=5)
    rep.save(folder / "rep")
    bare.save(folder / "bare")
    (folder / "m.toml").write_text(example_text("thesis"), encoding="utf-8")
    return folder, rep, bare


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _machine_file(tmp_path, table: str):
    text = example_text("thesis").split("\n[reproducibility]")[0] + "\n" + table
    path = tmp_path / "m.toml"
    path.write_text(text, encoding="utf-8")
    return path


# -- 1. the machine file states it --------------------------------------------------


def test_the_thesis_machine_states_its_reproducibility_and_where_it_comes_from(machine):
    m = machine
    assert m.reproducibility_um == 3.0
    assert "REALISTIC_JITTER" in m.reproducibility_source and "appendix-c" in m.reproducibility_source
    assert m.reproducibility_um == cmmpose.sim.runs.REALISTIC_JITTER * 1e3  # the figure the demo simulates
    assert ("per-scan reproducibility", f"3 um per axis ({m.reproducibility_source})") in m.describe()
    # the other examples state none: a machine of the user's has not been measured
    assert Machine.example("gantry").reproducibility_um is None


@pytest.mark.parametrize("value, words", [
    ("-2.0", "expected a positive number of um, got -2.0"),
    ("0.0", "expected a positive number of um, got 0.0"),
    ("nan", "expected a positive number of um, got nan"),
    ("inf", "expected a positive number of um, got inf"),
    ("3000.0", "3000 um per axis is implausible"),
    ('"3"', "expected a positive number of um, got '3'"),
    ("true", "expected a positive number of um, got True"),
])
def test_a_bad_reproducibility_in_a_machine_file_is_refused_naming_file_and_key(tmp_path, value, words):
    path = _machine_file(tmp_path, f"[reproducibility]\nper_scan_um = {value}\n")
    with pytest.raises(InputError) as err:
        load_machine(path)
    assert str(err.value).startswith(f"{path}: reproducibility.per_scan_um: ") and words in str(err.value)
    res = _cli("machine", "check", path)
    assert res.exit_code == 1 and "reproducibility.per_scan_um" in res.output


def test_a_reproducibility_table_without_its_value_or_with_unknown_keys_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"m\.toml: reproducibility\.per_scan_um is missing"):
        load_machine(_machine_file(tmp_path, '[reproducibility]\nsource = "a repeat test"\n'))
    with pytest.raises(InputError, match=r"m\.toml: unknown key reproducibility\.per_scan_mm"):
        load_machine(_machine_file(tmp_path, "[reproducibility]\nper_scan_mm = 0.003\n"))
    with pytest.raises(InputError, match=r"m\.toml: reproducibility\.source must be a non-empty text"):
        load_machine(_machine_file(tmp_path, "[reproducibility]\nper_scan_um = 3\nsource = 4\n"))
    # the bound is the diagnosis's own (MAX_REPRODUCIBILITY_MM): 1000 um passes, more is a unit slip
    assert load_machine(_machine_file(tmp_path, "[reproducibility]\nper_scan_um = 1000\n")).reproducibility_um == 1000


def test_with_reproducibility_replaces_the_table_or_adds_it_and_reads_back():
    text = example_text("thesis")
    new = with_reproducibility(text, 2.5, 'a repeat test, "10 scans"')
    doc = tomllib.loads(new)
    assert doc["reproducibility"] == {"per_scan_um": 2.5, "source": 'a repeat test, "10 scans"'}
    # everything else, comments included, as it was
    assert new.split("[reproducibility]")[0] == text.split("[reproducibility]")[0]
    assert "# Measure yours" in new and new.count("per_scan_um =") == 1
    added = tomllib.loads(with_reproducibility(example_text("gantry"), 4.0, "x"))
    assert added["reproducibility"]["per_scan_um"] == 4.0
    assert {k: v for k, v in added.items() if k != "reproducibility"} == tomllib.loads(example_text("gantry"))
    with pytest.raises(InputError, match="reproducibility.per_scan_um: expected a positive number"):
        with_reproducibility(text, -1.0, "x")


# -- 2. runs that repeat scans, and the command that estimates it from them -------------


def test_repeated_scans_leave_the_earlier_sweeps_as_they_were_and_name_the_same_balls():
    bare, rep = _run(0), _run(5)
    n = bare.n_points
    for col in ("u", "v", "D", "E", "F", "t"):
        assert np.array_equal(rep.points[col][:n], bare.points[col]), col
    sc = rep.scans
    assert len(sc["scan_id"]) == 16 + 5 and rep.metadata["repeat_scans"] == 5
    # ball 1, 2 of position 1, then of position 2, ...: each the same ball at the same pose again
    assert sc["position"][16:].tolist() == [1, 1, 2, 2, 3] and sc["ball"][16:].tolist() == [1, 2, 1, 2, 1]
    assert sc["pose_id"][16:].tolist() == [sc["pose_id"][k] for k in range(5)]
    assert not repeats_scans(cmmpose.diagnosis.identify.Problem(cmmpose.Model(cmmpose.ErrorMapSet.thesis()),
                                                                bare, {})).any()
    for bad in (-1, 17, 2.0, True):
        with pytest.raises(InputError, match="repeat_scans: expected a whole number of sweeps from 0 to 16"):
            _run(bad)


def test_the_estimate_is_the_pooled_disagreement_of_repeated_centres(runs):
    _, rep, _ = runs
    est = reproducibility_from_runs([rep])
    # by hand: each repeated ball's two centres (thesis maps), less their mean; 1 dof per axis per pair
    xyz = cmmpose.Model(cmmpose.ErrorMapSet.thesis()).compensate(rep)
    fits = cmmpose.fit_spheres(xyz, rep.points["scan_id"])
    c = fits.centre[fits.positions(np.arange(8))]  # the first 8 sweeps, scanned again as sweeps 16..23
    r = fits.centre[fits.positions(np.arange(16, 24))]
    dev = (r - c) / 2  # each of the two scans is this far from their mean
    per_axis = np.sqrt(2 * np.sum(dev ** 2, axis=0) / 8) * 1e3
    np.testing.assert_allclose(est["per_axis_um"], per_axis[[0, 1, 2]], rtol=1e-9)
    assert est["per_scan_um"] == pytest.approx(math.sqrt(np.mean(per_axis ** 2)), rel=1e-12)
    assert est["dof"] == 24 and est["scans"] == 16 and est["spheres"] == 8
    assert est["u_um"] == pytest.approx(est["per_scan_um"] / math.sqrt(48), rel=1e-12)
    # 24 dof: the estimate is within 3 of its standard uncertainties of the simulated 3 um
    assert abs(est["per_scan_um"] - JITTER * 1e3) < 3 * JITTER * 1e3 / math.sqrt(48)


def test_runs_without_repeated_scans_are_refused_by_name(runs):
    _, rep, bare = runs
    with pytest.raises(InputError, match=r"runs: B repeats no scan of a sphere"):
        reproducibility_from_runs([rep, bare], run_names=["A", "B"])
    with pytest.raises(InputError, match="runs: none given"):
        reproducibility_from_runs([])


def test_the_command_writes_a_new_machine_file_and_never_an_input(runs, tmp_path):
    folder, rep, _ = runs
    machine = folder / "m.toml"
    before = machine.read_bytes()
    out = tmp_path / "new.toml"
    res = _cli("machine", "reproducibility", folder / "rep", "--machine", machine, "-o", out, "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    written = load_machine(out)
    assert written.reproducibility_um == pytest.approx(doc["per_scan_um"], rel=1e-3)  # written to 4 digits
    assert "Type A from 16 repeated scans of 8 spheres" in written.reproducibility_source
    assert machine.read_bytes() == before
    # the machine file as output, an existing output, a run without repeats: refused, naming them
    res = _cli("machine", "reproducibility", folder / "rep", "--machine", machine, "-o", machine, "--overwrite")
    assert res.exit_code == 1 and "an input is never overwritten" in res.output and machine.read_bytes() == before
    res = _cli("machine", "reproducibility", folder / "rep", "--machine", machine, "-o", out)
    assert res.exit_code == 1 and "exists" in res.output and "use --overwrite" in res.output
    res = _cli("machine", "reproducibility", folder / "rep", folder / "bare", "--machine", machine, "-o",
               tmp_path / "other.toml")
    assert res.exit_code == 1 and f"runs: {folder / 'bare'} repeats no scan" in res.output
    assert not (tmp_path / "other.toml").exists()


# -- 3. the diagnosis takes the floor it has ---------------------------------------


def _floor(*args):
    res = _cli("diagnose", *args, "--json", "--no-map-corrections", "--max-effects", "1")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    return doc["noise_floor"] if "noise_floor" in doc else {k: v["noise_floor"] for k, v in doc.items()}


def test_diagnose_takes_the_machine_files_floor_for_a_run_that_repeats_no_scan(runs, tmp_path):
    folder, _, _ = runs
    machine = _machine_file(tmp_path, "[reproducibility]\nper_scan_um = 2.5\n")
    stated = _floor(folder / "bare", "--machine", machine)
    assert stated["source"] == f"stated in the machine file {machine}" and stated["floor_stated_or_measured"]
    assert stated["centre_reproducibility_um"] == 2.5
    # crossed layout, one scan per ball: a length's floor is sqrt(2) x 2.5 um
    # ... with this run's own fit scatter beside the stated value, in quadrature
    (run,) = stated["runs"]
    assert run["floor_centre_um"] == pytest.approx(math.hypot(2.5, run["fit_scatter_um"]), rel=1e-12)
    assert 0 < run["fit_scatter_um"] < 2.5
    assert stated["floor_um"] == pytest.approx(run["floor_centre_um"] * math.sqrt(2), rel=1e-12)
    # --reproducibility wins, and says so
    given = _floor(folder / "bare", "--machine", machine, "--reproducibility", "1.5")
    assert given["source"] == "stated (--reproducibility)" and given["centre_reproducibility_um"] == 1.5
    # a run that repeats scans measures its own
    assert _floor(folder / "rep", "--machine", machine)["source"] == "repeated scans (Type A)"
    # without a machine file the default machine states nothing of a run it may not have measured
    bare = _floor(folder / "bare")
    assert bare["source"] == FIT_SCATTER and bare["verdict"].startswith(NO_FLOOR)
    # several runs (not joint): each its own
    fleet = _floor(folder / "bare", folder / "rep", "--machine", machine)
    assert [f["source"] for f in fleet.values()] == [f"stated in the machine file {machine}",
                                                     "repeated scans (Type A)"]


def test_the_joint_diagnosis_takes_one_reproducibility_or_one_per_run(runs):
    folder, _, _ = runs
    one = _floor(folder / "bare", folder / "rep", "--joint", "--reproducibility", "2")
    assert [r["source"] for r in one["runs"]] == ["stated (--reproducibility)", "repeated scans (Type A)"]
    assert one["runs"][0]["centre_reproducibility_um"] == 2.0
    each = _floor(folder / "bare", folder / "rep", "--joint", "--reproducibility", "2.5,4")
    assert each["runs"][0]["centre_reproducibility_um"] == 2.5  # the second measures its own
    res = _cli("diagnose", folder / "bare", folder / "rep", "--joint", "--reproducibility", "2,-1")
    assert res.exit_code == 1 and "--reproducibility: expected a positive number of um, got -1.0" in res.output
    res = _cli("diagnose", folder / "bare", "--reproducibility", "2,3")
    assert res.exit_code == 2 and "one value per run is for --joint" in res.output
    with pytest.raises(InputError, match=r"reproducibility_um: one value, or one per run \(2\), got 3"):
        diagnose_jointly([_run(0, seed=5), _run(8, seed=4)], reproducibility_um=[1, 2, 3])


# -- 4. without any floor ------------------------------------------------------------


def test_the_fit_scatter_is_the_sphere_fits_centre_sd(runs):
    _, _, bare = runs
    model = cmmpose.Model(cmmpose.ErrorMapSet.thesis())
    problem = cmmpose.diagnosis.identify.Problem(model, bare, {})
    fits = cmmpose.fit_spheres(model.compensate(bare), bare.points["scan_id"])
    var = np.array([np.mean(np.diag(fits[k].covariance)[:3]) for k in range(16)])
    assert fit_scatter_um(problem)[0] == pytest.approx(math.sqrt(np.mean(var)) * 1e3, rel=1e-9)
    # 8 um scanner noise over ~1,500 points: a fraction of a micrometre, far below the simulated 3 um
    assert 0.05 < fit_scatter_um(problem)[0] < 1.0


def test_without_a_floor_the_verdict_says_so_first_and_never_says_missing_nothing(runs):
    from cmmpose.diagnosis.html_report import _verdict

    _, _, bare = runs
    d = cmmpose.diagnose(bare, patterns=False, map_corrections=False, max_effects=1)
    noise = d.noise
    assert noise["verdict"].startswith(NO_FLOOR) and noise["source"] == FIT_SCATTER
    assert not noise["floor_stated_or_measured"] and noise["floor_um"] > 0 and noise["p_value"] is not None
    text = _verdict(d, None, None)
    assert text.startswith("Noise floor: " + NO_FLOOR) and "missing nothing" not in text
    # 3 um of per-scan movement is far above the fit scatter: said, not called noise
    assert not noise["noise"] and "cannot tell apart" in noise["verdict"]
    # with a stated floor that the residuals reach, and nothing added, "missing nothing" may be said
    stated = cmmpose.diagnose(bare, patterns=False, map_corrections=False, max_effects=1,
                              reproducibility_um=JITTER * 1e3)
    assert stated.added == [] and stated.noise["noise"] and stated.noise["floor_stated_or_measured"]
    assert _verdict(stated, None, None).startswith("The model was missing nothing the run can show")


def test_the_selection_floors_the_headline_noise_at_the_fit_scatter(runs):
    from cmmpose.diagnosis.diagnose import state_floor

    _, _, bare = runs
    model = cmmpose.Model(cmmpose.ErrorMapSet.thesis())
    problem = cmmpose.diagnosis.identify.Problem(model, bare, {})
    before = problem.class_floor[0]
    state_floor(problem)
    # one scan per ball: a length's floor is sqrt(1 + 1) times the per-scan centre scatter
    assert problem.class_floor[0] == pytest.approx(math.sqrt(2) * fit_scatter_um(problem)[0] * 1e-3, rel=1e-12)
    assert problem.class_floor[0] > before


def test_a_type_a_floor_is_tested_with_its_own_degrees_of_freedom(runs):
    from scipy.special import fdtrc

    _, rep, _ = runs
    d = cmmpose.diagnose(rep, patterns=False, map_corrections=False, max_effects=1)
    n = d.noise
    assert n["source"] == "repeated scans (Type A)" and n["floor_stated_or_measured"]
    # 8 balls scanned twice: 8 x 3 = 24 dof of centre disagreement
    assert n["p_value"] == pytest.approx(float(fdtrc(n["dof"], 24, n["chi2"] / n["dof"])), rel=1e-12)
    assert f"on {n['dof']} and 24 dof" in n["verdict"]


# -- 5. the commands that make runs and plans ----------------------------------------


def test_simulate_and_the_artefact_plan_repeat_scans_on_request(tmp_path):
    res = _cli("simulate", "--layout", "crossed", "--repeat-scans", "4", "-o", tmp_path / "r", "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["sweeps"] == 20 and doc["repeat_scans"] == 4
    res = _cli("simulate", "--layout", "crossed", "--repeat-scans", "17", "-o", tmp_path / "s")
    assert res.exit_code == 1 and "--repeat-scans: expected a whole number of sweeps from 0 to 16" in res.output
    from cmmpose.acquire.plan import artefact_plan

    plain, repeated = artefact_plan("koba-0320", ["xy"]), artefact_plan("koba-0320", ["xy"], repeat_scans=3)
    assert len(repeated.scans) == len(plain.scans) + 3
    key = ("pose_id", "position", "ball", "sweep_axis", "sweep_start_mm")
    assert [[s[k] for k in key] for s in repeated.scans[-3:]] == [[s[k] for k in key] for s in plain.scans[:3]]
    assert [s["scan_id"] for s in repeated.scans] == list(range(len(repeated.scans)))
    res = _cli("artefact", "plan", "koba-0320", "--placement", "xy", "--repeat-scans", "2", "-o", tmp_path / "p.json")
    assert res.exit_code == 0, res.output
    assert len(json.loads((tmp_path / "p.json").read_text())["scans"]) == len(plain.scans) + 2
