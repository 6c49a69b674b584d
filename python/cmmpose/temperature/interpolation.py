"""Temperatures at time stamps from a thermocouple log:
:func:`temperatures_at` interpolates each channel's clean samples (see
:func:`~cmmpose.temperature.check_log`) in time at the points' time stamps
and applies a combination: ``'machine_mean'`` (the thesis: mean of the
axis-scale channels), ``'per_axis'`` (one temperature per axis, for
per-carriage maps), ``'role:ROLE'`` (the clean channels of one thermocouple
role) or ``'channel:NAME'``; :func:`per_scan_temperature` gives one
temperature per scan (the time average over the scan's duration).

Units: times in s, temperatures in degrees C. Rows in messages are counted
from 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._lazy import LazyModule
from ..errors import InputError, InputTypeError
from .log import LogColumns, LogReport, check_log, read_log

# The run format loads on first use (tests/compensation/test_pipeline_and_import_footprint.py).
_run = LazyModule("cmmpose.run")

__all__ = ["temperatures_at", "per_scan_temperature", "ThermalSummary", "ScanTemperatures", "POLICIES", "AXIS_ROLES"]

#: Combinations of :func:`temperatures_at` (plus ``'role:ROLE'`` and ``'channel:NAME'``).
POLICIES = ("machine_mean", "per_axis", "role:ROLE", "channel:NAME")
#: Roles of the axis-scale channels, in X, Y, Z order.
AXIS_ROLES = ("x_scale", "y_scale", "z_scale")


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


# -- temperatures at time stamps ----------------------------------------------------
def _groups(policy, log: LogColumns) -> tuple[str, list[tuple[str, list[int]]]]:
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


def _describe_channels(log: LogColumns) -> str:
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


def _check_report(report, log: LogColumns, temperatures, channels) -> LogReport:
    if report is None:
        return check_log(temperatures, channels)
    if not isinstance(report, LogReport):
        raise InputTypeError(f"report: expected a LogReport from check_log, got {type(report).__name__}")
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


def _evaluate(tq: np.ndarray, log: LogColumns, rep: LogReport, groups, interpolate: bool) -> tuple[_Eval, np.ndarray, list]:
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


def _why(row: int, tq: float, log: LogColumns, rep: LogReport, label: str, chans: list[int],
         can_bridge: bool) -> InputError:
    """The error for a point with no usable channel of a group."""
    where = f"point row {row} (t = {tq:g} s)"
    t = log.t
    k = int(np.searchsorted(t, tq, side="right")) - 1
    if 0 <= k < len(t) - 1 and t[k] < tq and t[k + 1] - t[k] > rep.max_gap:
        return InputError(f"{where} falls in a gap of the temperature log: no samples from {t[k]:g} s to "
                          f"{t[k + 1]:g} s ({t[k + 1] - t[k]:g} s > max_gap {rep.max_gap:g} s)", row=row,
                          option="on_gap", remedy="on_gap")
    names = [log.names[c] for c in chans]
    near = [str(p) for p in rep.problems
            if p.channel in names and p.start - rep.max_gap <= tq <= p.end + rep.max_gap]
    return InputError(f"{where}: no clean {label} reading ({', '.join(names)}) within max_gap {rep.max_gap:g} s"
                      + (f" [{'; '.join(near)}]" if near else ""), row=row,
                      option="on_gap" if can_bridge else None, remedy="on_gap_stretch" if can_bridge else None)


def _all_broken(log: LogColumns, rep: LogReport, groups, policy: str) -> None:
    for label, g in groups:
        if not rep.clean[:, g].any():
            names = [log.names[k] for k in g]
            why = "; ".join(str(p) for p in rep.problems if p.channel in names)
            raise InputError(f"policy {policy!r}: every {label} channel is unusable ({', '.join(names)}): {why}")


def _select(t, temperatures, channels, policy, report, on_gap, out_of_range):
    """Shared body of temperatures_at and per_scan_temperature."""
    log = read_log(temperatures, channels)
    if isinstance(temperatures, _run.Run) and channels is None:
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
                             + (f"; {int(outside.sum())} points in all" if outside.sum() > 1 else ""),
                             row=r, option="out_of_range", remedy="log_end_hold")
        gi = next(i for i, m in enumerate(per_group) if m[r])
        glabel, g = groups[gi]
        can_bridge = not interpolate and _bridgeable(tq_eff[r], log, rep, g)
        raise _why(r, float(tq[r]), log, rep, glabel, g, can_bridge)
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


def _bridgeable(tq: float, log: LogColumns, rep: LogReport, g: list[int]) -> bool:
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
    sid = _scan_ids(scan_id, tt)
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
                             f"from {g0[gk]:g} s to {g1[gk]:g} s ({g1[gk] - g0[gk]:g} s > max_gap {rep.max_gap:g} s)",
                             option="on_gap", remedy="on_gap")
    q, first, n_in = _knots(lt, a, b)
    kev, none_any, _ = _evaluate(q, log, rep, groups, interpolate)
    if none_any.any():
        j = int(np.argmax(none_any))
        k = int(np.searchsorted(first, j, side="right")) - 1
        raise InputError(f"scan {ids[k]} ({a[k]:g} s to {b[k]:g} s): no clean channel for policy {policy!r} at "
                         f"{q[j]:g} s inside the scan", option="on_gap", remedy="on_gap")
    owner = np.repeat(np.arange(s), n_in + 2)
    mean = _time_means(q, kev.values, owner, first, a, b)
    temp = mean if policy == "per_axis" else mean[:, 0]
    per_point = temp[inv]
    across = np.zeros(s, dtype=bool)
    np.logical_or.at(across, owner, kev.bridged)
    if len(gaps):
        across |= ((lt[gaps][None, :] < b[:, None]) & (lt[gaps + 1][None, :] > a[:, None])).any(axis=1)
    for arr in (ids, a, b, temp, n_pts, per_point):
        arr.flags.writeable = False
    return ScanTemperatures(ids, a, b, temp, n_pts, per_point, summary, int(across.sum()))


def _scan_ids(scan_id, tt: np.ndarray) -> np.ndarray:
    """The points' scan ids: one per time, integers (whole floats taken as such)."""
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
    return sid


def _knots(lt: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The times the log is evaluated at: each scan's ends [a, b] and the log samples strictly inside it, scan after
    scan; (times, index of each scan's first, samples inside each)."""
    s = len(a)
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
    return q, first, n_in


def _time_means(q: np.ndarray, y: np.ndarray, owner: np.ndarray, first: np.ndarray, a: np.ndarray,
                b: np.ndarray) -> np.ndarray:
    """Each scan's time mean of the temperatures ``y`` (K, G) at the knots ``q`` (trapezoids between knots of one
    scan); a scan of no duration takes the value at its time."""
    s = len(a)
    dq = np.diff(q)
    area = 0.5 * (y[1:] + y[:-1]) * dq[:, None]
    same = owner[1:] == owner[:-1]
    integral = np.zeros((s, y.shape[1]))
    np.add.at(integral, owner[1:][same], area[same])
    dur = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(dur[:, None] > 0, integral / np.where(dur > 0, dur, 1.0)[:, None], y[first])
