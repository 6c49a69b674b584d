"""Recording a ball-plate run (issue 24, "Acquisition"): the plan of an
artefact run (`cmmpose artefact plan`: the pose and sweep of every ball of
every placement) says what the simulator does; a simulated plate run played
by the simulated instruments over ptys, recorded by `cmmpose acquire --plan`
as a real subprocess, evaluates as the simulated run does; a plan naming a
ball the artefact lacks is refused when read."""

import json
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose import artefacts
from cmmpose.acquire.plan import Plan, artefact_plan
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.cli import main
from cmmpose.errormap import ErrorMapSet
from cmmpose.errors import AcquisitionError, InputError
from cmmpose.run import Run
from cmmpose.sim import Scanner
from cmmpose.sim.artefact_runs import simulate_artefact_run
from cmmpose.sim.instruments import SimClock, SimLogger, SimScanner
from tests.acquire.test_recorder_end_to_end import CLI, TIMEOUT, stop_process, wait_for

PLACEMENTS = ["xy@z=-450", "xy@z=-450,rot=90"]
#: Agreement of deviations and length errors, acquired vs simulated, mm (as
#: test_recorder_end_to_end's ballbar figures): the points go over the link as
#: float32 (about 2 nm at 500 mm) and the temperatures are sampled at the
#: recorder's poll times, not at the simulated log's (its noisy readings
#: move the maps' thermal terms and each placement's expansion by tens of nm).
TOL = 0.2e-3


@pytest.fixture(scope="module")
def plate(machine):
    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0320"), PLACEMENTS, None, 22.5, machine=machine,
                                   scanner=Scanner(points_per_profile=256), speed=20.0, scan_interval=4.0, seed=5)
    return run, machine


def test_plan_says_what_the_simulator_does(plate):
    """Pose, placement, ball and sweep per scan: the plan's rows are the simulated run's."""
    run, machine = plate
    plan = artefact_plan("koba-0320", PLACEMENTS, machine, speed=20.0)
    sc = run.scans
    assert [s["scan_id"] for s in plan.scans] == sc["scan_id"].tolist()
    for key in ("feature", "position", "ball", "sweep_axis", "sweep_direction", "sweep_speed"):
        assert [s[key] for s in plan.scans] == sc[key].tolist(), key
    pose_of = {int(i): (a, b, g) for i, a, b, g in zip(*(run.poses[k] for k in ("pose_id", "alpha", "beta", "gamma")))}
    plan_pose = {p["pose_id"]: (p["alpha"], p["beta"], p["gamma"]) for p in plan.poses}
    assert [plan_pose[s["pose_id"]] for s in plan.scans] == [pose_of[int(p)] for p in sc["pose_id"]]
    assert plan.artefact["definition"] == run.artefact["definition"]
    assert plan.artefact["placements"] == run.artefact["placements"]
    # the sweep covers the ball's diameter and 5 mm on each side (11 mm balls)
    assert all(s["sweep_length_mm"] == pytest.approx(2 * 11.0 + 10.0, abs=0.01) for s in plan.scans)


def test_a_plate_run_recorded_through_simulated_instruments_evaluates_as_simulated(plate, tmp_path):
    run, _ = plate
    plan_file = tmp_path / "plan.json"
    res = CliRunner().invoke(main, ["artefact", "plan", "koba-0320", *[a for p in PLACEMENTS for a in ("--placement", p)],
                                    "--speed", "20", "--repeat-scans", "0", "-o", str(plan_file)])
    # (no repeats: the plan must match the simulated run's 50 sweeps, which repeats none)
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())  # Rich wraps at the terminal's width, which the test does not choose
    assert "50 sweeps" in said and "+X" in said
    clock = SimClock(60.0, t0=-5.0)
    scanner = SimScanner(run, clock, clock_offset=100.0, clock_drift_ppm=200.0)
    logger = SimLogger(run, clock, clock_offset=7.0, clock_drift_ppm=-200.0)
    out = tmp_path / "acquired"
    proc = subprocess.Popen(CLI + ["acquire", "--scanner", scanner.port, "--thermo", logger.port, "-o", str(out),
                                   "--plan", str(plan_file), "--thermo-interval", "0.05", "--flush-interval", "0.1",
                                   "--no-display"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    with scanner, logger:
        try:
            wait_for(scanner.finished.is_set, what="the scanner to play the run")
            last = run.points["t"].max()
            wait_for(lambda: logger.answered and logger.answered[-1]["sim_t"] > last + 5.0, what="the logger")
        finally:
            code, _, stderr = stop_process(proc)
    assert scanner.error is None and logger.error is None
    assert code == 0, stderr[-3000:]

    got = Run.load(out)
    assert got.n_points == run.n_points
    assert got.artefact["definition"] == run.artefact["definition"]
    assert got.scans["ball"].tolist() == run.scans["ball"].tolist()
    assert got.scans["position"].tolist() == run.scans["position"].tolist()
    maps = ErrorMapSet.thesis()
    direct, acquired = evaluate_artefact(run, maps), evaluate_artefact(got, maps)
    for label in ("uncompensated", "compensated"):
        ref, mine = getattr(direct, label), getattr(acquired, label)
        np.testing.assert_allclose([b.deviation for b in mine.balls], [b.deviation for b in ref.balls], atol=TOL)
        np.testing.assert_allclose([e.error for p in mine.placements for e in p.lengths],
                                   [e.error for p in ref.placements for e in p.lengths], atol=2 * TOL)
    assert direct.compensated.rms < 2e-3 < direct.uncompensated.rms
    # and as a user would: the CLI evaluates the recorded run as an artefact run
    res = subprocess.run(CLI + ["evaluate", str(out), "--json"], capture_output=True, timeout=TIMEOUT, check=False)
    assert res.returncode == 0, res.stderr.decode()[-2000:]
    doc = json.loads(res.stdout.decode())
    assert doc["artefact"]["kind"] == "ball-plate"
    assert doc["results"][1]["rms_deviation_um"] == pytest.approx(acquired.compensated.rms * 1e3, abs=1e-3)


def test_a_plan_with_a_ball_the_artefact_lacks_is_refused(tmp_path):
    plan = artefact_plan("koba-0320", ["xy"])
    doc = plan.to_dict()
    doc["scans"][3]["ball"] = 26
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=r"bad\.json: plan: scans\[3\]: ball 26 is not a ball of KOBA 0320"):
        Plan.read(path)
    doc["scans"][3]["ball"] = 4
    doc["scans"][5]["position"] = 2
    path.write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=r"scans\[5\]: position 2 is not one of the artefact's 1 placements"):
        Plan.read(path)
    doc["scans"][5]["position"] = 1
    doc["scans"][6]["scan_id"] = 0
    path.write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=r"scans\[6\]: scan_id 0 is also scans\[0\]"):
        Plan.read(path)


def test_a_plan_out_of_reach_names_the_ball_and_axis():
    with pytest.raises(InputError, match=r"ball \d+ .* X travel 0\.\.900 mm"):
        artefact_plan("koba-0420", ["xy@x=1000,z=-525"])
    res = CliRunner().invoke(main, ["artefact", "plan", "koba-0620", "--placement", "planes", "-o", "p.json"])
    assert res.exit_code != 0 and "cannot stand in the XZ plane" in res.output
