"""LinuxCNC axis compensation tables: the files named by ``COMP_FILE`` in the
``[JOINT_n]`` (older: ``[AXIS_n]``) sections of a LinuxCNC INI file, one file
per joint, in machine units (docs/formats.md).

Each line is three numbers separated by white space: the nominal position,
then by ``COMP_FILE_TYPE``

- ``0`` (LinuxCNC's default): the forward and reverse positions, where the
  axis actually is at that nominal position travelling forward / in reverse;
- ``1``: the forward and reverse trims, the amounts LinuxCNC adds to the
  commanded position, trim = nominal - actual.

So, with deviation = actual - nominal (the sign of the map's linear
components): type 0 forward = nominal + deviation, type 1 trim = -deviation.
LinuxCNC reads lines until the first one that is not three numbers and
stops there silently, needs the nominal positions to increase and keeps at
most 256 entries per joint; the reader refuses a file that LinuxCNC would
read otherwise than as written.

These are one file per axis: the registered map file format ``'linuxcnc'``
declares it (``per_axis``, files ``x.comp``, ``y.comp``, ``z.comp``), so
:func:`read_comp_files` takes a mapping axis -> file and
:func:`write_comp_files` writes one file per axis. Reading keeps the mean of
the two directions (:mod:`cmmpose.formats.linearaxis`).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Mapping

import numpy as np

from . import mapformats
from .._validate import parse_number
from ..atomicfile import write_text
from ..errormap import CARRIAGES, ErrorMap
from ..errors import InputError, MapError, read_lines
from .linearaxis import REVERSAL_LIMIT_UM, AxisResult, build_map, linear_components

__all__ = ["MAX_ENTRIES", "UNITS", "read_comp_file", "read_comp_files", "write_comp_files"]

#: LinuxCNC's limit on compensation entries per joint (EMCMOT_COMP_SIZE).
MAX_ENTRIES = 256

#: Machine units ([TRAJ] LINEAR_UNITS) and their size in mm.
UNITS = {"mm": 1.0, "inch": 25.4}

#: Decimals written, machine units (1e-6 mm = 1 nm; the style of LinuxCNC's own example).
DECIMALS = 6

_COLUMNS = {0: ("nominal", "forward position", "reverse position"), 1: ("nominal", "forward trim", "reverse trim")}

#: A deviation (actual - nominal) larger than the larger of these is refused
#: as not a machine's error: DEVIATION_LIMIT_MM, or DEVIATION_LIMIT_FRACTION
#: of the table's span. A machine's linear errors are micrometres to a few
#: hundred micrometres (an uncompensated ball screw ~0.1 mm per 300 mm; steel
#: 10 K off 20 C is 115 um per m, 1.2 mm over a 10 m gantry axis), so 2 mm and
#: 1 % leave a wide margin. A file read with the other COMP_FILE_TYPE gives
#: deviations of minus the nominal position itself (type 1 read as 0: trim -
#: nominal; type 0 read as 1: -position), at least half the span at one end:
#: 50 times the 1 % limit, caught whenever the span exceeds 4 mm.
DEVIATION_LIMIT_MM = 2.0
DEVIATION_LIMIT_FRACTION = 0.01


def _check_options(comp_file_type, units) -> float:
    """The size of the machine unit in mm; ``InputError`` on a bad type or unit."""
    if comp_file_type not in (0, 1) or isinstance(comp_file_type, bool):
        raise InputError(f"comp_file_type: expected 0 or 1 (LinuxCNC COMP_FILE_TYPE), got {comp_file_type!r}")
    if units not in UNITS:
        raise InputError(f"units: expected one of {', '.join(map(repr, UNITS))} (machine units), got {units!r}")
    return UNITS[units]


def _axis_key(axis) -> str:
    if not isinstance(axis, str) or axis.upper() not in CARRIAGES:
        raise InputError(f"files: axis {axis!r} is not 'X', 'Y' or 'Z'")
    return axis.upper()


def read_comp_file(path: str | PathLike, axis: str, *, comp_file_type: int = 0, units: str = "mm") -> AxisResult:
    """Read one LinuxCNC compensation file into the linear-axis result of ``axis``.

    Parameters
    ----------
    path : str or PathLike
        The file named by ``COMP_FILE``.
    axis : str
        The carriage it compensates, ``'X'``, ``'Y'`` or ``'Z'``.
    comp_file_type : {0, 1}, optional
        The joint's ``COMP_FILE_TYPE``: 0 = nominal, forward and reverse
        positions; 1 = nominal, forward and reverse trims.
    units : {'mm', 'inch'}, optional
        The machine units of the file (``[TRAJ] LINEAR_UNITS``).

    Returns
    -------
    AxisResult
        Targets in mm, deviations (actual - nominal) in um per direction.

    Raises
    ------
    MapError
        Naming the file and line: an empty file, a line that is not three
        numbers (a blank line or comment before more data, where LinuxCNC
        would stop reading), a malformed or non-finite number, nominal
        positions that do not strictly increase, fewer than 2 or more than
        ``MAX_ENTRIES`` lines; a deviation larger than 2 mm and 1 % of the
        table's span (``DEVIATION_LIMIT_MM``, ``DEVIATION_LIMIT_FRACTION``),
        which a file of the other ``comp_file_type`` gives (the message says
        when the other type reads as plausible deviations).
    """
    scale = _check_options(comp_file_type, units)
    axis = _axis_key(axis)
    path = Path(path)
    lines = read_lines(path, "LinuxCNC file")
    while lines and not lines[-1].strip():
        lines.pop()  # trailing blank lines: LinuxCNC stops there, with nothing after
    if not lines:
        raise MapError(f"{path}: empty compensation file")
    names = _COLUMNS[comp_file_type]
    rows: list[tuple[float, float, float]] = []
    for lineno, raw in enumerate(lines, start=1):
        where = f"{path}:{lineno}"
        fields = raw.split()
        comment = raw.lstrip().startswith(("#", ";"))
        if len(fields) != 3 or comment:
            what = "a blank line" if not fields else "a comment" if comment else f"{len(fields)} fields"
            raise MapError(f"{where}: expected 3 numbers ({', '.join(names)}), got {what}; LinuxCNC stops "
                           f"reading a compensation file at the first line that is not three numbers")
        values = [parse_number(f, where, n) for f, n in zip(fields, names)]
        if rows and values[0] <= rows[-1][0]:
            kind = "duplicates" if values[0] == rows[-1][0] else "is less than"
            raise MapError(f"{where}: nominal {values[0]:g} {kind} the previous nominal {rows[-1][0]:g} "
                           f"(line {lineno - 1}); LinuxCNC needs nominal positions that strictly increase")
        rows.append(tuple(values))
    if len(rows) < 2:
        raise MapError(f"{path}: {len(rows)} line; at least 2 are needed to interpolate")
    if len(rows) > MAX_ENTRIES:
        raise MapError(f"{path}:{MAX_ENTRIES + 1}: more than {MAX_ENTRIES} lines; LinuxCNC keeps at most "
                       f"{MAX_ENTRIES} compensation entries per joint")
    a = np.array(rows, dtype=float)
    # The one unit boundary: machine units -> mm (positions) and um (deviations).
    nominal_mm = a[:, 0] * scale
    if comp_file_type == 0:
        up_um, down_um = ((a[:, j] - a[:, 0]) * scale * 1e3 for j in (1, 2))
    else:
        up_um, down_um = (0.0 - a[:, j] * scale * 1e3 for j in (1, 2))  # 0.0 - x: no -0.0 in the map
    _check_deviations(path, a, scale, comp_file_type, np.column_stack([up_um, down_um]) * 1e-3)
    return AxisResult(axis, nominal_mm, up_um, down_um, str(path), tuple(range(1, len(rows) + 1)))


def _check_deviations(path: Path, a: np.ndarray, scale: float, comp_file_type: int, dev_mm: np.ndarray) -> None:
    """Raise ``MapError`` if a deviation (mm, rows x directions) is of the size
    of the positions rather than of a machine's error (``DEVIATION_LIMIT_MM``)."""
    span_mm = float(a[-1, 0] - a[0, 0]) * scale
    limit = max(DEVIATION_LIMIT_MM, DEVIATION_LIMIT_FRACTION * span_mm)
    big = np.abs(dev_mm) > limit
    if not big.any():
        return
    row, col = (int(i) for i in np.argwhere(big)[0])
    names = _COLUMNS[comp_file_type]
    other = 1 - comp_file_type
    # The same values read as the other type: deviation = -trim (as type 1) or position - nominal (as type 0).
    other_mm = (-a[:, 1:] if other == 1 else a[:, 1:] - a[:, :1]) * scale
    kind = {0: "positions", 1: "trims"}
    what = kind[other]
    hint = (f"the values read as COMP_FILE_TYPE {other} ({what}) give deviations within "
            f"{np.abs(other_mm).max() * 1e3:.4g} um: read the file with comp_file_type={other} "
            f"(--comp-file-type {other})"
            if np.abs(other_mm).max() <= limit else
            f"read as COMP_FILE_TYPE {other} ({what}) they are too large as well (up to "
            f"{np.abs(other_mm).max():.4g} mm): check the file's units and columns")
    raise MapError(
        f"{path}:{row + 1}: {names[col + 1]} {a[row, col + 1]:g} at nominal {a[row, 0]:g} is a deviation "
        f"(actual - nominal) of {dev_mm[row, col]:.6g} mm as COMP_FILE_TYPE {comp_file_type} "
        f"({kind[comp_file_type]}), more than {limit:.3g} mm (the larger of {DEVIATION_LIMIT_MM:g} mm and "
        f"{DEVIATION_LIMIT_FRACTION:.0%} of the table's {span_mm:g} mm span), far beyond a machine's error; {hint}")


def read_comp_files(files: Mapping[str, str | PathLike], *, comp_file_type: int = 0, units: str = "mm",
                    base: ErrorMap | None = None, temperature: float | None = None, ranges=None,
                    hold_ends: bool = False, reversal_limit_um: float = REVERSAL_LIMIT_UM) -> ErrorMap:
    """Read LinuxCNC compensation files, one per axis, into the linear components of an error map.

    Parameters
    ----------
    files : mapping of str to path
        Axis (``'X'``, ``'Y'``, ``'Z'``) -> its ``COMP_FILE``; axes may be missing.
    comp_file_type : {0, 1}, optional
        ``COMP_FILE_TYPE`` of every file (0: positions, 1: trims).
    units : {'mm', 'inch'}, optional
        Machine units of the files.
    base : ErrorMap, optional
        Replace only the linear components of this map (interpolated onto its
        grid, mm); default: a map that is zero but for the linear components.
    temperature : float, optional
        Map temperature, degrees C (default: the base's, else none).
    ranges : sequence of 3 (lo, hi), optional
        Range (mm) of the all-zero table of an axis without a file, without a
        base (default: those of ``ErrorMap.zero()``).
    hold_ends : bool, optional
        With a base whose grid runs beyond a file's nominal positions: hold
        the end values there instead of raising ``MapError``.
    reversal_limit_um : float, optional
        Reversal values (forward - reverse deviation, um) above this are
        logged as warnings.

    Returns
    -------
    ErrorMap
        delta_x of X, delta_y of Y, delta_z of Z = mean of the forward and
        reverse deviations (actual - nominal), um.

    Raises
    ------
    MapError
        Malformed content (see :func:`read_comp_file`) or a position outside
        the base's range, naming the file and line.
    InputError
        A bad axis, type or unit, or no files.
    """
    _check_options(comp_file_type, units)
    if not isinstance(files, Mapping) or not files:
        raise InputError("files: expected a mapping of axis ('X', 'Y', 'Z') to compensation file, with at least one")
    results = {}
    for axis, path in files.items():
        key = _axis_key(axis)
        if key in results:
            raise InputError(f"files: axis {key} given twice")
        results[key] = read_comp_file(path, key, comp_file_type=comp_file_type, units=units)
    names = ", ".join(f"{k}={Path(results[k].where).name}" for k in CARRIAGES if k in results)
    return build_map(results, source=f"LinuxCNC compensation files (COMP_FILE_TYPE {comp_file_type}, {units}) {names}",
                     base=base, temperature=temperature, ranges=ranges, hold_ends=hold_ends,
                     reversal_limit_um=reversal_limit_um)


def write_comp_files(error_map: ErrorMap, files: Mapping[str, str | PathLike], *, comp_file_type: int = 0,
                     units: str = "mm", decimals: int = DECIMALS) -> None:
    """Write the linear component of each axis of ``error_map`` as a LinuxCNC compensation file.

    Parameters
    ----------
    error_map : ErrorMap
        The map; for axis X its delta_x of X (um) at the X grid positions
        (mm), likewise Y and Z. Both directions get the map's value.
    files : mapping of str to path
        Axis (``'X'``, ``'Y'``, ``'Z'``) -> the file to write.
    comp_file_type : {0, 1}, optional
        0: nominal, forward and reverse positions (nominal + deviation);
        1: nominal, forward and reverse trims (-deviation).
    units : {'mm', 'inch'}, optional
        Machine units to write.
    decimals : int, optional
        Decimals written, machine units (default 6).

    Raises
    ------
    InputError
        A bad axis, type, unit or ``decimals``; a grid of more than
        ``MAX_ENTRIES`` positions (LinuxCNC would ignore the rest).
    """
    scale = _check_options(comp_file_type, units)
    if not isinstance(decimals, int) or isinstance(decimals, bool) or not 0 <= decimals <= 12:
        raise InputError(f"decimals: expected an integer 0..12, got {decimals!r}")
    if not isinstance(files, Mapping) or not files:
        raise InputError("files: expected a mapping of axis ('X', 'Y', 'Z') to output file, with at least one")
    components = linear_components(error_map)
    targets = {}
    for axis, path in files.items():
        key = _axis_key(axis)
        if key in targets:
            raise InputError(f"files: axis {key} given twice")
        if len(components[key][0]) > MAX_ENTRIES:
            raise InputError(f"files: the map's {key} grid has {len(components[key][0])} positions; LinuxCNC "
                             f"keeps at most {MAX_ENTRIES} compensation entries per joint")
        targets[key] = path
    for key, path in targets.items():
        pos_mm, dev_um = components[key]
        # The one unit boundary: mm and um -> machine units.
        nominal = np.round(pos_mm / scale, decimals)
        deviation = dev_um * 1e-3 / scale
        second = nominal + deviation if comp_file_type == 0 else -deviation
        lines = [" ".join(_fixed(v, decimals) for v in (n, s, s)) for n, s in zip(nominal, second)]
        write_text(path, "\n".join(lines) + "\n")


def _fixed(v: float, decimals: int) -> str:
    text = f"{float(v):.{decimals}f}"
    return text[1:] if float(text) == 0 and text.startswith("-") else text  # no '-0.000000'


mapformats.register("linuxcnc", read=read_comp_files, write=write_comp_files, per_axis="{axis}.comp",
                    description="LinuxCNC compensation tables (COMP_FILE), one file per axis, machine units")
