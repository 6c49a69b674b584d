"""Host and device clocks: the host time stamp of every received record, and
the fit of each instrument's clock to the host's, from which the offset and
drift between the two instruments follow (docs/protocols.md, "Clocks").

A record stamped ``d`` by its device reaches the host at ``h = c + r d + L``:
``c`` the offset, ``r`` the rate (host seconds per device second, 1 + drift)
and ``L >= 0`` the transmission and scheduling latency. Latency only ever
delays, so the fit is of the lower envelope: least squares, then again on the
records at or below the median residual, a few times, which converges to the
least-delayed records (as NTP-style offset estimators do).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["host_time", "ClockFit", "fit_clock", "fit_with_rate"]

_WALL0 = time.time()
_MONO0 = time.monotonic()


def host_time() -> float:
    """Host time, s since the Unix epoch, from the monotonic clock (never steps back)."""
    return _WALL0 + (time.monotonic() - _MONO0)


@dataclass(frozen=True)
class ClockFit:
    """``host = offset + rate * device`` for one clock segment.

    Attributes
    ----------
    offset : float
        Host time at device time 0, s.
    rate : float
        Host seconds per device second (1 + drift).
    records : int
        Records the fit used.
    span : float
        Device time covered, s.
    residual_rms : float
        RMS of the residuals of the envelope records, s.
    latency_median : float
        Median delay of all records above the envelope, s.
    rate_fitted : bool
        False when the segment was too short and the rate was borrowed.
    """

    offset: float
    rate: float
    records: int
    span: float
    residual_rms: float
    latency_median: float
    rate_fitted: bool = True

    def host(self, device):
        """Host time (s) of device time(s) ``device`` (s)."""
        return self.offset + self.rate * np.asarray(device, dtype=float)

    def device(self, host):
        """Device time (s) of host time(s) ``host`` (s)."""
        return (np.asarray(host, dtype=float) - self.offset) / self.rate

    def to_dict(self) -> dict:
        """JSON-ready dict (drift in ppm added)."""
        d = asdict(self)
        d["drift_ppm"] = (self.rate - 1.0) * 1e6
        return d


#: Shortest device-time span over which a rate is fitted, s.
MIN_SPAN = 2.0
#: Fewest records for a fitted rate.
MIN_RECORDS = 5


def fit_clock(device, host, *, iterations: int = 6) -> ClockFit:
    """Fit ``host = offset + rate * device`` to the least-delayed records.

    Parameters
    ----------
    device : array_like, shape (K,)
        Device time stamps, s.
    host : array_like, shape (K,)
        Host receive times, s.
    iterations : int
        Envelope refinements (each keeps the records at or below the median residual).

    Returns
    -------
    ClockFit
        With ``rate_fitted`` False (rate 1) when there are fewer than
        ``MIN_RECORDS`` records or they span less than ``MIN_SPAN`` s;
        use ``fit_with_rate`` with another segment's rate then.
    """
    d = np.asarray(device, dtype=float)
    h = np.asarray(host, dtype=float)
    if len(d) < MIN_RECORDS or np.ptp(d) < MIN_SPAN:
        return fit_with_rate(d, h, 1.0, fitted=False)
    d0, h0 = d[0], h[0]
    x = d - d0
    h = h - h0
    keep = np.ones(len(d), dtype=bool)
    slope, icpt = 1.0, 0.0
    for _ in range(iterations):
        slope, icpt = np.polyfit(x[keep], h[keep], 1)
        res = h - (icpt + slope * x)
        nxt = keep & (res <= np.median(res[keep]))
        if nxt.sum() < MIN_RECORDS or np.ptp(x[nxt]) < MIN_SPAN / 2:
            break
        keep = nxt
    res = h - (icpt + slope * x)
    shift = float(np.min(res[keep]))  # the envelope touches the least-delayed record
    return ClockFit(
        offset=float(h0 + icpt + shift - slope * d0),
        rate=float(slope),
        records=int(len(d)),
        span=float(np.ptp(d)),
        residual_rms=float(np.sqrt(np.mean((res[keep] - shift) ** 2))),
        latency_median=float(np.median(res - shift)),
    )


def fit_with_rate(device, host, rate: float, *, fitted: bool = False) -> ClockFit:
    """Offset only, with a known ``rate``: the least-delayed record sets it.

    Parameters
    ----------
    device, host : array_like, shape (K,), K >= 1
        Device and host times, s.
    rate : float
        Host seconds per device second.
    fitted : bool
        Stored as ``rate_fitted``.
    """
    d = np.asarray(device, dtype=float)
    h = np.asarray(host, dtype=float)
    lat = h - rate * d
    off = float(np.min(lat)) if len(d) else 0.0
    return ClockFit(off, float(rate), int(len(d)), float(np.ptp(d)) if len(d) else 0.0, 0.0,
                    float(np.median(lat - off)) if len(d) else 0.0, fitted)
