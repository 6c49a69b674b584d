"""Each fault of the serial links, over real pty pairs with the simulated
instruments: every good record is kept, every bad one is counted with the
right reason in the run's log (acquire.log)."""

import json
import time

import numpy as np

from cmmpose.acquire import LOG_NAME, Recorder, read_journal
from cmmpose.sim.instruments import LoggerFaults, ScannerFaults, SimClock, SimLogger, SimScanner, synthetic_profiles

N = 40  # profiles per test
TIMEOUT = 30.0  # s, generous: a loaded 2-core machine


def wait_for(cond, timeout=TIMEOUT, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def log_events(run_dir):
    return [json.loads(line) for line in (run_dir / LOG_NAME).read_text().splitlines()]


def rejected(events, stream):
    out = {}
    for e in events:
        if e["stream"] == stream and e["type"] == "rejected":
            out[e["reason"]] = out.get(e["reason"], 0) + 1
    return out


def record_scanner(tmp_path, faults=None, *, profiles=None, rate=40.0, link=False, burst=False, **opts):
    """Play profiles through a faulty simulated scanner into a recorder; returns (sim, run, events)."""
    profiles = profiles or synthetic_profiles(N, points=64, rate=rate)
    sim = SimScanner(profiles, SimClock(1.0), faults=faults, link=tmp_path / "scanner" if link else None, burst=burst,
                     settle=0.1)
    run_dir = tmp_path / "run"
    opts.setdefault("flush_interval", 0.05)
    rec = Recorder(run_dir, sim.port, None, fsync=False, **opts)
    sim.start()
    rec.start()
    try:
        wait_for(sim.finished.is_set, what="the scanner to send everything")
        assert sim.error is None, sim.error
        wait_for(lambda: rec.stats.scanner.records >= len(sim.sent), what="every good record to arrive")
    finally:
        run = rec.finish()
        sim.stop()
    return sim, run, log_events(run_dir)


def assert_all_good_kept(sim, run, run_dir):
    frames = [f for _, f in read_journal(run_dir / "journal.cmmj").scanner]
    assert frames == [s["frame"] for s in sim.sent]
    assert run.n_points == sum(s["n"] for s in sim.sent)
    assert run.metadata["acquisition"]["scanner"]["records"] == len(sim.sent)


def test_garbage_and_partial_records(tmp_path):
    faults = ScannerFaults(garbage={3: 100, 10: 7, 30: 2000}, truncate={5, 12, 20}, corrupt_header={8})
    sim, run, events = record_scanner(tmp_path, faults)
    assert_all_good_kept(sim, run, tmp_path / "run")
    assert len(sim.sent) == N - 4
    rej = rejected(events, "scanner")
    assert rej["truncated"] == 3 and rej["header_crc"] == 1
    assert rej["garbage"] >= 3  # the three garbage bursts (and the corrupted header's remains)
    a = run.metadata["acquisition"]["scanner"]
    assert a["rejected"] == rej and a["missing"] == 4  # the four damaged records' sequence numbers


def test_bad_checksums(tmp_path):
    sim, run, events = record_scanner(tmp_path, ScannerFaults(corrupt={4, 9, 15, 33}))
    assert_all_good_kept(sim, run, tmp_path / "run")
    assert rejected(events, "scanner") == {"crc": 4}
    seqs = sorted(e["seq"] for e in events if e.get("reason") == "crc")
    assert seqs == [4, 9, 15, 33]


def test_sequence_gaps_counted_never_invented(tmp_path):
    sim, run, events = record_scanner(tmp_path, ScannerFaults(drop={5, 6, 7, 20}))
    assert_all_good_kept(sim, run, tmp_path / "run")
    gaps = [e for e in events if e["type"] == "gap"]
    assert [(g["after"], g["seq"], g["missing"]) for g in gaps] == [(4, 8, 3), (19, 21, 1)]
    a = run.metadata["acquisition"]["scanner"]
    assert (a["gaps"], a["missing"], a["rejected"]) == (2, 4, {})
    assert len(np.unique(run.points["t"])) == N - 4  # one time per profile kept, none made up


def test_device_reset_restarts_sequence_and_clock(tmp_path):
    sim, run, events = record_scanner(tmp_path, ScannerFaults(reset={25}), rate=20.0)
    assert_all_good_kept(sim, run, tmp_path / "run")
    assert [e["seq"] for e in events if e["type"] == "reset"] == [0]
    a = run.metadata["acquisition"]
    assert a["scanner"]["resets"] == 1 and a["scanner"]["gaps"] == 0
    assert len(a["clock"]["scanner_segments"]) == 2
    # the run's time base carries on across the reset (through the host clock)
    t = np.unique(run.points["t"])
    assert np.all(np.diff(t) > 0)
    expected = np.arange(N) / 20.0
    assert np.max(np.abs(t - expected)) < 0.05  # host jitter bound on a loaded machine, s


def test_port_disappears_and_comes_back(tmp_path):
    sim, run, events = record_scanner(tmp_path, ScannerFaults(unplug={12: 0.6}), link=True)
    assert_all_good_kept(sim, run, tmp_path / "run")
    assert len(sim.sent) == N
    kinds = [e["type"] for e in events if e["stream"] == "scanner"]
    assert "disconnected" in kinds and "reconnected" in kinds
    assert run.metadata["acquisition"]["scanner"]["reconnects"] >= 1


def test_read_timeout_scanner_silence(tmp_path):
    sim, run, events = record_scanner(tmp_path, ScannerFaults(pause={15: 0.8}), scanner_timeout=0.3)
    assert_all_good_kept(sim, run, tmp_path / "run")
    timeouts = [e for e in events if e["stream"] == "scanner" and e["type"] == "timeout"]
    assert len(timeouts) >= 1 and timeouts[0]["silent_s"] >= 0.3


def test_burst_faster_than_disk_backpressure(tmp_path):
    profiles = synthetic_profiles(150, points=1024)  # 8.2 kB each, 1.2 MB in all
    cap = 64 * 1024
    sim, run, events = record_scanner(tmp_path, profiles=profiles, burst=True, buffer_bytes=cap, disk_rate=1.5e6)
    assert_all_good_kept(sim, run, tmp_path / "run")
    assert len(sim.sent) == 150
    bp = [e for e in events if e["type"] == "backpressure"]
    assert bp and sum(e["stalls"] for e in bp) > 0
    assert max(e["buffer_high_water"] for e in bp) <= cap + len(sim.sent[0]["frame"]) + 64
    assert run.metadata["acquisition"]["backpressure"]["stalls"] > 0


# -- the logger ------------------------------------------------------------------------
def logger_log(seconds=60.0):
    t = np.arange(0.0, seconds + 1.0)
    return {"t": t, **{n: 20.0 + 0.01 * k + 0.001 * t for k, n in enumerate(
        ("X1", "X2", "X3", "Y1", "Y2", "Y3", "Z1", "Z2", "Z3", "GT", "GB"))}}


def record_logger(tmp_path, faults, polls, *, link=False, **opts):
    sim = SimLogger(logger_log(), SimClock(1.0), faults=faults, link=tmp_path / "thermo" if link else None,
                    clock_offset=100.0, settle=0.1)
    run_dir = tmp_path / "run"
    opts.setdefault("thermo_timeout", 0.3)
    rec = Recorder(run_dir, None, sim.port, thermo_interval=0.03, flush_interval=0.05, fsync=False, **opts)
    sim.start()
    rec.start()
    try:
        wait_for(lambda: sim.reads >= polls, what=f"{polls} polls")
    finally:
        run = rec.finish()
        sim.stop()
    assert sim.error is None, sim.error
    return sim, run, log_events(run_dir)


def assert_all_scans_kept(sim, run, run_dir):
    lines = read_journal(run_dir / "journal.cmmj").thermo
    assert len(lines) == len(sim.answered)
    got = np.array([[float(x) for x in line.split(";")[0].split(",")[0::2]] for _, _, line in lines])
    want = np.array([a["values"] for a in sim.answered])
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert len(run.temperatures["t"]) == len(sim.answered)


def test_logger_read_timeouts(tmp_path):
    sim, run, events = record_logger(tmp_path, LoggerFaults(mute={3, 4}), 12)
    assert_all_scans_kept(sim, run, tmp_path / "run")
    to = [e for e in events if e["stream"] == "thermo" and e["type"] == "timeout"]
    assert len(to) == 2 and all(e["command"] == "READ?;:SYST:ERR?" for e in to)


def test_logger_scpi_error_and_reset(tmp_path):
    faults = LoggerFaults(error={3: (-230, "Data corrupt or stale")}, reset={8}, garbage={12})
    sim, run, events = record_logger(tmp_path, faults, 18)
    assert_all_scans_kept(sim, run, tmp_path / "run")
    rej = [e for e in events if e["stream"] == "thermo" and e["type"] == "rejected"]
    assert [(e["reason"], e.get("code")) for e in rej] == [("scpi_error", -230), ("scpi_error", -221), ("malformed", None)]
    assert sum(e["type"] == "configured" for e in events) == 3  # start, after each error
    a = run.metadata["acquisition"]["thermo"]
    assert a["rejected"] == {"malformed": 1, "scpi_error": 2} and a["resets"] == 1
    assert len(a and run.metadata["acquisition"]["clock"]["thermo_segments"]) == 2


def test_logger_port_disappears_and_comes_back(tmp_path):
    sim, run, events = record_logger(tmp_path, LoggerFaults(unplug={4: 0.5}), 12, link=True)
    assert_all_scans_kept(sim, run, tmp_path / "run")
    kinds = [e["type"] for e in events if e["stream"] == "thermo"]
    assert "disconnected" in kinds and "reconnected" in kinds


def test_non_finite_points_and_huge_scan_numbers_are_kept_in_the_journal_and_left_out_by_name(tmp_path):
    """A NaN (u, v), an infinite scale reading and a scan number beyond int32 in valid frames: the journal keeps
    every frame as received, the run is built from the rest, and what was left out or renumbered is counted and
    named (issue 35: a recording is never lost)."""
    from dataclasses import replace as dc_replace
    from cmmpose.acquire.assemble import SCAN_ID_MAX
    profiles = synthetic_profiles(N, points=64, rate=40.0, per_scan=10)
    uv = profiles[3].uv.copy()
    uv[[2, 5]] = np.nan
    uv[7, 1] = np.inf
    profiles[3] = dc_replace(profiles[3], uv=uv)
    profiles[7] = dc_replace(profiles[7], scales=(float("inf"), 275.0, -250.0))
    profiles = [dc_replace(p, scan=2**31 + 5) if p.scan == 3 else p for p in profiles]
    sim, run, _ = record_scanner(tmp_path, profiles=profiles)
    frames = [f for _, f in read_journal(tmp_path / "run" / "journal.cmmj").scanner]
    assert frames == [s["frame"] for s in sim.sent] and len(frames) == N  # every frame kept as received
    excluded = run.metadata["acquisition"]["scanner"]["excluded"]
    assert excluded["non_finite_points"] == 3 and excluded["non_finite_readings"] == 64
    assert excluded["scans"] == [0]
    assert run.n_points == N * 64 - 3 - 64
    assert np.isfinite(run.uv).all() and np.isfinite(run.scales).all()
    renumbered = run.metadata["acquisition"]["scanner"]["renumbered_scans"]
    assert [(r["scan"], r["reason"]) for r in renumbered] == [(2**31 + 5, "beyond int32")]
    assert renumbered[0]["scan_id"] <= SCAN_ID_MAX and np.all(run.points["scan_id"] >= 0)
