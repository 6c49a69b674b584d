"""The canonical error-map file: one tidy CSV per map, with the temperature
and squareness in a commented header and units in the column names
(docs/formats.md). Registered as the map file format ``'csv'``
(:mod:`cmmpose.formats.mapformats`)."""

from __future__ import annotations

import hashlib
import json
import logging
from os import PathLike
from pathlib import Path

import numpy as np

from . import mapformats
from ..atomicfile import write_text
from .._validate import parse_number
from ..errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap
from ..errors import Error, InputError, MapError, read_lines
from ..point_uncertainty import MapUncertainty

MAGIC = "cmmpose-error-map"
VERSION = "1"
HEADER = ("carriage",) + TABLE_COLUMNS
SQUARENESS_KEYS = ("squareness_xy_arcsec", "squareness_yz_arcsec", "squareness_zx_arcsec")
# Header keys the reader uses; each may be given once (a repeated one would silently win).
KEYS = ("temperature_C", *SQUARENESS_KEYS, "kinematics", "source", "uncertainty", "rows", "sha256")
#: The machine configuration of a map without a ``kinematics`` line (every file before the line existed).
DEFAULT_KINEMATICS = "thesis"

logger = logging.getLogger(__name__)


def body_sha256(lines) -> str:
    """SHA-256 (lower-case hex) of a map's body: the column-header row and the
    data rows, each stripped of surrounding white space and ended by one
    ``\\n``, in file order (blank and ``#`` lines excluded; docs/formats.md)."""
    digest = hashlib.sha256()
    for line in lines:
        digest.update(line.strip().encode("utf-8") + b"\n")
    return digest.hexdigest()


def _rows_text(counts: dict[str, int]) -> str:
    return " ".join(f"{c}={counts[c]}" for c in CARRIAGES)


def _check_body(path: Path, meta: dict[str, tuple[str, int]], counts: dict[str, int], body: list[str]) -> None:
    """Verify the declared ``rows`` and ``sha256`` header lines against the body read."""
    missing = [k for k in ("rows", "sha256") if k not in meta]
    if missing:
        logger.info("%s: no %s line; a cut or edited table cannot be detected in this file "
                    "(maps written by cmmpose carry them; docs/formats.md)",
                    path, " or ".join(f"'# {k}:'" for k in missing))
    if "rows" in meta:
        text, lineno = meta["rows"]
        declared: dict[str, int] = {}
        for item in text.split():
            c, sep, n = item.partition("=")
            c = c.strip().upper()
            if not sep or c not in CARRIAGES or c in declared or not n.strip().isdigit():
                raise MapError(f"{path}:{lineno}: rows: expected 'X=<count> Y=<count> Z=<count>', got {text!r}")
            declared[c] = int(n)
        if set(declared) != set(CARRIAGES):
            raise MapError(f"{path}:{lineno}: rows: expected 'X=<count> Y=<count> Z=<count>', got {text!r}")
        if declared != counts:
            wrong = ", ".join(f"{c} has {counts[c]} (declared {declared[c]})" for c in CARRIAGES
                              if counts[c] != declared[c])
            raise MapError(f"{path}:{lineno}: the table disagrees with '# rows: {_rows_text(declared)}': {wrong}; "
                           "the file was cut or rows were added or removed")
    if "sha256" in meta:
        text, lineno = meta["sha256"]
        found = body_sha256(body)
        if text.lower() != found:
            raise MapError(f"{path}:{lineno}: the table does not match its '# sha256:' line (declared {text}, "
                           f"the rows give {found}): the file was cut or changed after it was written; "
                           "if you edited it on purpose, delete the '# sha256:' and '# rows:' lines")


def read_map(path: str | PathLike) -> ErrorMap:
    """Read a canonical error-map CSV.

    Parameters
    ----------
    path : str or PathLike
        The file.

    Returns
    -------
    ErrorMap

    Raises
    ------
    MapError
        On any malformed content, naming the file and line.
    """
    path = Path(path)
    lines = read_lines(path, "map file")
    meta: dict[str, tuple[str, int]] = {}
    rows: dict[str, list[list[float]]] = {c: [] for c in CARRIAGES}
    body: list[str] = []  # the column-header row and the data rows, for the sha256 check
    header_seen = False
    if not lines or lines[0].strip() != f"# {MAGIC}: {VERSION}":
        raise MapError(f"{path}:1: not a cmmpose error map (first line must be '# {MAGIC}: {VERSION}')")
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        where = f"{path}:{lineno}"
        if not line:
            continue
        if line.startswith("#"):
            if header_seen:
                continue  # comments after the header row are allowed and ignored
            key, sep, value = line[1:].partition(":")
            key = key.strip()
            if sep and key in meta and key in KEYS:
                raise MapError(f"{where}: header key {key!r} is repeated (first on line {meta[key][1]}); "
                               "give each key once")
            if sep:
                meta[key] = (value.strip(), lineno)
            continue
        body.append(line)
        fields = [f.strip() for f in line.split(",")]
        if not header_seen:
            if tuple(fields) != HEADER:
                raise MapError(f"{where}: header must be {','.join(HEADER)!r}, got {line!r}")
            header_seen = True
            continue
        if len(fields) != len(HEADER):
            raise MapError(f"{where}: expected {len(HEADER)} fields, got {len(fields)}")
        carriage = fields[0].upper()
        if carriage not in rows:
            raise MapError(f"{where}: carriage {fields[0]!r} is not X, Y or Z")
        values = [parse_number(f, where, name) for f, name in zip(fields[1:], TABLE_COLUMNS)]
        previous = rows[carriage][-1][0] if rows[carriage] else None
        if previous is not None and values[0] <= previous:
            kind = "duplicates" if values[0] == previous else "is less than"
            raise MapError(
                f"{where}: {carriage} position {values[0]:g} mm {kind} the previous {carriage} position "
                f"{previous:g} mm; positions must strictly increase"
            )
        rows[carriage].append(values)
    if not header_seen:
        raise MapError(f"{path}: no header row {','.join(HEADER)!r}")
    for c in CARRIAGES:
        if not rows[c]:
            raise MapError(f"{path}: no rows for the {c} carriage")
        if len(rows[c]) < 2:
            raise MapError(f"{path}: the {c} carriage has {len(rows[c])} row; at least 2 are needed to interpolate")
    _check_body(path, meta, {c: len(rows[c]) for c in CARRIAGES}, body)
    squareness = []
    for key in SQUARENESS_KEYS:
        if key not in meta:
            raise MapError(f"{path}: header line '# {key}: <value>' is missing")
        value, lineno = meta[key]
        squareness.append(parse_number(value, f"{path}:{lineno}", key))
    if "temperature_C" not in meta:
        raise MapError(f"{path}: header line '# temperature_C: <value or none>' is missing")
    t_text, t_line = meta["temperature_C"]
    temperature = None if t_text.lower() == "none" else parse_number(t_text, f"{path}:{t_line}", "temperature_C")
    source = meta.get("source", (str(path), 0))[0]
    error_map = ErrorMap(*(np.array(rows[c]) for c in CARRIAGES), squareness, temperature, source=source)
    if "uncertainty" in meta:
        error_map = error_map.with_uncertainty(_uncertainty(path, *meta["uncertainty"]))
    if "kinematics" in meta:
        name, lineno = meta["kinematics"]
        try:
            error_map = error_map.with_kinematics(name)
        except Error as exc:
            raise MapError(f"{path}:{lineno}: kinematics: {exc}") from None
    return error_map


def _no_repeats(pairs):
    keys = [k for k, _ in pairs]
    repeated = sorted({k for k in keys if keys.count(k) > 1})
    if repeated:
        raise ValueError(f"key(s) {', '.join(repeated)} repeated")
    return dict(pairs)


def _uncertainty(path: Path, text: str, lineno: int) -> MapUncertainty:
    """The ``# uncertainty:`` header line: one JSON object of
    :class:`cmmpose.point_uncertainty.MapUncertainty`'s fields (um,
    arc-seconds, ppm), checked key by key."""
    where = f"{path}:{lineno}: uncertainty"
    try:
        d = json.loads(text, object_pairs_hook=_no_repeats)
    except ValueError as exc:
        raise MapError(f"{where}: not a JSON object of the map's uncertainties ({exc})") from None
    try:
        return MapUncertainty.from_dict(d, where)
    except InputError as exc:
        raise MapError(str(exc)) from None


def _fmt(v: float) -> str:
    # Shortest text that reads back to the same float.
    return repr(float(v)).removesuffix(".0") if float(v).is_integer() else repr(float(v))


def write_map(error_map: ErrorMap, path: str | PathLike) -> None:
    """Write ``error_map`` as a canonical CSV at ``path``; read back it is equal."""
    t = error_map.temperature
    lines = [
        f"# {MAGIC}: {VERSION}",
        f"# temperature_C: {'none' if t is None else _fmt(t)}",
        *(f"# {k}: {_fmt(v)}" for k, v in zip(SQUARENESS_KEYS, error_map.squareness)),
    ]
    kinematics = error_map.kinematics
    if kinematics == "custom":
        raise InputError(f"{path}: the map is for a machine configuration without a name, which the canonical map "
                         "file cannot hold (its '# kinematics:' line names a configuration); give it a named one "
                         "(ErrorMap.with_kinematics)")
    if kinematics != DEFAULT_KINEMATICS:
        lines.append(f"# kinematics: {kinematics}")
    if error_map.source:
        source = str(error_map.source).replace("\r", " ").replace("\n", " ")  # one header line
        lines.append(f"# source: {source}")
    if error_map.stated_uncertainty is not None:
        lines.append(f"# uncertainty: {json.dumps(error_map.stated_uncertainty.to_dict(), allow_nan=False)}")
    body = [",".join(HEADER)]
    for c in CARRIAGES:
        for row in error_map.table(c):
            body.append(",".join([c, *(_fmt(v) for v in row)]))
    lines.append(f"# rows: {_rows_text({c: len(error_map.table(c)) for c in CARRIAGES})}")
    lines.append(f"# sha256: {body_sha256(body)}")
    write_text(path, "\n".join(lines + body) + "\n")


def is_canonical_map(path: str | PathLike) -> bool:
    """True when the first line of the file at ``path`` is the canonical map's magic line."""
    try:
        with open(path, "rb") as f:
            first = f.readline(256)
    except OSError:
        return False
    return first.decode("utf-8", "replace").strip() == f"# {MAGIC}: {VERSION}"


mapformats.register("csv", sniff=is_canonical_map, read=read_map, write=write_map,
                    description="canonical error-map CSV (docs/formats.md)")
