"""Reader of the CMM controller error file of thesis Appendix B
(``errors_1102.txt``).

Layout: a header with axis parameters (min, max, increment, probe head) and
squareness, then one block per axis (``Map Data: X Axis``) whose columns are
*named*, in an order that differs per axis, e.g. for Y:
``Y Position, Y Linear, Z Straight, X Straight, X Rotation, Z Rotation, Y Rotation``.
Column header lines repeat at page breaks; lines of dashes are separators.

Units: linear and straightness values in um, rotations and squareness in
arc-seconds (the magnitudes match the thesis tables; the file does not say).

Squareness sign: the controller states squareness with the opposite sign to
the thesis's convention (Table 7, eq. 11): the same machine reads XY +169.4
here and -173 in Table 7. The reader therefore negates all three values.

Registered as the read-only map file format ``'controller'``
(:mod:`cmmpose.formats.mapformats`).
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path

import numpy as np

from . import mapformats
from .._validate import parse_number
from ..errormap import CARRIAGES, ErrorMap
from ..errors import MapError, read_lines

#: Sign applied to the file's squareness values to get the thesis convention.
SQUARENESS_SIGN = -1.0

_BLOCK = re.compile(r"^Map Data:\s*([XYZ])\s+Axis\s*$", re.IGNORECASE)
_SQUARENESS = re.compile(r"^(XY|YZ|ZX)\s*:\s*(\S+)\s*$", re.IGNORECASE)
_AXIS_PARAM = re.compile(r"^([XYZ])\s+(\S+)\s+(\S+)\s+(\S+)(?:\s+(\S+))?\s*$")
_COLUMN = re.compile(r"^([XYZ])\s+(Position|Linear|Straight|Rotation)$", re.IGNORECASE)


def _column_index(name: str, axis: str, where: str) -> int:
    """Canonical table column (0 = position, 1..3 deltas, 4..6 angles) of a named column."""
    m = _COLUMN.match(name.strip())
    if not m:
        raise MapError(f"{where}: unknown column {name.strip()!r}")
    letter, kind = m.group(1).upper(), m.group(2).lower()
    k = CARRIAGES.index(letter)
    if kind == "position":
        if letter != axis:
            raise MapError(f"{where}: column {name.strip()!r} in the {axis} axis block")
        return 0
    if kind == "linear":
        if letter != axis:
            raise MapError(f"{where}: linear column {name.strip()!r} in the {axis} axis block")
        return 1 + k
    if kind == "straight":
        if letter == axis:
            raise MapError(f"{where}: straightness {name.strip()!r} along the axis itself")
        return 1 + k
    return 4 + k  # rotation about that machine axis


def read_controller_file(path: str | PathLike, temperature: float | None = None) -> ErrorMap:
    """Read a controller error file (thesis Appendix B layout).

    Parameters
    ----------
    path : str or PathLike
        The ``errors_1102.txt``-style file.
    temperature : float, optional
        Temperature (C) at which the map was measured; the file does not state it
        (Appendix B: 22 C).

    Returns
    -------
    ErrorMap
        Squareness converted to the thesis sign convention (``SQUARENESS_SIGN``).

    Raises
    ------
    MapError
        Naming the file and line of any malformed content.
    """
    path = Path(path)
    lines = read_lines(path, "controller file")
    squareness: dict[str, float] = {}
    axis_params: dict[str, tuple[float, float, float]] = {}
    blocks: dict[str, list[tuple[int, list[float]]]] = {}
    columns: dict[str, list[int]] = {}
    axis: str | None = None
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        where = f"{path}:{lineno}"
        if not line or set(line) <= set("-\t "):
            continue
        m = _BLOCK.match(line)
        if m:
            axis = m.group(1).upper()
            if axis in blocks:
                raise MapError(f"{where}: second 'Map Data: {axis} Axis' block")
            blocks[axis] = []
            continue
        if axis is None:
            if m := _SQUARENESS.match(line):
                squareness[m.group(1).upper()] = parse_number(m.group(2), where, f"{m.group(1)} squareness")
            elif (m := _AXIS_PARAM.match(line)) and m.group(1) in CARRIAGES:
                lo, hi, step = (parse_number(m.group(i), where, f"{m.group(1)} axis parameter") for i in (2, 3, 4))
                axis_params[m.group(1)] = (lo, hi, step)
            continue  # other header lines (file name, engineer, dates) are informative
        fields = [f for f in re.split(r"\t+|\s{2,}", line) if f]
        if fields[0].lower().endswith("position"):
            idx = [_column_index(f, axis, where) for f in fields]
            if sorted(idx) != list(range(7)):
                raise MapError(f"{where}: the {axis} block needs a position column and six named components, got {fields}")
            if axis in columns and columns[axis] != idx:
                raise MapError(f"{where}: repeated {axis} header differs from the block's first header")
            columns[axis] = idx
            continue
        if axis not in columns:
            raise MapError(f"{where}: data row before the {axis} block's column header")
        fields = line.split()
        if len(fields) != 7:
            raise MapError(f"{where}: expected 7 values in a {axis} row, got {len(fields)}")
        row = [0.0] * 7
        for name_idx, text in zip(columns[axis], fields):
            row[name_idx] = parse_number(text, where, "value")
        previous = blocks[axis][-1] if blocks[axis] else None
        if previous is not None and row[0] <= previous[1][0]:
            kind = "duplicates" if row[0] == previous[1][0] else "is less than"
            raise MapError(f"{where}: {axis} position {row[0]:g} {kind} the previous {previous[1][0]:g}; positions must strictly increase")
        blocks[axis].append((lineno, row))
    for c in CARRIAGES:
        if c not in blocks:
            raise MapError(f"{path}: no 'Map Data: {c} Axis' block")
        if len(blocks[c]) < 2:
            raise MapError(f"{path}: the {c} axis block has {len(blocks[c])} data rows; at least 2 are needed")
        if c in axis_params:
            lo, hi, _ = axis_params[c]
            first, last = blocks[c][0][1][0], blocks[c][-1][1][0]
            if first != lo or last != hi:
                raise MapError(f"{path}: the {c} block spans {first:g}..{last:g} but the axis parameters say {lo:g}..{hi:g}")
    missing = [k for k in ("XY", "YZ", "ZX") if k not in squareness]
    if missing:
        raise MapError(f"{path}: squareness parameter(s) {', '.join(missing)} missing from the header")
    sq = tuple(SQUARENESS_SIGN * squareness[k] for k in ("XY", "YZ", "ZX"))
    tables = [np.array([row for _, row in blocks[c]]) for c in CARRIAGES]
    return ErrorMap(*tables, sq, temperature, source=f"controller file {path.name}")


def is_controller_file(path: str | PathLike) -> bool:
    """True when the file at ``path`` has a ``Map Data: <axis> Axis`` block line."""
    try:
        text = Path(path).read_bytes().decode("utf-8", "replace")
    except OSError:
        return False
    return any(_BLOCK.match(line.strip()) for line in text.splitlines())


mapformats.register("controller", sniff=is_controller_file, read=read_controller_file,
                    description="controller error file (thesis Appendix B)")
