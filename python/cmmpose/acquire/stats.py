"""Live counters of a recording, shared by the readers, the writer and the display."""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field

__all__ = ["StreamStats", "Stats", "Snapshot"]


@dataclass
class StreamStats:
    """Counters of one stream (scanner or thermo).

    Attributes
    ----------
    records : int
        Good records kept.
    points : int
        Points in them (scanner).
    rejected : Counter
        Rejected records (or skipped byte runs) by reason.
    garbage_bytes : int
        Bytes skipped that belonged to no record.
    gaps, missing : int
        Sequence gaps and the sequence numbers they skipped.
    resets, reconnects, timeouts : int
        Device restarts, port reconnections, read timeouts.
    connected : bool
        Port open now.
    port : str
        The port URL.
    last_error : str
        The latest port error.
    """

    port: str = ""
    records: int = 0
    points: int = 0
    bytes: int = 0
    rejected: Counter = field(default_factory=Counter)
    garbage_bytes: int = 0
    gaps: int = 0
    missing: int = 0
    resets: int = 0
    reconnects: int = 0
    timeouts: int = 0
    connected: bool = False
    last_error: str = ""
    backpressure_s: float = 0.0
    _times: deque = field(default_factory=lambda: deque(maxlen=4096), repr=False)

    def rate(self, window: float = 2.0, now: float | None = None) -> float:
        """Good records per second over the last ``window`` s."""
        now = time.monotonic() if now is None else now
        n = sum(1 for t in self._times if t >= now - window)
        return n / window


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of the counters for display and reports."""

    scanner: dict
    thermo: dict
    latest_temperatures: dict
    flush_age: float | None
    blocks: int
    journal_bytes: int
    buffer_bytes: int
    buffer_high_water: int
    buffer_capacity: int
    backpressure_stalls: int
    backpressure_seconds: float
    elapsed: float


class Stats:
    """Thread-safe counters of both streams and of the journal."""

    def __init__(self):
        self.lock = threading.Lock()
        self.scanner = StreamStats()
        self.thermo = StreamStats()
        self.latest_temperatures: dict[str, float] = {}
        self.last_flush: float | None = None
        self.blocks = 0
        self.journal_bytes = 0
        self.started = time.monotonic()

    def good(self, stream: StreamStats, nbytes: int, points: int = 0) -> None:
        """Count a good record."""
        with self.lock:
            stream.records += 1
            stream.points += points
            stream.bytes += nbytes
            stream._times.append(time.monotonic())

    def snapshot(self, buffer) -> Snapshot:
        """Copy of everything, with the buffer's fill and backpressure."""
        now = time.monotonic()
        with self.lock:
            def d(s: StreamStats) -> dict:
                return {
                    "port": s.port, "records": s.records, "points": s.points, "bytes": s.bytes,
                    "rate": s.rate(now=now), "rejected": dict(s.rejected), "rejected_total": sum(s.rejected.values()),
                    "garbage_bytes": s.garbage_bytes, "gaps": s.gaps, "missing": s.missing, "resets": s.resets,
                    "reconnects": s.reconnects, "timeouts": s.timeouts, "connected": s.connected,
                    "last_error": s.last_error, "backpressure_s": s.backpressure_s,
                }
            return Snapshot(
                scanner=d(self.scanner), thermo=d(self.thermo),
                latest_temperatures=dict(self.latest_temperatures),
                flush_age=None if self.last_flush is None else now - self.last_flush,
                blocks=self.blocks, journal_bytes=self.journal_bytes,
                buffer_bytes=buffer.nbytes, buffer_high_water=buffer.high_water, buffer_capacity=buffer.capacity,
                backpressure_stalls=buffer.stalls, backpressure_seconds=buffer.stall_seconds,
                elapsed=now - self.started,
            )
