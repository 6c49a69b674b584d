"""Artefact files, placements, artefact runs and their evaluation (issue 24;
docs/artefacts.md): the registry, the bundled examples, bad input, the CLI."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

from cmmpose import artefacts, placement
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.evaluation.artefact_balls import is_artefact_run, rigid_fit
from cmmpose.cli import main
from cmmpose.errormap import ErrorMap
from cmmpose.errors import InputError
from cmmpose.evaluation.ballbar import evaluate
from cmmpose.run import Run
from cmmpose.sim import Scanner, simulate_ballbar_run
from cmmpose.sim.artefact_runs import simulate_artefact_run

PLATE = """
kind = "ball-plate"
name = "test plate"
certificate = "test"
reference_temperature_C = 20.0
expansion_ppm_per_K = 11.5
balls = [
  { id = 1, xyz_mm = [0.0, 0.0, 0.0], u_um = [0.4, 0.4, 0.6] },
  { id = 2, xyz_mm = [100.0, 0.0, 0.0], u_um = [0.4, 0.4, 0.6] },
  { id = 3, xyz_mm = [0.0, 100.0, 0.0], u_um = [0.4, 0.4, 0.6] },
  { id = 4, xyz_mm = [100.0, 100.0, 0.0], u_um = [0.4, 0.4, 0.6] },
]

[radius]
nominal_mm = 11.0
calibrated_mm = 11.0
u_um = 0.2
"""


def write(tmp_path, text, name="a.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


# -- the registry and the bundled examples ---------------------------------------------

def test_registry_has_the_four_kinds_each_with_an_example():
    kinds = artefacts.available()
    assert set(kinds) == {"ballbar", "ball-plate", "step-gauge", "sphere"}
    for kind, cls in kinds.items():
        a = artefacts.load_artefact(cls.example)
        assert a.kind == kind


@pytest.mark.parametrize("name, kind, n, pitch", [
    ("koba-0620", "ball-plate", 25, 133.0), ("koba-0420", "ball-plate", 25, 83.0),
    ("koba-0320", "ball-plate", 25, 60.0), ("apmp-plate", "ball-plate", 64, 50.0),
    ("step-gauge-31x20", "step-gauge", 31, 20.0), ("thesis-ballbar", "ballbar", 2, 404.2357)])
def test_bundled_examples_have_their_nominal_geometry(name, kind, n, pitch):
    a = artefacts.load_artefact(name)
    assert (a.kind, a.n_balls) == (kind, n)
    gaps = np.linalg.norm(a.centres[:, None] - a.centres[None], axis=2)
    assert np.min(gaps[gaps > 0]) == pytest.approx(pitch, abs=0.005)
    assert np.all(a.u_centres > 0)


def test_embedded_definition_round_trips():
    a = artefacts.load_artefact("apmp-plate")
    b = artefacts.from_dict(json.loads(json.dumps(a.to_dict())))
    np.testing.assert_array_equal(a.centres, b.centres)
    np.testing.assert_array_equal(a.u_centres, b.u_centres)
    assert (a.expansion, a.calibrated_radius, a.u_radius) == (b.expansion, b.calibrated_radius, b.u_radius)


# -- bad artefact files ----------------------------------------------------------------

@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("id = 2,", "id = 1,"), "ball 1 is repeated"),
    (lambda t: t.replace("[100.0, 100.0, 0.0]", "[0.0, 100.0, 0.0]"), "balls[2] (ball 3) and balls[3] (ball 4)"),
    (lambda t: t.replace("xyz_mm = [100.0, 0.0, 0.0], u_um = [0.4, 0.4, 0.6]", "xyz_mm = [100.0, 0.0, 0.0]"),
     "balls[1].u_um: missing"),
    (lambda t: t.replace("expansion_ppm_per_K = 11.5", "expansion_ppm_per_K = 500.0"), "expansion_ppm_per_K = 500 is not physical"),
    (lambda t: t.replace("expansion_ppm_per_K = 11.5", "expansion_ppm_per_K = -40.0"), "is not physical"),
    (lambda t: t.replace("expansion_ppm_per_K = 11.5", 'expansion_ppm_per_K = "11.5"'), "expansion_ppm_per_K: expected a number"),
    (lambda t: t.replace("expansion_ppm_per_K = 11.5\n", ""), "expansion_ppm_per_K: missing"),
    (lambda t: t.replace('name = "test plate"', 'name = "test plate"\ncolour = "red"'), "unknown key colour"),
    (lambda t: t.replace("{ id = 4,", "{ mass = 1, id = 4,"), "unknown key balls[3].mass"),
    (lambda t: t.replace("u_um = 0.2", "u_um = 0.2\nsize = 3"), "unknown key radius.size"),
    (lambda t: t.replace('kind = "ball-plate"', 'kind = "gauge-block"'), "kind = 'gauge-block' is not one of"),
    (lambda t: t.replace("u_um = [0.4, 0.4, 0.6] },\n  { id = 3", "u_um = [0.4, -0.4, 0.6] },\n  { id = 3"), "must be >= 0 um"),
    (lambda t: t.replace("calibrated_mm = 11.0", "calibrated_mm = 22.0"), "a diameter given as a radius"),
    (lambda t: t.replace("[100.0, 100.0, 0.0]", "[100.0, 100.0, 80.0]"), "off the plane of the others"),
    (lambda t: t.replace("[0.0, 100.0, 0.0]", "[200.0, 0.0, 0.0]").replace("[100.0, 100.0, 0.0]", "[300.0, 0.0, 0.0]"),
     "the balls are in a row"),
    (lambda t: t.replace("id = 3,", "id = 0,"), "balls[2].id: expected a whole number >= 1"),
])
def test_bad_artefact_files_name_the_file_and_key(tmp_path, edit, message):
    assert artefacts.load_artefact(write(tmp_path, PLATE)).n_balls == 4  # the unedited file is good
    path = write(tmp_path, edit(PLATE), "bad.toml")
    with pytest.raises(InputError, match="bad.toml") as err:
        artefacts.load_artefact(path)
    assert message in str(err.value)


def test_step_gauge_balls_must_be_in_a_row(tmp_path):
    text = artefacts.example_text("step-gauge").replace("{ id = 5, xyz_mm = [80.0", "{ id = 5, xyz_mm = [80.0")
    doc = tomllib.loads(text)
    doc["balls"][4]["xyz_mm"][1] = 30.0
    with pytest.raises(InputError, match=r"balls\[4\] \(ball 5\) is 2\d\.\d+ mm off the line"):
        artefacts.parse_artefact(doc, "sg.toml")


def test_not_toml_and_missing_file(tmp_path):
    with pytest.raises(InputError, match="not a TOML file"):
        artefacts.load_artefact(write(tmp_path, "kind = [", "x.toml"))
    with pytest.raises(InputError, match="no such artefact file"):
        artefacts.load_artefact(tmp_path / "none.toml")


# -- placements ------------------------------------------------------------------------

def test_placement_shorthand():
    (p,) = placement.parse("xz@y=600,rot=90,z=-200")
    # xz: artefact x along X, y along Z, +z along -Y; turned 90 degrees: artefact x along Z
    np.testing.assert_allclose(p.rotation @ [1, 0, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(p.rotation @ [0, 0, 1], [0, -1, 0], atol=1e-12)
    assert np.isnan(p.centre[0]) and p.centre[1] == 600 and p.centre[2] == -200
    assert len(placement.parse("planes")) == 3
    iso = placement.parse("iso10360-2", ((0, 900), (0, 550), (-500, 0)))
    assert len(iso) == 7
    for p in iso:
        np.testing.assert_allclose(p.rotation.T @ p.rotation, np.eye(3), atol=1e-12)
        assert np.linalg.det(p.rotation) == pytest.approx(1.0)


@pytest.mark.parametrize("text, message", [
    ("", "empty"), ("ab@z=1", "'ab' is not a plane"), ("xy@", "nothing after '@'"), ("xy@q=3", "'q=3' is not"),
    ("xy@z=1,z=2", "z is given twice"), ("xy@z=abc", "z='abc' is not a number of mm"),
    ("xy@rot=nan", "rot='nan' is not a number of degrees"), ("xy@z", "'z' is not")])
def test_bad_placements(text, message):
    with pytest.raises(InputError, match="placement") as err:
        placement.parse(text)
    assert message in str(err.value)


def test_a_placement_out_of_travel_names_the_ball_and_axis(machine):
    a = artefacts.load_artefact("koba-0420")
    with pytest.raises(InputError, match=r"placement 1 \(xy@x=1000,z=-525\): ball 5 .* X \d+\.\d\.\.\d+\.\d mm .*"
                                         r"X travel 0\.\.900 mm"):
        placement.plan(placement.parse("xy@x=1000,z=-525"), a, machine)
    # at x = 800 the far balls are reached with other poses (W along -X, ...) rather than W along +X
    _, scans = placement.plan(placement.parse("xy@x=800,z=-525"), a, machine)
    assert (90.0, 90.0, 0.0) in {s.pose for s in scans} and (-90.0, 90.0, 0.0) in {s.pose for s in scans}
    # the KOBA 0620 does not fit the 500 mm Z travel standing up
    with pytest.raises(InputError, match=r"ball \d+ .* Z travel -500\.\.0 mm.*span 532 mm of Z .* more than the "
                                         r"500 mm travel: it cannot stand so"):
        placement.plan(placement.parse("xz"), artefacts.load_artefact("koba-0620"), machine)


def test_the_planes_layout_refuses_a_plate_too_big_naming_the_planes_that_fit(machine):
    with pytest.raises(InputError, match=r"layout 'planes': KOBA 0620 .* cannot stand in the XZ plane .* it fits in "
                                         r"XY: .* --placement xy --placement xy@rot=90 .*ball \d+"):
        placement.plan(placement.parse("planes"), artefacts.load_artefact("koba-0620"), machine)
    resolved, scans = placement.plan(placement.parse("planes"), artefacts.load_artefact("koba-0420"), machine)
    assert [p.label for p in resolved] == ["planes/xy", "planes/xz", "planes/yz"] and len(scans) == 75


@pytest.mark.parametrize("name, fits", [("koba-0620", "xy"), ("koba-0420", "xy xz yz"), ("koba-0320", "xy xz yz"),
                                        ("apmp-plate", "xy xz yz"), ("step-gauge-31x20", "xy xz")])
def test_which_placements_fit_as_the_docs_say(name, fits, machine):
    """docs/artefacts.md, 'Which placements fit' (the thesis machine's 900 x 550 x 500 mm travel)."""
    a, m = artefacts.load_artefact(name), machine
    got = []
    for plane in placement.PLANES:
        try:
            placement.plan(placement.parse(plane), a, m)
            got.append(plane)
        except InputError as exc:
            assert "cannot stand so on this machine" in str(exc)  # too big, not merely badly centred
    assert " ".join(got) == fits


def test_rigid_fit_recovers_a_transform():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(6, 3)) * 100
    (p,) = placement.parse("xz@rot=30,x=1,y=2,z=3")
    r, t = rigid_fit(src, src @ p.rotation.T + [1, 2, 3])
    np.testing.assert_allclose(r, p.rotation, atol=1e-12)
    np.testing.assert_allclose(t, [1, 2, 3], atol=1e-9)


# -- runs and evaluation ---------------------------------------------------------------

@pytest.fixture(scope="module")
def plate_run():
    return simulate_artefact_run(artefacts.load_artefact("koba-0320"), ["xy@z=-525", "xy@z=-525,rot=90"],
                                 ErrorMap.zero(temperature=20.0), 20.0, scanner=Scanner(noise=0.0), seed=2)


def test_artefact_run_records_artefact_placements_and_balls(plate_run, tmp_path):
    run, truth = plate_run
    assert is_artefact_run(run) and run.artefact["kind"] == "ball-plate"
    assert len(run.artefact["placements"]) == 2
    assert sorted(set(run.scans["position"].tolist())) == [1, 2]
    assert sorted(run.scans["ball"][run.scans["position"] == 2].tolist()) == list(range(1, 26))
    run.save(tmp_path / "r", truth=truth)
    back = Run.load(tmp_path / "r")
    assert back == run
    assert artefacts.from_dict(back.artefact["definition"]).n_balls == 25


def test_perfect_machine_gives_the_certificate(plate_run):
    run, _ = plate_run
    ev = evaluate_artefact(run, None, 20.0)
    assert ev.uncompensated.rms < 1e-6  # mm: < 0.001 um on an error-free machine without noise
    for p in ev.uncompensated.placements:
        assert len(p.lengths) == 25 * 24 // 2
        assert max(abs(e.error) for e in p.lengths) < 2e-6
        for b in p.balls:  # the certificate's u (0.4, 0.4, 0.6 um) less what the rigid fit takes
            assert np.all(b.u > 0.25e-3) and np.all(b.u < 0.61e-3)


def test_ballbar_evaluation_refuses_a_plate_run(plate_run):
    with pytest.raises(InputError, match="measured a 'ball-plate', not a ballbar"):
        evaluate(plate_run[0], None, 20.0)


def _relabel(run, scan, **values):
    scans = {k: np.array(v).copy() for k, v in run.scans.items()}
    for key, value in values.items():
        scans[key][scans["scan_id"] == scan] = value
    return Run(points=run.points, scans=scans, poses=run.poses, temperatures=run.temperatures,
               temperature_channels=run.temperature_channels, artefact=run.artefact, maps=run.maps,
               metadata=run.metadata)


def test_a_ball_the_artefact_lacks_is_an_error(plate_run):
    with pytest.raises(InputError, match=r"has no ball 99 \(balls 1-25\)"):
        evaluate_artefact(_relabel(plate_run[0], 3, ball=99), None, 20.0)


def test_a_ball_measured_twice_under_two_labels_is_an_error(plate_run):
    run, _ = plate_run
    # scan 3 measured ball 4; its points again as scan 999 labelled ball 5 (ball 5's own scan 4 left out)
    keep = run.scans["scan_id"] != 4
    scans = {k: np.asarray(v)[keep] for k, v in run.scans.items()}
    row = int(np.flatnonzero(scans["scan_id"] == 3)[0])
    scans = {k: np.append(v, v[row]) for k, v in scans.items()}
    scans["scan_id"][-1], scans["ball"][-1] = 999, 5
    pk = run.points["scan_id"] != 4
    copy = run.points["scan_id"] == 3
    points = {k: np.concatenate([np.asarray(v)[pk], np.asarray(v)[copy]]) for k, v in run.points.items()}
    points["scan_id"][-int(copy.sum()):] = 999
    twice = Run(points=points, scans=scans, poses=run.poses, temperatures=run.temperatures,
                temperature_channels=run.temperature_channels, artefact=run.artefact, metadata=run.metadata)
    with pytest.raises(InputError, match=r"scan 3 \(ball 4\) and scan 999 \(ball 5\) of position 1 measured the "
                                         r"same ball"):
        evaluate_artefact(twice, None, 20.0)


def test_one_label_on_two_balls_is_an_error(plate_run):
    # scan 4 (ball 5) relabelled ball 4: "ball 4" measured at two places 60 mm apart
    with pytest.raises(InputError, match=r"scans 3 and 4 are both labelled ball 4 of position 1 but lie 60\.0\d* mm "
                                         r"apart"):
        evaluate_artefact(_relabel(plate_run[0], 4, ball=4), None, 20.0)


def test_a_position_the_run_lacks_is_an_error(plate_run):
    with pytest.raises(InputError, match=r"scan 7 is labelled position 3; the run's placements are 1\.\.2"):
        evaluate_artefact(_relabel(plate_run[0], 7, position=3), None, 20.0)


def test_a_ball_not_measured_is_stated(plate_run):
    run, _ = plate_run
    keep = run.scans["scan_id"] != 0
    scans = {k: np.asarray(v)[keep] for k, v in run.scans.items()}
    pk = run.points["scan_id"] != 0
    points = {k: np.asarray(v)[pk] for k, v in run.points.items()}
    cut = Run(points=points, scans=scans, poses=run.poses, temperatures=run.temperatures,
              temperature_channels=run.temperature_channels, artefact=run.artefact, metadata=run.metadata)
    ev = evaluate_artefact(cut, None, 20.0)
    assert "position 1: balls 1 were not measured" in ev.provenance["notes"]
    assert ev.to_dict()["results"][0]["placements"][0]["missing_balls"] == [1]


def test_old_ballbar_runs_evaluate_as_before(simulated_run):
    run = simulated_run
    assert not is_artefact_run(run)
    assert len(evaluate(run, None).uncompensated.lengths) == 8
    with pytest.raises(InputError, match="records no artefact definition"):
        evaluate_artefact(run)


# -- the CLI ---------------------------------------------------------------------------

def test_cli_example_show_check(tmp_path):
    r = CliRunner()
    out = tmp_path / "plate.toml"
    res = r.invoke(main, ["artefact", "example", "ball-plate", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert artefacts.load_artefact(out).name.startswith("KOBA 0620")
    res = r.invoke(main, ["artefact", "example", "ball-plate", "-o", str(out)])
    assert res.exit_code == 1 and "exists" in res.output
    res = r.invoke(main, ["artefact", "example", "gauge-block", "-o", str(tmp_path / "g.toml")])
    assert res.exit_code == 2 and "gauge-block" in res.output
    res = r.invoke(main, ["artefact", "check", str(out)])
    assert res.exit_code == 0 and "ok:" in res.output
    assert r.invoke(main, ["artefact", "show", "step-gauge-31x20"]).exit_code == 0
    bad = write(tmp_path, PLATE.replace("id = 2,", "id = 1,"), "bad.toml")
    res = r.invoke(main, ["artefact", "check", str(bad)])
    assert res.exit_code == 1 and "bad.toml" in res.output and "ball 1 is repeated" in res.output
    assert "Traceback" not in res.output


def test_cli_simulate_and_evaluate(tmp_path):
    r = CliRunner()
    run_dir = tmp_path / "run"
    res = r.invoke(main, ["simulate", "--artefact", "koba-0320", "--placement", "xy@z=-525", "--placement",
                          "xy@z=-525,rot=45", "--temperature", "21", "-o", str(run_dir)])
    assert res.exit_code == 0, res.output
    res = r.invoke(main, ["evaluate", str(run_dir), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout[res.stdout.index("{"):])
    assert [x["label"] for x in doc["results"]] == ["uncompensated", "compensated"]
    comp = doc["results"][1]
    assert len(comp["placements"]) == 2 and comp["rms_deviation_um"] < 2.0 < doc["results"][0]["rms_deviation_um"]
    report = tmp_path / "report"
    res = r.invoke(main, ["evaluate", str(run_dir), "--report", str(report)])
    assert res.exit_code == 0, res.output
    assert (report / "evaluation.json").is_file() and (report / "lengths.csv").is_file()
    pytest.importorskip("matplotlib")
    assert (report / "deviations_compensated.png").is_file() and (report / "length_errors.png").is_file()


@pytest.mark.parametrize("args, code, message", [
    (["--placement", "xy"], 2, "--placement needs --artefact"),
    (["--artefact", "koba-0420", "--placement", "xy@x=1000,z=-525"], 1, "ball 5 at X 1166.0"),
    (["--artefact", "koba-0420", "--placement", "xy@w=3"], 1, "'w=3' is not"),
    (["--artefact", "koba-0420", "--calibrated"], 2, "--calibrated is for ballbar runs"),
    (["--artefact", "no-such.toml"], 2, "no such artefact file"),  # a missing input: a usage error
])
def test_cli_simulate_bad_input(tmp_path, args, code, message):
    res = CliRunner().invoke(main, ["simulate", *args, "-o", str(tmp_path / "run")])
    assert res.exit_code == code, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "run").exists()


def test_fleet_table_gives_an_artefact_run_its_own_figures(plate_run):
    """`cmmpose evaluate A B ...` across runs: a plate run shows its rms
    deviation and largest |E|, not the NaN of ballbar lengths it lacks."""
    import math

    from cmmpose import scale
    from cmmpose.errormap import ErrorMapSet

    run, _ = plate_run
    maps = ErrorMapSet.thesis()
    ev = scale.fleet._evaluate_run(run, maps, temperature=20.0, expansion_ppm_per_K=11.5, skip_incomplete=False)
    direct = evaluate_artefact(run, maps, 20.0)
    bar, _ = simulate_ballbar_run(maps, 20.0, layout="crossed", scanner=Scanner(points_per_profile=64), seed=1)
    rows = scale.fleet_summary(["plate", "bar"], [ev, scale.fleet._evaluate_run(bar, maps)])
    plate, ballbar = rows
    assert plate.kind == "ball-plate" and ballbar.kind == "ballbar"
    assert plate.rms_uncompensated == direct.uncompensated.rms and plate.rms_compensated == direct.compensated.rms
    assert plate.b89_compensated == abs(direct.compensated.largest_length_error.error)
    assert all(math.isfinite(getattr(r, f)) for r in rows for f in ("rms_uncompensated", "b89_uncompensated",
                                                                       "rms_compensated", "b89_compensated"))
    assert ev.skipped == []
