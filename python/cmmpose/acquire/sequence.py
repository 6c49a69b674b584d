"""Sequence numbers and device clocks of a stream: gaps, resets and clock
segments. The recorder uses it live (to count and log) and the assembly uses
it again on the journal (to split the clock fits), so both agree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SequenceTracker", "SeqStep", "segments"]


@dataclass(frozen=True)
class SeqStep:
    """What one record means for the stream.

    Attributes
    ----------
    kind : str
        ``first``, ``next`` (the expected number), ``gap`` (numbers skipped),
        ``reset`` (the number or the device clock went back: the device
        restarted) or ``duplicate`` (the same number and time again).
    missing : int
        Sequence numbers skipped (``gap``), never invented.
    segment : int
        Clock segment of the record: 0 until the first reset, then 1, ...
    """

    kind: str
    missing: int
    segment: int


class SequenceTracker:
    """Follows (sequence number, device time) of a stream record by record."""

    def __init__(self):
        self.last: tuple[int, int] | None = None
        self.segment = 0
        self.gaps = 0
        self.missing = 0
        self.resets = 0

    def step(self, seq: int, time: int | float) -> SeqStep:
        """Classify the next record.

        Parameters
        ----------
        seq : int or None
            Its sequence number (None for streams without one: only the clock counts).
        time : int or float
            Its device time stamp (any unit, increasing while the device runs).
        """
        last = self.last
        if last is None:
            self.last = (seq, time)
            return SeqStep("first", 0, self.segment)
        lseq, ltime = last
        if seq is not None and seq == lseq and time == ltime:
            return SeqStep("duplicate", 0, self.segment)
        self.last = (seq, time)
        if time < ltime or (seq is not None and seq <= lseq):
            self.segment += 1
            self.resets += 1
            return SeqStep("reset", 0, self.segment)
        if seq is not None and seq > lseq + 1:
            k = seq - lseq - 1
            self.gaps += 1
            self.missing += k
            return SeqStep("gap", k, self.segment)
        return SeqStep("next", 0, self.segment)


def segments(seq, time) -> tuple[np.ndarray, np.ndarray]:
    """Clock segment and step kind of every record of a stream, in arrival order.

    Parameters
    ----------
    seq : array_like of int or None
        Sequence numbers (None: the stream has none).
    time : array_like
        Device time stamps.

    Returns
    -------
    segment : ndarray of int
        Clock segment per record.
    keep : ndarray of bool
        False for duplicates.
    """
    tr = SequenceTracker()
    time = list(time)
    seq = [None] * len(time) if seq is None else [int(s) for s in seq]
    seg = np.empty(len(time), dtype=np.int64)
    keep = np.ones(len(time), dtype=bool)
    for i, (s, t) in enumerate(zip(seq, time)):
        st = tr.step(s, t)
        seg[i] = st.segment
        keep[i] = st.kind != "duplicate"
    return seg, keep
