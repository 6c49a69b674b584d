"""Simulated instruments on pseudo-terminals: the scanner + scales stream and
the SCPI thermocouple logger of docs/protocols.md, fed by a simulated run
(``simulate_ballbar_run``) and paced by a shared, optionally accelerated
clock, with switches that inject the faults a lab sees (line noise, cut and
corrupted records, lost records, resets, unplugged cables, silence, SCPI
errors).

Each instrument owns the master side of a pty; the recorder opens the slave
(``instrument.port``, or a stable symlink to it when ``link`` is given, like a
``/dev/serial/by-id`` name, so the port can disappear and come back under
the same name). An instrument starts talking only once something has opened
its port, and waits while nobody has it open.

Run from a shell: ``python -m cmmpose.sim.instruments RUN_DIR [--speed 10]``
prints the two ports and a plan file for ``cmmpose acquire``.
"""

from __future__ import annotations

import errno
import fcntl
import os
import pty
import select
import struct
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..acquire.plan import plan_from_run
from ..acquire.protocol import encode_profile
from ..atomicfile import replace_link
from ..run import Run

__all__ = [
    "SimClock",
    "Profile",
    "profiles_from_run",
    "ScannerFaults",
    "LoggerFaults",
    "SimScanner",
    "SimLogger",
    "PtyDevice",
    "synthetic_profiles",
]


class SimClock:
    """Simulated time shared by the instruments: ``t0 + speed * (real seconds since start)``.

    Parameters
    ----------
    speed : float
        Simulated seconds per real second (> 0).
    t0 : float
        Simulated time at ``start``, s (negative for a lead-in before the run's t = 0).
    """

    def __init__(self, speed: float = 1.0, t0: float = 0.0):
        self.speed = float(speed)
        self.t0 = float(t0)
        self._start: float | None = None
        self._lock = threading.Lock()

    def start(self) -> None:
        """Start the clock now (the first call counts)."""
        with self._lock:
            if self._start is None:
                self._start = time.monotonic()

    def now(self) -> float:
        """Simulated time, s (``t0`` before ``start``)."""
        return self.t0 if self._start is None else self.t0 + self.speed * (time.monotonic() - self._start)

    def real_until(self, t: float) -> float:
        """Real seconds until simulated time ``t`` (<= 0 if past)."""
        return (t - self.now()) / self.speed


@dataclass(frozen=True)
class Profile:
    """One scanner profile: time (s), sweep number, scale readings D, E, F (mm), points (n, 2) u, v (mm)."""

    t: float
    scan: int
    scales: tuple[float, float, float]
    uv: np.ndarray


def profiles_from_run(run: Run) -> list[Profile]:
    """The profiles of a run: its points grouped by scan and time stamp, in time order."""
    p = run.points
    order = np.lexsort((p["t"], p["scan_id"]))
    sid, t = p["scan_id"][order], p["t"][order]
    cut = np.flatnonzero((np.diff(sid) != 0) | (np.diff(t) != 0)) + 1
    bounds = np.concatenate([[0], cut, [len(order)]])
    uv = np.column_stack([p["u"][order], p["v"][order]])
    dfe = np.column_stack([p["D"][order], p["E"][order], p["F"][order]])
    out = [Profile(float(t[a]), int(sid[a]), tuple(float(x) for x in dfe[a]), uv[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
    out.sort(key=lambda pr: pr.t)
    return out


class Disconnected(Exception):
    """Nobody has the port open (or the pty was unplugged)."""


class PtyDevice:
    """The instrument's end of a pty, optionally behind a stable symlink.

    Parameters
    ----------
    link : str or path-like, optional
        A path to keep pointing at the current pty slave.
    """

    def __init__(self, link=None):
        self.link = None if link is None else Path(link)
        self.master: int | None = None
        self.slave_name = ""
        self.plug()

    @property
    def port(self) -> str:
        """What the recorder opens: the link, or the pty slave's name."""
        return str(self.link) if self.link is not None else self.slave_name

    def plug(self) -> None:
        """Create a new pty (and point the link at it)."""
        m, s = pty.openpty()
        tty.setraw(s)
        self.slave_name = os.ttyname(s)
        os.close(s)
        os.set_blocking(m, False)
        self.master = m
        if self.link is not None:
            replace_link(self.link, self.slave_name)

    def drain(self, timeout: float = 2.0) -> None:
        """Wait until the reader has taken every byte already written (a UART
        finishing its transmission before the cable is pulled)."""
        if self.master is None or not self.slave_name:
            return
        try:
            fd = os.open(self.slave_name, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return
        try:
            end = time.monotonic() + timeout
            empty = 0  # the kernel hands bytes to the slave asynchronously: insist
            while time.monotonic() < end and empty < 5:
                time.sleep(0.01)
                queued = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
                empty = empty + 1 if queued == 0 else 0
        finally:
            os.close(fd)

    def unplug(self) -> None:
        """Close the pty: the port disappears (its reader gets an error; the link goes)."""
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()
        if self.master is not None:
            os.close(self.master)
            self.master = None

    def is_open(self) -> bool:
        """Somebody has the slave open (no hang-up on the master)."""
        if self.master is None:
            return False
        p = select.poll()
        p.register(self.master, select.POLLHUP)
        return not any(ev & select.POLLHUP for _, ev in p.poll(0))

    def wait_open(self, stop: threading.Event, settle: float = 0.2) -> bool:
        """Wait until somebody opens the port, then ``settle`` s more (the opener
        flushes its input right after opening). False if ``stop`` was set."""
        while not stop.is_set():
            if self.is_open():
                return not stop.wait(settle)
            stop.wait(0.01)
        return False

    def write(self, data: bytes, stop: threading.Event) -> None:
        """Write everything, waiting while the reader's buffer is full (flow control).

        Raises
        ------
        Disconnected
            The reader closed the port or the pty was unplugged.
        """
        view = memoryview(data)
        p = select.poll()
        p.register(self.master, select.POLLOUT | select.POLLHUP)
        while view:
            if stop.is_set():
                raise Disconnected("stopped")
            evs = p.poll(50)
            if any(ev & select.POLLHUP for _, ev in evs):
                raise Disconnected("no reader")
            if not evs:
                continue
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EAGAIN):
                    raise Disconnected(str(exc)) from None
                raise
            view = view[n:]

    def read(self, timeout: float) -> bytes:
        """Bytes from the reader (b'' after ``timeout`` s)."""
        if self.master is None:
            raise Disconnected("unplugged")
        r, _, _ = select.select([self.master], [], [], timeout)
        if not r:
            return b""
        try:
            return os.read(self.master, 65536)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise Disconnected("no reader") from None
            raise

    def close(self) -> None:
        """Close for good."""
        self.unplug()


@dataclass
class ScannerFaults:
    """Fault switches of the simulated scanner, keyed by profile index k (0, 1, ...).

    Attributes
    ----------
    garbage : dict of int -> int
        Random bytes (count) sent before profile k.
    truncate : set of int
        Profile k is cut after half its bytes (reason ``truncated``).
    corrupt : set of int
        One byte of profile k's points flipped (reason ``crc``).
    corrupt_header : set of int
        One byte of profile k's header flipped (reason ``header_crc``).
    drop : set of int
        Profile k is never sent (a sequence gap).
    reset : set of int
        The scanner restarts before profile k: sequence number 0, clock from ``boot_time``.
    unplug : dict of int -> float
        The port disappears before profile k for that many real seconds; the
        scanner keeps the profiles due meanwhile and sends them when the port
        is back and open.
    pause : dict of int -> float
        Silence of that many real seconds before profile k.
    boot_time : float
        Device clock right after a reset, s.
    seed : int
        Seed of the garbage bytes.
    """

    garbage: dict = field(default_factory=dict)
    truncate: set = field(default_factory=set)
    corrupt: set = field(default_factory=set)
    corrupt_header: set = field(default_factory=set)
    drop: set = field(default_factory=set)
    reset: set = field(default_factory=set)
    unplug: dict = field(default_factory=dict)
    pause: dict = field(default_factory=dict)
    boot_time: float = 0.5
    seed: int = 0


class _Instrument(threading.Thread):
    def __init__(self, clock: SimClock, link, settle: float):
        super().__init__(daemon=True, name=f"sim-{type(self).__name__}")
        self.clock = clock
        self.device = PtyDevice(link)
        self.settle = settle
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.finished = threading.Event()

    @property
    def port(self) -> str:
        """The port to give the recorder."""
        return self.device.port

    def stop(self, timeout: float = 10.0) -> None:
        """Stop talking and close the pty."""
        self.stop_event.set()
        if self.is_alive():
            self.join(timeout)
        self.device.close()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()


class SimScanner(_Instrument):
    """The scanner + scales: one profile record at each profile's time.

    Parameters
    ----------
    profiles : Run or list of Profile
        What to send (a run's points grouped into profiles).
    clock : SimClock, optional
        Shared simulated time (started when the port is first opened); default real time.
    link : str or path-like, optional
        Stable port name (a symlink), needed for the unplug fault.
    faults : ScannerFaults, optional
        Fault switches.
    clock_offset : float
        Device clock at simulated time 0, s.
    clock_drift_ppm : float
        Device clock rate error, parts per million.
    burst : bool
        Ignore the clock: send every profile as fast as the reader takes them.
    settle : float
        Real seconds to wait after the port is opened before talking.

    Attributes
    ----------
    sent : list of dict
        Every record sent completely and intact: ``k`` (profile index),
        ``seq``, ``time_us``, ``scan``, ``n``, ``frame`` (bytes).
    bad : list of dict
        Every record sent damaged: ``k``, ``seq``, ``fault``.
    lost : list of int
        Profiles never sent (dropped, or due while unplugged).
    """

    def __init__(self, profiles, clock: SimClock | None = None, *, link=None, faults: ScannerFaults | None = None,
                 clock_offset: float = 0.0, clock_drift_ppm: float = 0.0, burst: bool = False, settle: float = 0.2):
        super().__init__(clock or SimClock(), link, settle)
        self.profiles = profiles_from_run(profiles) if isinstance(profiles, Run) else list(profiles)
        self.faults = faults or ScannerFaults()
        self.clock_offset = clock_offset
        self.rate = 1.0 + clock_drift_ppm * 1e-6
        self.burst = burst
        self.sent: list[dict] = []
        self.bad: list[dict] = []
        self.lost: list[int] = []

    def run(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # noqa: BLE001 - tests read .error
            self.error = exc
        finally:
            self.finished.set()

    def _run(self) -> None:
        f, dev, stop = self.faults, self.device, self.stop_event
        rng = np.random.default_rng(f.seed)
        if not dev.wait_open(stop, self.settle):
            return
        self.clock.start()
        seq, zero, base = 0, 0.0, self.clock_offset  # device clock = base + rate * (t - zero)
        for k, prof in enumerate(self.profiles):
            if stop.is_set():
                return
            if k in f.unplug:
                dev.drain()
                dev.unplug()
                if stop.wait(f.unplug[k]):
                    return
                dev.plug()
                if not dev.wait_open(stop, self.settle):
                    return
            if k in f.pause and stop.wait(f.pause[k]):
                return
            if not self.burst:
                wait = self.clock.real_until(prof.t)
                if wait > 0 and stop.wait(wait):
                    return
            if k in f.reset:
                seq, zero, base = 0, prof.t, f.boot_time
            this_seq = seq
            seq += 1
            if k in f.drop:
                self.lost.append(k)
                continue
            time_us = int(round((base + self.rate * (prof.t - zero)) * 1e6))
            frame = encode_profile(this_seq, time_us, prof.scan, prof.scales, prof.uv)
            fault = None
            data = frame
            if k in f.truncate:
                data, fault = frame[: len(frame) // 2], "truncated"
            elif k in f.corrupt:
                i = 52 + int(rng.integers(0, max(1, len(frame) - 56)))
                data = bytearray(frame)
                data[i] ^= 0x5A
                data, fault = bytes(data), "crc"
            elif k in f.corrupt_header:
                data = bytearray(frame)
                data[30] ^= 0x01
                data, fault = bytes(data), "header_crc"
            if k in f.garbage:
                junk = rng.integers(0, 256, f.garbage[k], dtype=np.uint8).tobytes().replace(b"\xa5", b"\x00")
                data = junk + data
            while True:
                try:
                    dev.write(data, stop)
                    break
                except Disconnected:
                    if stop.is_set():
                        return
                    # the recorder closed the port: wait for it, this record is lost
                    self.lost.append(k)
                    if not dev.wait_open(stop, self.settle):
                        return
                    data = None
                    break
            if data is None:
                continue
            entry = {"k": k, "seq": this_seq, "time_us": time_us, "scan": prof.scan, "n": len(prof.uv)}
            if fault:
                self.bad.append({**entry, "fault": fault})
            else:
                self.sent.append({**entry, "frame": frame})


@dataclass
class LoggerFaults:
    """Fault switches of the simulated logger, keyed by the number k of the
    ``READ?`` it is asked (0, 1, ...).

    Attributes
    ----------
    mute : set of int
        No answer to READ? k (a read timeout).
    error : dict of int -> (int, str)
        READ? k fails with that SCPI error (no readings; the error is queued).
    garbage : set of int
        The answer to READ? k arrives garbled (reason ``malformed``).
    reset : set of int
        Power cycle before READ? k: clock from 0, configuration lost (READ? then
        fails with -221 until the logger is configured again).
    unplug : dict of int -> float
        The port disappears before READ? k for that many real seconds.
    """

    mute: set = field(default_factory=set)
    error: dict = field(default_factory=dict)
    garbage: set = field(default_factory=set)
    reset: set = field(default_factory=set)
    unplug: dict = field(default_factory=dict)


class SimLogger(_Instrument):
    """A thermocouple logger speaking SCPI (docs/protocols.md): readings from a
    run's temperature log, interpolated at the simulated time (held beyond its ends).

    Parameters
    ----------
    log : Run or dict
        A run (its ``temperatures``) or a log ``{"t": ..., name: ...}`` (s, degrees C).
    clock : SimClock, optional
        Shared simulated time.
    link : str or path-like, optional
        Stable port name (a symlink).
    faults : LoggerFaults, optional
        Fault switches.
    clock_offset : float
        Logger clock at simulated time 0, s (its power-up was that long before).
    clock_drift_ppm : float
        Logger clock rate error, parts per million.
    settle : float
        Real seconds to wait after the port is opened.

    Attributes
    ----------
    answered : list of dict
        Every good scan sent: ``k``, ``time`` (device s), ``sim_t`` (s), ``values``.
    commands : list of str
        Every command received.
    """

    IDN = "cmmpose,SIM-DAQ-TC,0,1.0"

    def __init__(self, log, clock: SimClock | None = None, *, link=None, faults: LoggerFaults | None = None,
                 clock_offset: float = 0.0, clock_drift_ppm: float = 0.0, settle: float = 0.2):
        super().__init__(clock or SimClock(), link, settle)
        if isinstance(log, Run):
            names = [ch["name"] for ch in log.temperature_channels]
            log = {"t": log.temperatures["t"], **{n: log.temperatures[n] for n in names}}
        self.log_t = np.asarray(log["t"], dtype=float)
        self.names = [k for k in log if k != "t"]
        self.log_v = np.column_stack([np.asarray(log[n], dtype=float) for n in self.names])
        self.faults = faults or LoggerFaults()
        self.clock_offset = clock_offset
        self.rate = 1.0 + clock_drift_ppm * 1e-6
        self.answered: list[dict] = []
        self.commands: list[str] = []
        self._power_up()
        self._zero_sim = 0.0
        self._base = clock_offset
        self.reads = 0

    def _power_up(self) -> None:
        self.scan_list: list[int] = []
        self.tc_type = None
        self.time_on = False
        self.errors: list[tuple[int, str]] = []

    def device_time(self) -> float:
        """The logger's clock now, s since power-up."""
        return self._base + self.rate * (self.clock.now() - self._zero_sim)

    def values(self, t: float) -> np.ndarray:
        """Readings of the scan list's channels at simulated time t, degrees C."""
        v = np.array([np.interp(t, self.log_t, self.log_v[:, j]) for j in range(self.log_v.shape[1])])
        return v[[c - 101 for c in self.scan_list if 0 <= c - 101 < len(v)]]

    def run(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # noqa: BLE001
            self.error = exc
        finally:
            self.finished.set()

    def _run(self) -> None:
        dev, stop = self.device, self.stop_event
        if not dev.wait_open(stop, self.settle):
            return
        self.clock.start()
        pending = bytearray()
        while not stop.is_set():
            try:
                data = dev.read(0.05)
            except Disconnected:
                if not dev.wait_open(stop, self.settle):
                    return
                pending.clear()
                continue
            if not data:
                if not dev.is_open():
                    pending.clear()
                    if not dev.wait_open(stop, self.settle):
                        return
                continue
            pending += data
            while b"\n" in pending:
                k = pending.index(b"\n")
                line = bytes(pending[:k]).decode("ascii", "replace").strip()
                del pending[: k + 1]
                reply = self._message(line)
                if reply is None:
                    continue
                try:
                    dev.write(reply.encode("ascii", "replace") + b"\n", stop)
                except Disconnected:
                    pending.clear()
                    break

    def _message(self, line: str) -> str | None:
        """Execute one line of commands; the answer line or None."""
        answers: list[str] = []
        for cmd in line.split(";"):
            cmd = cmd.strip().lstrip(":")
            if not cmd:
                continue
            self.commands.append(cmd)
            head, _, arg = cmd.partition(" ")
            head = head.upper()
            if head == "READ?":
                out = self._read()
                if out == "":
                    return None  # muted: no answer at all
                if out is not None:
                    answers.append(out)
            elif head == "*IDN?":
                answers.append(self.IDN)
            elif head == "*RST":
                self.scan_list, self.tc_type, self.time_on = [], None, False
            elif head == "*CLS":
                self.errors.clear()
            elif head in ("SYST:ERR?", "SYSTEM:ERROR?", "SYST:ERR:NEXT?"):
                code, msg = self.errors.pop(0) if self.errors else (0, "No error")
                answers.append(f"{code:+d},\"{msg}\"")
            elif head in ("CONF:TEMP", "CONFIGURE:TEMPERATURE"):
                parts = [p.strip() for p in arg.split(",", 2)]
                if len(parts) != 3 or parts[0].upper() != "TC" or not parts[2].startswith("(@"):
                    self.errors.append((-224, "Illegal parameter value"))
                else:
                    self.tc_type = parts[1].upper()
                    self.scan_list = _channels(parts[2])
            elif head == "UNIT:TEMP":
                if arg.strip().upper() not in ("C", "CEL"):
                    self.errors.append((-224, "Illegal parameter value"))
            elif head == "FORM:READ:TIME":
                self.time_on = arg.strip().upper() in ("ON", "1")
            elif head == "FORM:READ:TIME:TYPE":
                if arg.strip().upper() != "REL":
                    self.errors.append((-224, "Illegal parameter value"))
            elif head == "ROUT:SCAN":
                self.scan_list = _channels(arg.strip())
            else:
                self.errors.append((-113, "Undefined header"))
        return ";".join(answers) if answers else None

    def _read(self) -> str | None:
        k = self.reads
        self.reads += 1
        f = self.faults
        if k in f.unplug:
            self.device.drain()
            self.device.unplug()
            self.stop_event.wait(f.unplug[k])
            self.device.plug()
            return ""
        if k in f.reset:
            self._power_up()
            self._zero_sim, self._base = self.clock.now(), 0.0
        if k in f.mute:
            return ""
        if k in f.error:
            self.errors.append(tuple(f.error[k]))
            return None
        if not self.scan_list or self.tc_type is None:
            self.errors.append((-221, "Settings conflict, no thermocouple scan configured"))
            return None
        t_sim = self.clock.now()
        dev_t = self.device_time()
        vals = self.values(t_sim)
        fields = []
        for j, v in enumerate(vals):
            fields.append(f"{v:+.6E}")
            if self.time_on:
                fields.append(f"{dev_t + 0.001 * j:+.4f}")
        text = ",".join(fields)
        if k in f.garbage:
            return text[:20] + "\x07#~" + text[25:]
        self.answered.append({"k": k, "time": dev_t, "sim_t": t_sim, "values": vals})
        return text


def _channels(text: str) -> list[int]:
    """SCPI channel list ``(@101:111)`` or ``(@101,102)`` as channel numbers."""
    body = text.strip()
    if not (body.startswith("(@") and body.endswith(")")):
        return []
    out: list[int] = []
    for part in body[2:-1].split(","):
        a, _, b = part.partition(":")
        try:
            lo, hi = int(a), int(b or a)
        except ValueError:
            return []
        out.extend(range(lo, hi + 1))
    return out


def synthetic_profiles(count: int, points: int = 1024, rate: float = 6.6, *, per_scan: int = 50, seed: int = 0) -> list[Profile]:
    """Profiles of random points for rate tests: ``count`` profiles of ``points``
    points, ``rate`` profiles per simulated second, a new sweep every ``per_scan``.

    Parameters
    ----------
    count : int
        Profiles.
    points : int
        Points per profile (Hyscan: up to 1024).
    rate : float
        Profiles per second, Hz (Hyscan bidirectional: 6.6).
    per_scan : int
        Profiles per sweep.
    seed : int
        Seed of the points.
    """
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-30.0, 30.0, (count, points, 2)).astype(np.float32)
    return [Profile(k / rate, k // per_scan, (100.0 + 0.35 * k, 275.0, -250.0), uv[k]) for k in range(count)]


def main(argv=None) -> None:
    """``python -m cmmpose.sim.instruments RUN_DIR [--speed S] [--link-dir DIR]``: play a run."""
    import argparse

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("run_dir")
    ap.add_argument("--speed", type=float, default=1.0, help="simulated seconds per real second")
    ap.add_argument("--link-dir", default=None, help="make stable port names DIR/scanner and DIR/thermo")
    args = ap.parse_args(argv)
    run = Run.load(args.run_dir)
    clock = SimClock(args.speed, t0=-2.0)
    links = (None, None) if args.link_dir is None else (Path(args.link_dir) / "scanner", Path(args.link_dir) / "thermo")
    scanner = SimScanner(run, clock, link=links[0])
    logger = SimLogger(run, clock, link=links[1])
    plan = Path(args.run_dir) / "plan.json"
    plan_from_run(run).write(plan)
    scanner.start()
    logger.start()
    print(f"scanner: {scanner.port}\nthermo:  {logger.port}\nplan:    {plan}", flush=True)
    print(f"cmmpose acquire --scanner {scanner.port} --thermo {logger.port} --plan {plan} -o RUN_OUT", flush=True)
    try:
        while scanner.is_alive():
            scanner.join(0.5)
        time.sleep(3.0 / args.speed + 1.0)
    except KeyboardInterrupt:
        pass
    scanner.stop()
    logger.stop()


if __name__ == "__main__":
    main()
