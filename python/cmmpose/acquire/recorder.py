"""The recorder: both port readers, the bounded buffer and the journal writer,
started and stopped together; ``acquire`` records for a while and returns the
run (docs/protocols.md)."""

from __future__ import annotations

import json
import math
import os
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

from ..errors import AcquisitionError
from ..pose import MountOffset
from ..run import Run
from .assemble import assemble
from .buffer import BoundedBuffer
from .clock import host_time
from .plan import Plan
from .reader import ScannerReader, ThermoReader
from .scpi import TC_TYPES
from .stats import Snapshot, Stats
from .store import EVENT, JOURNAL_NAME, LOG_NAME, JournalContents, JournalWriter, encode_record, event_data, read_journal

__all__ = ["Recorder", "acquire", "recover", "Recovery", "PLAN_NAME", "check_options"]

PLAN_NAME = "plan.json"
_RUN_FILES = ("run.json", "points.parquet", "scans.parquet", "poses.parquet", "temperatures.parquet")


def _utc(t: float) -> str:
    return datetime.fromtimestamp(t, timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


class Recorder:
    """Records the scanner and the thermocouple logger into ``run_dir``.

    Parameters
    ----------
    run_dir : str or path-like
        The run directory (created). It holds ``journal.cmmj`` (the recording),
        ``acquire.log`` (one JSON event per line), ``plan.json`` and, after
        ``finish``, the run itself (run.json and the tables).
    scanner, thermo : str, optional
        pyserial URLs of the two ports (a device path, ``socket://``,
        ``rfc2217://``, a pty); either may be None.
    plan : Plan, str or path-like, optional
        What the sweeps measured (``cmmpose.acquire.Plan`` or a plan JSON file).
    pose : sequence of 3 float
        Pose (alpha, beta, gamma), degrees, when the plan has no poses.
    offset : sequence of 3 float, optional
        Mount offset U1, V1, W1, mm, when the plan has no poses; default the thesis digitizer.
    tc_type : str
        Thermocouple type for the logger (thesis: E).
    thermo_interval : float
        Seconds between logger polls.
    flush_interval : float
        Longest time a received record waits before its block is written and
        synced to disk, s.
    buffer_bytes : int
        Capacity of the buffer between readers and writer, bytes; when full the
        readers wait (backpressure, reported).
    scanner_baudrate, thermo_baudrate : int
        bit/s (ignored by ptys and sockets).
    scanner_timeout : float
        Scanner silence counted as a read timeout, s.
    thermo_timeout : float
        Wait for a logger answer, s.
    fsync : bool
        Sync every block to disk (default), not only write it.
    disk_rate : float, optional
        Limit the writer to this many bytes per second (to test a slow disk).
    overwrite : bool
        Replace a recording already in ``run_dir``.
    """

    def __init__(self, run_dir, scanner: str | None = None, thermo: str | None = None, *, plan=None,
                 pose=(90.0, 90.0, 0.0), offset=None, tc_type: str = "E", thermo_interval: float = 1.0,
                 flush_interval: float = 0.2, buffer_bytes: int = 64 << 20, scanner_baudrate: int = 921600,
                 thermo_baudrate: int = 9600, scanner_timeout: float = 2.0, thermo_timeout: float = 2.0,
                 fsync: bool = True, disk_rate: float | None = None, overwrite: bool = False):
        if scanner is None and thermo is None:
            raise AcquisitionError("nothing to record: give a scanner port, a thermo port or both")
        check_options(tc_type=tc_type, thermo_interval=thermo_interval, flush_interval=flush_interval,
                      buffer_bytes=buffer_bytes, scanner_baudrate=scanner_baudrate, thermo_baudrate=thermo_baudrate,
                      scanner_timeout=scanner_timeout, thermo_timeout=thermo_timeout, disk_rate=disk_rate)
        self.run_dir = Path(run_dir)
        self.scanner_url, self.thermo_url = scanner, thermo
        if plan is None:
            plan = Plan()
        elif not isinstance(plan, Plan):
            plan = Plan.read(plan)
        if not plan.poses:
            off = MountOffset.thesis() if offset is None else MountOffset(*(float(x) for x in offset))
            plan.poses = [{"pose_id": 0, "alpha": float(pose[0]), "beta": float(pose[1]), "gamma": float(pose[2]),
                           "U1": off[0], "V1": off[1], "W1": off[2]}]
        self.plan = plan
        self.options = dict(tc_type=tc_type, thermo_interval=thermo_interval, scanner_baudrate=scanner_baudrate,
                            thermo_baudrate=thermo_baudrate, scanner_timeout=scanner_timeout, thermo_timeout=thermo_timeout)
        self.flush_interval = float(flush_interval)
        self.disk_rate = disk_rate
        self.fsync = fsync
        self.overwrite = overwrite
        self.stats = Stats()
        self.buffer = BoundedBuffer(buffer_bytes)
        self._stop = threading.Event()
        self._writer_stop = threading.Event()
        self._readers: list = []
        self._writer: threading.Thread | None = None
        self._journal: JournalWriter | None = None
        self._log = None
        self.error: BaseException | None = None
        self._bp_lock = threading.Lock()
        self._bp = {"scanner": [0, 0.0, 0.0], "thermo": [0, 0.0, 0.0]}  # stalls, seconds, last report
        self.started: float | None = None
        self.finished = False

    # -- sink interface used by the readers ---------------------------------------------
    def put(self, kind: int, host: float, data: bytes, stream, points: int = 0) -> None:
        """Queue one good record for the journal (waits while the buffer is full)."""
        rec = encode_record(kind, host, data)
        waited = self.buffer.put(rec, stop=self._writer_stop)
        self.stats.good(stream, len(data), points)
        if waited > 0:
            name = "scanner" if stream is self.stats.scanner else "thermo"
            with self.stats.lock:
                stream.backpressure_s += waited
            self._backpressure(name, waited)

    def _backpressure(self, name: str, waited: float, force: bool = False) -> None:
        with self._bp_lock:
            acc = self._bp[name]
            if waited:
                acc[0] += 1
                acc[1] += waited
            now = time.monotonic()
            if acc[0] and (force or now - acc[2] >= 1.0):
                stalls, secs = acc[0], acc[1]
                acc[:] = [0, 0.0, now]
            else:
                return
        self.event("journal", "backpressure", source=name, stalls=stalls, waited_s=round(secs, 4),
                   buffer_capacity=self.buffer.capacity, buffer_high_water=self.buffer.high_water)

    def event(self, stream: str, kind: str, **fields) -> None:
        """Log an event (never waits)."""
        ev = {"t": round(host_time(), 6), "stream": stream, "type": kind, **fields}
        self.buffer.put(encode_record(EVENT, ev["t"], event_data(ev)), force=True)

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> Recorder:
        """Open the ports, then create the run directory and journal, start the threads.

        The ports are opened before anything is written: a port that cannot be
        opened leaves ``run_dir`` as it was (a recording to be replaced with
        ``overwrite`` is kept). Should the files then fail to be created, what
        this call created is removed again.

        Raises
        ------
        AcquisitionError
            A port that cannot be opened, a directory already holding a recording.
        """
        d = self.run_dir
        journal = d / JOURNAL_NAME
        if (journal.exists() or (d / "run.json").exists()) and not self.overwrite:
            raise AcquisitionError(f"{d}: already holds a recording", file=str(d), option="overwrite",
                                   remedy="overwrite_recording")
        if d.exists() and not d.is_dir():
            raise AcquisitionError(f"{d}: not a directory")
        self._open_readers()
        created: list[Path] = []
        try:
            self._create_files(created)
        except BaseException:
            self._close_readers()
            for f in (self._journal, self._log):
                if f is not None:
                    f.close()
            self._journal = self._log = None
            _remove_created(created)
            raise
        self.started = host_time()
        self.event("journal", "start", created=_utc(self.started), scanner=self.scanner_url, thermo=self.thermo_url,
                   flush_interval_s=self.flush_interval, buffer_bytes=self.buffer.capacity, **self.options)
        self._writer = threading.Thread(target=self._write_loop, name="cmmpose-journal", daemon=True)
        self._writer.start()
        for r in self._readers:
            r.start()
        return self

    def _open_readers(self) -> None:
        """Open both ports (the readers' threads are not started); on a failure close what was opened."""
        o = self.options
        try:
            if self.scanner_url:
                self._readers.append(ScannerReader(self.scanner_url, self, self._stop, baudrate=o["scanner_baudrate"],
                                                   timeout=o["scanner_timeout"]))
            if self.thermo_url:
                self._readers.append(ThermoReader(self.thermo_url, self, self._stop, channels=self.plan.channels,
                                                  tc_type=o["tc_type"], interval=o["thermo_interval"],
                                                  baudrate=o["thermo_baudrate"], timeout=o["thermo_timeout"]))
        except BaseException:
            self._close_readers()
            raise

    def _close_readers(self) -> None:
        for r in self._readers:
            try:
                r._port.close()
            except OSError:
                pass
        self._readers.clear()

    def _create_files(self, created: list[Path]) -> None:
        """Create the run directory (and its missing parents), plan.json, acquire.log and the
        journal, appending to ``created`` every path this call made, in the order made."""
        d = self.run_dir
        try:
            missing = []
            p = d
            while not p.exists():
                missing.append(p)
                p = p.parent
            created.extend(reversed(missing))  # listed first: removed again even if mkdir fails half-way
            d.mkdir(parents=True, exist_ok=True)
            if self.overwrite:
                for name in (JOURNAL_NAME, LOG_NAME, PLAN_NAME, *_RUN_FILES):
                    if (d / name).is_file():
                        (d / name).unlink()
            plan, log = d / PLAN_NAME, d / LOG_NAME
            made = [path for path in (plan, log) if not path.exists()]
            self.plan.write(plan)
            created.extend(path for path in made if path == plan)
            self._log = open(log, "a", encoding="utf-8")
            created.extend(path for path in made if path == log)
        except OSError as exc:
            raise AcquisitionError(f"{d}: cannot create the run directory ({exc.strerror or exc})") from None
        self._journal = JournalWriter(d / JOURNAL_NAME, fsync=self.fsync)
        created.append(d / JOURNAL_NAME)

    def _write_loop(self) -> None:
        try:
            last = time.monotonic()
            while True:
                stopping = self._writer_stop.is_set()
                left = 0.0 if stopping else max(0.0, last + self.flush_interval - time.monotonic())
                items = self.buffer.take(left, min_bytes=max(1, self.buffer.capacity // 2) if not stopping else 1 << 62)
                last = time.monotonic()
                if items:
                    n = self._journal.write_block(items)
                    lines = [json.loads(it[13:].decode("utf-8")) for it in items if it[0] == EVENT]
                    if lines:
                        self._log.write("".join(json.dumps(ev, separators=(", ", ": "), allow_nan=False) + "\n" for ev in lines))
                        self._log.flush()
                    with self.stats.lock:
                        self.stats.blocks = self._journal.blocks
                        self.stats.journal_bytes = self._journal.bytes_written
                    if self.disk_rate:
                        time.sleep(n / self.disk_rate)
                with self.stats.lock:
                    self.stats.last_flush = time.monotonic()
                if stopping and not items and self.buffer.nbytes == 0:
                    return
        except BaseException as exc:  # noqa: BLE001
            self.error = exc
            self._stop.set()
            self.buffer.close()

    def snapshot(self) -> Snapshot:
        """Counters for display (records, rates, rejections, temperatures, flush age, buffer)."""
        return self.stats.snapshot(self.buffer)

    @property
    def running(self) -> bool:
        """True while the writer runs (no fatal error)."""
        return self._writer is not None and self._writer.is_alive() and self.error is None

    def stop(self) -> None:
        """Stop the readers, write what is buffered, close the journal."""
        if self._writer is None or self.finished:
            return
        self._stop.set()
        for r in self._readers:
            r.join(timeout=10.0)
        for name in ("scanner", "thermo"):
            self._backpressure(name, 0.0, force=True)
        self.event("journal", "stop", reader_errors=[repr(r.error) for r in self._readers if r.error])
        self._writer_stop.set()
        self.buffer.close()
        self._writer.join(timeout=60.0)
        self._journal.close()
        self._log.close()
        self.finished = True
        if self.error is not None:
            raise AcquisitionError(f"{self.run_dir / JOURNAL_NAME}: recording failed ({self.error})") from self.error

    def finish(self) -> Run:
        """``stop``, then build the run from the journal and save it in ``run_dir``.

        Returns
        -------
        Run
            The recorded run (``metadata['acquisition']`` has the counts and clock fits).
        """
        self.stop()
        return recover(self.run_dir).run

    def __enter__(self) -> Recorder:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class Recovery:
    """The result of ``recover``: the run, the journal's contents and its torn tail.

    Attributes
    ----------
    run : Run
    contents : JournalContents
    torn_tail : TornTail or None
        Bytes after the last good block (a crash mid-write), None if the journal ends cleanly.
    clean_stop : bool
        The journal ends with the recorder's stop event.
    """

    def __init__(self, run: Run, contents: JournalContents):
        self.run = run
        self.contents = contents
        self.torn_tail = contents.torn_tail
        self.clean_stop = bool(contents.events) and contents.events[-1].get("type") == "stop"

    def __repr__(self) -> str:
        tail = "none" if self.torn_tail is None else f"{self.torn_tail.nbytes} bytes at {self.torn_tail.offset} ({self.torn_tail.reason})"
        return (f"Recovery({len(self.contents.scanner)} scanner records, {len(self.contents.thermo)} logger scans, "
                f"{self.contents.blocks} blocks, torn tail: {tail}, clean stop: {self.clean_stop})")


def _remove_created(paths: list[Path]) -> None:
    """Remove files and (empty) directories a failed start created, newest first."""
    for p in reversed(paths):
        try:
            if p.is_dir():
                p.rmdir()
            else:
                p.unlink()
        except OSError:
            pass


def _positive(name: str, value, *, integer: bool = False, optional: bool = False) -> None:
    if optional and value is None:
        return
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) and value > 0
    if ok and integer:
        ok = float(value).is_integer()
    if not ok:
        raise AcquisitionError(f"{name}: expected a finite {'integer' if integer else 'number'} > 0, got {value!r}")


def check_options(*, tc_type="E", thermo_interval=1.0, flush_interval=0.2, buffer_bytes=64 << 20,
                  scanner_baudrate=921600, thermo_baudrate=9600, scanner_timeout=2.0, thermo_timeout=2.0,
                  disk_rate=None, duration=None) -> None:
    """Check the recorder's options before any port is opened or file written.

    Parameters are those of ``Recorder`` (and ``acquire``'s ``duration``, s,
    None: until stopped).

    Raises
    ------
    AcquisitionError
        Naming the option: a thermocouple type the logger code does not know
        (``scpi.TC_TYPES``), an interval, timeout or duration that is not a
        finite number > 0, a baud rate or buffer size that is not an integer > 0.
    """
    if not isinstance(tc_type, str) or tc_type.upper() not in TC_TYPES:
        raise AcquisitionError(f"tc_type: {tc_type!r} is not a thermocouple type ({', '.join(TC_TYPES)})")
    for name, value in (("thermo_interval", thermo_interval), ("flush_interval", flush_interval),
                        ("scanner_timeout", scanner_timeout), ("thermo_timeout", thermo_timeout)):
        _positive(name, value)
    _positive("duration", duration, optional=True)
    _positive("disk_rate", disk_rate, optional=True)
    for name, value in (("buffer_bytes", buffer_bytes), ("scanner_baudrate", scanner_baudrate),
                        ("thermo_baudrate", thermo_baudrate)):
        _positive(name, value, integer=True)


def recover(run_dir, *, save: bool = True) -> Recovery:
    """Rebuild the run in ``run_dir`` from its journal (after a clean stop or a crash).

    Parameters
    ----------
    run_dir : str or path-like
        A directory written by ``Recorder``.
    save : bool
        Save the run into ``run_dir`` (replacing run.json and the tables).

    Returns
    -------
    Recovery
        Every record in the journal's good blocks; the torn tail, if any, is
        reported (and left in the file untouched).

    Raises
    ------
    AcquisitionError
        A journal holding no points (a recording that never started, or a
        scanner that sent nothing) -- unless it is a logger-only recording
        holding logger scans; a plan.json that is not a valid plan.
    """
    d = Path(run_dir)
    if not (d / JOURNAL_NAME).is_file():
        raise AcquisitionError(f"{d}: no journal ({JOURNAL_NAME}) to recover a run from")
    contents = read_journal(d / JOURNAL_NAME)
    plan = Plan.read(d / PLAN_NAME) if (d / PLAN_NAME).is_file() else Plan()
    start = next((e for e in contents.events if e.get("type") == "start"), None)
    if not contents.scanner and not contents.thermo:
        raise AcquisitionError(f"{d / JOURNAL_NAME}: holds no points and no temperatures, no run to build "
                               f"({contents.blocks} blocks" + ("" if start else ", no start event: the recording "
                               "never started") + ")")
    created = start["created"] if start else _utc(os.path.getmtime(d / JOURNAL_NAME))
    run = assemble(contents, plan, created=created)
    if run.n_points == 0 and (not contents.thermo or (start or {}).get("scanner")):
        raise AcquisitionError(f"{d / JOURNAL_NAME}: holds no points, no run to build ({len(contents.scanner)} "
                               f"scanner records, {len(contents.thermo)} logger scans)")
    if save:
        run.save(d, overwrite=True)
    return Recovery(run, contents)


def acquire(run_dir, scanner: str | None = None, thermo: str | None = None, *, duration: float | None = None,
            stop: threading.Event | None = None, on_update=None, update_interval: float = 0.25, **options) -> Run:
    """Record both instruments into ``run_dir`` until ``duration`` s pass,
    ``stop`` is set or Ctrl-C, then close the run.

    Parameters
    ----------
    run_dir : str or path-like
        The run directory.
    scanner, thermo : str, optional
        pyserial URLs of the scanner and logger ports.
    duration : float, optional
        Seconds to record; None: until ``stop`` or Ctrl-C.
    stop : threading.Event, optional
        Set it to stop recording.
    on_update : callable, optional
        Called with a ``Snapshot`` every ``update_interval`` s.
    update_interval : float
        s.
    **options
        ``Recorder`` options (plan, flush_interval, buffer_bytes, ...).

    Returns
    -------
    Run
        The run, also saved in ``run_dir``.
    """
    check_options(duration=duration)
    rec = Recorder(run_dir, scanner, thermo, **options).start()
    stop = stop or threading.Event()
    end = None if duration is None else time.monotonic() + duration
    try:
        while not stop.is_set() and rec.running:
            wait = update_interval if end is None else min(update_interval, end - time.monotonic())
            if wait <= 0:
                break
            stop.wait(wait)
            if on_update:
                on_update(rec.snapshot())
    except KeyboardInterrupt:
        pass
    return rec.finish()
