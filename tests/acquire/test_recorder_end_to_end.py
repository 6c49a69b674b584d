"""End to end over ptys with the recorder as a real subprocess: a simulated
ballbar run played by the simulated instruments, recorded by `cmmpose acquire`
(stopped with Ctrl-C), evaluated; a recorder killed with SIGKILL and its run
recovered; a timed recording with the live display."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np

import cmmpose
from cmmpose import sim
from cmmpose.acquire import plan_from_run, read_journal, recover
from cmmpose.evaluation.ballbar_uncertainty import evaluation_uncertainty
from cmmpose.run import Run
from child_processes import default_signals
from cmmpose.sim.instruments import SimClock, SimLogger, SimScanner, synthetic_profiles

CLI = [sys.executable, "-c", "from cmmpose.cli import main; main()"]
TIMEOUT = 60.0
#: Agreement of the ballbar figures, acquired vs simulated, mm. The points go
#: over the link as float32 (about 2 nm at 30 mm) and the temperatures are
#: sampled at the recorder's poll times, not at the simulated log's.
TOL = 0.2e-3


def wait_for(cond, timeout=TIMEOUT, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def stop_process(proc, sig=signal.SIGINT):
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"recorder did not stop: {err.decode()[-2000:]}")
    return proc.returncode, out.decode(), err.decode()


def test_simulated_ballbar_acquired_then_evaluated(tmp_path):
    maps = cmmpose.ErrorMapSet.thesis()
    run, _ = sim.simulate_ballbar_run(maps, 22.5, layout="crossed", scanner=sim.Scanner(points_per_profile=256), seed=3)
    plan = tmp_path / "plan.json"
    plan_from_run(run).write(plan)
    clock = SimClock(40.0, t0=-10.0)  # 40 simulated s per real s; a lead-in before the first profile
    scanner = SimScanner(run, clock, clock_offset=3600.0, clock_drift_ppm=500.0)
    logger = SimLogger(run, clock, clock_offset=12.0, clock_drift_ppm=-500.0)
    out = tmp_path / "acquired"
    proc = subprocess.Popen(CLI + ["acquire", "--scanner", scanner.port, "--thermo", logger.port, "-o", str(out),
                                   "--plan", str(plan), "--thermo-interval", "0.05", "--flush-interval", "0.1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=default_signals)
    with scanner, logger:
        try:
            wait_for(scanner.finished.is_set, what="the scanner to play the run")
            last = run.points["t"].max()
            wait_for(lambda: logger.answered and logger.answered[-1]["sim_t"] > last + 5.0, what="the logger to pass the end")
        finally:
            code, stdout, stderr = stop_process(proc)  # Ctrl-C
    assert scanner.error is None and logger.error is None
    assert code == 0, stderr[-3000:]
    assert "scanner records" in stdout

    got = Run.load(out)
    assert got.n_points == run.n_points == sum(s["n"] for s in scanner.sent)
    a = got.metadata["acquisition"]
    assert a["scanner"]["rejected"] == {} and a["scanner"]["missing"] == 0
    assert a["scanner"]["records"] == len(scanner.sent) and a["thermo"]["records"] == len(logger.answered)
    # the run's time base is the scanner's clock; the logger's offset and drift were found
    np.testing.assert_allclose(np.unique(got.points["t"]), 3600.0 + np.unique(run.points["t"]) * 1.0005, atol=2e-6)
    c = a["clock"]["thermo_to_scanner"]
    rate = 1.0005 / 0.9995
    assert abs(c["rate"] - rate) < 1e-4 and abs(c["offset_s"] - (3600.0 - 12.0 * rate)) < 0.5

    # evaluate the recorded run with the CLI, exactly as a user would
    res = subprocess.run(CLI + ["evaluate", str(out), "--json"], capture_output=True, timeout=TIMEOUT)
    assert res.returncode == 0, res.stderr.decode()[-2000:]
    doc = json.loads(res.stdout.decode())
    direct, acquired = cmmpose.evaluate(run, maps), cmmpose.evaluate(got, maps)
    lib = json.loads(acquired.to_json())
    # The CLI adds every figure's uncertainty (cmmpose.evaluation.ballbar_uncertainty): the library's, too.
    lib["uncertainty"] = json.loads(json.dumps(evaluation_uncertainty(got, acquired, maps).to_dict()))
    for d in (lib, doc):  # when each evaluation ran is the one thing that may differ
        d["provenance"].pop("date_utc")
    assert lib == doc  # the CLI and the library agree
    for label in ("uncompensated", "compensated"):
        ref, mine = getattr(direct, label), getattr(acquired, label)
        np.testing.assert_allclose(mine.lengths, ref.lengths, atol=TOL)
        assert abs(mine.rms_accuracy_error - ref.rms_accuracy_error) < TOL
        assert abs(mine.b89 - ref.b89) < TOL
    assert direct.compensated.rms_accuracy_error < 2e-3 < direct.uncompensated.rms_accuracy_error


def test_kill_9_recovers_everything_flushed(tmp_path):
    clock = SimClock(1.0)
    scanner = SimScanner(synthetic_profiles(4000, points=256, rate=100.0), clock)
    logger = SimLogger({"t": np.array([0.0, 1e4]), **{f"C{k}": np.array([20.0, 21.0]) for k in range(11)}}, clock)
    out = tmp_path / "crashed"
    proc = subprocess.Popen(CLI + ["acquire", "--scanner", scanner.port, "--thermo", logger.port, "-o", str(out),
                                   "--thermo-interval", "0.1", "--flush-interval", "0.1", "--no-display"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=default_signals)
    journal = out / "journal.cmmj"
    with scanner, logger:
        try:
            wait_for(lambda: journal.exists() and len(read_journal(journal).scanner) >= 150, what="150 records on disk")
            before = read_journal(journal)
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.communicate(timeout=TIMEOUT)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "run.json").exists()  # it never closed the run

    rec = recover(out)
    frames = [f for _, f in rec.contents.scanner]
    assert len(frames) >= len(before.scanner)
    assert frames == [s["frame"] for s in scanner.sent[: len(frames)]]  # a gapless prefix of what was sent
    assert len(rec.contents.thermo) >= len(before.thermo)
    assert not rec.clean_stop
    assert rec.torn_tail is None or rec.torn_tail.nbytes > 0
    got = Run.load(out)
    assert got.n_points == 256 * len(frames)

    # a crash mid-write leaves a torn tail: recovery keeps every whole block and says so
    data = journal.read_bytes()
    journal.write_bytes(data + data[len(b"CMMPJNL\x01") : len(b"CMMPJNL\x01") + 100])
    res = subprocess.run(CLI + ["acquire", "--recover", "-o", str(out)], capture_output=True, timeout=TIMEOUT)
    assert res.returncode == 0, res.stderr.decode()
    assert "torn tail: 100 bytes" in res.stderr.decode()
    assert Run.load(out).n_points == got.n_points


def test_timed_recording_with_live_display(tmp_path):
    clock = SimClock(1.0)
    scanner = SimScanner(synthetic_profiles(2000, points=64, rate=50.0), clock)
    logger = SimLogger({"t": np.array([0.0, 1e4]), **{f"C{k}": np.array([20.0, 21.0]) for k in range(11)}}, clock)
    out = tmp_path / "timed"
    with scanner, logger:
        res = subprocess.run(CLI + ["acquire", "--scanner", scanner.port, "--thermo", logger.port, "-o", str(out),
                                    "--duration", "1.5", "--thermo-interval", "0.1"],
                             capture_output=True, timeout=TIMEOUT, env={**os.environ, "COLUMNS": "140"})
    assert res.returncode == 0, res.stderr.decode()[-2000:]
    err = res.stderr.decode()
    assert "records/s" in err and "latest temperatures" in err and "last flush" in err
    got = Run.load(out)
    assert got.n_points > 0 and len(got.temperatures["t"]) > 3
    frames = [f for _, f in read_journal(out / "journal.cmmj").scanner]
    assert len(frames) > 20 and frames == [s["frame"] for s in scanner.sent[: len(frames)]]
    assert got.metadata["acquisition"]["scanner"]["rejected"] == {}  # stopped at a record boundary
    # a second recording into the same directory is refused, naming it
    res = subprocess.run(CLI + ["acquire", "--thermo", logger.port, "-o", str(out), "--duration", "0.1"],
                         capture_output=True, timeout=TIMEOUT)
    assert res.returncode != 0 and str(out) in res.stderr.decode()
