"""A run folder's files: run.json read and checked against its schema, its fields checked, the tables read from
Parquet or CSV, the truth a simulation saved (never read by analysis).
"""

from __future__ import annotations

import json
import logging
import math
import zipfile
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path

import numpy as np

from .._lazy import LazyModule
from ..errors import RunError, RunFileError, read_input_text
from ..schemas import loads_json, validate
from ..schemas.run import CHANNEL_ROLES, SCHEMA, SUPPORTED_SCHEMA_VERSIONS, TABLES
from ._tables import Where, first_index

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pc = LazyModule("pyarrow.compute")
pa_csv = LazyModule("pyarrow.csv")
pq = LazyModule("pyarrow.parquet")

_log = logging.getLogger("cmmpose.run")
#: Arrow type (a ``pyarrow`` factory's name) of each column type.
_ARROW = {"int32": "int32", "int8": "int8", "float64": "float64", "str": "string"}
_JSON_KEYS = ("schema", "schema_version", "created", "artefact", "maps", "temperature_channels", "metadata", "rows")
TRUTH_DIR, TRUTH_ARRAYS, TRUTH_INFO = "truth", "truth.npz", "truth.json"
#: The files a run directory consists of (relative to it); nothing else in it is the run's.
RUN_FILES = ("run.json", *(f"{t}{s}" for t in TABLES for s in (".parquet", ".csv")),
             f"{TRUTH_DIR}/{TRUTH_ARRAYS}", f"{TRUTH_DIR}/{TRUTH_INFO}")
_FLOAT_RE = r"^\s*[+-]?(nan|inf|infinity|(\d+\.?\d*|\.\d+)(e[+-]?\d+)?)\s*$"
_INT_RE = r"^\s*[+-]?\d+\s*$"


def from_arrow(col: pa.ChunkedArray, dtype: str, name: str, where: Where) -> np.ndarray:
    """An Arrow column (from Parquet or CSV) as numpy, before ``as_column``;
    nulls and non-numeric text are reported with their first row."""
    if col.null_count:
        r = first_index(col.is_null().to_numpy(zero_copy_only=False))
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
            r = first_index(bad)
            raise RunError(f"{where}: column {name!r}: {col[r].as_py()!r} at {where.row(r)} is not {kind}")
        raise RunError(f"{where}: column {name!r}: has type {t}, expected {dtype}")
    elif not (pa.types.is_integer(t) or pa.types.is_floating(t)):
        raise RunError(f"{where}: column {name!r}: has type {t}, expected {dtype}")
    return col.to_numpy(zero_copy_only=False)


def check_json_value(value, what: str) -> object:
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


def check_artefact_numbers(artefact: dict, what: str) -> None:
    """The artefact's sizes are numbers (not "12.7", not true), finite and > 0."""
    items = [(k, artefact[k]) for k in ARTEFACT_NUMBERS if k in artefact]
    ref = artefact.get("reference_sphere")
    if isinstance(ref, dict) and "radius_mm" in ref:
        items.append(("reference_sphere.radius_mm", ref["radius_mm"]))
    for key, v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise RunError(f"{what}.{key}: expected a positive number of mm, got {v!r}")


def check_created(created, what: str) -> str:
    if not isinstance(created, str):
        raise RunError(f"{what}: expected an ISO-8601 UTC time string, got {type(created).__name__}")
    try:
        when = datetime.fromisoformat(created)
    except ValueError:
        raise RunError(f"{what}: {created!r} is not an ISO-8601 time") from None
    if when.utcoffset() is None or when.utcoffset().total_seconds() != 0:
        raise RunError(f"{what}: {created!r} is not UTC (end it with 'Z' or '+00:00')")
    return created


def check_channels(channels, prefix: str) -> list[dict]:
    what = f"{prefix}temperature_channels"
    if not isinstance(channels, list):
        raise RunError(f"{what}: expected a list of {{'name': ..., 'role': ...}}, got {type(channels).__name__}")
    channels = check_json_value(channels, what)
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


# -- reading --------------------------------------------------------------------------
def read_run_json(path: Path) -> dict:
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
    check_channels(doc["temperature_channels"], f"{path}: ")
    for key in ("artefact", "maps", "metadata"):
        if not isinstance(doc[key], dict):
            raise RunError(f"{path}: {key}: expected a dict (JSON object), got {type(doc[key]).__name__}")
    check_artefact_numbers(doc["artefact"], f"{path}: artefact")
    check_created(doc["created"], f"{path}: created")
    validate(doc, "run", path, error=RunFileError)  # every key typed and every number within its range
    return doc


def check_row_counts(path: Path, rows, tables: dict, where: dict) -> None:
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
    unknown = [k for k in rows if k not in TABLES]
    if unknown:
        raise RunError(f"{path}: 'rows' names an unknown table {unknown[0]!r} (tables: {', '.join(TABLES)})")
    for name in TABLES:
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


def table_path(run_dir: Path, name: str, required: bool) -> Path | None:
    for suffix in (".parquet", ".csv"):
        p = run_dir / f"{name}{suffix}"
        if p.is_file():
            return p
    if required:
        why = " (run.json lists temperature channels)" if name == "temperatures" else ""
        raise RunError(f"{run_dir}: missing {name}.parquet (or {name}.csv){why}")
    return None


def arrow_column(values: np.ndarray, dtype: str) -> pa.Array:
    """One checked column (``as_column``) as an Arrow array of its schema type.

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


def read_table_file(path: Path, spec: dict[str, str], where: Where) -> dict[str, np.ndarray]:
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
                cols[c] = from_arrow(table.column(c), spec[c], c, where)
            except (pa.ArrowException, UnicodeDecodeError) as exc:  # damaged bytes outside the checksummed pages
                raise RunError(f"{path}: column {c!r} is damaged ({exc})") from None
        else:
            cols[c] = None  # reported as unexpected by as_table
    return cols


# -- truth ----------------------------------------------------------------------------
def check_truth(truth) -> tuple[dict[str, np.ndarray], dict]:
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
    return out, check_json_value(info, "truth: info")


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
    tdir = Path(run_dir) / TRUTH_DIR
    if not tdir.is_dir():
        raise RunError(f"{tdir}: missing (the run has no truth)")
    apath, ipath = tdir / TRUTH_ARRAYS, tdir / TRUTH_INFO
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
