"""The measurement run format: one directory per run, simulated or recorded by
acquisition (docs/formats.md, "Measurement run").

A run directory holds ``run.json`` (schema, artefact, which maps apply, the
temperature channels, free metadata) and four tables: ``points``, ``scans``,
``poses`` and, when there are temperature channels, ``temperatures``. Tables
are Parquet files; a table whose ``.parquet`` file is missing is read from a
``.csv`` file of the same name with a header row of the same column names.
An optional ``truth/`` folder holds what a simulator knows and analysis must
never read: :meth:`Run.load` never opens it, :func:`load_truth` does.

Units: t in s, u, v, D, E, F, U1, V1, W1 in mm, alpha, beta, gamma in degrees
(Euler 3-1-3), sweep speed in mm/s, temperatures in degrees C. Rows in error
messages are counted from 0 (the first data row); CSV messages also give the
line of the file.
"""

from __future__ import annotations

import json
import logging
import math
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from datetime import datetime, timezone
from functools import cached_property
from operator import index as _as_index
from pathlib import Path

import numpy as np

from ._lazy import LazyModule
from .atomicfile import staged_folder
from .errors import RunError, RunFileError, read_input_text
from .schemas import loads_json, validate
from .schemas.run import CHANNEL_ROLES, SCHEMA, SCHEMA_VERSION, SUPPORTED_SCHEMA_VERSIONS, SWEEP_AXES, TABLES
from .formats.pointformats.common import parquet_options

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pc = LazyModule("pyarrow.compute")
pa_csv = LazyModule("pyarrow.csv")
pq = LazyModule("pyarrow.parquet")

_log = logging.getLogger("cmmpose.run")

__all__ = [
    "Run",
    "check_run_target",
    "RunError",
    "load_truth",
    "SCHEMA",
    "SCHEMA_VERSION",
    "SUPPORTED_SCHEMA_VERSIONS",
    "CHANNEL_ROLES",
    "POINTS_COLUMNS",
    "SCANS_COLUMNS",
    "POSES_COLUMNS",
    "RUN_FILES",
]


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
_TABLES = TABLES
_FIXED = {"points": POINTS_COLUMNS, "scans": SCANS_COLUMNS, "poses": POSES_COLUMNS}
#: Arrow type (a ``pyarrow`` factory's name) of each column type.
_ARROW = {"int32": "int32", "int8": "int8", "float64": "float64", "str": "string"}
_JSON_KEYS = ("schema", "schema_version", "created", "artefact", "maps", "temperature_channels", "metadata", "rows")
_TRUTH_DIR, _TRUTH_ARRAYS, _TRUTH_INFO = "truth", "truth.npz", "truth.json"
#: The files a run directory consists of (relative to it); nothing else in it is the run's.
RUN_FILES = ("run.json", *(f"{t}{s}" for t in _TABLES for s in (".parquet", ".csv")),
             f"{_TRUTH_DIR}/{_TRUTH_ARRAYS}", f"{_TRUTH_DIR}/{_TRUTH_INFO}")
_FLOAT_RE = r"^\s*[+-]?(nan|inf|infinity|(\d+\.?\d*|\.\d+)(e[+-]?\d+)?)\s*$"
_INT_RE = r"^\s*[+-]?\d+\s*$"


def _utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


# -- where a problem is: a table name or a file ------------------------------------
class _Where:
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


class _Labels:
    """Labels of the four tables and of the run.json fields."""

    def __init__(self, tables: dict[str, _Where], json_prefix: str):
        self.tables = tables
        self.json = json_prefix

    @classmethod
    def in_memory(cls) -> _Labels:
        return cls({t: _Where(t) for t in _TABLES}, "")


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


# -- columns --------------------------------------------------------------------------
def _as_column(values, dtype: str, name: str, where: _Where, copy: bool) -> np.ndarray:
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


def _as_float_column(a: np.ndarray, name: str, where: _Where) -> np.ndarray:
    if a.dtype.kind == "f":
        out = a.astype(np.float64, copy=False)
    elif a.dtype.kind in "iu":
        big = np.abs(a.astype(np.float64)) > 2.0**53
        if big.any():
            r = _first(big)
            raise RunError(f"{where}: column {name!r}: integer {a[r]} at {where.row(r)} cannot be converted to float64 exactly")
        out = a.astype(np.float64)
    else:
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected float64 numbers")
    bad = ~np.isfinite(out)
    if bad.any():
        r = _first(bad)
        raise RunError(f"{where}: column {name!r}: {out[r]} at {where.row(r)}; values must be finite")
    return out


def _as_int_column(a: np.ndarray, dtype: str, name: str, where: _Where) -> np.ndarray:
    info = np.iinfo(dtype)
    if a.dtype.kind in "iu":
        bad = (a < info.min) | (a > info.max)
        if bad.any():
            r = _first(bad)
            raise RunError(f"{where}: column {name!r}: {a[r]} at {where.row(r)} does not fit in {dtype}")
    elif a.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(a) | (a != np.round(a)) | (a < info.min) | (a > info.max)
        if bad.any():
            r = _first(bad)
            raise RunError(f"{where}: column {name!r}: {a[r]} at {where.row(r)} is not an integer that fits in {dtype}")
    else:
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected integers ({dtype})")
    return a.astype(dtype, copy=False)


def _as_str_column(a: np.ndarray, name: str, where: _Where) -> np.ndarray:
    if a.dtype.kind == "U":
        return a.astype(object)
    if a.dtype.kind != "O":
        raise RunError(f"{where}: column {name!r}: has dtype {a.dtype}, expected strings")
    # Only string columns (one entry per scan, never per point) are checked element-wise.
    is_str = np.fromiter((isinstance(x, str) for x in a), dtype=bool, count=a.size)
    if not is_str.all():
        r = _first(~is_str)
        raise RunError(f"{where}: column {name!r}: {a[r]!r} at {where.row(r)} is not a string")
    return np.array([str(x) for x in a], dtype=object) if a.size else np.empty(0, dtype=object)


def _from_arrow(col: pa.ChunkedArray, dtype: str, name: str, where: _Where) -> np.ndarray:
    """An Arrow column (from Parquet or CSV) as numpy, before ``_as_column``;
    nulls and non-numeric text are reported with their first row."""
    if col.null_count:
        r = _first(col.is_null().to_numpy(zero_copy_only=False))
        raise RunError(f"{where}: column {name!r}: empty value at {where.row(r)}")
    t = col.type
    if pa.types.is_null(t):  # an empty CSV column
        return np.empty(0, dtype=object if dtype == "str" else dtype)
    if pa.types.is_dictionary(t):
        col, t = col.cast(t.value_type), t.value_type
    text = pa.types.is_string(t) or pa.types.is_large_string(t)
    if dtype == "str":
        if not text:
            raise RunError(f"{where}: column {name!r}: has type {t}, expected strings")
    elif text:
        ok = pc.match_substring_regex(col, _FLOAT_RE if dtype == "float64" else _INT_RE, ignore_case=True)
        bad = ~ok.to_numpy(zero_copy_only=False)
        kind = "a number" if dtype == "float64" else "an integer"
        if bad.any():
            r = _first(bad)
            raise RunError(f"{where}: column {name!r}: {col[r].as_py()!r} at {where.row(r)} is not {kind}")
        raise RunError(f"{where}: column {name!r}: has type {t}, expected {dtype}")
    elif not (pa.types.is_integer(t) or pa.types.is_floating(t)):
        raise RunError(f"{where}: column {name!r}: has type {t}, expected {dtype}")
    return col.to_numpy(zero_copy_only=False)


def _table(columns, spec: dict[str, str], where: _Where, copy: bool) -> dict[str, np.ndarray]:
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
    out = {c: _as_column(columns[c], dt, c, where, copy) for c, dt in spec.items()}
    lengths = {c: len(a) for c, a in out.items()}
    if len(set(lengths.values())) > 1:
        raise RunError(f"{where}: columns have different lengths {lengths}")
    return out


def _duplicates(ids: np.ndarray, name: str, where: _Where) -> None:
    order = np.argsort(ids, kind="stable")
    s = ids[order]
    dup = s[1:] == s[:-1]
    if dup.any():
        k = np.flatnonzero(dup)
        i = int(np.argmin(order[k + 1]))
        first, second = int(order[k[i]]), int(order[k[i] + 1])
        raise RunError(f"{where}: duplicate {name} {s[k[i] + 1]} at {where.row(second)} (first at {where.row(first)})")


def _check_json_value(value, what: str) -> object:
    """A deep copy of ``value`` through JSON; anything that would not come back
    equal from run.json (tuples, non-str keys, NaN, numpy scalars) is refused."""
    try:
        text = json.dumps(value, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise RunError(f"{what}: not storable as JSON ({exc})") from None
    back = json.loads(text)
    if back != value:
        raise RunError(f"{what}: does not survive a JSON round trip unchanged (use lists, str keys, plain int/float/str/bool/None)")
    return back


#: Artefact entries the evaluation and diagnosis compute with: positive mm.
ARTEFACT_NUMBERS = ("ball_radius_mm", "calibrated_length_mm", "calibrated_radius_mm")


def _check_artefact_numbers(artefact: dict, what: str) -> None:
    """The artefact's sizes are numbers (not "12.7", not true), finite and > 0."""
    items = [(k, artefact[k]) for k in ARTEFACT_NUMBERS if k in artefact]
    ref = artefact.get("reference_sphere")
    if isinstance(ref, dict) and "radius_mm" in ref:
        items.append(("reference_sphere.radius_mm", ref["radius_mm"]))
    for key, v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise RunError(f"{what}.{key}: expected a positive number of mm, got {v!r}")


def _check_created(created, what: str) -> str:
    if not isinstance(created, str):
        raise RunError(f"{what}: expected an ISO-8601 UTC time string, got {type(created).__name__}")
    try:
        when = datetime.fromisoformat(created)
    except ValueError:
        raise RunError(f"{what}: {created!r} is not an ISO-8601 time") from None
    if when.utcoffset() is None or when.utcoffset().total_seconds() != 0:
        raise RunError(f"{what}: {created!r} is not UTC (end it with 'Z' or '+00:00')")
    return created


def _check_channels(channels, prefix: str) -> list[dict]:
    what = f"{prefix}temperature_channels"
    if not isinstance(channels, list):
        raise RunError(f"{what}: expected a list of {{'name': ..., 'role': ...}}, got {type(channels).__name__}")
    channels = _check_json_value(channels, what)
    seen: set[str] = set()
    for k, ch in enumerate(channels):
        w = f"{what}[{k}]"
        if not isinstance(ch, dict):
            raise RunError(f"{w}: expected an object with 'name' and 'role', got {ch!r}")
        name = ch.get("name")
        if not isinstance(name, str) or not name:
            raise RunError(f"{w}: 'name' must be a non-empty string, got {name!r}")
        if name == "t":
            raise RunError(f"{w}: a channel may not be named 't' (the time column)")
        if name in seen:
            raise RunError(f"{w}: duplicate channel name {name!r}")
        seen.add(name)
        if "role" not in ch:
            raise RunError(f"{w}: channel {name!r} has no 'role' (allowed: {', '.join(CHANNEL_ROLES)})")
        if ch["role"] not in CHANNEL_ROLES:
            raise RunError(f"{w}: unknown role {ch['role']!r} of channel {name!r} (allowed: {', '.join(CHANNEL_ROLES)})")
    return channels


# -- the run ------------------------------------------------------------------------
def check_run_target(run_dir, *, overwrite: bool = False) -> Path:
    """The checks :meth:`Run.save` makes, to make before any work: ``RunError`` if ``run_dir`` is not a
    folder, or (without ``overwrite``) is a folder that holds anything."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise RunError(f"{run_dir}: exists and is not a directory")
    if run_dir.is_dir() and any(run_dir.iterdir()) and not overwrite:
        raise RunError(f"{run_dir}: directory is not empty", file=str(run_dir), option="overwrite",
                       remedy="overwrite_run")
    return run_dir


@dataclass(frozen=True, eq=False, repr=False)
class Run:
    """One measurement run: points, scans, poses, temperatures and what they
    were measured on.

    Every table is a dict of column name -> 1-D numpy array; the constructor
    checks and converts them (the same checks as :meth:`load`, messages naming
    the table, column and row) and stores read-only copies, so the inputs are
    never modified nor shared.

    Parameters
    ----------
    points : dict of str -> array_like, each shape (N,)
        ``scan_id`` (int32), ``t`` (float64, s, non-decreasing within each
        scan), ``u``, ``v`` (float64, mm, scan plane), ``D``, ``E``, ``F``
        (float64, mm, scale readings). One row per point.
    scans : dict of str -> array_like, each shape (S,)
        ``scan_id`` (int32, unique), ``pose_id`` (int32, in poses),
        ``feature`` (str, e.g. "ball"), ``position`` (int32, e.g. B89
        position, -1 if none), ``ball`` (int32, 1 or 2, -1 if none),
        ``sweep_axis`` (str, "X", "Y" or "Z"), ``sweep_direction`` (int8, +1
        or -1), ``sweep_speed`` (float64, mm/s).
    poses : dict of str -> array_like, each shape (P,)
        ``pose_id`` (int32, unique), ``alpha``, ``beta``, ``gamma`` (float64,
        degrees, Euler 3-1-3), ``U1``, ``V1``, ``W1`` (float64, mm, mount
        offset).
    temperatures : dict of str -> array_like, each shape (M,), or None
        ``t`` (float64, s, strictly increasing) and one float64 column per
        channel of ``temperature_channels`` (degrees C). None only when there
        are no channels.
    temperature_channels : list of dict
        ``{"name": str, "role": str}`` per channel (other keys are kept);
        roles are those of ``CHANNEL_ROLES``.
    artefact, maps, metadata : dict
        Free JSON data: the artefact (e.g. ``{"kind": "ballbar", "radius_mm":
        38.125, "length_mm": 404.2}``), which error maps apply (e.g.
        ``{"kind": "bundled", "name": "thesis"}``), anything else. Must come
        back equal from JSON (lists not tuples, str keys, finite numbers).
    created : str
        ISO-8601 UTC time the run was made, e.g. "2025-01-31T12:00:00Z";
        default now.
    """

    points: dict[str, np.ndarray]
    scans: dict[str, np.ndarray]
    poses: dict[str, np.ndarray]
    temperatures: dict[str, np.ndarray] | None = None
    temperature_channels: list[dict] = field(default_factory=list)
    artefact: dict = field(default_factory=dict)
    maps: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    created: str = field(default_factory=_utc_now)

    def __post_init__(self):
        self._validate(_Labels.in_memory(), copy=True)

    # -- validation, shared by the constructor and load -----------------------------
    def _validate(self, labels: _Labels, copy: bool) -> None:
        set_ = object.__setattr__
        j = labels.json
        for name in ("artefact", "maps", "metadata"):
            value = getattr(self, name)
            if not isinstance(value, dict):
                raise RunError(f"{j}{name}: expected a dict (JSON object), got {type(value).__name__}")
            set_(self, name, _check_json_value(value, f"{j}{name}"))
        _check_artefact_numbers(self.artefact, f"{j}artefact")
        set_(self, "created", _check_created(self.created, f"{j}created"))
        channels = _check_channels(self.temperature_channels, j)
        set_(self, "temperature_channels", channels)

        tw = labels.tables
        points = _table(self.points, POINTS_COLUMNS, tw["points"], copy)
        scans = _table(self.scans, SCANS_COLUMNS, tw["scans"], copy)
        poses = _table(self.poses, POSES_COLUMNS, tw["poses"], copy)
        names = [ch["name"] for ch in channels]
        if self.temperatures is None:
            if names:
                raise RunError(f"{tw['temperatures']}: missing, but {j}temperature_channels lists {len(names)} channels ({', '.join(names)})")
            temps = None
        else:
            w = tw["temperatures"]
            if isinstance(self.temperatures, Mapping):
                absent = [n for n in names if n not in self.temperatures]
                if absent:
                    raise RunError(f"{w}: missing column {absent[0]!r} (a channel listed in {j}temperature_channels)")
            temps = _table(self.temperatures, {"t": "float64", **{n: "float64" for n in names}}, w, copy)

        # scans: unique ids, allowed values, poses exist
        w = tw["scans"]
        _duplicates(scans["scan_id"], "scan_id", w)
        bad = ~np.isin(scans["sweep_direction"], (1, -1))
        if bad.any():
            r = _first(bad)
            raise RunError(f"{w}: column 'sweep_direction': {scans['sweep_direction'][r]} at {w.row(r)}; must be +1 or -1")
        bad = ~np.isin(scans["sweep_axis"], SWEEP_AXES)
        if bad.any():
            r = _first(bad)
            raise RunError(f"{w}: column 'sweep_axis': {scans['sweep_axis'][r]!r} at {w.row(r)}; must be 'X', 'Y' or 'Z'")
        _duplicates(poses["pose_id"], "pose_id", tw["poses"])
        bad = ~np.isin(scans["pose_id"], poses["pose_id"])
        if bad.any():
            r = _first(bad)
            raise RunError(f"{w}: column 'pose_id': pose {scans['pose_id'][r]} at {w.row(r)} is not in {tw['poses']}")

        # points: scans exist, t non-decreasing within each scan
        w = tw["points"]
        sid, t = points["scan_id"], points["t"]
        bad = ~np.isin(sid, scans["scan_id"])
        if bad.any():
            r = _first(bad)
            raise RunError(f"{w}: column 'scan_id': scan {sid[r]} at {w.row(r)} is not in {tw['scans']}")
        order = np.argsort(sid, kind="stable")
        s, ts = sid[order], t[order]
        back = (s[1:] == s[:-1]) & (ts[1:] < ts[:-1])
        if back.any():
            k = np.flatnonzero(back)
            i = int(np.argmin(order[k + 1]))
            r, p = int(order[k[i] + 1]), int(order[k[i]])
            raise RunError(f"{w}: column 't' decreases within scan {s[k[i] + 1]} at {w.row(r)} (t = {float(t[r])!r} s after {float(t[p])!r} s at {w.row(p)})")

        if temps is not None:
            w = tw["temperatures"]
            tt = temps["t"]
            bad = tt[1:] <= tt[:-1]
            if bad.any():
                r = _first(bad) + 1
                raise RunError(f"{w}: column 't' not strictly increasing at {w.row(r)} (t = {float(tt[r])!r} s after {float(tt[r - 1])!r} s)")

        set_(self, "points", points)
        set_(self, "scans", scans)
        set_(self, "poses", poses)
        set_(self, "temperatures", temps)
        order.flags.writeable = False
        set_(self, "_point_order", order)

    # -- files -------------------------------------------------------------------------
    @classmethod
    def load(cls, run_dir) -> Run:
        """Read and check a run directory; ``truth/`` is never opened.

        Parameters
        ----------
        run_dir : str or path-like
            The run directory (run.json and the tables, docs/formats.md).

        Returns
        -------
        Run

        Raises
        ------
        RunError
            Naming the file, column and first bad row of any problem.
        """
        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise RunError(f"{run_dir}: no such run directory" if not run_dir.exists() else f"{run_dir}: not a directory")
        doc = _read_run_json(run_dir / "run.json")
        where = {}
        tables = {}
        for name in _TABLES:
            path = _table_path(run_dir, name, required=name != "temperatures" or bool(doc["temperature_channels"]))
            if path is None:
                tables[name] = None
                where[name] = _Where(str(run_dir / f"{name}.parquet"))
                continue
            where[name] = _Where(str(path), csv=path.suffix == ".csv")
            spec = _FIXED.get(name) or {"t": "float64", **{ch["name"]: "float64" for ch in doc["temperature_channels"]}}
            tables[name] = _read_table(path, spec, where[name])
        _check_row_counts(run_dir / "run.json", doc.get("rows"), tables, where)
        run = cls.__new__(cls)
        for name in _TABLES:
            object.__setattr__(run, name, tables[name])
        for name in ("temperature_channels", "artefact", "maps", "metadata", "created"):
            object.__setattr__(run, name, doc[name])
        run._validate(_Labels(where, f"{run_dir / 'run.json'}: "), copy=False)
        object.__setattr__(run, "_source", str(run_dir))  # for messages (Run.source); not part of the run's data
        return run

    @property
    def source(self) -> str | None:
        """The directory the run was loaded from, for messages (None: a run
        made in memory, or passed to another process)."""
        return self.__dict__.get("_source")

    def save(self, run_dir, truth=None, *, overwrite: bool = False) -> None:
        """Write the run as a directory (run.json and Parquet tables).

        Parameters
        ----------
        run_dir : str or path-like
            Directory to write; created with its parents if missing.
        truth : tuple (dict of str -> ndarray, dict), optional
            What a simulator knows and analysis must never read: arrays (any
            shape, numeric/bool/str dtype, units up to the simulator) written to
            ``truth/truth.npz`` and free JSON data written to
            ``truth/truth.json``. Read back only by :func:`load_truth`.
        overwrite : bool
            Write into a non-empty directory, replacing the run files there
            (run.json, the tables as .parquet or .csv, truth/); other files are
            left alone. Without it a non-empty directory raises ``RunError``
            (:func:`check_run_target` makes the same check before any work),
            and the run is created exclusively: of two writers of one folder
            one fails, and the folder holds one whole run, never a mix.

        The new run is written into a temporary folder beside ``run_dir`` and
        swapped in only when complete (:func:`cmmpose.atomicfile.staged_folder`):
        a failure (a full disk, Ctrl-C, SIGTERM) leaves the old run whole.
        """
        final = run_dir = Path(run_dir)
        arrays, info = _check_truth(truth) if truth is not None else (None, None)
        check_run_target(run_dir, overwrite=overwrite)
        # without overwrite: created exclusively (of two writers of one folder, one fails; nothing mixed)
        with staged_folder(final, RUN_FILES, error=RunError, exclusive=not overwrite) as run_dir:
            self._write_files(run_dir, final, arrays, info)

    def _write_files(self, run_dir: Path, final: Path, arrays, info) -> None:
        """Write the run's files into the empty folder ``run_dir`` (messages name ``final``)."""
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            doc = {
                "schema": SCHEMA,
                "schema_version": SCHEMA_VERSION,
                "created": self.created,
                "artefact": self.artefact,
                "maps": self.maps,
                "temperature_channels": self.temperature_channels,
                "metadata": self.metadata,
                # Each table's row count, checked on load: a table cut short (or grown) is an error.
                "rows": {name: len(next(iter(getattr(self, name).values())))
                         for name in _TABLES if getattr(self, name) is not None},
            }
            (run_dir / "run.json").write_text(json.dumps(doc, indent=2, allow_nan=False, ensure_ascii=False) + "\n", encoding="utf-8")
            for name in _TABLES:
                cols = getattr(self, name)
                if cols is None:
                    continue
                spec = _FIXED.get(name) or dict.fromkeys(cols, "float64")
                table = pa.Table.from_arrays([_arrow_column(cols[c], dt) for c, dt in spec.items()], names=list(spec))
                # Page checksums (CRC32), verified on load: a flipped bit
                # names the damaged file instead of loading changed values.
                pq.write_table(table, run_dir / f"{name}.parquet", write_page_checksum=True,
                               **parquet_options(table.schema))
            if arrays is not None:
                tdir = run_dir / _TRUTH_DIR
                tdir.mkdir(exist_ok=True)
                with zipfile.ZipFile(tdir / _TRUTH_ARRAYS, "w", zipfile.ZIP_STORED) as zf:
                    for key, a in arrays.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                            np.lib.format.write_array(fh, a, allow_pickle=False)
                (tdir / _TRUTH_INFO).write_text(json.dumps(info, indent=2, allow_nan=False, ensure_ascii=False) + "\n", encoding="utf-8")
        except OSError as exc:
            raise RunError(f"{final}: cannot write ({exc.strerror or exc})") from None

    # -- convenience ------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        """Number of points N."""
        return len(self.points["scan_id"])

    @cached_property
    def uv(self) -> np.ndarray:
        """Scan-plane coordinates u, v of every point, (N, 2) float64 mm, C-contiguous, read-only."""
        return _stack(self.points, ("u", "v"))

    @cached_property
    def scales(self) -> np.ndarray:
        """Scale readings D, E, F of every point, (N, 3) float64 mm, C-contiguous, read-only."""
        return _stack(self.points, ("D", "E", "F"))

    @cached_property
    def _scan_index(self):
        """(sorted scan ids, start, stop, columns): rows start:stop of
        ``columns`` are one scan's points in file order. ``columns`` are the
        points themselves when every scan's points are contiguous, else copies
        sorted (stably) by scan_id, made once."""
        order = self._point_order
        s = self.points["scan_id"][order]
        ids = np.sort(self.scans["scan_id"])
        lo = np.searchsorted(s, ids, side="left")
        hi = np.searchsorted(s, ids, side="right")
        used = hi > lo
        contiguous = bool(np.all(order[hi[used] - 1] - order[lo[used]] == (hi - lo)[used] - 1))
        if contiguous:
            start = np.zeros_like(lo)
            start[used] = order[lo[used]]
            return ids, start, start + (hi - lo), self.points
        cols = {}
        for c, a in self.points.items():
            cols[c] = a[order]
            cols[c].flags.writeable = False
        return ids, lo, hi, cols

    def scan_points(self, scan_id: int) -> dict[str, np.ndarray]:
        """The points of one scan, in file order.

        Parameters
        ----------
        scan_id : int
            A scan id of ``scans``.

        Returns
        -------
        dict of str -> ndarray
            The columns of ``points`` for that scan (units as in ``points``),
            read-only views; empty arrays if the scan has no points.
        """
        ids, start, stop, cols = self._scan_index
        sid = _as_index(scan_id)
        k = int(np.searchsorted(ids, sid))
        if k == len(ids) or ids[k] != sid:
            raise RunError(f"scan {sid} is not in scans")
        a, b = int(start[k]), int(stop[k])
        return {c: v[a:b] for c, v in cols.items()}

    @cached_property
    def _pose_index(self):
        order = np.argsort(self.poses["pose_id"])
        return self.poses["pose_id"][order], order

    def points_by_pose(self):
        """The points pose by pose: ``(rows, (alpha, beta, gamma), (U1, V1, W1))``
        for each pose that took points (rows: indices into the points; angles
        in degrees, offset in mm), in pose-id order."""
        ids = self.scans["scan_id"]
        order = np.argsort(ids)
        sid = self.points["scan_id"]
        # Run validation guarantees every point's scan exists.
        pose_of_point = self.scans["pose_id"][order][np.searchsorted(ids[order], sid)] if len(sid) else sid
        for pose_id in np.unique(pose_of_point):
            yield (np.flatnonzero(pose_of_point == pose_id), *self.pose(int(pose_id)))

    def pose(self, pose_id: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Pose angles and mount offset of one pose.

        Parameters
        ----------
        pose_id : int
            A pose id of ``poses``.

        Returns
        -------
        (alpha, beta, gamma) : tuple of float
            Euler 3-1-3 angles, degrees.
        (U1, V1, W1) : tuple of float
            Mount offset, mm.
        """
        ids, order = self._pose_index
        pid = _as_index(pose_id)
        k = int(np.searchsorted(ids, pid))
        if k == len(ids) or ids[k] != pid:
            raise RunError(f"pose {pid} is not in poses")
        r = order[k]
        p = self.poses
        return (
            (float(p["alpha"][r]), float(p["beta"][r]), float(p["gamma"][r])),
            (float(p["U1"][r]), float(p["V1"][r]), float(p["W1"][r])),
        )

    # -- pickling (sent to a worker process: cmmpose.scale) -------------------------------
    def __getstate__(self) -> dict:
        """The checked tables and records, without the cached stacks (``uv``,
        ``scales``, scan index), which a worker rebuilds when it needs them."""
        return {f.name: getattr(self, f.name) for f in fields(self)} | {"_point_order": self._point_order}

    def __setstate__(self, state: dict) -> None:
        """Restore a pickled run as it was checked: every column read-only again
        (unpickled arrays come back writeable)."""
        for name, value in state.items():
            if isinstance(value, dict) and name in _TABLES:
                for col in value.values():
                    col.flags.writeable = False
            elif isinstance(value, np.ndarray):
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    # -- comparison -------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        """Exact equality: equal dicts and bitwise-equal columns of equal dtype."""
        if not isinstance(other, Run):
            return NotImplemented
        if (self.temperature_channels, self.artefact, self.maps, self.metadata, self.created) != (
            other.temperature_channels,
            other.artefact,
            other.maps,
            other.metadata,
            other.created,
        ):
            return False
        return all(_tables_equal(getattr(self, t), getattr(other, t)) for t in _TABLES)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        nt = 0 if self.temperatures is None else len(self.temperatures["t"])
        return (
            f"Run({self.n_points} points, {len(self.scans['scan_id'])} scans, {len(self.poses['pose_id'])} poses, "
            f"{len(self.temperature_channels)} temperature channels x {nt} readings, "
            f"artefact={self.artefact!r}, maps={self.maps!r}, created={self.created!r})"
        )


def _stack(cols: dict[str, np.ndarray], names) -> np.ndarray:
    out = np.empty((len(cols[names[0]]), len(names)), dtype=np.float64)
    for k, c in enumerate(names):
        out[:, k] = cols[c]
    out.flags.writeable = False
    return out


def _tables_equal(a, b) -> bool:
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


# -- reading --------------------------------------------------------------------------
def _read_run_json(path: Path) -> dict:
    """run.json, checked for schema and version and completed with defaults."""
    if not path.is_file():
        raise RunError(f"{path}: missing (every run directory has a run.json)")
    # the one door in: a FIFO or a device refused, the size bounded, a bad byte named; a repeated key refused
    text = read_input_text(path, "run header", error=RunFileError)
    doc = loads_json(text, path, "run header", error=RunFileError, constants=False)
    if not isinstance(doc, dict):
        raise RunError(f"{path}: expected a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != SCHEMA:
        raise RunError(f"{path}: 'schema' is {doc.get('schema')!r}, expected {SCHEMA!r}")
    version = doc.get("schema_version")
    if type(version) is not int or version not in SUPPORTED_SCHEMA_VERSIONS:
        supported = ", ".join(str(v) for v in SUPPORTED_SCHEMA_VERSIONS)
        raise RunError(f"{path}: unsupported schema_version {version!r} (this cmmpose reads version {supported})")
    extra = [k for k in doc if k not in _JSON_KEYS]
    if extra:
        raise RunError(f"{path}: unknown key {extra[0]!r} (allowed: {', '.join(_JSON_KEYS)})")
    if "created" not in doc:
        raise RunError(f"{path}: missing key 'created' (ISO-8601 UTC time)")
    for key in ("artefact", "maps", "metadata"):
        doc.setdefault(key, {})
    doc.setdefault("temperature_channels", [])
    _check_channels(doc["temperature_channels"], f"{path}: ")
    for key in ("artefact", "maps", "metadata"):
        if not isinstance(doc[key], dict):
            raise RunError(f"{path}: {key}: expected a dict (JSON object), got {type(doc[key]).__name__}")
    _check_artefact_numbers(doc["artefact"], f"{path}: artefact")
    _check_created(doc["created"], f"{path}: created")
    validate(doc, "run", path, error=RunFileError)  # every key typed and every number within its range
    return doc


def _check_row_counts(path: Path, rows, tables: dict, where: dict) -> None:
    """Each table's rows against run.json's ``rows`` (written by :meth:`Run.save`):
    a table cut short or grown raises ``RunError`` naming it, the rows expected
    and found. A run.json without ``rows`` (an older cmmpose) is not checked,
    with a logged note."""
    if rows is None:
        _log.info("%s: no row counts ('rows', written since cmmpose checks them): the tables are not checked for "
                  "truncation", path)
        return
    if not isinstance(rows, dict) or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                                             for v in rows.values()):
        raise RunError(f"{path}: 'rows' must be an object of table name -> row count (a whole number >= 0)")
    unknown = [k for k in rows if k not in _TABLES]
    if unknown:
        raise RunError(f"{path}: 'rows' names an unknown table {unknown[0]!r} (tables: {', '.join(_TABLES)})")
    for name in _TABLES:
        cols = tables.get(name)
        if cols is None:
            if name in rows:
                raise RunError(f"{path}: 'rows' says {name} has {rows[name]} rows, but the run has no {name} table")
            continue
        found = next((len(v) for v in cols.values() if v is not None), None)
        if found is None:
            continue  # no known column: the table's own check names what is missing
        if name not in rows:
            raise RunError(f"{where[name].label}: run.json's 'rows' gives no row count for this table ({found} rows): "
                           "was it added after the run was saved?")
        if found != rows[name]:
            what = "cut short" if found < rows[name] else "longer than saved"
            raise RunError(f"{where[name].label}: {found} rows, run.json says {rows[name]}: the table is {what}")


def _table_path(run_dir: Path, name: str, required: bool) -> Path | None:
    for suffix in (".parquet", ".csv"):
        p = run_dir / f"{name}{suffix}"
        if p.is_file():
            return p
    if required:
        why = " (run.json lists temperature channels)" if name == "temperatures" else ""
        raise RunError(f"{run_dir}: missing {name}.parquet (or {name}.csv){why}")
    return None


def _arrow_column(values: np.ndarray, dtype: str) -> pa.Array:
    """One checked column (``_as_column``) as an Arrow array of its schema type.

    Built from its buffers (zero-copy for numbers): ``pa.array`` on an ndarray
    or a list imports pandas to ask whether it was given a pandas object,
    about 0.15 s that would be a third of a ``cmmpose simulate``.

    Parameters
    ----------
    values : ndarray
        The column: numbers of ``dtype``, or an object array of Python str
        for ``"str"``.
    dtype : str
        A key of ``_ARROW``.

    Returns
    -------
    pyarrow.Array
        Without nulls, of the Arrow type ``_ARROW[dtype]`` names.
    """
    if dtype == "str":
        data = [s.encode("utf-8") for s in values.tolist()]
        ends = np.cumsum([len(b) for b in data], dtype=np.int64)
        if len(ends) and ends[-1] > np.iinfo(np.int32).max:
            raise RunError(f"a text column holds {ends[-1]} bytes, more than a Parquet string column's 2 GiB")
        offsets = np.zeros(len(data) + 1, dtype=np.int32)
        offsets[1:] = ends
        return pa.Array.from_buffers(pa.string(), len(data), [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(data))])
    a = np.ascontiguousarray(values, dtype=np.dtype(dtype).newbyteorder("<"))
    return pa.Array.from_buffers(getattr(pa, _ARROW[dtype])(), len(a), [None, pa.py_buffer(a)])


def _read_table(path: Path, spec: dict[str, str], where: _Where) -> dict[str, np.ndarray]:
    try:
        if path.suffix == ".csv":
            opts = pa_csv.ConvertOptions(
                null_values=[""],
                strings_can_be_null=False,
                column_types={c: pa.string() for c, dt in spec.items() if dt == "str"},
            )
            table = pa_csv.read_csv(path, convert_options=opts)
        else:
            table = pq.read_table(path, page_checksum_verification=True)
    except (pa.ArrowException, OSError, UnicodeDecodeError) as exc:
        kind = "CSV" if path.suffix == ".csv" else "Parquet"
        raise RunError(f"{path}: not a readable {kind} file ({exc})") from None
    try:
        names = table.column_names
    except UnicodeDecodeError as exc:  # a damaged schema (the footer has no checksum)
        raise RunError(f"{path}: damaged column names ({exc})") from None
    dup = [c for c in names if names.count(c) > 1]
    if dup:
        raise RunError(f"{path}: column {dup[0]!r} appears more than once")
    cols = {}
    for c in names:
        if c in spec:
            try:
                cols[c] = _from_arrow(table.column(c), spec[c], c, where)
            except (pa.ArrowException, UnicodeDecodeError) as exc:  # damaged bytes outside the checksummed pages
                raise RunError(f"{path}: column {c!r} is damaged ({exc})") from None
        else:
            cols[c] = None  # reported as unexpected by _table
    return cols


# -- truth ----------------------------------------------------------------------------
def _check_truth(truth) -> tuple[dict[str, np.ndarray], dict]:
    if not (isinstance(truth, tuple) and len(truth) == 2):
        raise RunError("truth: expected a tuple (dict of str -> ndarray, dict)")
    arrays, info = truth
    if not isinstance(arrays, Mapping):
        raise RunError(f"truth: arrays must be a dict of str -> ndarray, got {type(arrays).__name__}")
    if not isinstance(info, dict):
        raise RunError(f"truth: info must be a dict, got {type(info).__name__}")
    out = {}
    for key, a in arrays.items():
        if not isinstance(key, str) or not key or "/" in key or "\\" in key:
            raise RunError(f"truth: array name {key!r} must be a non-empty string without slashes")
        a = np.asarray(a)
        if a.dtype.hasobject:
            raise RunError(f"truth: array {key!r} has dtype {a.dtype}; only numeric, bool and str arrays can be stored")
        out[key] = a
    return out, _check_json_value(info, "truth: info")


def load_truth(run_dir) -> tuple[dict[str, np.ndarray], dict]:
    """What the simulator of a run knows (``truth/``); analysis must not call this.

    Parameters
    ----------
    run_dir : str or path-like
        The run directory.

    Returns
    -------
    arrays : dict of str -> ndarray
        The arrays of ``truth/truth.npz`` as saved (units up to the simulator).
    info : dict
        The contents of ``truth/truth.json``.
    """
    tdir = Path(run_dir) / _TRUTH_DIR
    if not tdir.is_dir():
        raise RunError(f"{tdir}: missing (the run has no truth)")
    apath, ipath = tdir / _TRUTH_ARRAYS, tdir / _TRUTH_INFO
    for p in (apath, ipath):
        if not p.is_file():
            raise RunError(f"{p}: missing")
    if not zipfile.is_zipfile(apath):
        raise RunError(f"{apath}: not a readable .npz file (not a zip archive)")
    try:
        with np.load(apath, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise RunError(f"{apath}: not a readable .npz file ({exc})") from None
    try:
        info = json.loads(ipath.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise RunError(f"{ipath}: not readable JSON ({exc})") from None
    if not isinstance(info, dict):
        raise RunError(f"{ipath}: expected a JSON object, got {type(info).__name__}")
    return arrays, info
