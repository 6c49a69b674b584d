"""Point files for the CLI: scanner points ``u, v, D, E, F`` and an optional
``T`` in any registered point format (:mod:`cmmpose.formats.pointformats`; CSV with a
header row, NPY ((N, 5) or (N, 6) in that column order, or a structured
array with those field names), Parquet, PLY, or XYZ with a header naming
them). Units: mm and degrees C. Any other column (``scan_id``,
``intensity``, ...) is an extra column that ``cmmpose compensate`` passes
through to its output unchanged.

Reading is strict: a CSV must be UTF-8 with every row as wide as the header
(an extra field would shift the columns) and plain numbers; an NPY must be
a real-valued array whose header matches the file's size; a Parquet file
must hold real-valued columns without nulls. Every format is read and
written in chunks, so a file of any size takes bounded memory.
Writing goes to a temporary file renamed into place, so a failure leaves
nothing behind. A file whose suffix names no registered format is read as
CSV, except a compressed one (``.gz``, ``.zip``, ...), refused by name; an
output with such a suffix is refused, listing the known ones, unless the
format is given by name (a stream - ``-``, ``/dev/null``, a FIFO - is CSV
by default: it has no suffix to go by)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import pointformats
from ..atomicfile import check_not_input
from .pointclouds import UNITS
from .pointformats.common import check_file, check_writable, numeric_column

__all__ = ["REQUIRED", "CHUNK_POINTS", "read_points", "write_points", "point_chunks", "PointWriter", "output_format",
           "RereadPoints", "check_writable"]

REQUIRED = ("u", "v", "D", "E", "F")
#: What compensate needs of a point file.
NEED = pointformats.Need(REQUIRED, ("T",), {5: REQUIRED, 6: (*REQUIRED, "T")}, "u, v, D, E, F (and optionally T)")
#: Points per chunk when a file is streamed.
CHUNK_POINTS = 1_000_000


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read ``uv`` (N, 2), ``scales`` (N, 3) and temperatures (N,) or None.

    Parameters
    ----------
    path : path-like
        A point file in any registered format (by suffix; CSV for an unknown
        one) holding columns u, v, D, E, F (mm) and optionally T (degrees C).

    Raises
    ------
    InputError
        Naming the file, and the line and column where it can: a missing
        file, text that is not UTF-8, a header without u, v, D, E, F, a row
        of another width than the header, a field that is not a number, an
        NPY that is not a plain real array of the right shape.
    """
    path = check_file(path)
    uv, scales, temps, _ = _split(path, pointformats.read_all(pointformats.for_path(path, default="csv"), path, NEED))
    return uv, scales, temps


def write_points(path: str | Path, xyz: np.ndarray, extras: dict[str, np.ndarray] | None = None) -> None:
    """Write (N, 3) machine coordinates (mm) and any extra columns in the
    format of the suffix (see :class:`PointWriter`). The file appears whole
    or not at all."""
    writer = PointWriter(path)
    try:
        writer.write(xyz, extras)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def _split(path, cols: dict[str, np.ndarray]):
    """A chunk's columns as (uv, scales, temps, extras); every format's reader
    has checked that u, v, D, E, F are there."""
    f = {c: numeric_column(path, c, cols[c]).astype(np.float64, copy=False) for c in REQUIRED}
    uv = np.column_stack([f["u"], f["v"]])
    scales = np.column_stack([f["D"], f["E"], f["F"]])
    temps = np.ascontiguousarray(numeric_column(path, "T", cols["T"]), dtype=np.float64) if "T" in cols else None
    extras = {c: numeric_column(path, c, v) for c, v in cols.items() if c not in REQUIRED and c != "T"}
    return uv, scales, temps, extras


def point_chunks(path: str | Path, chunk: int | None = None, *, extras: bool = False):
    """The points of ``path`` in chunks of about ``chunk`` rows, so a file of
    any size is compensated in bounded memory.

    Parameters
    ----------
    path : path-like
        A point file (see :func:`read_points`).
    chunk : int, optional
        Rows per chunk (default :data:`CHUNK_POINTS`).
    extras : bool
        Also yield each chunk's extra columns (every column but u, v, D, E,
        F, T), a dict of 1-D arrays in their stored types.

    Returns
    -------
    size : int
        The file's size in bytes (for progress).
    chunks : iterator of (uv, scales, temps, bytes_done), or of (uv, scales, temps, extras, bytes_done)
        As :func:`read_points` returns them, per chunk, with how far into the
        file (bytes) the chunk ends. A CSV file the fast reader refuses is
        read whole by the strict one, which raises naming the line at fault;
        if it accepts the file, :class:`RereadPoints` carries the whole file.
    """
    path = check_file(path)  # missing, a folder or a special file (a FIFO, /dev/zero) said as such
    chunk = CHUNK_POINTS if chunk is None else int(chunk)
    fmt = pointformats.for_path(path, default="csv")
    size, chunks = fmt.chunks(path, chunk, NEED)
    return size, _tuples(path, chunks, extras)


def _tuples(path, chunks, with_extras: bool):
    try:
        for cols, done in chunks:
            uv, scales, temps, extras = _split(path, cols)
            yield (uv, scales, temps, extras, done) if with_extras else (uv, scales, temps, done)
    except pointformats.Reread as again:
        raise RereadPoints(_split(path, again.columns)) from None


class RereadPoints(Exception):
    """The fast reader refused part of a file the strict one then read whole:
    ``points`` is (uv, scales, temps) of the whole file, ``extras`` its extra
    columns."""

    def __init__(self, parts):
        super().__init__("re-read")
        self.points = parts[:3]
        self.extras = parts[3]


def output_format(path, format: str | None = None):
    """The format an output ``path`` is written in: ``format`` by name, else its suffix's; ``InputError``
    naming the file and listing the known suffixes for an unknown suffix (never CSV by default: ``out.txt``
    is not silently CSV), except for a stream (``-``, ``/dev/null``, a FIFO), which is CSV by default."""
    import os
    import stat

    stream = str(path) == "-"
    if not stream:
        try:
            stream = not stat.S_ISREG(os.stat(path).st_mode) and not stat.S_ISDIR(os.stat(path).st_mode)
        except OSError:
            stream = False
    return pointformats.for_path(path, format, default="csv" if stream else None)


class PointWriter:
    """Machine coordinates (mm) and any extra columns written chunk by chunk
    to a temporary file renamed over ``path`` on success, in the format of
    the suffix (refused if unknown: :func:`output_format`) or ``format``: CSV (header
    ``X,Y,Z[,extra...]``, coordinates rounded to 1 nm), NPY ((N, 3) float64,
    or a structured array X, Y, Z and the extras when there are extras),
    Parquet (columns X, Y, Z float64 and the extras), PLY, XYZ, PTS or E57
    (written in metres). Memory stays bounded by one chunk in every format.
    The first chunk written fixes the extra columns' names and types. A
    ``path`` that is one of ``inputs`` (any spelling or link) is refused with
    ``InputError``; a special file (``/dev/null``, a FIFO) is written as a
    stream (:mod:`cmmpose.atomicfile`)."""

    def __init__(self, path: str | Path, *, format: str | None = None, inputs=()):
        self.path = check_writable(path)
        check_not_input(self.path, inputs)
        self.format = output_format(self.path, format)
        self._scale = 1.0 / UNITS[self.format.units]  # mm to the format's unit
        self._w = self.format.writer(self.path)

    @property
    def f(self):
        """The temporary file being written."""
        return self._w.f

    @property
    def tmp(self):
        """The temporary file's name."""
        return self._w.tmp

    def write(self, xyz: np.ndarray, extras: dict[str, np.ndarray] | None = None) -> None:
        """Append (n, 3) coordinates in mm and, optionally, extra columns of length n."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        self._w.write(xyz * self._scale if self._scale != 1.0 else xyz, extras)

    def close(self) -> None:
        """Finish the file and rename it into place."""
        self._w.close()

    def abort(self) -> None:
        """Remove the temporary file; ``path`` is left as it was."""
        self._w.abort()
