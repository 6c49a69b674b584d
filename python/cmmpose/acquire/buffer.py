"""The bounded buffer between the port readers and the journal writer.

Readers put encoded records; the writer takes everything at each flush. The
buffer holds at most ``capacity`` bytes: a reader that would overfill it waits
(it stops reading its port, so the port's own buffer and, on a real line, the
device's flow control hold the data instead) and the wait is reported as
backpressure. Events (small) never wait, so a stalled reader can still log.
"""

from __future__ import annotations

import threading
import time

__all__ = ["BoundedBuffer"]


class BoundedBuffer:
    """Byte-bounded FIFO of encoded journal records.

    Parameters
    ----------
    capacity : int
        Largest number of buffered bytes (a single record larger than this is
        still accepted when the buffer is empty).
    """

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self._items: list[bytes] = []
        self._bytes = 0
        self._cond = threading.Condition()
        self.high_water = 0
        self.stalls = 0
        self.stall_seconds = 0.0
        self._closed = False

    @property
    def nbytes(self) -> int:
        """Bytes held now."""
        return self._bytes

    def put(self, item: bytes, *, force: bool = False, stop: threading.Event | None = None) -> float:
        """Append one record, waiting while the buffer is full.

        Parameters
        ----------
        item : bytes
            An encoded record.
        force : bool
            Never wait (for small event records).
        stop : threading.Event, optional
            Give up waiting when set (the record is then still appended).

        Returns
        -------
        float
            Seconds waited (0 when there was room): the backpressure.
        """
        n = len(item)
        waited = 0.0
        with self._cond:
            if not force and self._bytes and self._bytes + n > self.capacity:
                t0 = time.monotonic()
                self.stalls += 1
                while self._bytes and self._bytes + n > self.capacity and not self._closed:
                    if stop is not None and stop.is_set():
                        break
                    self._cond.wait(0.05)
                waited = time.monotonic() - t0
                self.stall_seconds += waited
            self._items.append(item)
            self._bytes += n
            self.high_water = max(self.high_water, self._bytes)
            self._cond.notify_all()
        return waited

    def take(self, timeout: float, min_bytes: int = 1) -> list[bytes]:
        """Everything buffered, after waiting up to ``timeout`` s for at least
        ``min_bytes`` bytes (or for ``close``)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._bytes < min_bytes and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            items, self._items, self._bytes = self._items, [], 0
            self._cond.notify_all()
            return items

    def close(self) -> None:
        """No more waiting: pending and future puts go through."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
