"""The canonical error-map file: one tidy CSV per map, with the temperature
and squareness in a commented header and units in the column names
(docs/formats.md). Registered as the map file format ``'csv'``
(:mod:`cmmpose.mapformats`)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from . import mapformats
from ._validate import parse_number
from .errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap
from .errors import MapError, read_lines

MAGIC = "cmmpose-error-map"
VERSION = "1"
HEADER = ("carriage",) + TABLE_COLUMNS
SQUARENESS_KEYS = ("squareness_xy_arcsec", "squareness_yz_arcsec", "squareness_zx_arcsec")


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
    lines = read_lines(path)
    meta: dict[str, tuple[str, int]] = {}
    rows: dict[str, list[list[float]]] = {c: [] for c in CARRIAGES}
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
            if sep:
                meta[key.strip()] = (value.strip(), lineno)
            continue
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
    return ErrorMap(*(np.array(rows[c]) for c in CARRIAGES), squareness, temperature, source=source)


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
    if error_map.source:
        lines.append(f"# source: {error_map.source}")
    lines.append(",".join(HEADER))
    for c in CARRIAGES:
        for row in error_map.table(c):
            lines.append(",".join([c, *(_fmt(v) for v in row)]))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


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
