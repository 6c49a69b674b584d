"""Port readers: one thread per instrument, reading through pyserial (any URL
``serial.serial_for_url`` accepts: a device path, ``socket://host:port``,
``rfc2217://host:port``, a pty), reconnecting with backoff when the port
fails, and handing good records and events to the recorder's sink."""

from __future__ import annotations

import struct
import threading
import time

import serial

from ..errors import AcquisitionError
from . import scpi
from .clock import host_time
from .protocol import FrameParser
from .sequence import SequenceTracker
from .store import SCANNER, THERMO, thermo_data

__all__ = ["open_port", "ScannerReader", "ThermoReader"]

_PORT_ERRORS = (serial.SerialException, OSError, ValueError)


def open_port(url: str, *, baudrate: int, timeout: float) -> serial.SerialBase:
    """Open ``url`` with pyserial, 8N1, no flow control.

    Parameters
    ----------
    url : str
        Device path or pyserial URL.
    baudrate : int
        Line speed, bit/s (ignored by ptys and sockets).
    timeout : float
        Read timeout, s.

    Raises
    ------
    AcquisitionError
        Naming the port, when it cannot be opened.
    """
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, write_timeout=max(timeout, 1.0))
    except _PORT_ERRORS as exc:
        raise AcquisitionError(f"{url}: cannot open the port ({exc})") from None


class _Reconnect(Exception):
    """Close the port and open it again (the device stopped answering)."""


class _PortReader(threading.Thread):
    """Open, read, and on failure close and reopen with exponential backoff."""

    stream = ""
    #: First and largest wait between reconnection attempts, s.
    BACKOFF = (0.05, 2.0)

    def __init__(self, url: str, sink, stop: threading.Event, *, baudrate: int, timeout: float):
        super().__init__(name=f"cmmpose-{self.stream}", daemon=True)
        self.url = url
        self.sink = sink
        self.stop = stop
        self.baudrate = baudrate
        self.timeout = timeout
        self.stats = getattr(sink.stats, self.stream)
        self.stats.port = url
        self.error: BaseException | None = None
        self._port = open_port(url, baudrate=baudrate, timeout=self.poll_timeout)
        self._set_connected(True)

    poll_timeout = 0.1

    def _set_connected(self, value: bool, why: str = "") -> None:
        with self.sink.stats.lock:
            self.stats.connected = value
            if why:
                self.stats.last_error = why

    def run(self) -> None:
        try:
            port = self._port
            wait = self.BACKOFF[0]
            while True:
                with self.sink.stats.lock:
                    before = self.stats.records
                try:
                    self.session(port)
                except (_Reconnect, *_PORT_ERRORS) as exc:
                    why = str(exc) or type(exc).__name__
                    self._set_connected(False, why)
                    self.sink.event(self.stream, "disconnected", port=self.url, error=why)
                finally:
                    self.ended(port)
                    try:
                        port.close()
                    except _PORT_ERRORS:
                        pass
                if self.stop.is_set():
                    return
                with self.sink.stats.lock:
                    if self.stats.records > before:
                        wait = self.BACKOFF[0]  # the connection delivered records: start the backoff over
                port, wait = self._reopen(wait)
                if port is None:
                    return
        except BaseException as exc:  # noqa: BLE001 - reported by the recorder
            self.error = exc
            self.sink.event(self.stream, "reader_failed", port=self.url, error=repr(exc))

    def _reopen(self, wait: float):
        """Wait, then open the port again, the wait doubling (up to ``BACKOFF[1]``)
        after every failed attempt. Every reconnect waits: a device that accepts
        the connection but fails every session (a configuration it rejects) is
        retried at the backoff's pace, never in a tight loop.

        Returns
        -------
        (port, wait)
            The open port (None when stopped) and the wait before the next reconnect, s.
        """
        top = self.BACKOFF[1]
        attempts = 0
        while not self.stop.wait(wait):
            wait = min(2 * wait, top)
            attempts += 1
            try:
                port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.poll_timeout,
                                             write_timeout=max(self.timeout, 1.0))
            except _PORT_ERRORS as exc:
                self._set_connected(False, str(exc))
                continue
            with self.sink.stats.lock:
                self.stats.reconnects += 1
            self._set_connected(True)
            self.sink.event(self.stream, "reconnected", port=self.url, attempts=attempts)
            return port, wait
        return None, wait

    def session(self, port) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def ended(self, port) -> None:
        """Called when a connection ends (before closing)."""


class ScannerReader(_PortReader):
    """Reads profile frames (``protocol``), checks sequence numbers, journals
    every good frame with its host receive time.

    Parameters
    ----------
    url : str
        The scanner's port.
    sink : Recorder
        Where records and events go (``put``, ``event``, ``stats``).
    stop : threading.Event
        Set to end the thread.
    baudrate : int
        bit/s.
    timeout : float
        Silence longer than this many seconds is counted as a read timeout.
    """

    stream = "scanner"

    def __init__(self, url, sink, stop, *, baudrate: int = 921600, timeout: float = 2.0):
        super().__init__(url, sink, stop, baudrate=baudrate, timeout=timeout)
        self.tracker = SequenceTracker()
        self._parser: FrameParser | None = None

    def session(self, port) -> None:
        parser = self._parser = FrameParser()
        last_data = time.monotonic()
        silent_reported = False
        st, sink = self.stats, self.sink
        stopping_since = None
        while True:
            if self.stop.is_set():
                # stop at the next record boundary (or when the port is quiet)
                stopping_since = stopping_since or time.monotonic()
                if parser.pending == 0 or time.monotonic() - stopping_since > 2.0:
                    return
            data = port.read(1)
            now = time.monotonic()
            if self.stop.is_set() and not data:
                return  # stopped, and the port is drained
            if not data:
                if not silent_reported and now - last_data > self.timeout:
                    silent_reported = True
                    with sink.stats.lock:
                        st.timeouts += 1
                    sink.event(self.stream, "timeout", port=self.url, silent_s=round(now - last_data, 3))
                continue
            failure = None
            try:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(waiting)
            except _PORT_ERRORS as exc:
                failure = exc  # keep what was read, then report the failure
            host = host_time()
            last_data, silent_reported = now, False
            frames, rejections = parser.feed(data)
            for r in rejections:
                self._reject(r)
            for frame in frames:
                seq, time_us = struct.unpack_from("<IQ", frame, 4)
                step = self.tracker.step(seq, time_us)
                if step.kind == "duplicate":
                    self._count_reject("duplicate", seq=seq, nbytes=len(frame))
                    continue
                if step.kind == "gap":
                    with sink.stats.lock:
                        st.gaps += 1
                        st.missing += step.missing
                    sink.event(self.stream, "gap", port=self.url, after=seq - step.missing - 1, seq=seq, missing=step.missing)
                elif step.kind == "reset":
                    with sink.stats.lock:
                        st.resets += 1
                    sink.event(self.stream, "reset", port=self.url, seq=seq, device_time_us=time_us)
                n = struct.unpack_from("<H", frame, 20)[0]
                sink.put(SCANNER, host, frame, st, points=n)
            if failure is not None:
                raise failure

    def ended(self, port) -> None:
        if self._parser is not None:
            for r in self._parser.flush():
                self._reject(r)
            self._parser = None

    def _reject(self, r) -> None:
        if r.reason == "garbage":
            with self.sink.stats.lock:
                self.stats.garbage_bytes += r.nbytes
        self._count_reject(r.reason, seq=r.seq, nbytes=r.nbytes, offset=r.offset)

    def _count_reject(self, reason: str, **info) -> None:
        with self.sink.stats.lock:
            self.stats.rejected[reason] += 1
        self.sink.event(self.stream, "rejected", port=self.url, reason=reason, **{k: v for k, v in info.items() if v is not None})


class ThermoReader(_PortReader):
    """Configures the logger (``scpi.configure_commands``) and polls it every
    ``interval`` seconds; journals every good scan with its host send and
    receive times.

    Parameters
    ----------
    url : str
        The logger's port.
    sink : Recorder
        Where records and events go.
    stop : threading.Event
        Set to end the thread.
    channels : sequence of (str, int)
        Channel name and multiplexer channel number, in scan order.
    tc_type : str
        Thermocouple type.
    interval : float
        Seconds between polls.
    baudrate : int
        bit/s.
    timeout : float
        Seconds to wait for an answer.
    retries : int
        Consecutive timeouts after which the port is reopened and the logger reconfigured.
    """

    stream = "thermo"

    def __init__(self, url, sink, stop, *, channels, tc_type: str = "E", interval: float = 1.0,
                 baudrate: int = 9600, timeout: float = 2.0, retries: int = 3):
        if not isinstance(tc_type, str) or tc_type.upper() not in scpi.TC_TYPES:
            raise AcquisitionError(f"{url}: thermocouple type {tc_type!r} is not one of {', '.join(scpi.TC_TYPES)}")
        self.channels = list(channels)
        self.tc_type = tc_type
        self.interval = interval
        self.retries = retries
        self.tracker = SequenceTracker()
        self._pending = bytearray()
        super().__init__(url, sink, stop, baudrate=baudrate, timeout=timeout)

    def _readline(self, port, timeout: float) -> bytes | None:
        """One line (without LF), or None after ``timeout`` s (partial bytes are kept)."""
        deadline = time.monotonic() + timeout
        buf = self._pending
        while True:
            k = buf.find(b"\n")
            if k >= 0:
                line = bytes(buf[:k])
                del buf[: k + 1]
                return line.rstrip(b"\r")
            left = deadline - time.monotonic()
            if left <= 0:
                return None  # an answer already asked for is awaited even while stopping
            port.timeout = min(left, self.poll_timeout)
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                buf += chunk

    def _query(self, port, text: str) -> tuple[float, float, bytes | None]:
        tx = host_time()
        port.write(text.encode("ascii") + b"\n")
        line = self._readline(port, self.timeout)
        return tx, host_time(), line

    def _configure(self, port) -> bool:
        """Send the configuration; True when the logger reports no error."""
        self._pending.clear()
        port.reset_input_buffer()
        cmds = scpi.configure_commands([c for _, c in self.channels], self.tc_type)
        for cmd in cmds[:-1]:
            port.write(cmd.encode("ascii") + b"\n")
        _, _, line = self._query(port, cmds[-1])
        if line is None:
            self._timeout(port, cmds[-1])
            return False
        try:
            code, msg = scpi.parse_error(line.decode("ascii", "replace"))
        except ValueError as exc:
            self._reject("malformed", command=cmds[-1], detail=str(exc))
            return False
        if code != 0:
            self._reject("scpi_error", command="configure", code=code, message=msg)
            self._drain(port)
            return False
        self.sink.event(self.stream, "configured", port=self.url, channels=[c for _, c in self.channels], tc_type=self.tc_type)
        return True

    def _drain(self, port) -> None:
        """Empty the logger's error queue (each entry is logged)."""
        for _ in range(20):
            _, _, line = self._query(port, scpi.ERROR_QUERY)
            if line is None:
                return
            try:
                code, msg = scpi.parse_error(line.decode("ascii", "replace"))
            except ValueError:
                return
            if code == 0:
                return
            self.sink.event(self.stream, "scpi_error_queue", port=self.url, code=code, message=msg)

    def _timeout(self, port, command: str) -> None:
        with self.sink.stats.lock:
            self.stats.timeouts += 1
        partial = bytes(self._pending)
        self._pending.clear()
        port.reset_input_buffer()
        self.sink.event(self.stream, "timeout", port=self.url, command=command, timeout_s=self.timeout,
                        partial=partial[:80].decode("ascii", "replace"))

    def _reject(self, reason: str, **info) -> None:
        with self.sink.stats.lock:
            self.stats.rejected[reason] += 1
        self.sink.event(self.stream, "rejected", port=self.url, reason=reason, **info)

    def session(self, port) -> None:
        failures = 0
        configured = False
        next_poll = time.monotonic()
        names = [n for n, _ in self.channels]
        while not self.stop.is_set():
            if not configured:
                configured = self._configure(port)
                if not configured:
                    failures += 1
                    if failures >= self.retries:
                        raise _Reconnect(f"{self.url}: logger not configured after {failures} attempts")
                    self.stop.wait(min(self.interval, 1.0))
                    continue
                failures = 0
            now = time.monotonic()
            if now < next_poll:
                self.stop.wait(next_poll - now)
                continue
            next_poll = max(next_poll + self.interval, now)
            tx, rx, line = self._query(port, scpi.POLL)
            if line is None:
                if self.stop.is_set():
                    return
                self._timeout(port, scpi.POLL)
                failures += 1
                if failures >= self.retries:
                    raise _Reconnect(f"{self.url}: no answer to {failures} polls")
                continue
            failures = 0
            try:
                text = line.decode("ascii")
            except UnicodeDecodeError as exc:
                self._reject("malformed", detail=f"byte {line[exc.start]:#04x} at column {exc.start + 1} is not ASCII")
                self._pending.clear()
                port.reset_input_buffer()
                continue
            reply = scpi.parse_reply(text, len(self.channels))
            if reply.reason == "scpi_error":
                self._reject("scpi_error", code=reply.error_code, message=reply.error_message)
                self._drain(port)
                configured = False
                continue
            if reply.reason is not None:
                self._reject(reply.reason, detail=reply.detail, line=text[:120])
                self._pending.clear()
                port.reset_input_buffer()
                continue
            scan = reply.scan
            step = self.tracker.step(None, scan.times[0])
            if step.kind == "reset":
                with self.sink.stats.lock:
                    self.stats.resets += 1
                self.sink.event(self.stream, "reset", port=self.url, device_time_s=scan.times[0])
            with self.sink.stats.lock:
                self.sink.stats.latest_temperatures = dict(zip(names, scan.values))
            self.sink.put(THERMO, rx, thermo_data(tx, text), self.stats)
