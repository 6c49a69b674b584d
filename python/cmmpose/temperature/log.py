"""The thermocouple log's checks: :func:`check_log` finds what is wrong with
a log (gaps in time, stuck channels, open-circuit or implausible readings,
NaN) and gives a clean mask per channel and sample (:class:`LogReport`,
:class:`LogProblem`); :func:`check_log_coverage` refuses points beyond the
hold at the log's ends; :func:`read_log` checks and converts a log
(docs/thermal.md).

Units: times in s, temperatures in degrees C, temperature differences in K.
Rows in messages are counted from 0.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .._lazy import LazyModule
from ..errors import InputError

# The run format loads on first use (tests/compensation/test_pipeline_and_import_footprint.py).
_run = LazyModule("cmmpose.run")

__all__ = ["check_log", "check_log_coverage", "LogProblem", "LogReport", "LogColumns", "read_log", "PLAUSIBLE",
           "STUCK_AFTER", "STUCK_TOLERANCE", "GAP_FACTOR", "OPEN_CIRCUIT_ABOVE"]

#: Default plausible range of a machine thermocouple reading, degrees C.
PLAUSIBLE = (0.0, 50.0)
#: Default: a channel flat for longer than this while others vary is stuck, s.
STUCK_AFTER = 300.0
#: Default: readings within this of each other count as constant, K.
STUCK_TOLERANCE = 1e-3
#: Default ``max_gap`` is this many times the median sample spacing.
GAP_FACTOR = 5.0
#: Readings this far from any room (|T| >= this, degrees C) are reported as an
#: open circuit (a data logger's burn-out value such as 999.9 C) rather than
#: merely implausible.
OPEN_CIRCUIT_ABOVE = 500.0
_KIND_LABEL = {"gap": "gap", "stuck": "stuck", "open_circuit": "open circuit", "implausible": "implausible",
               "nan": "NaN"}
#: More runs than this of one kind on one channel are reported as one problem.
_MAX_RUNS_LISTED = 20


def check_log_coverage(run, t, log_hold: float) -> None:
    """Raise ``InputError`` if a point lies more than ``log_hold`` s outside
    the run's thermocouple log, naming the first such row and time.

    Parameters
    ----------
    run : Run
        The run whose ``temperatures['t']`` (s) is the log.
    t : array_like, shape (N,)
        The points' time stamps, s.
    log_hold : float
        How far outside the log a point may lie, s.
    """
    lt = np.asarray(run.temperatures["t"], dtype=float)
    t = np.asarray(t, dtype=float)
    if not len(lt) or not len(t):
        return
    far = (t < lt[0] - log_hold) | (t > lt[-1] + log_hold)
    if np.any(far):
        i = int(np.argmax(far))
        gap = lt[0] - t[i] if t[i] < lt[0] else t[i] - lt[-1]
        raise InputError(f"point row {i}: t = {t[i]:g} s is {gap:.1f} s outside the temperature log "
                         f"({lt[0]:g}..{lt[-1]:g} s), more than the {log_hold:g} s held at its ends",
                         row=i, value=float(t[i]), unit="s", option="log_hold", remedy="log_hold")


# -- the report ---------------------------------------------------------------------
@dataclass(frozen=True)
class LogProblem:
    """One problem found in a thermocouple log.

    Attributes
    ----------
    channel : str
        The channel's name; ``'t'`` for a gap in time (which affects every
        channel).
    kind : str
        ``'gap'`` (sample spacing above ``max_gap``), ``'stuck'`` (constant
        while the others vary), ``'open_circuit'`` (a burn-out reading such as
        999.9 C), ``'implausible'`` (outside the plausible range) or ``'nan'``
        (NaN or infinite).
    start, end : float
        First and last affected sample time, s; for a gap the two samples
        around it.
    samples : int
        Samples affected (0 for a gap).
    runs : int
        Separate stretches merged into this entry (1 unless the channel had
        many short ones).
    detail : str
        What was read, e.g. ``'reads 999.9 C'``.
    """

    channel: str
    kind: str
    start: float
    end: float
    samples: int
    runs: int = 1
    detail: str = ""

    def __str__(self) -> str:
        where = "log" if self.channel == "t" else self.channel
        if self.kind == "gap":
            lead = f"{where}: gap, {self.detail}" if self.runs == 1 else f"{where}: {self.runs} gaps, {self.detail}"
            return lead
        span = f"at {self.start:g} s" if self.start == self.end else f"from {self.start:g} s to {self.end:g} s"
        runs = f" in {self.runs} stretches" if self.runs > 1 else ""
        detail = f" ({self.detail})" if self.detail else ""
        return f"{where}: {_KIND_LABEL[self.kind]} {span}{runs}, {self.samples} samples{detail}"


@dataclass(frozen=True, eq=False)
class LogReport:
    """What :func:`check_log` found in a thermocouple log.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Sample times, s.
    channels : tuple of str
        Channel names, in the order of the columns of ``clean``.
    roles : tuple of str
        Role of each channel (``cmmpose.run.CHANNEL_ROLES``).
    clean : ndarray of bool, shape (M, C)
        True where a sample of a channel is usable: finite, plausible and not
        stuck. Gaps in time do not clear it.
    problems : tuple of LogProblem
        Everything found, gaps first, then by channel.
    max_gap : float
        Largest sample spacing accepted, s.
    median_spacing : float
        Median sample spacing, s.
    plausible : tuple of 2 float
        Plausible reading range used, degrees C.
    stuck_after : float or None
        Stuck-channel window used, s (None: detection was off).
    stuck_tolerance : float
        Tolerance for "constant", K.
    """

    t: np.ndarray = field(repr=False)
    channels: tuple[str, ...]
    roles: tuple[str, ...]
    clean: np.ndarray = field(repr=False)
    problems: tuple[LogProblem, ...]
    max_gap: float
    median_spacing: float
    plausible: tuple[float, float]
    stuck_after: float | None
    stuck_tolerance: float

    @property
    def ok(self) -> bool:
        """True when nothing was found."""
        return not self.problems

    @property
    def gaps(self) -> tuple[LogProblem, ...]:
        """The gaps in time."""
        return tuple(p for p in self.problems if p.kind == "gap")

    @property
    def samples(self) -> int:
        """Number of samples M."""
        return int(self.t.shape[0])

    @property
    def dropped(self) -> dict[str, int]:
        """Unclean samples per channel."""
        return dict(zip(self.channels, (self.samples - self.clean.sum(axis=0)).tolist()))

    def problems_of(self, channel: str) -> tuple[LogProblem, ...]:
        """Problems of one channel (``'t'``: the gaps)."""
        self._index(channel)
        return tuple(p for p in self.problems if p.channel == channel)

    def clean_of(self, channel: str) -> np.ndarray:
        """Clean mask of one channel, shape (M,)."""
        return self.clean[:, self._index(channel)]

    @property
    def bad_channels(self) -> tuple[str, ...]:
        """Channels with at least one problem."""
        names = {p.channel for p in self.problems}
        return tuple(c for c in self.channels if c in names)

    def _index(self, channel: str) -> int:
        if channel == "t":
            return -1
        try:
            return self.channels.index(channel)
        except ValueError:
            raise InputError(f"channel {channel!r}: not in the log (channels {', '.join(self.channels)})") from None

    def __str__(self) -> str:
        t = self.t
        head = (f"Temperature log: {len(self.channels)} channels, {self.samples} samples, {t[0]:g} to {t[-1]:g} s "
                f"(median spacing {self.median_spacing:g} s, max_gap {self.max_gap:g} s)")
        wn = max([7] + [len(c) for c in self.channels])
        wr = max([4] + [len(r) for r in self.roles])
        lines = [head, f"{'channel':<{wn}}  {'role':<{wr}}  {'clean':>7}  {'dropped':>7}  problems"]
        dropped = self.dropped
        for c, r in zip(self.channels, self.roles):
            kinds = sorted({_KIND_LABEL[p.kind] for p in self.problems if p.channel == c})
            lines.append(f"{c:<{wn}}  {r:<{wr}}  {self.samples - dropped[c]:>7}  {dropped[c]:>7}  "
                         f"{', '.join(kinds) if kinds else '-'}")
        if self.ok:
            lines.append("OK: no problems found.")
        else:
            lines.append(f"Problems ({len(self.problems)}):")
            lines += [f"  {p}" for p in self.problems]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"LogReport(channels={len(self.channels)}, samples={self.samples}, ok={self.ok}, "
                f"problems={len(self.problems)})")


# -- reading the log ----------------------------------------------------------------
@dataclass(frozen=True)
class LogColumns:
    t: np.ndarray  # (M,)
    names: tuple[str, ...]
    roles: tuple[str, ...]
    values: np.ndarray  # (M, C)


def _channel_list(channels) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and roles from ``[{'name':, 'role':}, ...]`` or ``[(name, role), ...]``."""
    if isinstance(channels, (str, bytes, Mapping)) or not isinstance(channels, Sequence):
        raise InputError("channels: expected a list of {'name': ..., 'role': ...} (Run.temperature_channels) "
                         f"or of (name, role) pairs, got {type(channels).__name__}")
    if not channels:
        raise InputError("channels: empty; the log needs at least one temperature channel")
    names, roles = [], []
    for k, ch in enumerate(channels):
        if isinstance(ch, Mapping):
            name, role = ch.get("name"), ch.get("role")
        elif isinstance(ch, Sequence) and not isinstance(ch, (str, bytes)) and len(ch) == 2:
            name, role = ch
        else:
            raise InputError(f"channels[{k}]: expected {{'name': ..., 'role': ...}} or a (name, role) pair, got {ch!r}")
        if not isinstance(name, str) or not name or name == "t":
            raise InputError(f"channels[{k}]: name must be a non-empty string other than 't', got {name!r}")
        if role not in _run.CHANNEL_ROLES:
            raise InputError(f"channels[{k}]: unknown role {role!r} of channel {name!r} (allowed: {', '.join(_run.CHANNEL_ROLES)})")
        if name in names:
            raise InputError(f"channels[{k}]: duplicate channel name {name!r}")
        names.append(name)
        roles.append(role)
    return tuple(names), tuple(roles)


def read_log(temperatures, channels) -> LogColumns:
    """Check and convert a log: ``t`` finite and strictly increasing, every
    channel a float column of the same length (NaN allowed: check_log reports it)."""
    if isinstance(temperatures, _run.Run):
        if temperatures.temperatures is None:
            raise InputError("run has no temperature log (no temperature channels)")
        if channels is None:
            channels = temperatures.temperature_channels
        temperatures = temperatures.temperatures
    if not isinstance(temperatures, Mapping):
        raise InputError("temperatures: expected a dict with 't' (s) and one column per channel (C), or a Run, "
                         f"got {type(temperatures).__name__}")
    if channels is None:
        raise InputError("channels: required with a dict log (list of {'name': ..., 'role': ...})")
    names, roles = _channel_list(channels)
    if "t" not in temperatures:
        raise InputError("temperatures: no time column 't' (s)")
    t = _column(temperatures["t"], "t")
    if t.shape[0] < 2:
        raise InputError(f"temperatures: column 't' has {t.shape[0]} samples; a log needs at least 2")
    bad = ~np.isfinite(t)
    if bad.any():
        r = int(np.argmax(bad))
        raise InputError(f"temperatures: column 't' is {t[r]} at row {r}; times must be finite (s)")
    back = np.diff(t) <= 0
    if back.any():
        r = int(np.argmax(back)) + 1
        raise InputError(f"temperatures: column 't' not strictly increasing at row {r} "
                         f"(t = {t[r]:g} s after {t[r - 1]:g} s)")
    missing = [n for n in names if n not in temperatures]
    if missing:
        raise InputError(f"temperatures: no column for channel {missing[0]!r} (columns: "
                         f"{', '.join(map(str, temperatures))})")
    cols = []
    for n in names:
        c = _column(temperatures[n], n)
        if c.shape != t.shape:
            raise InputError(f"temperatures: column {n!r} has {c.shape[0]} samples but 't' has {t.shape[0]}")
        cols.append(c)
    return LogColumns(t, names, roles, np.column_stack(cols))


def _column(values, name: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"temperatures: column {name!r} cannot be read as numbers ({exc})") from None
    if a.ndim != 1:
        raise InputError(f"temperatures: column {name!r} must be 1-D, got shape {a.shape}")
    return a


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) indices of the runs of True in a 1-D mask."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1


def _segment_range(values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """max - min of ``values`` (M,) or (M, K) over rows starts[i]..ends[i]
    (inclusive), ignoring NaN (all NaN gives NaN)."""
    pad = np.concatenate([values, np.full((1,) + values.shape[1:], np.nan)])
    idx = np.column_stack([starts, ends + 1]).ravel()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        hi = np.fmax.reduceat(pad, idx, axis=0)[::2]
        lo = np.fmin.reduceat(pad, idx, axis=0)[::2]
    return hi - lo


def _problems_from_mask(name: str, kind: str, mask: np.ndarray, t: np.ndarray, detail) -> list[LogProblem]:
    """One problem per run of True in ``mask`` (merged into one when there
    are more than _MAX_RUNS_LISTED runs). ``detail(start_index)`` -> str."""
    starts, ends = _runs(mask)
    if not len(starts):
        return []
    if len(starts) > _MAX_RUNS_LISTED:
        return [LogProblem(name, kind, float(t[starts[0]]), float(t[ends[-1]]), int(mask.sum()), len(starts),
                           detail(int(starts[0])))]
    counts = (ends - starts + 1).tolist()
    return [LogProblem(name, kind, float(t[s]), float(t[e]), n, 1, detail(int(s)))
            for s, e, n in zip(starts.tolist(), ends.tolist(), counts)]  # one entry per run, at most 20


# -- check_log ----------------------------------------------------------------------
def check_log(
    temperatures,
    channels=None,
    *,
    plausible: tuple[float, float] = PLAUSIBLE,
    max_gap: float | None = None,
    stuck_after: float | None = STUCK_AFTER,
    stuck_tolerance: float = STUCK_TOLERANCE,
) -> LogReport:
    """Find what is wrong with a thermocouple log.

    Parameters
    ----------
    temperatures : dict of str -> array_like, or Run
        The log: ``t`` (s, finite, strictly increasing, at least 2 samples)
        and one column per channel (degrees C), as ``Run.temperatures``; or a
        ``Run`` (its log and channels).
    channels : list of dict or of (str, str) pairs
        ``{'name': str, 'role': str}`` per channel (``Run.temperature_channels``)
        or ``(name, role)`` pairs (``cmmpose.sim.CHANNELS``); roles from
        ``cmmpose.run.CHANNEL_ROLES``. Only these columns are read. Optional
        with a Run.
    plausible : tuple of 2 float
        Lowest and highest believable reading, degrees C (inclusive). Readings
        outside are implausible; at 500 C or more from zero they are reported
        as an open circuit (a logger's burn-out value such as 999.9 C).
    max_gap : float, optional
        Largest sample spacing that is not a gap, s. Default 5 times the
        median spacing.
    stuck_after : float or None
        A channel constant (to within ``stuck_tolerance``) over a window
        longer than this, s, while another channel varies by more than the
        tolerance, or exactly constant while another changes at all (or it is
        the only channel), is stuck over that window. None turns detection off.
        A logger that quantises coarsely in a very stable room reads constant
        for long stretches: raise ``stuck_after`` for such logs.
    stuck_tolerance : float
        What counts as constant, K (>= 0).

    Returns
    -------
    LogReport
        Problems per channel with their times, and the clean mask
        (finite, plausible, not stuck) per channel and sample.

    Raises
    ------
    InputError
        A malformed log: no or non-increasing ``t``, NaN times, a missing
        channel column, columns of different lengths, bad options.
    """
    log = read_log(temperatures, channels)
    lo, hi = _pair(plausible, "plausible")
    if not lo < hi:
        raise InputError(f"plausible: expected (low, high) with low < high (C), got {plausible!r}")
    if stuck_after is not None and not (np.isfinite(stuck_after) and stuck_after > 0):
        raise InputError(f"stuck_after: expected a positive time in s or None, got {stuck_after!r}")
    if not (np.isfinite(stuck_tolerance) and stuck_tolerance >= 0):
        raise InputError(f"stuck_tolerance: expected a non-negative temperature difference in K, got {stuck_tolerance!r}")
    t, v = log.t, log.values
    dt = np.diff(t)
    median = float(np.median(dt))
    if max_gap is None:
        max_gap = GAP_FACTOR * median
    elif not (np.isfinite(max_gap) and max_gap > 0):
        raise InputError(f"max_gap: expected a positive time in s, got {max_gap!r}")
    max_gap = float(max_gap)

    problems: list[LogProblem] = []
    # gaps in time: affect every channel
    gap = dt > max_gap
    gi = np.flatnonzero(gap)
    if len(gi) > _MAX_RUNS_LISTED:
        problems.append(LogProblem("t", "gap", float(t[gi[0]]), float(t[gi[-1] + 1]), 0, len(gi),
                                   f"{len(gi)} spacings above max_gap {max_gap:g} s between {t[gi[0]]:g} and "
                                   f"{t[gi[-1] + 1]:g} s (largest {dt[gi].max():g} s)"))
    else:
        problems += [LogProblem("t", "gap", float(t[i]), float(t[i + 1]), 0, 1,
                                f"no samples from {t[i]:g} s to {t[i + 1]:g} s ({dt[i]:g} s > max_gap {max_gap:g} s)")
                     for i in gi.tolist()]  # at most 20

    finite = np.isfinite(v)
    plaus = finite & (v >= lo) & (v <= hi)
    far = finite & ~plaus & (np.abs(v) >= OPEN_CIRCUIT_ABOVE)
    stuck = _stuck(t, v, plaus, stuck_after, stuck_tolerance)
    clean = plaus & ~stuck
    clean.flags.writeable = False
    t = t.copy()
    t.flags.writeable = False

    for c, name in enumerate(log.names):
        col = v[:, c]
        problems += _problems_from_mask(name, "nan", ~finite[:, c], t,
                                        lambda s, col=col: f"reads {col[s]}")
        problems += _problems_from_mask(name, "open_circuit", far[:, c], t,
                                        lambda s, col=col: f"reads {col[s]:g} C")
        problems += _problems_from_mask(name, "implausible", finite[:, c] & ~plaus[:, c] & ~far[:, c], t,
                                        lambda s, col=col: f"reads {col[s]:g} C, outside {lo:g} to {hi:g} C")
        problems += _problems_from_mask(name, "stuck", stuck[:, c], t,
                                        lambda s, col=col: f"holds {col[s]:g} C while others vary")
    return LogReport(t, log.names, log.roles, clean, tuple(problems), max_gap, median, (lo, hi),
                     None if stuck_after is None else float(stuck_after), float(stuck_tolerance))


def _pair(value, name: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected two numbers (low, high), got {value!r}") from None
    return a, b


def _stuck(t, v, plaus, stuck_after, tol) -> np.ndarray:
    """(M, C) mask of samples in stuck windows (see check_log)."""
    m, n = v.shape
    stuck = np.zeros((m, n), dtype=bool)
    if stuck_after is None:
        return stuck
    others_v = np.where(plaus, v, np.nan)
    for c in range(n):  # loop over channels; each is vectorised over samples
        ok = plaus[:, c]
        link = ok[1:] & ok[:-1] & (np.abs(np.diff(v[:, c])) <= tol)
        starts, ends = _runs(link)  # link runs a..b-1 cover samples a..b
        ends = ends + 1
        long = (t[ends] - t[starts]) > stuck_after
        starts, ends = starts[long], ends[long]
        if not len(starts):
            continue
        own = _segment_range(v[:, c], starts, ends)
        if n > 1:
            rest = _segment_range(np.delete(others_v, c, axis=1), starts, ends)
            with np.errstate(invalid="ignore"):
                vary = np.any(rest > tol, axis=1)
                change = np.any(rest > 0, axis=1)
        else:
            vary = np.zeros(len(starts), dtype=bool)
            change = np.ones(len(starts), dtype=bool)
        hit = (own <= tol) & (vary | ((own == 0) & change))
        starts, ends = starts[hit], ends[hit]
        if len(starts):
            mark = np.zeros(m + 1, dtype=np.int32)
            np.add.at(mark, starts, 1)
            np.add.at(mark, ends + 1, -1)
            stuck[:, c] = np.cumsum(mark[:-1]) > 0
    return stuck
