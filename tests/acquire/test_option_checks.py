"""`cmmpose acquire` refuses what it cannot record before it opens a port or
writes a file: bad option values (usage errors naming the option), a plan whose
scans, poses or channels do not fit together (naming the plan file and the scan
or channel), a port that cannot be opened (the run directory left as it was);
a journal with no points is not turned into an empty run; and a logger that
rejects its configuration is retried at the backoff's pace, not in a tight loop.

No test here waits on the clock: the ports are pyserial's ``loop://`` (which
echoes what is written) or a stand-in that fails to open, and the reconnect
backoff is read from the waits the reader asks its stop event for."""

from __future__ import annotations

import json
import threading

import cmmpose.acquire.reader as reader_module
import cmmpose.acquire.recorder as recorder_module
import pytest
import serial
from click.testing import CliRunner
from cmmpose.acquire import (
    JOURNAL_NAME,
    Plan,
    Recorder,
    acquire,
    plan_from_run,
    recover,
)
from cmmpose.acquire.reader import ThermoReader
from cmmpose.acquire.store import JournalWriter
from cmmpose.cli import main
from cmmpose.errors import AcquisitionError


@pytest.fixture
def no_ports(monkeypatch):
    """Every port open fails (and is counted): a command that gets as far as opening one is seen doing so."""
    opened = []

    def refuse(url, **kwargs):
        opened.append(url)
        raise serial.SerialException(f"could not open port {url}: none in this test")

    monkeypatch.setattr(reader_module.serial, "serial_for_url", refuse)
    return opened


def invoke(*args):
    return CliRunner().invoke(main, ["acquire", "--no-display", *[str(a) for a in args]])


# -- 1. option values -------------------------------------------------------------------------

BAD_OPTIONS = [
    ("--tc-type", "Q"), ("--tc-type", ""), ("--thermo-interval", "-5"), ("--thermo-interval", "0"),
    ("--thermo-interval", "nan"), ("--duration", "nan"), ("--duration", "-1"), ("--duration", "inf"),
    ("--duration", "0"), ("--flush-interval", "-1"), ("--flush-interval", "nan"), ("--scanner-baud", "0"),
    ("--thermo-baud", "-9600"),
]


@pytest.mark.parametrize("option, value", BAD_OPTIONS)
def test_a_bad_option_value_is_a_usage_error_before_any_port_opens(tmp_path, no_ports, option, value):
    out = tmp_path / "rec"
    r = invoke("--scanner", "scanner-port", "--thermo", "thermo-port", "-o", out, "--duration", "1", option, value)
    assert r.exit_code == 2, r.output  # click's usage error
    assert f"Invalid value for '{option}'" in r.output
    assert no_ports == []
    assert not out.exists()


def test_good_option_values_pass_the_checks(tmp_path, no_ports):
    r = invoke("--scanner", "scanner-port", "-o", tmp_path / "rec", "--duration", "0.5", "--tc-type", "k",
               "--thermo-interval", "0.25", "--flush-interval", "1e-3", "--scanner-baud", "115200")
    assert r.exit_code == 1 and "scanner-port: cannot open the port" in r.output  # got as far as the port
    assert no_ports == ["scanner-port"]


@pytest.mark.parametrize("option, value", [("tc_type", "Q"), ("thermo_interval", -5.0), ("thermo_interval", float("nan")),
                                           ("flush_interval", -1.0), ("scanner_baudrate", 0), ("thermo_baudrate", 9600.5),
                                           ("thermo_timeout", float("inf")), ("buffer_bytes", 0)])
def test_the_recorder_refuses_bad_options_naming_them(tmp_path, option, value):
    with pytest.raises(AcquisitionError, match=option):
        Recorder(tmp_path / "rec", "loop://", "loop://", **{option: value})
    assert not (tmp_path / "rec").exists()


@pytest.mark.parametrize("duration", [float("nan"), -1.0, 0.0, float("inf")])
def test_acquire_refuses_a_bad_duration_before_starting(tmp_path, no_ports, duration):
    with pytest.raises(AcquisitionError, match="duration"):
        acquire(tmp_path / "rec", "loop://", duration=duration)
    assert no_ports == [] and not (tmp_path / "rec").exists()


class CountingStop(threading.Event):
    """A stop event that records every wait asked of it, returns at once, and
    sets itself after ``limit`` waits (or ``limit`` * 50 checks) so the reader ends."""

    def __init__(self, limit: int):
        super().__init__()
        self.limit, self.waits, self.checks = limit, [], 0

    def wait(self, timeout=None):
        self.waits.append(timeout)
        if len(self.waits) >= self.limit:
            self.set()
        return self.is_set()

    def is_set(self):
        self.checks += 1
        if self.checks >= 50 * self.limit:
            self.set()
        return super().is_set()


def test_a_logger_that_rejects_its_configuration_is_retried_at_the_backoffs_pace(tmp_path):
    # loop:// echoes the configuration back: never a valid answer, so every session
    # ends after `retries` failed configurations -- a failure that is not a disconnect.
    rec = Recorder(tmp_path / "rec", None, "loop://")
    interval = 0.3  # the wait between configuration attempts, told apart from the backoff's waits
    stop = CountingStop(limit=40)
    r = ThermoReader("loop://", rec, stop, channels=rec.plan.channels, interval=interval, timeout=0.2)
    r.run()  # in this thread; ends when the stop event sets itself
    assert r.error is None
    reconnects = rec.stats.thermo.reconnects
    assert reconnects >= 6
    backoff = [w for w in stop.waits if w != interval]
    first, top = ThermoReader.BACKOFF
    expected = [min(first * 2**k, top) for k in range(reconnects)]
    assert backoff[:reconnects] == pytest.approx(expected)
    # each reconnect came after `retries` configurations and one backoff wait, never straight away
    assert len(stop.waits) >= reconnects * r.retries


def test_the_backoff_starts_over_after_a_connection_that_delivered_records(tmp_path):
    rec = Recorder(tmp_path / "rec", "loop://", None)
    stop = CountingStop(limit=8)

    class Flaky(reader_module.ScannerReader):
        def session(self, port):  # one good record every other session, then the port fails
            if len(stop.waits) % 2:
                with rec.stats.lock:
                    self.stats.records += 1
            raise serial.SerialException("device reports readiness to read but returned no data")

    Flaky("loop://", rec, stop).run()
    w0 = Flaky.BACKOFF[0]
    # sessions 2, 4, 6 delivered a record: the wait after each starts over at w0 (else it doubles)
    assert stop.waits == pytest.approx([w0, w0, 2 * w0, w0, 2 * w0, w0, 2 * w0, w0])


# -- 2. the plan ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def plan_doc(simulated_run):
    return plan_from_run(simulated_run).to_dict()


def write_plan(tmp_path, doc, name="plan.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_a_scan_naming_a_missing_pose_is_refused_when_the_plan_is_read(tmp_path, plan_doc):
    doc = json.loads(json.dumps(plan_doc))
    doc["scans"][2]["pose_id"] = 5
    sid = doc["scans"][2]["scan_id"]
    path = write_plan(tmp_path, doc, "bad_pose.json")
    with pytest.raises(AcquisitionError, match=rf"bad_pose.json: plan: scans\[2\] \(scan_id {sid}\): pose_id 5 is not a pose"):
        Plan.read(path)


def test_a_plan_without_poses_takes_scans_of_pose_0_only(tmp_path, plan_doc):
    doc = {"scans": [dict(plan_doc["scans"][0], pose_id=0), dict(plan_doc["scans"][1], pose_id=3)]}
    with pytest.raises(AcquisitionError, match=r"scans\[1\].*pose_id 3, but the plan lists no poses"):
        Plan.read(write_plan(tmp_path, doc))
    assert Plan.read(write_plan(tmp_path, {"scans": doc["scans"][:1]})).scans[0]["pose_id"] == 0


def test_two_thermocouples_on_one_channel_are_refused(tmp_path, plan_doc):
    doc = json.loads(json.dumps(plan_doc))
    doc["temperature_channels"][0]["channel"] = 102  # X1 on X2's channel
    path = write_plan(tmp_path, doc, "dup.json")
    with pytest.raises(AcquisitionError, match=r"dup.json: plan: temperature_channels\[1\]: 'X2' on channel 102, which is "
                                               r"also 'X1' \(temperature_channels\[0\]\)"):
        Plan.read(path)


@pytest.mark.parametrize("where, key, value, message", [
    ("poses", "pose_id", None, r"poses\[1\]: pose_id 0 is also poses\[0\]"),
    ("scans", "sweep_axis", "W", r"sweep_axis 'W' is not one of X, Y, Z"),
    ("scans", "sweep_direction", 0, r"sweep_direction 0 is not \+1 or -1"),
    ("temperature_channels", "name", "X2", r"temperature_channels\[1\]: name 'X2' is also temperature_channels\[0\]"),
    ("temperature_channels", "channel", 0, r"channel 0 of 'X1' is not a multiplexer channel"),
])
def test_what_the_run_would_refuse_is_refused_in_the_plan(tmp_path, plan_doc, where, key, value, message):
    doc = json.loads(json.dumps(plan_doc))
    if where == "poses":
        doc["poses"] = [doc["poses"][0], dict(doc["poses"][0])]
    else:
        doc[where][0][key] = value
    with pytest.raises(AcquisitionError, match=message):
        Plan.read(write_plan(tmp_path, doc))


def test_the_acquire_command_checks_the_plan_before_opening_a_port(tmp_path, plan_doc, no_ports):
    doc = json.loads(json.dumps(plan_doc))
    doc["scans"][0]["pose_id"] = 5
    path = write_plan(tmp_path, doc, "bad_pose.json")
    out = tmp_path / "rec"
    r = invoke("--scanner", "scanner-port", "-o", out, "--duration", "1", "--plan", path)
    assert r.exit_code == 1 and "bad_pose.json" in r.output and "scans[0]" in r.output, r.output
    assert no_ports == [] and not out.exists()


def test_recover_names_the_bad_plan_in_the_run_directory(tmp_path, plan_doc):
    d = tmp_path / "rec"
    d.mkdir()
    doc = json.loads(json.dumps(plan_doc))
    doc["scans"][0]["pose_id"] = 5
    write_plan(d, doc)
    JournalWriter(d / JOURNAL_NAME, fsync=False).close()
    with pytest.raises(AcquisitionError, match=r"plan.json: plan: scans\[0\]"):
        recover(d)


# -- 3. a failed start --------------------------------------------------------------------------

def test_a_port_that_cannot_be_opened_leaves_no_run_behind(tmp_path):
    out = tmp_path / "new" / "rec"
    for _ in range(2):  # the retry fails the same way, not with "already holds a recording"
        with pytest.raises(AcquisitionError, match="cannot open the port"):
            Recorder(out, str(tmp_path / "no-such-port")).start()
        assert not (tmp_path / "new").exists()


def test_a_failed_start_keeps_what_the_directory_held(tmp_path):
    out = tmp_path / "rec"
    out.mkdir()
    (out / "notes.txt").write_text("operator's notes")
    with pytest.raises(AcquisitionError, match="cannot open the port"):
        Recorder(out, str(tmp_path / "no-such-port")).start()
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_a_failed_start_keeps_the_recording_it_was_to_overwrite(tmp_path):
    out = tmp_path / "rec"
    out.mkdir()
    for name in (JOURNAL_NAME, "run.json", "plan.json", "acquire.log"):
        (out / name).write_text("the earlier recording")
    with pytest.raises(AcquisitionError, match="cannot open the port"):
        Recorder(out, str(tmp_path / "no-such-port"), overwrite=True).start()
    assert all((out / n).read_text() == "the earlier recording" for n in (JOURNAL_NAME, "run.json", "plan.json"))


def test_files_made_before_a_later_failure_are_removed(tmp_path, monkeypatch):
    def no_journal(path, **kwargs):
        raise AcquisitionError(f"{path}: cannot open for writing (disk full)")

    monkeypatch.setattr(recorder_module, "JournalWriter", no_journal)
    out = tmp_path / "rec"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    rec = Recorder(out, "loop://")
    with pytest.raises(AcquisitionError, match="disk full"):
        rec.start()
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert rec._readers == []  # the port opened was closed again
    with pytest.raises(AcquisitionError, match="disk full"):
        Recorder(tmp_path / "fresh", "loop://").start()
    assert not (tmp_path / "fresh").exists()


def test_a_journal_without_points_is_not_recovered_into_an_empty_run(tmp_path):
    out = tmp_path / "rec"
    rec = Recorder(out, "loop://", fsync=False).start()  # a scanner that sends nothing
    rec.stop()
    with pytest.raises(AcquisitionError, match=r"journal.cmmj: holds no points"):
        recover(out)
    assert not (out / "run.json").exists()
    r = CliRunner().invoke(main, ["acquire", "--recover", "-o", str(out)])
    assert r.exit_code == 1 and "holds no points" in r.output, r.output


def test_an_empty_journal_says_the_recording_never_started(tmp_path):
    out = tmp_path / "rec"
    out.mkdir()
    JournalWriter(out / JOURNAL_NAME, fsync=False).close()
    with pytest.raises(AcquisitionError, match="no points and no temperatures.*never started"):
        recover(out)
