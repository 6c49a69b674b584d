"""Point clouds read from and written to files, in any registered point
format (:mod:`cmmpose.formats.pointformats`: CSV, NPY, Parquet, PLY, XYZ, PTS, E57;
docs/formats.md): coordinates in mm plus the extra columns a file carries
(``scan_id``, ``intensity``, colours, ...), unchanged.

The unit is converted once, here: ``units=`` says what the file's numbers
are in, and :attr:`PointCloud.xyz` is always mm."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import pointformats
from ..errors import InputError, InputTypeError
from .pointformats.common import numeric_column

__all__ = ["PointCloud", "read_point_cloud", "write_point_cloud", "unit_factor", "UNITS"]

_log = logging.getLogger("cmmpose")

#: Millimetres per unit, for ``units=``.
UNITS = {"mm": 1.0, "m": 1000.0, "um": 1e-3, "in": 25.4}

#: Need of a point cloud: coordinates found by name (any case); a plain NPY array is (N, 3).
_NEED = pointformats.Need(plain={3: ("X", "Y", "Z")}, what="X, Y, Z")


@dataclass(frozen=True)
class PointCloud:
    """Points with coordinates and any further per-point columns.

    Attributes
    ----------
    xyz : ndarray, shape (N, 3), float64
        Coordinates, mm.
    columns : dict of str to ndarray
        Further columns, each of shape (N,), in the types the file stored them
        (``scan_id`` an integer type, ``intensity`` a float, ``red`` ... as
        stored). Units as stored: nothing but the coordinates is converted.
    """

    xyz: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        xyz = np.array(self.xyz, dtype=np.float64)  # a copy: the caller's array is never shared
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InputError(f"PointCloud: xyz must have shape (N, 3), got {xyz.shape}")
        xyz.flags.writeable = False
        columns = {}
        for name, values in dict(self.columns).items():
            if name.lower() in ("x", "y", "z"):
                raise InputError(f"PointCloud: a column named {name!r} would collide with the coordinates")
            col = np.array(numeric_column("PointCloud", name, values))
            if len(col) != len(xyz):
                raise InputError(f"PointCloud: column {name!r} has {len(col)} values for {len(xyz)} points")
            col.flags.writeable = False
            columns[name] = col
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "columns", columns)

    def __len__(self) -> int:
        return len(self.xyz)


def _factor(units: str | None, fmt) -> float:
    unit = fmt.units if units is None else units
    try:
        return UNITS[unit]
    except KeyError:
        raise InputError(f"units={unit!r}: expected one of {', '.join(UNITS)}") from None


def unit_factor(path: str | Path, units: str | None = None, format: str | None = None) -> float:
    """Millimetres per unit of a file's coordinates: ``units``, or its format's
    own (metres for E57, mm for every other), as :func:`read_point_cloud`
    converts them. For quantities given in the file's units (a scanner origin)."""
    return _factor(units, pointformats.for_path(path, format))


def _coordinate_names(path, names) -> list[str]:
    """The columns holding x, y and z (any case), or ``InputError``."""
    out = []
    for axis in "xyz":
        found = [n for n in names if n.lower() == axis]
        if len(found) != 1:
            problem = "no" if not found else f"more than one ({found})"
            raise InputError(f"{path}: {problem} {axis.upper()} coordinate column (have {list(names)})")
        out.append(found[0])
    return out


def read_point_cloud(path: str | Path, *, units: str | None = None, format: str | None = None) -> PointCloud:
    """Read a point cloud.

    Parameters
    ----------
    path : path-like
        The file; its format by suffix: .csv, .npy, .parquet/.pq, .ply, .xyz,
        .pts, .e57 (any case).
    units : {"mm", "m", "um", "in"}, optional
        The unit of the file's coordinates; they are converted to mm. Default:
        the format's own, metres for E57 (the standard's) and mm for every other.
    format : str, optional
        A registered format name (``cmmpose.formats.pointformats.names()``) instead of
        the suffix.

    Returns
    -------
    PointCloud
        Coordinates in mm and every other column as stored.

    Raises
    ------
    InputError
        Naming the file, and the line, row or element where it can: an unknown
        suffix, a missing file, a malformed header, truncated data, a field
        that is not a number, no X, Y or Z column.
    """
    fmt = pointformats.for_path(path, format)
    factor = _factor(units, fmt)
    cols = dict(pointformats.read_all(fmt, path, _NEED))
    coords = _coordinate_names(path, list(cols))
    xyz = np.column_stack([np.asarray(cols.pop(c), dtype=np.float64) for c in coords])
    if factor != 1.0:
        xyz *= factor  # column_stack made it: scale in place rather than copy it again
    _log.debug("read %d points and columns %s from %s (%s)", len(xyz), list(cols), path, fmt.name)
    return PointCloud(xyz, cols)


def write_point_cloud(path: str | Path, cloud: PointCloud, *, format: str | None = None,
                      units: str | None = None) -> None:
    """Write a point cloud; the file appears whole or not at all.

    Parameters
    ----------
    path : path-like
        The file; its format by suffix as for :func:`read_point_cloud`.
    cloud : PointCloud
        Coordinates in mm and the extra columns, written unchanged (PLY
        narrows 64-bit integers to 32 bits when the values fit).
    format : str, optional
        A registered format name instead of the suffix: ``"ply-ascii"`` and
        ``"ply-big-endian"`` select the other PLY encodings.
    units : {"mm", "m", "um", "in"}, optional
        The unit written; default the format's own (metres for E57, mm otherwise).

    Raises
    ------
    InputError
        An unknown suffix or format, a missing folder, or columns the format
        cannot carry (PTS beyond intensity and colour, names a text header
        cannot hold, integers beyond PLY's 32 bits).
    """
    if not isinstance(cloud, PointCloud):
        raise InputTypeError(f"write_point_cloud: expected a PointCloud, got {type(cloud).__name__}")
    fmt = pointformats.for_path(path, format)
    factor = _factor(units, fmt)
    writer = fmt.writer(path)
    try:
        writer.write(cloud.xyz / factor if factor != 1.0 else cloud.xyz, cloud.columns)
    except BaseException:
        writer.abort()
        raise
    writer.close()
