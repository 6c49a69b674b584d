"""A run's tables in memory: the columns of each, every column coerced to its type with the table and the row
named in messages, the tables compared bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime, timezone

import numpy as np

from ..errors import RunError
from ..schemas.run import SWEEP_AXES, TABLES

# run.json's ``schema`` and versions (SCHEMA, SCHEMA_VERSION, SUPPORTED_SCHEMA_VERSIONS) and the allowed roles
# of a temperature channel (CHANNEL_ROLES) and the sweep axes of scans.sweep_axis (SWEEP_AXES) live with run.json's
# schema (cmmpose.schemas.run), defined once there.

# Column name -> numpy dtype of each table, in file order. "str" columns are
# stored as numpy object arrays of Python str.
#: Columns of the points table: scan id, time (s), scan-plane u, v (mm), scale readings D, E, F (mm).
POINTS_COLUMNS = {
    "scan_id": "int32",
    "t": "float64",
    "u": "float64",
    "v": "float64",
    "D": "float64",
    "E": "float64",
    "F": "float64",
}
#: Columns of the scans table (sweep_speed in mm/s).
SCANS_COLUMNS = {
    "scan_id": "int32",
    "pose_id": "int32",
    "feature": "str",
    "position": "int32",
    "ball": "int32",
    "sweep_axis": "str",
    "sweep_direction": "int8",
    "sweep_speed": "float64",
}
#: Columns of the poses table: Euler 3-1-3 angles (degrees) and mount offset (mm).
POSES_COLUMNS = {
    "pose_id": "int32",
    "alpha": "float64",
    "beta": "float64",
    "gamma": "float64",
    "U1": "float64",
    "V1": "float64",
    "W1": "float64",
}
FIXED_COLUMNS = {"points": POINTS_COLUMNS, "scans": SCANS_COLUMNS, "poses": POSES_COLUMNS}


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


# -- where a problem is: a table name or a file ------------------------------------
class Where:
    """Label of one table in messages: the table name (constructor) or the
    file path (load); CSV files also give line numbers."""

    __slots__ = ("label", "csv")

    def __init__(self, label: str, csv: bool = False):
        self.label = label
        self.csv = csv

    def row(self, r: int) -> str:
        return f"row {r} (line {r + 2})" if self.csv else f"row {r}"

    def __str__(self) -> str:
        return self.label


class Labels:
    """Labels of the four tables and of the run.json fields."""

    def __init__(self, tables: dict[str, Where], json_prefix: str):
        self.tables = tables
        self.json = json_prefix

    @classmethod
    def in_memory(cls) -> Labels:
        return cls({t: Where(t) for t in TABLES}, "")


def first_index(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


# -- columns --------------------------------------------------------------------------
def as_column(values, dtype: str, name: str, where: Where, copy: bool) -> np.ndarray:
    """``values`` as a read-only 1-D contiguous column of ``dtype`` ('float64',
    'int32', 'int8' or 'str' = object array of str), checked: finite floats,
    integers in range, strings only."""
    try:
        a = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise RunError(f"{where}: column {name!r}: not an array ({exc})") from None
    if a.ndim != 1:
        raise RunError(f"{where}: column {name!r}: expected a 1-D array, got shape {a.shape}")
    if dtype == "str":
        out = _as_str_column(a, name, where)
    elif dtype == "float64":
        out = _as_float_column(a, name, where)
    else:
        out = _as_int_column(a, dtype, name, where)
    if copy and out.dtype != object and np.may_share_memory(out, a):
        out = out.copy()
    out = np.ascontiguousarray(out)
    out.flags.writeable = False
    return out


def _as_float_column(a: np.ndarray, name: str, where: Where) -> np.ndarray:
    if a.dtype.kind == "f":
        out = a.astype(np.float64, copy=False)
    elif a.dtype.kind in "iu":
        big = np.abs(a.astype(np.float64)) > 2.0**53
        if big.any():
            r = first_index(big)
            raise RunError(f"{where}: column {name!r}: integer {a[r]} at {where.row(r)} cannot be converted to float64 exactly")
        out = a.astype(np.float64)
    else:
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected float64 numbers")
    bad = ~np.isfinite(out)
    if bad.any():
        r = first_index(bad)
        raise RunError(f"{where}: column {name!r}: {out[r]} at {where.row(r)}; values must be finite")
    return out


def _as_int_column(a: np.ndarray, dtype: str, name: str, where: Where) -> np.ndarray:
    info = np.iinfo(dtype)
    if a.dtype.kind in "iu":
        bad = (a < info.min) | (a > info.max)
        if bad.any():
            r = first_index(bad)
            raise RunError(f"{where}: column {name!r}: {a[r]} at {where.row(r)} does not fit in {dtype}")
    elif a.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(a) | (a != np.round(a)) | (a < info.min) | (a > info.max)
        if bad.any():
            r = first_index(bad)
            raise RunError(f"{where}: column {name!r}: {a[r]} at {where.row(r)} is not an integer that fits in {dtype}")
    else:
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected integers ({dtype})")
    return a.astype(dtype, copy=False)


def _as_str_column(a: np.ndarray, name: str, where: Where) -> np.ndarray:
    if a.dtype.kind == "U":
        return a.astype(object)
    if a.dtype.kind != "O":
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected strings")
    # Only string columns (one entry per scan, never per point) are checked element-wise.
    is_str = np.fromiter((isinstance(x, str) for x in a), dtype=bool, count=a.size)
    if not is_str.all():
        r = first_index(~is_str)
        raise RunError(f"{where}: column {name!r}: {a[r]!r} at {where.row(r)} is not a string")
    return np.array([str(x) for x in a], dtype=object) if a.size else np.empty(0, dtype=object)


def as_table(columns, spec: dict[str, str], where: Where, copy: bool) -> dict[str, np.ndarray]:
    """Check a table (mapping of column name -> 1-D values) against ``spec``:
    every column present, no others, equal lengths; columns converted."""
    if not isinstance(columns, Mapping):
        raise RunError(f"{where}: expected a dict of column name -> 1-D array, got {type(columns).__name__}")
    missing = [c for c in spec if c not in columns]
    if missing:
        raise RunError(f"{where}: missing column {missing[0]!r} (expected columns {list(spec)})")
    extra = [c for c in columns if c not in spec]
    if extra:
        raise RunError(f"{where}: unexpected column {extra[0]!r} (expected columns {list(spec)})")
    out = {c: as_column(columns[c], dt, c, where, copy) for c, dt in spec.items()}
    lengths = {c: len(a) for c, a in out.items()}
    if len(set(lengths.values())) > 1:
        raise RunError(f"{where}: columns have different lengths {lengths}")
    return out


def check_unique(ids: np.ndarray, name: str, where: Where) -> None:
    order = np.argsort(ids, kind="stable")
    s = ids[order]
    dup = s[1:] == s[:-1]
    if dup.any():
        k = np.flatnonzero(dup)
        i = int(np.argmin(order[k + 1]))
        first, second = int(order[k[i]]), int(order[k[i] + 1])
        raise RunError(f"{where}: duplicate {name} {s[k[i] + 1]} at {where.row(second)} (first at {where.row(first)})")


def stack_columns(cols: dict[str, np.ndarray], names) -> np.ndarray:
    out = np.empty((len(cols[names[0]]), len(names)), dtype=np.float64)
    for k, c in enumerate(names):
        out[:, k] = cols[c]
    out.flags.writeable = False
    return out


def tables_equal(a, b) -> bool:
    if a is None or b is None:
        return a is b
    if a.keys() != b.keys():
        return False
    for c in a:
        x, y = a[c], b[c]
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
        if x.dtype == object:
            if not np.array_equal(x, y):
                return False
        elif not np.array_equal(x.view(f"u{x.itemsize}"), y.view(f"u{y.itemsize}")):
            return False
    return True


def check_scans(scans: dict, poses: dict, tw: dict) -> None:
    """The scans table against itself and the poses: unique ids, a sweep direction of +-1 and an axis X, Y or Z,
    a pose that the poses table holds (its ids unique)."""
    w = tw["scans"]
    check_unique(scans["scan_id"], "scan_id", w)
    bad = ~np.isin(scans["sweep_direction"], (1, -1))
    if bad.any():
        r = first_index(bad)
        raise RunError(f"{w}: column 'sweep_direction': {scans['sweep_direction'][r]} at {w.row(r)}; must be +1 or -1")
    bad = ~np.isin(scans["sweep_axis"], SWEEP_AXES)
    if bad.any():
        r = first_index(bad)
        raise RunError(f"{w}: column 'sweep_axis': {scans['sweep_axis'][r]!r} at {w.row(r)}; must be 'X', 'Y' or 'Z'")
    check_unique(poses["pose_id"], "pose_id", tw["poses"])
    bad = ~np.isin(scans["pose_id"], poses["pose_id"])
    if bad.any():
        r = first_index(bad)
        raise RunError(f"{w}: column 'pose_id': pose {scans['pose_id'][r]} at {w.row(r)} is not in {tw['poses']}")


def check_points(points: dict, scans: dict, tw: dict) -> np.ndarray:
    """The points table against the scans: each point's scan exists, its time does not decrease within the scan.
    Returns the points' order by scan (stable)."""
    w = tw["points"]
    sid, t = points["scan_id"], points["t"]
    bad = ~np.isin(sid, scans["scan_id"])
    if bad.any():
        r = first_index(bad)
        raise RunError(f"{w}: column 'scan_id': scan {sid[r]} at {w.row(r)} is not in {tw['scans']}")
    order = np.argsort(sid, kind="stable")
    s, ts = sid[order], t[order]
    back = (s[1:] == s[:-1]) & (ts[1:] < ts[:-1])
    if back.any():
        k = np.flatnonzero(back)
        i = int(np.argmin(order[k + 1]))
        r, p = int(order[k[i] + 1]), int(order[k[i]])
        raise RunError(f"{w}: column 't' decreases within scan {s[k[i] + 1]} at {w.row(r)} (t = {float(t[r])!r} s after {float(t[p])!r} s at {w.row(p)})")
    return order


def check_temperature_times(temps: dict, w: Where) -> None:
    """The temperatures table's times strictly increase."""
    tt = temps["t"]
    bad = tt[1:] <= tt[:-1]
    if bad.any():
        r = first_index(bad) + 1
        raise RunError(f"{w}: column 't' not strictly increasing at {w.row(r)} (t = {float(tt[r])!r} s after {float(tt[r - 1])!r} s)")
