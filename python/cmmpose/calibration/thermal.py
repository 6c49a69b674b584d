"""Thermal selection: the machine temperature at each point's time stamp from
the thermocouple log (thesis section 6.4; docs/conventions.md, Interpolation).

The thesis machine logs 11 type-E thermocouples (three on each axis scale,
granite top and bottom) with time stamps in a separate file; each point's time
stamp queries the log, and the machine temperature selects (and blends) the
error maps. This module does that join robustly:

- :func:`check_log` finds what is wrong with a log: gaps in time, stuck
  channels, open-circuit or implausible readings, NaN; it gives a clean mask
  per channel and sample.
- :func:`temperatures_at` interpolates the clean samples in time at the
  points' time stamps and applies a policy: ``'machine_mean'`` (the thesis:
  mean of the axis-scale channels), ``'per_axis'`` (one temperature per axis,
  for per-carriage maps), ``'role:ROLE'`` (the clean channels of one
  thermocouple role) or ``'channel:NAME'``.
- :func:`per_scan_temperature` gives one temperature per scan (the time
  average over the scan's duration).
- :func:`select_map_temperature` checks temperatures against the range of an
  :class:`~cmmpose.ErrorMapSet`, refusing or clamping.

Units: times in s, temperatures in degrees C, temperature differences in K.
Rows in messages are counted from 0.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errormap import ErrorMapSet
from ..errors import ClampWarning, InputError, OutOfRangeError
from ..run import CHANNEL_ROLES, Run

__all__ = [
    "LogProblem",
    "LogReport",
    "ThermalSummary",
    "ScanTemperatures",
    "check_log",
    "temperatures_at",
    "per_scan_temperature",
    "select_map_temperature",
    "PLAUSIBLE",
    "STUCK_AFTER",
    "STUCK_TOLERANCE",
    "GAP_FACTOR",
    "POLICIES",
    "AXIS_ROLES",
]

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
#: Policies of :func:`temperatures_at` (plus ``'role:ROLE'`` and ``'channel:NAME'``).
POLICIES = ("machine_mean", "per_axis", "role:ROLE", "channel:NAME")
#: Roles of the axis-scale channels, in X, Y, Z order.
AXIS_ROLES = ("x_scale", "y_scale", "z_scale")
#: More runs than this of one kind on one channel are reported as one problem.
_MAX_RUNS_LISTED = 20
_KIND_LABEL = {"gap": "gap", "stuck": "stuck", "open_circuit": "open circuit", "implausible": "implausible",
               "nan": "NaN"}


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


@dataclass(frozen=True, eq=False)
class ThermalSummary:
    """How :func:`temperatures_at` (or :func:`per_scan_temperature`) got its
    temperatures.

    Attributes
    ----------
    policy : str
        The policy applied.
    channels : tuple of str
        The channels the policy reads (e.g. the nine axis-scale channels).
    channels_used : tuple of str
        Those that contributed to at least one point.
    channels_excluded : tuple of str
        Those that contributed to no point (broken throughout, say).
    samples_dropped : int
        Unclean samples of the policy's channels, left out.
    dropped_by_channel : dict of str -> int
        Unclean samples per policy channel.
    points : int
        Number of points (time stamps).
    points_missing_channels : int
        Points at which at least one policy channel had no clean reading
        (the others were averaged).
    points_across_gaps : int
        Points whose temperature was interpolated across a gap wider than
        ``max_gap`` (only with ``on_gap='interpolate'``).
    points_held : int
        Points outside the log, given the log's end value (only with
        ``out_of_range='hold'``).
    report : LogReport
        The log check used.
    """

    policy: str
    channels: tuple[str, ...]
    channels_used: tuple[str, ...]
    channels_excluded: tuple[str, ...]
    samples_dropped: int
    dropped_by_channel: dict[str, int]
    points: int
    points_missing_channels: int
    points_across_gaps: int
    points_held: int
    report: LogReport = field(repr=False)

    def __str__(self) -> str:
        lines = [f"policy {self.policy!r}: {self.points} points from channels {', '.join(self.channels_used) or '-'}"]
        if self.channels_excluded:
            lines.append(f"  excluded (no clean reading where needed): {', '.join(self.channels_excluded)}")
        if self.samples_dropped:
            per = ", ".join(f"{c} {n}" for c, n in self.dropped_by_channel.items() if n)
            lines.append(f"  samples dropped: {self.samples_dropped} ({per})")
        if self.points_missing_channels:
            lines.append(f"  points averaged over fewer channels: {self.points_missing_channels}")
        if self.points_across_gaps:
            lines.append(f"  points interpolated across gaps wider than {self.report.max_gap:g} s: {self.points_across_gaps}")
        if self.points_held:
            lines.append(f"  points outside the log, held at its end values: {self.points_held}")
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class ScanTemperatures:
    """One temperature per scan, from :func:`per_scan_temperature`.

    Attributes
    ----------
    scan_id : ndarray of int, shape (S,)
        Scan ids, ascending.
    start, end : ndarray, shape (S,)
        First and last point time of each scan, s.
    temperature : ndarray, shape (S,) or (S, 3)
        Time average of the policy temperature over each scan, degrees C
        (``'per_axis'``: X, Y, Z columns).
    n_points : ndarray of int, shape (S,)
        Points per scan.
    per_point : ndarray, shape (N,) or (N, 3)
        Each point's scan temperature, degrees C, in the order of the input
        points (ready for :func:`cmmpose.compensate`).
    summary : ThermalSummary
        Channels used and samples dropped (``points``: the input points).
    scans_across_gaps : int
        Scans whose average was interpolated across a gap wider than
        ``max_gap`` (only with ``on_gap='interpolate'``).
    """

    scan_id: np.ndarray
    start: np.ndarray
    end: np.ndarray
    temperature: np.ndarray
    n_points: np.ndarray
    per_point: np.ndarray = field(repr=False)
    summary: ThermalSummary = field(repr=False)
    scans_across_gaps: int = 0

    def __str__(self) -> str:
        temp = self.temperature
        lines = [f"{'scan':>6}  {'start (s)':>10}  {'end (s)':>10}  {'points':>7}  temperature (C)"]
        for k in range(len(self.scan_id)):  # one line per scan: a text table
            tk = temp[k]
            txt = f"{tk:.3f}" if temp.ndim == 1 else "  ".join(f"{v:.3f}" for v in tk)
            lines.append(f"{self.scan_id[k]:>6}  {self.start[k]:>10.3f}  {self.end[k]:>10.3f}  {self.n_points[k]:>7}  {txt}")
        if self.scans_across_gaps:
            lines.append(f"scans averaged across gaps in the log: {self.scans_across_gaps}")
        return "\n".join(lines + [str(self.summary)])


# -- reading the log ----------------------------------------------------------------
@dataclass(frozen=True)
class _Log:
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
        if role not in CHANNEL_ROLES:
            raise InputError(f"channels[{k}]: unknown role {role!r} of channel {name!r} (allowed: {', '.join(CHANNEL_ROLES)})")
        if name in names:
            raise InputError(f"channels[{k}]: duplicate channel name {name!r}")
        names.append(name)
        roles.append(role)
    return tuple(names), tuple(roles)


def _read_log(temperatures, channels) -> _Log:
    """Check and convert a log: ``t`` finite and strictly increasing, every
    channel a float column of the same length (NaN allowed: check_log reports it)."""
    if isinstance(temperatures, Run):
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
    return _Log(t, names, roles, np.column_stack(cols))


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
    log = _read_log(temperatures, channels)
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


# -- temperatures at time stamps ----------------------------------------------------
def _groups(policy, log: _Log) -> tuple[str, list[tuple[str, list[int]]]]:
    """(label, [(group label, channel indices)]) of a policy."""
    if not isinstance(policy, str):
        raise InputError(f"policy: expected one of {', '.join(repr(p) for p in POLICIES)}, got {policy!r}")
    if policy == "machine_mean":
        idx = [k for k, r in enumerate(log.roles) if r in AXIS_ROLES]
        if not idx:
            raise InputError("policy 'machine_mean': the log has no axis-scale channel (roles x_scale, y_scale, "
                             f"z_scale); channels: {_describe_channels(log)}")
        return policy, [("axis-scale", idx)]
    if policy == "per_axis":
        out = []
        for role in AXIS_ROLES:
            idx = [k for k, r in enumerate(log.roles) if r == role]
            if not idx:
                raise InputError(f"policy 'per_axis': the log has no channel with role {role!r}; "
                                 f"channels: {_describe_channels(log)}")
            out.append((role, idx))
        return policy, out
    if policy.startswith("role:"):
        role = policy[len("role:"):]
        idx = [k for k, r in enumerate(log.roles) if r == role]
        if not idx:
            raise InputError(f"policy {policy!r}: no channel with role {role!r}; channels: {_describe_channels(log)}")
        return policy, [(role, idx)]
    if policy.startswith("channel:"):
        name = policy[len("channel:"):]
        if name not in log.names:
            raise InputError(f"policy {policy!r}: no channel {name!r} in the log (channels: {', '.join(log.names)})")
        return policy, [(f"channel {name}", [log.names.index(name)])]
    raise InputError(f"policy: unknown policy {policy!r}; expected one of {', '.join(repr(p) for p in POLICIES)}")


def _describe_channels(log: _Log) -> str:
    return ", ".join(f"{n} ({r})" for n, r in zip(log.names, log.roles))


def _times(t, name: str = "t") -> np.ndarray:
    try:
        a = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as times in s ({exc})") from None
    if a.ndim > 1:
        raise InputError(f"{name}: expected one time stamp per point, shape (N,), got {a.shape}")
    flat = a.reshape(-1)
    bad = ~np.isfinite(flat)
    if bad.any():
        r = int(np.argmax(bad))
        raise InputError(f"{name}: row {r} is {flat[r]}; time stamps must be finite (s)")
    return a


def _check_report(report, log: _Log, temperatures, channels) -> LogReport:
    if report is None:
        return check_log(temperatures, channels)
    if not isinstance(report, LogReport):
        raise InputError(f"report: expected a LogReport from check_log, got {type(report).__name__}")
    if report.channels != log.names or report.t.shape != log.t.shape or not np.array_equal(report.t, log.t):
        raise InputError("report: made from a different log (its channels or sample times differ); "
                         "call check_log on this log")
    return report


def _option(value, name: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise InputError(f"{name}: expected one of {', '.join(repr(a) for a in allowed)}, got {value!r}")
    return value


@dataclass
class _Eval:
    values: np.ndarray  # (N, G)
    used: np.ndarray  # (C_policy,) bool: channel contributed to some point
    missing: np.ndarray  # (N,) bool: some policy channel not used at the point
    bridged: np.ndarray  # (N,) bool: a value came across a gap > max_gap
    idx: list[int]  # policy channel indices, in order


def _evaluate(tq: np.ndarray, log: _Log, rep: LogReport, groups, interpolate: bool) -> tuple[_Eval, np.ndarray, list]:
    """Group temperatures at times ``tq`` (inside the log). Returns the
    evaluation, a (N,) mask of points with no usable channel in some group,
    and per group that group's mask."""
    n = tq.shape[0]
    idx = sorted({k for _, g in groups for k in g})
    vals, strict, loose, far = {}, {}, {}, {}
    # one search in the log; each channel's clean samples are a subset of its rows
    jl = np.searchsorted(log.t, tq, side="right")
    for k in idx:  # loop over channels; vectorised over points
        keep = rep.clean[:, k]
        s, y = log.t[keep], log.values[keep, k]
        if not len(s):
            vals[k] = np.full(n, np.nan)
            strict[k] = loose[k] = far[k] = np.zeros(n, dtype=bool)
            continue
        j = np.concatenate(([0], np.cumsum(keep)))[jl]  # clean samples at or before tq: s[j-1] <= tq < s[j]
        has_l, has_r = j > 0, j < len(s)
        i0, i1 = np.maximum(j - 1, 0), np.minimum(j, len(s) - 1)
        left, right = s[i0], s[i1]
        exact = has_l & (left == tq)
        inside = has_l & has_r
        span = right - left
        wide = inside & ~exact & (span > rep.max_gap)
        strict[k] = exact | (inside & ~wide)
        loose[k] = exact | inside
        far[k] = wide
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(inside & (span > 0), (tq - left) / span, 0.0)
        yl = y[i0]
        vals[k] = yl + w * (y[i1] - yl)  # linear in time between the clean samples around tq
    out = np.full((n, len(groups)), np.nan)
    missing = np.zeros(n, dtype=bool)
    bridged = np.zeros(n, dtype=bool)
    used = dict.fromkeys(idx, False)
    none_any = np.zeros(n, dtype=bool)
    per_group = []
    for gi, (_, g) in enumerate(groups):  # at most 3 groups
        st = np.column_stack([strict[k] for k in g])
        need = ~st.any(axis=1)
        avail = st | (np.column_stack([loose[k] for k in g]) & need[:, None]) if interpolate else st
        v = np.column_stack([vals[k] for k in g])
        cnt = avail.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, gi] = np.where(avail, v, 0.0).sum(axis=1) / cnt
        out[cnt == 0, gi] = np.nan
        missing |= (cnt < len(g)) & (cnt > 0)
        bridged |= (avail & np.column_stack([far[k] for k in g])).any(axis=1)
        for col, k in enumerate(g):
            used[k] = used[k] or bool(avail[:, col].any())
        none_any |= cnt == 0
        per_group.append(cnt == 0)
    return _Eval(out, np.array([used[k] for k in idx]), missing, bridged, idx), none_any, per_group


def _why(row: int, tq: float, log: _Log, rep: LogReport, label: str, chans: list[int], can_bridge: bool) -> str:
    """Message for a point with no usable channel of a group."""
    where = f"point row {row} (t = {tq:g} s)"
    t = log.t
    k = int(np.searchsorted(t, tq, side="right")) - 1
    if 0 <= k < len(t) - 1 and t[k] < tq and t[k + 1] - t[k] > rep.max_gap:
        return (f"{where} falls in a gap of the temperature log: no samples from {t[k]:g} s to {t[k + 1]:g} s "
                f"({t[k + 1] - t[k]:g} s > max_gap {rep.max_gap:g} s); pass on_gap='interpolate' to interpolate across it")
    names = [log.names[c] for c in chans]
    near = [str(p) for p in rep.problems
            if p.channel in names and p.start - rep.max_gap <= tq <= p.end + rep.max_gap]
    hint = "; pass on_gap='interpolate' to interpolate across the bad stretch" if can_bridge else ""
    return (f"{where}: no clean {label} reading ({', '.join(names)}) within max_gap {rep.max_gap:g} s"
            + (f" [{'; '.join(near)}]" if near else "") + hint)


def _all_broken(log: _Log, rep: LogReport, groups, policy: str) -> None:
    for label, g in groups:
        if not rep.clean[:, g].any():
            names = [log.names[k] for k in g]
            why = "; ".join(str(p) for p in rep.problems if p.channel in names)
            raise InputError(f"policy {policy!r}: every {label} channel is unusable ({', '.join(names)}): {why}")


def _select(t, temperatures, channels, policy, report, on_gap, out_of_range):
    """Shared body of temperatures_at and per_scan_temperature."""
    log = _read_log(temperatures, channels)
    if isinstance(temperatures, Run) and channels is None:
        channels = temperatures.temperature_channels
    rep = _check_report(report, log, temperatures, channels)
    interpolate = _option(on_gap, "on_gap", ("raise", "interpolate")) == "interpolate"
    hold = _option(out_of_range, "out_of_range", ("raise", "hold")) == "hold"
    label, groups = _groups(policy, log)
    _all_broken(log, rep, groups, label)
    t = _times(t)
    tq = t.reshape(-1)
    t0, t1 = log.t[0], log.t[-1]
    outside = (tq < t0) | (tq > t1)
    tq_eff = np.clip(tq, t0, t1) if hold else tq
    ev, none_any, per_group = _evaluate(tq_eff, log, rep, groups, interpolate)
    bad = none_any | (outside & ~hold)
    if bad.any():
        r = int(np.argmax(bad))
        if outside[r] and not hold:
            raise InputError(f"point row {r} (t = {tq[r]:g} s) is outside the temperature log ({t0:g} s to {t1:g} s)"
                             + (f"; {int(outside.sum())} points in all" if outside.sum() > 1 else "")
                             + "; pass out_of_range='hold' to use the log's end values")
        gi = next(i for i, m in enumerate(per_group) if m[r])
        glabel, g = groups[gi]
        can_bridge = not interpolate and _bridgeable(tq_eff[r], log, rep, g)
        raise InputError(_why(r, float(tq[r]), log, rep, glabel, g, can_bridge))
    names = tuple(log.names[k] for k in ev.idx)
    dropped = {log.names[k]: int(rep.samples - rep.clean[:, k].sum()) for k in ev.idx}
    summary = ThermalSummary(
        policy=label,
        channels=names,
        channels_used=tuple(n for n, u in zip(names, ev.used) if u),
        channels_excluded=tuple(n for n, u in zip(names, ev.used) if not u),
        samples_dropped=sum(dropped.values()),
        dropped_by_channel=dropped,
        points=int(tq.shape[0]),
        points_missing_channels=int(ev.missing.sum()),
        points_across_gaps=int(ev.bridged.sum()),
        points_held=int((outside & hold).sum()),
        report=rep,
    )
    return t, ev, summary, log, rep, groups, interpolate, hold


def _bridgeable(tq: float, log: _Log, rep: LogReport, g: list[int]) -> bool:
    """Would on_gap='interpolate' give a value at ``tq`` for some channel of ``g``?"""
    for k in g:  # loop over a group's channels
        s = log.t[rep.clean[:, k]]
        if len(s) and s[0] <= tq <= s[-1]:
            return True
    return False


def temperatures_at(
    t,
    temperatures,
    channels=None,
    *,
    policy: str = "machine_mean",
    report: LogReport | None = None,
    on_gap: str = "raise",
    out_of_range: str = "raise",
):
    """Temperature at each point's time stamp from the thermocouple log.

    Each channel's clean samples (see :func:`check_log`) are interpolated
    linearly in time at the time stamps; a channel counts at a time stamp
    only if clean samples lie on both sides of it no more than ``max_gap``
    apart (or one lies exactly on it). The policy then combines the channels
    that count, point by point.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps of the points, s (finite, any order; same clock as the
        log's ``t``).
    temperatures : dict of str -> array_like, or Run
        The log: ``t`` (s) and one column per channel (degrees C), as
        ``Run.temperatures``; or a Run (its log and channels).
    channels : list of dict or of (str, str) pairs
        Names and roles of the log's channels, as in :func:`check_log`.
        Optional with a Run.
    policy : str
        ``'machine_mean'``: mean of the axis-scale channels (roles x_scale,
        y_scale, z_scale), the thesis's machine temperature (section 6.4).
        ``'per_axis'``: mean of each axis's scale channels, X, Y, Z columns
        (for per-carriage maps). ``'role:ROLE'``: mean of the channels of one
        thermocouple role (a broken channel dropped as for the others).
        ``'channel:NAME'``: one channel.
    report : LogReport, optional
        A :func:`check_log` report of this log (to choose its options such as
        ``max_gap``, ``plausible``, ``stuck_after``); default ``check_log``
        with its defaults.
    on_gap : {'raise', 'interpolate'}
        A point in a gap of the log wider than ``max_gap`` s, or where no
        channel of the policy has a clean reading within ``max_gap`` s,
        raises ``InputError`` naming the first such row and time; or is
        interpolated across the gap (counted in ``points_across_gaps``). With
        ``'interpolate'``, channels are bridged across a long bad stretch only
        at points where no channel of the group has a close clean reading.
    out_of_range : {'raise', 'hold'}
        A point before the first or after the last sample of the log raises
        ``InputError`` naming the first such row and time, or takes the log's
        value at that end (counted in ``points_held``).

    Returns
    -------
    temperatures : ndarray, shape (N,), or (N, 3) for 'per_axis'
        Degrees C (a 0-d ``t`` gives a 0-d or (3,) result).
    summary : ThermalSummary
        Channels used and excluded, samples dropped, points averaged over
        fewer channels, interpolated across gaps or held.

    Raises
    ------
    InputError
        A malformed log (see :func:`check_log`), NaN time stamps, an unknown
        policy or channel, a policy with no channel of its role, every
        channel of the policy broken, or a point outside the log, in a gap
        or with no clean channel (naming the row and time).
    """
    t, ev, summary, *_ = _select(t, temperatures, channels, policy, report, on_gap, out_of_range)
    out = ev.values if policy == "per_axis" else ev.values[:, 0]
    return out.reshape(t.shape + out.shape[1:]), summary


def per_scan_temperature(
    t,
    scan_id,
    temperatures,
    channels=None,
    *,
    policy: str = "machine_mean",
    report: LogReport | None = None,
    on_gap: str = "raise",
    out_of_range: str = "raise",
) -> ScanTemperatures:
    """One temperature per scan: the time average of the policy temperature
    over the scan's duration (its first to last point time).

    The policy temperature is piecewise linear between log samples, so the
    average is exact: the trapezoid rule over the scan's ends and the log
    samples inside it. A scan of one point (or zero duration) takes the
    temperature at its time.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps of the points, s (``run.points['t']``).
    scan_id : array_like of int, shape (N,)
        Scan of each point (``run.points['scan_id']``).
    temperatures : dict of str -> array_like, or Run
        The log (``t`` in s, channels in degrees C) or a Run.
    channels : list of dict or of (str, str) pairs
        Names and roles of the channels (optional with a Run).
    policy : str
        As in :func:`temperatures_at`.
    report : LogReport, optional
        As in :func:`temperatures_at`.
    on_gap : {'raise', 'interpolate'}
        As in :func:`temperatures_at`; also a scan whose duration spans a gap
        of the log wider than ``max_gap`` s, or a stretch with no clean
        channel between its points, raises naming the scan, unless
        ``'interpolate'``.
    out_of_range : {'raise', 'hold'}
        As in :func:`temperatures_at` (time in s outside the log).

    Returns
    -------
    ScanTemperatures
        ``scan_id``, ``start``, ``end`` (s), ``temperature`` (degrees C, (S,)
        or (S, 3) for 'per_axis'), ``n_points``, ``per_point`` ((N,) or
        (N, 3), degrees C, each point's scan value) and ``summary``.

    Raises
    ------
    InputError
        As :func:`temperatures_at`; also ``scan_id`` not integers or of a
        different length from ``t``, a scan spanning a gap.
    """
    tt = _times(t)
    if tt.ndim != 1:
        raise InputError(f"t: expected shape (N,), got {tt.shape}")
    sid = np.asarray(scan_id)
    if sid.ndim != 1:
        raise InputError(f"scan_id: expected shape (N,), got {sid.shape}")
    if sid.shape != tt.shape:
        raise InputError(f"scan_id: has {sid.shape[0]} entries but t has {tt.shape[0]}; one scan id per point")
    if sid.dtype.kind not in "iu":
        if sid.dtype.kind == "f" and np.all(np.isfinite(sid)) and np.all(sid == np.round(sid)):
            sid = sid.astype(np.int64)
        else:
            raise InputError(f"scan_id: expected integers, got dtype {sid.dtype}")
    if not len(tt):
        raise InputError("t: no points")
    tt, ev, summary, log, rep, groups, interpolate, hold = _select(tt, temperatures, channels, policy, report,
                                                                   on_gap, out_of_range)
    ids, inv, n_pts = np.unique(sid, return_inverse=True, return_counts=True)
    s = len(ids)
    a = np.full(s, np.inf)
    b = np.full(s, -np.inf)
    np.minimum.at(a, inv, tt)
    np.maximum.at(b, inv, tt)
    lt = log.t
    if hold:
        a, b = np.clip(a, lt[0], lt[-1]), np.clip(b, lt[0], lt[-1])
    # a scan spanning a gap of the log
    gaps = np.flatnonzero(np.diff(lt) > rep.max_gap)
    if len(gaps) and not interpolate:
        g0, g1 = lt[gaps], lt[gaps + 1]
        span = (g0[None, :] < b[:, None]) & (g1[None, :] > a[:, None])  # (S, gaps)
        if span.any():
            k, gk = np.unravel_index(int(np.argmax(span)), span.shape)
            raise InputError(f"scan {ids[k]} ({a[k]:g} s to {b[k]:g} s) spans a gap of the temperature log: no samples "
                             f"from {g0[gk]:g} s to {g1[gk]:g} s ({g1[gk] - g0[gk]:g} s > max_gap {rep.max_gap:g} s); "
                             "pass on_gap='interpolate' to interpolate across it")
    # knots: each scan's ends and the log samples strictly inside it
    i0 = np.searchsorted(lt, a, side="right")
    i1 = np.searchsorted(lt, b, side="left")
    n_in = np.maximum(i1 - i0, 0)
    first = np.concatenate(([0], np.cumsum(n_in + 2)[:-1]))
    q = np.empty(int((n_in + 2).sum()))
    q[first] = a
    q[first + n_in + 1] = b
    seg = np.repeat(np.arange(s), n_in)
    within = np.arange(int(n_in.sum())) - np.repeat(np.cumsum(n_in) - n_in, n_in)
    q[first[seg] + 1 + within] = lt[i0[seg] + within]
    kev, none_any, _ = _evaluate(q, log, rep, groups, interpolate)
    if none_any.any():
        j = int(np.argmax(none_any))
        k = int(np.searchsorted(first, j, side="right")) - 1
        raise InputError(f"scan {ids[k]} ({a[k]:g} s to {b[k]:g} s): no clean channel for policy {policy!r} at "
                         f"{q[j]:g} s inside the scan; pass on_gap='interpolate' to interpolate across it")
    y = kev.values  # (K, G)
    owner = np.repeat(np.arange(s), n_in + 2)
    dq = np.diff(q)
    area = 0.5 * (y[1:] + y[:-1]) * dq[:, None]
    same = owner[1:] == owner[:-1]
    integral = np.zeros((s, y.shape[1]))
    np.add.at(integral, owner[1:][same], area[same])
    dur = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(dur[:, None] > 0, integral / np.where(dur > 0, dur, 1.0)[:, None], y[first])
    temp = mean if policy == "per_axis" else mean[:, 0]
    per_point = temp[inv]
    across = np.zeros(s, dtype=bool)
    np.logical_or.at(across, owner, kev.bridged)
    if len(gaps):
        across |= ((lt[gaps][None, :] < b[:, None]) & (lt[gaps + 1][None, :] > a[:, None])).any(axis=1)
    for arr in (ids, a, b, temp, n_pts, per_point):
        arr.flags.writeable = False
    return ScanTemperatures(ids, a, b, temp, n_pts, per_point, summary, int(across.sum()))


# -- maps ---------------------------------------------------------------------------
def select_map_temperature(temperatures, error_map_set: ErrorMapSet, *, out_of_range: str = "raise"):
    """Check temperatures against the range an error map set covers.

    Parameters
    ----------
    temperatures : float or array_like, shape (N,) or (N, 3)
        Machine temperatures, degrees C (e.g. from :func:`temperatures_at`).
    error_map_set : ErrorMapSet
        The maps; their temperatures (``ErrorMapSet.temperatures``, degrees C)
        span the covered range.
    out_of_range : {'raise', 'clamp'}
        A temperature below the lowest or above the highest map temperature
        raises ``OutOfRangeError`` naming the first such row and value and the
        range; or is clamped to the range with a ``ClampWarning`` giving the
        count.

    Returns
    -------
    temperatures : ndarray, same shape as the input
        Degrees C, within the maps' range (a new array).
    clamped : int
        How many values were clamped (0 with ``'raise'``).

    Raises
    ------
    InputError
        Not numbers, NaN or infinite values (naming the row), not an
        ErrorMapSet, a bad ``out_of_range``.
    OutOfRangeError
        A temperature outside the maps' range, with ``out_of_range='raise'``.
    """
    if not isinstance(error_map_set, ErrorMapSet):
        raise InputError(f"error_map_set: expected a cmmpose.ErrorMapSet, got {type(error_map_set).__name__}")
    clamp = _option(out_of_range, "out_of_range", ("raise", "clamp")) == "clamp"
    try:
        temp = np.array(temperatures, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"temperatures: cannot be read as numbers in C ({exc})") from None
    if temp.ndim > 2:
        raise InputError(f"temperatures: expected a number, shape (N,) or (N, 3), got shape {temp.shape}")
    flat = temp.reshape(temp.shape[0] if temp.ndim else 1, -1)
    rows = ~np.isfinite(flat).all(axis=1)
    if rows.any():
        r = int(np.argmax(rows))
        raise InputError(f"temperatures: row {r} is {_fmt_row(flat[r])}; temperatures must be finite (C)")
    temps = [float(x) for x in error_map_set.temperatures]
    lo, hi = temps[0], temps[-1]
    out = (flat < lo) | (flat > hi)
    n_out = int(out.any(axis=1).sum())
    if n_out and not clamp:
        r = int(np.argmax(out.any(axis=1)))
        where = f"row {r}" if temp.ndim else "the temperature"
        col = int(np.argmax(out[r]))
        axis = f" ({'XYZ'[col]} axis)" if flat.shape[1] == 3 and temp.ndim == 2 else ""
        raise OutOfRangeError(
            f"{where}{axis}: temperature {flat[r, col]:g} C is outside the maps' range [{lo:g}, {hi:g}] C "
            f"(maps at {', '.join(f'{x:g}' for x in temps)} C; {n_out} of {flat.shape[0]} rows outside); "
            "pass out_of_range='clamp' to clamp instead")
    if n_out:
        temp = np.clip(temp, lo, hi)
        warnings.warn(f"clamped {n_out} of {flat.shape[0]} temperatures into the maps' range [{lo:g}, {hi:g}] C",
                      ClampWarning, stacklevel=2)
    return temp, n_out


def _fmt_row(row: np.ndarray) -> str:
    return f"{row[0]}" if row.shape[0] == 1 else "(" + ", ".join(f"{x:g}" for x in row) + ")"
