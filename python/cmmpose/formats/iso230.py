"""Linear positioning results in the style of ISO 230-2 as CSV: per carriage
and target position, the mean positional deviation of each approach
direction (docs/formats.md). Registered as the map file format
``'iso230-2'`` (:mod:`cmmpose.formats.mapformats`).

::

    axis,target_mm,mean_deviation_up_um,mean_deviation_down_um
    X,0,0,0.4
    X,100,2.1,2.9

Deviation = actual position - target position (ISO 230-2's x_ij = P_ij - P_j),
the sign of the map's linear components. Reading keeps the bidirectional
mean (:mod:`cmmpose.formats.linearaxis`); writing puts the map's value in both
directions.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from . import mapformats
from ..atomicfile import write_text
from .._validate import parse_number
from ..errormap import CARRIAGES, ErrorMap
from ..errors import InputError, MapError, read_lines
from .linearaxis import REVERSAL_LIMIT_UM, AxisResult, build_map, linear_components

__all__ = ["HEADER", "read_iso230", "write_iso230", "is_iso230_file"]

#: The columns, in the order written; a file may give them in any order.
HEADER = ("axis", "target_mm", "mean_deviation_up_um", "mean_deviation_down_um")

#: Decimals of the deviations written, um (0.001 um = 1 nm).
DECIMALS = 3

#: The largest mean deviation (um) a file may give, as a fraction of its axis's span of targets, with a floor and
#: a cap: beyond it the number is not a positioning error but a unit mix-up (mm or nm written as um) or a typo. A
#: machine's positioning error is a scale error - a screw's pitch or a scale's calibration, or its expansion
#: (11.5 ppm/K x 10 K = 0.012 %) - plus a reversal of tens of um: 1 % of the span is ~100 times the largest scale
#: error, the 500 um floor keeps a short axis's backlash in, and no machine worth a map is 5 mm off anywhere.
DEVIATION_LIMIT_FRACTION = 0.01
DEVIATION_LIMIT_FLOOR_UM = 500.0
DEVIATION_LIMIT_CAP_UM = 5000.0


def deviation_limit_um(span_mm: float) -> float:
    """The largest mean deviation (um) accepted on an axis whose targets span ``span_mm`` (mm):
    1 % of the span, at least 500 um and at most 5 mm (``DEVIATION_LIMIT_*``)."""
    return min(DEVIATION_LIMIT_CAP_UM, max(DEVIATION_LIMIT_FLOOR_UM, DEVIATION_LIMIT_FRACTION * span_mm * 1e3))


def _fields(line: str) -> list[str]:
    """Comma-separated fields, white space and enclosing double quotes removed."""
    out = []
    for f in line.split(","):
        f = f.strip()
        if len(f) >= 2 and f[0] == f[-1] == '"':
            f = f[1:-1].strip()
        out.append(f)
    return out


def _header_index(fields: list[str], where: str) -> dict[str, int]:
    """Column index of each name of ``HEADER``; ``MapError`` on a missing, unknown or repeated column."""
    names = [f.lower() for f in fields]
    for i, n in enumerate(names):
        if n not in HEADER:
            raise MapError(f"{where}: unknown column {fields[i]!r}; the columns are {','.join(HEADER)}")
        if names.index(n) != i:
            raise MapError(f"{where}: column {n!r} appears twice")
    missing = [n for n in HEADER if n not in names]
    if missing:
        extra = (" (each target needs the mean deviation of both approach directions)"
                 if any(m.startswith("mean_deviation") for m in missing) else "")
        raise MapError(f"{where}: missing column(s) {', '.join(missing)}{extra}; the header must name "
                       f"{','.join(HEADER)}")
    return {n: names.index(n) for n in HEADER}


def read_results(path: str | PathLike) -> dict[str, AxisResult]:
    """Read an ISO 230-2 style CSV into linear-axis results, without building a map.

    Parameters
    ----------
    path : str or PathLike
        The file.

    Returns
    -------
    dict of str to AxisResult
        Per carriage in the file: targets (mm) and mean deviations up and down (um).

    Raises
    ------
    MapError
        Naming the file and line: an empty file, a header without the four
        columns, a row with another number of fields, an axis other than X, Y,
        Z, a malformed or non-finite number, targets of an axis that do not
        strictly increase (duplicates named as such), an axis with one row, no
        data rows, a deviation that cannot be a positioning error (beyond
        :func:`deviation_limit_um` of the axis's span of targets).
    """
    path = Path(path)
    lines = read_lines(path, "ISO 230-2 file")
    index: dict[str, int] | None = None
    rows: dict[str, list[tuple[int, float, float, float]]] = {}
    for lineno, raw in enumerate(lines, start=1):
        line = raw.lstrip("\ufeff").strip() if lineno == 1 else raw.strip()
        where = f"{path}:{lineno}"
        if not line or line.startswith("#"):
            continue
        fields = _fields(line)
        if index is None:
            index = _header_index(fields, where)
            continue
        if len(fields) != len(index):
            raise MapError(f"{where}: expected {len(index)} fields, got {len(fields)}")
        axis = fields[index["axis"]].upper()
        if axis not in CARRIAGES:
            raise MapError(f"{where}: axis {fields[index['axis']]!r} is not X, Y or Z")
        target, up, down = (parse_number(fields[index[n]], where, n) for n in HEADER[1:])
        previous = rows.setdefault(axis, [])
        if previous and target <= previous[-1][1]:
            prev, prev_line = previous[-1][1], previous[-1][0]
            if target == prev:
                raise MapError(f"{where}: {axis} target {target:g} mm duplicates line {prev_line}; "
                               f"targets must strictly increase")
            raise MapError(f"{where}: {axis} target {target:g} mm is less than the previous {axis} target "
                           f"{prev:g} mm (line {prev_line}); targets must strictly increase")
        previous.append((lineno, target, up, down))
    if index is None:
        raise MapError(f"{path}: empty file: no header row {','.join(HEADER)}")
    if not rows:
        raise MapError(f"{path}: no data rows after the header")
    results = {}
    for axis, r in rows.items():
        if len(r) < 2:
            raise MapError(f"{path}:{r[0][0]}: the {axis} axis has 1 target; at least 2 are needed to interpolate")
        a = np.array([x[1:] for x in r])
        limit = deviation_limit_um(float(a[-1, 0] - a[0, 0]))
        for lineno, target, up, down in r:
            for column, v in (("mean_deviation_up_um", up), ("mean_deviation_down_um", down)):
                if abs(v) > limit:
                    raise MapError(f"{path}:{lineno}: {axis} {column} {v:g} um at {target:g} mm is not a machine's "
                                   f"positioning error (more than {limit:g} um: 1 % of the {axis} targets' span "
                                   f"{a[-1, 0] - a[0, 0]:g} mm, at least {DEVIATION_LIMIT_FLOOR_UM:g} um, at most "
                                   f"{DEVIATION_LIMIT_CAP_UM:g} um); deviations are in um (is the file in mm or nm?)")
        results[axis] = AxisResult(axis, a[:, 0], a[:, 1], a[:, 2], str(path), tuple(x[0] for x in r))
    return {a: results[a] for a in CARRIAGES if a in results}


def read_iso230(path: str | PathLike, *, base: ErrorMap | None = None, temperature: float | None = None,
                ranges=None, hold_ends: bool = False, reversal_limit_um: float = REVERSAL_LIMIT_UM) -> ErrorMap:
    """Read ISO 230-2 style results into the linear components of an error map.

    Parameters
    ----------
    path : str or PathLike
        The CSV file (docs/formats.md).
    base : ErrorMap, optional
        Replace only the linear components of this map (the results
        interpolated onto its grid, mm); default: a map that is zero but for
        the linear components.
    temperature : float, optional
        Map temperature, degrees C (default: the base's, else none).
    ranges : sequence of 3 (lo, hi), optional
        Range (mm) of the all-zero table of an axis missing from the file,
        without a base (default: those of ``ErrorMap.zero()``).
    hold_ends : bool, optional
        With a base whose grid runs beyond the targets: hold the end values
        there instead of raising ``MapError``.
    reversal_limit_um : float, optional
        Reversal values (um) above this are logged as warnings.

    Returns
    -------
    ErrorMap
        delta_x of X, delta_y of Y, delta_z of Z = bidirectional mean deviation (um).

    Raises
    ------
    MapError
        Malformed content (see :func:`read_results`) or a target outside the
        base's range, naming the file and line.
    """
    results = read_results(path)
    return build_map(results, source=f"ISO 230-2 results {Path(path).name}", base=base,
                     temperature=temperature, ranges=ranges, hold_ends=hold_ends,
                     reversal_limit_um=reversal_limit_um)


def _position(v: float) -> str:
    # Shortest text that reads back to the same float.
    return repr(float(v)).removesuffix(".0") if float(v).is_integer() else repr(float(v))


def _deviation(v: float, decimals: int) -> str:
    text = f"{round(float(v), decimals) + 0.0:.{decimals}f}"
    return "0." + "0" * decimals if float(text) == 0 else text  # no '-0.000'


def write_iso230(error_map: ErrorMap, path: str | PathLike, *, decimals: int = DECIMALS) -> None:
    """Write the linear components of ``error_map`` as ISO 230-2 style CSV.

    Parameters
    ----------
    error_map : ErrorMap
        The map; delta_x of X, delta_y of Y and delta_z of Z are written at
        each grid position (mm), both approach directions equal to the map's
        value (um). The other components and the squareness are not written.
    path : str or PathLike
        The file to write.
    decimals : int, optional
        Decimals of the deviations, um (default 3: 0.001 um). Target positions
        are written in the shortest form that reads back the same.
    """
    if not isinstance(decimals, int) or isinstance(decimals, bool) or not 0 <= decimals <= 9:
        raise InputError(f"decimals: expected an integer 0..9, got {decimals!r}")
    # A source of several lines: each its own '#' line, so that the file reads back.
    source = [t.strip() for t in str(error_map.source or "").splitlines() if t.strip()] or ["a cmmpose error map"]
    lines = [
        f"# ISO 230-2 style linear positioning results, from {source[0]}",
        *(f"# {t}" for t in source[1:]),
        "# deviation = actual - target position; up / down = positive / negative approach;"
        " both directions carry the map's single value",
        ",".join(HEADER),
    ]
    for axis, (pos, dev) in linear_components(error_map).items():
        for p, d in zip(pos, dev):
            text = _deviation(d, decimals)
            lines.append(f"{axis},{_position(p)},{text},{text}")
    write_text(path, "\n".join(lines) + "\n")


def is_iso230_file(path: str | PathLike) -> bool:
    """True when the first line of the file at ``path`` that is neither blank
    nor a ``#`` comment names the four columns of ``HEADER`` (in any order)."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError:
        return False
    for raw in head.decode("utf-8", "replace").splitlines():
        line = raw.lstrip("\ufeff").strip()
        if line and not line.startswith("#"):
            return sorted(f.lower() for f in _fields(line)) == sorted(HEADER)
    return False


mapformats.register("iso230-2", sniff=is_iso230_file, read=read_iso230, write=write_iso230,
                    description="ISO 230-2 style linear positioning results, CSV (docs/formats.md)")
