"""The raw laser-interferometer run and its file (thesis section 3.3; docs/interferometer.md).

:class:`InterferometerRun` holds one optics set-up on one carriage, several
repeats in both directions; :func:`read_run` and :func:`write_run` read and
write its file, checking the header and the rows (plausible air readings,
every target in both directions).

Units: positions and linear readings mm, straightness readings um, angles
arc-second, temperatures degrees C, pressure mmHg, humidity % RH.
"""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path

import numpy as np

from ...atomicfile import write_text
from ...errormap import CARRIAGES
from ...errors import InputError, InputTypeError, InterferometerRunError, MapError, read_lines
from .air import HENE_VACUUM_WAVELENGTH_NM, READING_BASES

MAGIC = "cmmpose-interferometer-run"
VERSION = "1"
#: Optics of a run and the unit of its reading column.
OPTICS = ("linear", "straightness", "angular")
READING_UNIT = {"linear": "mm", "straightness": "um", "angular": "arcsec"}
_KNOWN_KEYS = ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis", "source")
_AIR_COLUMNS = ("air_temperature_C", "pressure_mmHg", "humidity_percent", "material_temperature_C")
# Plausible ranges: catch Kelvin, hPa or fractions instead of percent.
_RANGES = {
    "air_temperature_C": (0.0, 50.0, "an air temperature in C (Kelvin?)"),
    "pressure_mmHg": (400.0, 900.0, "a pressure in mmHg (hPa or kPa? 1 hPa = 0.750062 mmHg)"),
    "humidity_percent": (0.0, 100.0, "a relative humidity in % RH"),
    "material_temperature_C": (0.0, 50.0, "a material temperature in C (Kelvin?)"),
}


def run_columns(optics: str) -> tuple[str, ...]:
    """Column names of a run file with ``optics`` (the reading column carries the unit)."""
    if optics not in OPTICS:
        raise InputError(f"optics: expected one of {OPTICS}, got {optics!r}")
    return ("target_mm", f"reading_{READING_UNIT[optics]}", "repeat", "direction") + _AIR_COLUMNS


def _check_header(axis, optics, error_axis, rotation_axis, wavelength, basis, where) -> None:
    """Header-level rules; ``where(key)`` names the place of ``key``."""
    if axis not in CARRIAGES:
        raise InterferometerRunError(f"{where('axis')}: axis must be X, Y or Z, got {axis!r}")
    if optics not in OPTICS:
        raise InterferometerRunError(
            f"{where('optics')}: unknown optics {optics!r}; expected one of {', '.join(OPTICS)}")
    if optics == "straightness":
        if error_axis not in CARRIAGES:
            raise InterferometerRunError(
                f"{where('error_axis')}: straightness needs error_axis X, Y or Z (the direction of the measured "
                f"error), got {error_axis!r}")
        if error_axis == axis:
            raise InterferometerRunError(
                f"{where('error_axis')}: a straightness error of the {axis} carriage is across the axis; error_axis "
                f"must differ from {axis} (the error along the axis is the linear optics' job)")
    elif error_axis is not None:
        raise InterferometerRunError(f"{where('error_axis')}: error_axis is only for straightness optics, not {optics}")
    if optics == "angular":
        if rotation_axis not in CARRIAGES:
            raise InterferometerRunError(
                f"{where('rotation_axis')}: angular optics need rotation_axis X, Y or Z, got {rotation_axis!r}")
    elif rotation_axis is not None:
        raise InterferometerRunError(f"{where('rotation_axis')}: rotation_axis is only for angular optics, not {optics}")
    if optics == "linear":
        if wavelength is None:
            raise InterferometerRunError(f"{where('wavelength_vacuum_nm')}: linear optics need the laser's vacuum "
                                         f"wavelength ('# wavelength_vacuum_nm: {HENE_VACUUM_WAVELENGTH_NM}')")
        if basis is None:
            raise InterferometerRunError(f"{where('reading_basis')}: linear optics need the reading basis "
                                         f"('# reading_basis: ' one of {', '.join(READING_BASES)})")
    if wavelength is not None and not (math.isfinite(wavelength) and wavelength > 0):
        raise InterferometerRunError(f"{where('wavelength_vacuum_nm')}: must be a positive number of nm, got {wavelength}")
    if basis is not None and basis not in READING_BASES:
        raise InterferometerRunError(
            f"{where('reading_basis')}: unknown reading basis {basis!r}; expected one of {', '.join(READING_BASES)}")


def _check_rows(cols: dict[str, np.ndarray], reading_name: str, where) -> None:
    """Row-level rules; ``where(i)`` names row i (file:line or 'row i')."""
    n = len(cols["target_mm"])
    for name, arr in cols.items():
        if len(arr) != n:
            raise InterferometerRunError(f"{name}: expected {n} values like target_mm, got {len(arr)}")
    if n == 0:
        raise InterferometerRunError(f"{where(None)}: no readings")
    float_cols = ("target_mm", reading_name) + _AIR_COLUMNS
    for name in float_cols:
        bad = np.flatnonzero(~np.isfinite(cols[name]))
        if len(bad):
            raise InterferometerRunError(f"{where(int(bad[0]))}: {name} is not finite ({cols[name][bad[0]]})")
    bad = np.flatnonzero(cols["repeat"] < 1)
    if len(bad):
        raise InterferometerRunError(f"{where(int(bad[0]))}: repeat must be an integer >= 1, got {cols['repeat'][bad[0]]}")
    bad = np.flatnonzero((cols["direction"] != 1) & (cols["direction"] != -1))
    if len(bad):
        raise InterferometerRunError(f"{where(int(bad[0]))}: direction must be +1 or -1, got {cols['direction'][bad[0]]}")
    for name, (lo, hi, what) in _RANGES.items():
        v = cols[name]
        bad = np.flatnonzero((v < lo) | (v > hi))
        if len(bad):
            raise InterferometerRunError(
                f"{where(int(bad[0]))}: {name} = {v[bad[0]]:g} is not {what}; expected {lo:g}..{hi:g}")
    seen: dict[tuple, int] = {}
    for i, key in enumerate(zip(cols["target_mm"].tolist(), cols["direction"].tolist(), cols["repeat"].tolist())):
        if key in seen:
            raise InterferometerRunError(
                f"{where(i)}: duplicate reading: target {key[0]:g} mm, direction {key[1]:+d}, repeat {key[2]} "
                f"already at {where(seen[key])}")
        seen[key] = i
    first: dict[float, int] = {}
    dirs: dict[float, set] = {}
    for i, (t, d) in enumerate(zip(cols["target_mm"].tolist(), cols["direction"].tolist())):
        first.setdefault(t, i)
        dirs.setdefault(t, set()).add(d)
    if len(first) < 2:
        raise InterferometerRunError(f"{where(None)}: only one target ({next(iter(first)):g} mm); a run needs at least two")
    for t, ds in dirs.items():
        if len(ds) < 2:
            missing = "-1" if 1 in ds else "+1"
            raise InterferometerRunError(
                f"{where(first[t])}: target {t:g} mm has no reading in direction {missing}; every target needs both "
                f"directions (+1 and -1) to average them and report the reversal")


def _fmt(v: float) -> str:
    v = float(v)
    return repr(v).removesuffix(".0") if v.is_integer() else repr(v)


class InterferometerRun:
    """One raw interferometer run: one optics set-up on one carriage, several
    repeats in both directions (file format: docs/interferometer.md).

    Parameters
    ----------
    axis : {'X', 'Y', 'Z'}
        The carriage that moves (its scale reading is the target).
    optics : {'linear', 'straightness', 'angular'}
        Linear optics measure delta_axis (reading in mm: the displacement the
        laser counted); straightness optics measure delta_{error_axis}
        (reading in um); angular optics measure eps_{rotation_axis} (reading in
        arc-seconds, right-hand rule). Roll measured with levels may be stored
        as angular with ``rotation_axis == axis``.
    target_mm : array_like (N,)
        Scale reading of the carriage at the stop, mm. The first row's target
        is home, where the component is zero.
    reading : array_like (N,)
        The instrument's reading: mm (linear), um (straightness) or arc-second
        (angular), signed along the positive machine axis.
    repeat : array_like of int (N,)
        Repeat number, >= 1.
    direction : array_like of int (N,)
        +1 if the target was approached moving towards +axis, -1 otherwise.
        Every target needs both.
    air_temperature_C, pressure_mmHg, humidity_percent : array_like (N,)
        Weather station: air T (C), P (mmHg), H (% RH) at the reading.
    material_temperature_C : array_like (N,)
        Machine (scale) temperature at the reading, C.
    error_axis : {'X', 'Y', 'Z'}, optional
        Straightness only: direction of the measured error (not ``axis``).
    rotation_axis : {'X', 'Y', 'Z'}, optional
        Angular only: axis of the measured rotation.
    wavelength_vacuum_nm : float, optional
        Laser vacuum wavelength, nm; required for linear optics.
    reading_basis : {'standard_air', 'vacuum', 'compensated'}, optional
        How linear readings were converted from fringes (``READING_BASES``);
        required for linear optics.
    metadata : mapping of str to str, optional
        Other header lines (date, operator, instrument...), kept verbatim.
    source : str, optional
        Where the run came from (file); used in messages.
    """

    __slots__ = ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis",
                 "metadata", "source", "_cols")

    def __init__(self, axis, optics, target_mm, reading, repeat, direction, air_temperature_C, pressure_mmHg,
                 humidity_percent, material_temperature_C, *, error_axis=None, rotation_axis=None,
                 wavelength_vacuum_nm=None, reading_basis=None, metadata=None, source=None, _where=None):
        axis = str(axis).upper() if axis is not None else axis
        error_axis = None if error_axis is None else str(error_axis).upper()
        rotation_axis = None if rotation_axis is None else str(rotation_axis).upper()
        if wavelength_vacuum_nm is not None:
            try:
                wavelength_vacuum_nm = float(wavelength_vacuum_nm)
            except (TypeError, ValueError):
                raise InterferometerRunError(f"wavelength_vacuum_nm: expected a number, got {wavelength_vacuum_nm!r}") from None
        label = source or "run"
        where_key = _where[0] if _where else (lambda key: f"{label}: {key}")
        where_row = _where[1] if _where else (lambda i: label if i is None else f"{label}: row {i}")
        _check_header(axis, optics, error_axis, rotation_axis, wavelength_vacuum_nm, reading_basis, where_key)
        reading_name = f"reading_{READING_UNIT[optics]}"
        cols: dict[str, np.ndarray] = {}
        raw = {"target_mm": target_mm, reading_name: reading, "air_temperature_C": air_temperature_C,
               "pressure_mmHg": pressure_mmHg, "humidity_percent": humidity_percent,
               "material_temperature_C": material_temperature_C}
        for name, v in raw.items():
            try:
                arr = np.array(v, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise InterferometerRunError(f"{label}: {name} cannot be read as numbers ({exc})") from None
            if arr.ndim != 1:
                raise InterferometerRunError(f"{label}: {name} must be 1-D, got shape {arr.shape}")
            cols[name] = arr
        for name, v in (("repeat", repeat), ("direction", direction)):
            arr = np.asarray(v)
            if arr.ndim != 1:
                raise InterferometerRunError(f"{label}: {name} must be 1-D, got shape {arr.shape}")
            try:
                as_f = arr.astype(np.float64)
            except (TypeError, ValueError):
                raise InterferometerRunError(f"{label}: {name} must be integers, got {arr.dtype}") from None
            bad = np.flatnonzero(~np.isfinite(as_f) | (as_f != np.round(as_f)) | (np.abs(as_f) > 2.0**53))
            if len(bad):
                raise InterferometerRunError(f"{where_row(int(bad[0]))}: {name} must be an integer, got {arr[bad[0]]}")
            cols[name] = as_f.astype(np.int64)
        _check_rows(cols, reading_name, where_row)
        for arr in cols.values():
            arr.setflags(write=False)
        self.axis = axis
        self.optics = optics
        self.error_axis = error_axis
        self.rotation_axis = rotation_axis
        self.wavelength_vacuum_nm = wavelength_vacuum_nm
        self.reading_basis = reading_basis
        self.metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        for k in self.metadata:
            if k in _KNOWN_KEYS or k == MAGIC or not k or ":" in k or "\n" in k or "\n" in self.metadata[k]:
                raise InterferometerRunError(f"{label}: metadata key {k!r} is reserved or not a single-line key")
        self.source = source
        self._cols = cols

    # -- columns ---------------------------------------------------------------
    @property
    def target_mm(self) -> np.ndarray:
        return self._cols["target_mm"]

    @property
    def reading(self) -> np.ndarray:
        """Readings in ``reading_unit``."""
        return self._cols[f"reading_{self.reading_unit}"]

    @property
    def repeat(self) -> np.ndarray:
        return self._cols["repeat"]

    @property
    def direction(self) -> np.ndarray:
        return self._cols["direction"]

    @property
    def air_temperature_C(self) -> np.ndarray:
        return self._cols["air_temperature_C"]

    @property
    def pressure_mmHg(self) -> np.ndarray:
        return self._cols["pressure_mmHg"]

    @property
    def humidity_percent(self) -> np.ndarray:
        return self._cols["humidity_percent"]

    @property
    def material_temperature_C(self) -> np.ndarray:
        return self._cols["material_temperature_C"]

    # -- what the run measures --------------------------------------------------
    @property
    def reading_unit(self) -> str:
        """'mm' (linear), 'um' (straightness) or 'arcsec' (angular)."""
        return READING_UNIT[self.optics]

    @property
    def component(self) -> str:
        """Map component measured: 'dx', 'dy', 'dz', 'ex', 'ey' or 'ez' (of carriage ``axis``)."""
        if self.optics == "linear":
            return "d" + self.axis.lower()
        if self.optics == "straightness":
            return "d" + self.error_axis.lower()
        return "e" + self.rotation_axis.lower()

    @property
    def column(self) -> str:
        """The map table column (``cmmpose.TABLE_COLUMNS``) this run fills, e.g. 'dy_um'."""
        return self.component + ("_um" if self.component[0] == "d" else "_arcsec")

    @property
    def home_mm(self) -> float:
        """Home: the first row's target, mm."""
        return float(self.target_mm[0])

    @property
    def name(self) -> str:
        """E.g. 'dy(X) straightness' (component, carriage, optics)."""
        return f"{self.component}({self.axis}) {self.optics}"

    def __len__(self) -> int:
        return len(self.target_mm)

    def columns(self) -> dict[str, np.ndarray]:
        """The columns in file order (read-only arrays)."""
        return {c: self._cols[c] for c in run_columns(self.optics)}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, InterferometerRun):
            return NotImplemented
        same = all(getattr(self, a) == getattr(other, a) for a in
                   ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis", "metadata"))
        return same and self._cols.keys() == other._cols.keys() and all(
            self._cols[k].dtype == other._cols[k].dtype and np.array_equal(self._cols[k], other._cols[k])
            for k in self._cols)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        reps = len(np.unique(self.repeat))
        targets = np.unique(self.target_mm)
        src = f", source={self.source!r}" if self.source else ""
        return (f"InterferometerRun({self.name}; {len(targets)} targets {targets[0]:g}..{targets[-1]:g} mm, "
                f"{reps} repeats, {len(self)} readings{src})")

    # -- files -----------------------------------------------------------------
    @classmethod
    def read(cls, path: str | PathLike) -> InterferometerRun:
        """Read a run file (docs/interferometer.md); see :func:`read_run`."""
        return read_run(path)

    def write(self, path: str | PathLike) -> None:
        """Write the run file (docs/interferometer.md); read back it is equal."""
        write_run(self, path)


def _split_run_lines(path: Path, lines: list[str]):
    """A run file's lines after the first: the header keys (key -> (value, line number)), the column header
    and its line number, and the data rows (fields) with their line numbers. A key given twice is refused;
    plain comments, and comments after the column header, are skipped."""
    meta: dict[str, tuple[str, int]] = {}
    header: tuple[str, ...] | None = None
    header_line = 0
    rows: list[list[str]] = []
    row_lines: list[int] = []
    for lineno, raw in enumerate(lines[1:], start=2):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if header is not None:
                continue  # comments after the column header are ignored
            key, sep, value = line[1:].partition(":")
            key = key.strip()
            if not sep or not key:
                continue  # a plain comment
            if key in meta:
                raise InterferometerRunError(f"{path}:{lineno}: header key {key!r} repeats line {meta[key][1]}")
            meta[key] = (value.strip(), lineno)
            continue
        fields = [f.strip() for f in line.split(",")]
        if header is None:
            header, header_line = tuple(fields), lineno
            continue
        rows.append(fields)
        row_lines.append(lineno)
    return meta, header, header_line, rows, row_lines


def _parse_rows(path: Path, expected: tuple[str, ...], rows: list[list[str]], row_lines: list[int]) -> dict:
    """Column -> values of a run file's data rows: ``repeat`` and ``direction`` integers, the others finite
    numbers; a row of another length, or a field that is not its column's kind, refused naming its line."""
    values: dict[str, list] = {c: [] for c in expected}
    for fields, lineno in zip(rows, row_lines):
        if len(fields) != len(expected):
            raise InterferometerRunError(f"{path}:{lineno}: expected {len(expected)} fields, got {len(fields)}")
        for name, text in zip(expected, fields):
            if name in ("repeat", "direction"):
                try:
                    v = int(text)
                except ValueError:
                    want = "+1 or -1" if name == "direction" else "an integer >= 1"
                    raise InterferometerRunError(f"{path}:{lineno}: {name} {text!r} is not {want}") from None
            else:
                try:
                    v = float(text)
                except ValueError:
                    raise InterferometerRunError(f"{path}:{lineno}: {name} {text!r} is not a number") from None
                if not math.isfinite(v):
                    raise InterferometerRunError(f"{path}:{lineno}: {name} is not finite ({text})")
            values[name].append(v)
    return values


def read_run(path: str | PathLike) -> InterferometerRun:
    """Read an interferometer run file.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    InterferometerRun

    Raises
    ------
    InterferometerRunError
        (a ``cmmpose.MapError``) on any malformed content, naming the file and line.
    """
    path = Path(path)
    try:
        lines = read_lines(path)
    except InterferometerRunError:
        raise
    except MapError as exc:
        raise InterferometerRunError(str(exc)) from None
    if not lines or lines[0].strip() != f"# {MAGIC}: {VERSION}":
        got = lines[0].strip() if lines else "an empty file"
        raise InterferometerRunError(
            f"{path}:1: not a cmmpose interferometer run (first line must be '# {MAGIC}: {VERSION}', got {got!r})")
    meta, header, header_line, rows, row_lines = _split_run_lines(path, lines)

    def where_key(key: str) -> str:
        return f"{path}:{meta[key][1]}" if key in meta else f"{path}: header line '# {key}: ...'"

    def value(key: str) -> str | None:
        return meta[key][0] if key in meta else None

    for key in ("axis", "optics"):
        if key not in meta:
            raise InterferometerRunError(f"{path}: header line '# {key}: <value>' is missing")
    optics = value("optics").lower()
    wavelength = value("wavelength_vacuum_nm")
    if wavelength is not None:
        try:
            wavelength = float(wavelength)
        except ValueError:
            raise InterferometerRunError(
                f"{where_key('wavelength_vacuum_nm')}: wavelength_vacuum_nm {wavelength!r} is not a number") from None
    basis = value("reading_basis")
    _check_header(value("axis").upper(), optics, None if value("error_axis") is None else value("error_axis").upper(),
                  None if value("rotation_axis") is None else value("rotation_axis").upper(), wavelength, basis,
                  where_key)
    expected = run_columns(optics)
    if header is None:
        raise InterferometerRunError(f"{path}: no column header row {','.join(expected)!r}")
    if header != expected:
        hint = ""
        if set(header) - set(expected) and any(h.startswith("reading_") for h in header):
            hint = f" ({optics} optics read in {READING_UNIT[optics]}: the column is 'reading_{READING_UNIT[optics]}')"
        raise InterferometerRunError(
            f"{path}:{header_line}: column header must be {','.join(expected)!r}, got {','.join(header)!r}{hint}")
    values = _parse_rows(path, expected, rows, row_lines)
    if not rows:
        raise InterferometerRunError(f"{path}: no readings after the column header (line {header_line})")
    metadata = {k: v for k, (v, _) in meta.items() if k not in _KNOWN_KEYS}
    where = (where_key, lambda i: str(path) if i is None else f"{path}:{row_lines[i]}")
    return InterferometerRun(
        value("axis").upper(), optics, values["target_mm"], values[expected[1]], values["repeat"],
        values["direction"], values["air_temperature_C"], values["pressure_mmHg"], values["humidity_percent"],
        values["material_temperature_C"], error_axis=value("error_axis"), rotation_axis=value("rotation_axis"),
        wavelength_vacuum_nm=wavelength, reading_basis=basis, metadata=metadata,
        source=value("source") or str(path), _where=where)


def write_run(run: InterferometerRun, path: str | PathLike) -> None:
    """Write ``run`` as a run file at ``path`` (floats as their shortest exact text)."""
    if not isinstance(run, InterferometerRun):
        raise InputTypeError(f"run: expected an InterferometerRun, got {type(run).__name__}")
    lines = [f"# {MAGIC}: {VERSION}", f"# axis: {run.axis}", f"# optics: {run.optics}"]
    if run.error_axis is not None:
        lines.append(f"# error_axis: {run.error_axis}")
    if run.rotation_axis is not None:
        lines.append(f"# rotation_axis: {run.rotation_axis}")
    if run.wavelength_vacuum_nm is not None:
        lines.append(f"# wavelength_vacuum_nm: {_fmt(run.wavelength_vacuum_nm)}")
    if run.reading_basis is not None:
        lines.append(f"# reading_basis: {run.reading_basis}")
    if run.source:
        lines.append(f"# source: {' '.join(str(run.source).split())}")
    lines += [f"# {k}: {v}" for k, v in run.metadata.items()]
    cols = run.columns()
    lines.append(",".join(cols))
    for i in range(len(run)):
        lines.append(",".join(
            (f"{int(a[i]):+d}" if name == "direction" else str(int(a[i])) if name == "repeat" else _fmt(a[i]))
            for name, a in cols.items()))
    write_text(path, "\n".join(lines) + "\n")
