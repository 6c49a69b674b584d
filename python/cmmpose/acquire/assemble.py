"""From the journal to a run: decode the records, fit the clocks, put every
point and temperature on one time base, and build the tables of
``cmmpose.Run`` (docs/protocols.md, "From journal to run").

The run's time base is the scanner's clock as it ran before its first reset:
points of that first clock segment keep their device time stamps exactly.
Every other clock segment (the scanner after a reset, every segment of the
logger) is carried over through the host clock: device -> host by its own fit,
host -> scanner time by the first segment's fit. That is how the logger's
readings are joined to the points: by corrected time.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from ..pose import MountOffset
from ..run import Run
from . import scpi
from .clock import ClockFit, fit_clock, fit_with_rate
from .plan import Plan
from .protocol import HEADER_SIZE
from .sequence import segments
from .store import JournalContents

__all__ = ["assemble", "HEADER_DTYPE"]

#: The frame header (before its CRC) as a NumPy record.
HEADER_DTYPE = np.dtype([("magic", "S4"), ("seq", "<u4"), ("time_us", "<u8"), ("scan", "<u4"), ("n", "<u2"),
                         ("flags", "<u2"), ("D", "<f8"), ("E", "<f8"), ("F", "<f8")])
_STREAMS = ("scanner", "thermo")
#: The largest scan number a run's int32 ``scan_id`` holds; a device's larger one is renumbered.
SCAN_ID_MAX = 2**31 - 1


def _fits(dev: np.ndarray, host: np.ndarray, seg: np.ndarray) -> list[ClockFit]:
    return [fit_clock(dev[seg == k], host[seg == k]) for k in range(int(seg.max()) + 1)] if len(seg) else []


def _borrow_rates(fits: list[ClockFit], dev, host, seg, fallback: float | None) -> list[ClockFit]:
    """Segments too short for a rate take the rate of the longest fitted one."""
    fitted = [f for f in fits if f.rate_fitted]
    rate = max(fitted, key=lambda f: f.span).rate if fitted else (fallback or 1.0)
    return [f if f.rate_fitted else fit_with_rate(dev[seg == k], host[seg == k], rate) for k, f in enumerate(fits)]


def _decode_scanner(frames: list[bytes]):
    heads = np.frombuffer(b"".join(f[: HEADER_DTYPE.itemsize] for f in frames), dtype=HEADER_DTYPE)
    uv = np.frombuffer(b"".join(f[HEADER_SIZE:-4] for f in frames), dtype="<f4").reshape(-1, 2)
    return heads, uv


def _summary(contents: JournalContents) -> dict:
    out = {s: {"records": 0, "rejected": {}, "gaps": 0, "missing": 0, "resets": 0, "reconnects": 0, "timeouts": 0}
           for s in _STREAMS}
    rejected = {s: Counter() for s in _STREAMS}
    backpressure = {"stalls": 0, "seconds": 0.0}
    for ev in contents.events:
        s, kind = ev.get("stream"), ev.get("type")
        if s not in out:
            if kind == "backpressure":
                backpressure["stalls"] += 1
                backpressure["seconds"] += float(ev.get("waited_s", 0.0))
            continue
        if kind == "rejected":
            rejected[s][ev.get("reason", "?")] += 1
        elif kind == "gap":
            out[s]["gaps"] += 1
            out[s]["missing"] += int(ev.get("missing", 0))
        elif kind == "reset":
            out[s]["resets"] += 1
        elif kind == "reconnected":
            out[s]["reconnects"] += 1
        elif kind == "timeout":
            out[s]["timeouts"] += 1
    for s in _STREAMS:
        out[s]["rejected"] = dict(sorted(rejected[s].items()))
    out["scanner"]["records"] = len(contents.scanner)
    out["thermo"]["records"] = len(contents.thermo)
    out["backpressure"] = backpressure
    return out


def _finite_points(points: dict) -> tuple[dict, dict]:
    """The points whose (u, v) and scale readings are finite, and what was
    left out: counted and named (the first scans), never dropped silently.
    The journal keeps every record as received, so nothing is lost: a later
    reader may decide otherwise."""
    bad_uv = ~(np.isfinite(points["u"]) & np.isfinite(points["v"]))
    bad_reading = ~(np.isfinite(points["D"]) & np.isfinite(points["E"]) & np.isfinite(points["F"]))
    bad = bad_uv | bad_reading
    excluded = {"non_finite_points": int((bad_uv & ~bad_reading).sum()), "non_finite_readings": int(bad_reading.sum())}
    if bad.any():
        excluded["scans"] = sorted({int(x) for x in points["scan_id"][bad]})[:10]
        points = {k: v[~bad] for k, v in points.items()}
    return points, excluded


def _infer_scan(scales: np.ndarray, t: np.ndarray) -> tuple[str, int, float]:
    """Sweep axis, direction and speed (mm/s) from one sweep's scale readings (mm) and times (s)."""
    if len(scales) < 2:
        return "X", 1, 0.0
    travel = scales[-1] - scales[0]
    a = int(np.argmax(np.ptp(scales, axis=0)))
    dt = float(t[-1] - t[0])
    speed = abs(float(travel[a])) / dt if dt > 0 else 0.0
    return "XYZ"[a], (1 if travel[a] >= 0 else -1), speed


def assemble(contents: JournalContents, plan: Plan, *, created: str, pose=(90.0, 90.0, 0.0), offset=None) -> Run:
    """Build the run from a journal's contents.

    Parameters
    ----------
    contents : JournalContents
        From ``read_journal``.
    plan : Plan
        Scans, poses, channels, artefact, maps.
    created : str
        ISO-8601 UTC time the recording started.
    pose : sequence of 3 float
        Pose (alpha, beta, gamma), degrees, used when the plan has no poses.
    offset : sequence of 3 float, optional
        Mount offset U1, V1, W1, mm, used when the plan has no poses; default the thesis digitizer.

    Returns
    -------
    Run
        With ``metadata["acquisition"]``: counts per stream (records, rejected by
        reason, gaps, missing sequence numbers, resets, reconnects, timeouts),
        backpressure, the clock fits, the logger-to-scanner offset and drift, and
        the journal's torn tail if any.
    """
    summary = _summary(contents)

    # -- scanner
    frames = [f for _, f in contents.scanner]
    s_host = np.array([h for h, _ in contents.scanner], dtype=float)
    if frames:
        heads, uv = _decode_scanner(frames)
        s_dev = heads["time_us"].astype(np.float64) * 1e-6
        s_seg, keep = segments(heads["seq"], heads["time_us"])
    else:
        heads, uv = np.empty(0, HEADER_DTYPE), np.empty((0, 2), np.float32)
        s_dev, s_seg, keep = np.empty(0), np.empty(0, np.int64), np.empty(0, bool)

    # -- logger
    names = [ch["name"] for ch in plan.temperature_channels]
    rows = [scpi.parse_reply(line, len(names)).scan for _, _, line in contents.thermo]
    good = np.array([r is not None for r in rows], dtype=bool)
    rows = [r for r in rows if r is not None]
    t_host = np.array([rx for (_, rx, _), g in zip(contents.thermo, good) if g], dtype=float)
    t_dev = np.array([np.mean(r.times) for r in rows], dtype=float)
    t_vals = np.array([r.values for r in rows], dtype=float).reshape(len(rows), len(names))
    t_seg = segments(None, t_dev)[0] if len(t_dev) else np.empty(0, np.int64)

    ref, s_fits, l_fits, clock = _clocks(s_dev[keep], s_host[keep], s_seg[keep], keep.any(), t_dev, t_host, t_seg)

    # -- points
    counts_all = heads["n"].astype(np.int64)
    starts = (np.cumsum(counts_all) - counts_all)[keep]
    heads, s_dev, s_seg = heads[keep], s_dev[keep], s_seg[keep]
    counts = counts_all[keep]
    t_rec = _to_run_time(s_dev, s_seg, s_fits, ref) if len(s_dev) else np.empty(0)
    ids, origin, renumbered = _scan_ids(s_seg, heads["scan"])
    order = np.lexsort((t_rec, ids))
    c = counts[order]
    take = np.repeat(starts[order] - (np.cumsum(c) - c), c) + np.arange(int(c.sum()))
    rep = np.repeat(order, c)
    uv64 = uv.astype(np.float64)[take] if len(take) else np.empty((0, 2))
    points = {"scan_id": ids[rep].astype(np.int32), "t": t_rec[rep], "u": uv64[:, 0], "v": uv64[:, 1],
              "D": heads["D"][rep], "E": heads["E"][rep], "F": heads["F"][rep]}
    points, summary["scanner"]["excluded"] = _finite_points(points)

    # -- scans and poses
    poses = _pose_table(plan, pose, offset)
    scans = _scan_table(plan, ids, origin, heads, t_rec, int(poses["pose_id"][0]))

    # -- temperatures
    t_run = _to_run_time(t_dev, t_seg, l_fits, ref) if len(t_dev) else np.empty(0)
    temps, summary["thermo"]["dropped_same_time"] = _temperature_table(t_run, t_vals, names)
    summary["scanner"]["points"] = int(counts.sum())
    summary["scanner"]["renumbered_scans"] = renumbered
    summary["clock"] = clock
    summary["journal"] = {"blocks": contents.blocks, "bytes": contents.good_bytes,
                          "torn_tail": None if contents.torn_tail is None else vars(contents.torn_tail)}
    return Run(
        points=points, scans=scans, poses=poses, temperatures=temps,
        temperature_channels=[{"name": ch["name"], "role": ch["role"], "channel": ch["channel"]} for ch in plan.temperature_channels],
        artefact=plan.artefact, maps=plan.maps, metadata={**plan.metadata, "acquisition": summary}, created=created,
    )


def _clocks(s_dev, s_host, s_seg, any_scans: bool, t_dev, t_host, t_seg):
    """The clock fits of the scanner's (kept frames) and the logger's segments, the one run time is counted in
    (the scanner's first segment, else the logger's, else the host's), and the record of them for the summary:
    (reference fit, scanner fits, logger fits, clock summary)."""
    s_fits = _fits(s_dev, s_host, s_seg) if any_scans else []
    l_fits = _fits(t_dev, t_host, t_seg)
    s_fits = _borrow_rates(s_fits, s_dev, s_host, s_seg, None) if s_fits else []
    donor = max((f for f in s_fits if f.rate_fitted), key=lambda f: f.span, default=None)
    l_fits = _borrow_rates(l_fits, t_dev, t_host, t_seg, donor.rate if donor else None) if l_fits else []
    if s_fits:
        ref = s_fits[0]
        base = "scanner clock (segment 0)"
    elif l_fits:
        ref = l_fits[0]
        base = "logger clock (segment 0)"
    else:
        ref = ClockFit(0.0, 1.0, 0, 0.0, 0.0, 0.0, False)
        base = "host clock"
    clock: dict = {"time_base": base, "scanner_segments": [f.to_dict() for f in s_fits],
                   "thermo_segments": [f.to_dict() for f in l_fits]}
    if s_fits and l_fits:
        # logger time L -> scanner time S: S = (cL + rL L - cS) / rS
        sf, lf = s_fits[0], l_fits[0]
        clock["thermo_to_scanner"] = {"offset_s": (lf.offset - sf.offset) / sf.rate, "rate": lf.rate / sf.rate,
                                      "drift_ppm": (lf.rate / sf.rate - 1.0) * 1e6,
                                      "meaning": "scanner_time = offset_s + rate * logger_time (first clock segments)"}
    return ref, s_fits, l_fits, clock


def _to_run_time(dev, seg, fits, ref) -> np.ndarray:
    """Device times of a stream's clock segments in run time (the reference fit's device clock)."""
    out = np.empty(len(dev))
    for k, f in enumerate(fits):
        m = seg == k
        out[m] = dev[m] if f is ref else ref.device(f.host(dev[m]))
    return out


def _scan_ids(seg, scan) -> tuple[np.ndarray, dict, list]:
    """The run's scan id of each frame (by clock segment and scanner scan number): a scan number already used in
    an earlier segment, or one the run's int32 cannot hold, gets the next free one. (ids, scan id -> the scanner's
    number, the renumbered ones for the summary)."""
    ids = np.empty(len(scan), dtype=np.int64)
    assigned: dict[tuple[int, int], int] = {}
    used: set[int] = set()
    origin: dict[int, int] = {}
    renumbered = []
    for i, (sg, sc) in enumerate(zip(seg.tolist(), scan.tolist())):
        key = (sg, sc)
        if key not in assigned:
            # A scan number already used, or one the run's int32 cannot hold, gets the next free one.
            fits = sc <= SCAN_ID_MAX
            new = sc if fits and sc not in used else max(used | ({sc} if fits else {-1})) + 1
            if new != sc:
                renumbered.append({"segment": sg, "scan": sc, "scan_id": new,
                                   **({"reason": "beyond int32"} if sc > SCAN_ID_MAX else {})})
            assigned[key] = new
            used.add(new)
            origin[new] = sc
        ids[i] = assigned[key]
    return ids, origin, renumbered


def _pose_table(plan: Plan, pose, offset) -> dict:
    """The plan's poses; without any, the one pose and mount offset given (default the thesis digitizer's)."""
    if plan.poses:
        return {c: np.array([p[c] for p in plan.poses]) for c in ("pose_id", "alpha", "beta", "gamma", "U1", "V1", "W1")}
    off = MountOffset.thesis() if offset is None else MountOffset(*(float(x) for x in offset))
    return {"pose_id": np.array([0]), "alpha": np.array([float(pose[0])]), "beta": np.array([float(pose[1])]),
            "gamma": np.array([float(pose[2])]), "U1": np.array([off[0]]), "V1": np.array([off[1]]), "W1": np.array([off[2]])}


def _scan_table(plan: Plan, ids, origin: dict, heads, t_rec, default_pose: int) -> dict:
    """The scans table: a planned scan as the plan says; one the plan lacks at the default pose, its sweep axis,
    direction and speed inferred from the scale readings."""
    planned = {int(s["scan_id"]): s for s in plan.scans}
    scan_rows = []
    for sid in sorted(set(ids.tolist())):
        m = ids == sid
        p = planned.get(origin[sid])
        if p is not None:
            scan_rows.append({**p, "scan_id": sid})
        else:
            sel = np.flatnonzero(m & np.isfinite(heads["D"]) & np.isfinite(heads["E"]) & np.isfinite(heads["F"]))
            sel = sel[np.argsort(t_rec[sel], kind="stable")]
            axis, direction, speed = _infer_scan(np.column_stack([heads["D"][sel], heads["E"][sel], heads["F"][sel]]), t_rec[sel])
            scan_rows.append({"scan_id": sid, "pose_id": default_pose, "feature": "unknown", "position": -1, "ball": -1,
                              "sweep_axis": axis, "sweep_direction": direction, "sweep_speed": speed})
    scan_cols = ("scan_id", "pose_id", "feature", "position", "ball", "sweep_axis", "sweep_direction", "sweep_speed")
    scans = {c: np.array([r[c] for r in scan_rows], dtype=object if c in ("feature", "sweep_axis") else None)
             if scan_rows else np.empty(0, dtype=object if c in ("feature", "sweep_axis") else np.int32)
             for c in scan_cols}
    if scan_rows:
        scans["sweep_speed"] = scans["sweep_speed"].astype(float)
    return scans


def _temperature_table(t_run, t_vals, names) -> tuple[dict, int]:
    """The temperatures table in time order, a reading at a time already read dropped; and how many were."""
    o = np.argsort(t_run, kind="stable")
    t_sorted = t_run[o]
    inc = np.concatenate([[True], np.diff(t_sorted) > 0]) if len(o) else np.empty(0, bool)
    temps = {"t": t_sorted[inc], **{n: t_vals[o][inc][:, k] for k, n in enumerate(names)}}
    return temps, int((~inc).sum())
