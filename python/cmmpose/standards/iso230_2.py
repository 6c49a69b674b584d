"""ISO 230-2:2014 evaluation of the positioning accuracy and repeatability of
one numerically controlled axis (docs/standards.md, "ISO 230-2").

The test: the axis approaches each of m target positions P_i from both sides
(direction +1 moving towards +axis, "up", and -1, "down") in n cycles; at
every approach the positional deviation x_ij = actual - target position is
recorded (a laser interferometer). Per target and direction (clause 3, terms
and definitions; the evaluation follows them one by one):

- mean unidirectional positional deviation x_up_i, x_down_i: the mean over the
  n cycles of that direction (divided by n, the number of cycles);
- mean bidirectional positional deviation x_i = (x_up_i + x_down_i) / 2;
- reversal value B_i = x_up_i - x_down_i;
- estimator of the unidirectional standard uncertainty s_up_i, s_down_i: the
  sample standard deviation (n - 1) of the cycles;
- unidirectional repeatability R_up_i = 4 s_up_i, R_down_i = 4 s_down_i
  (coverage 2 s on either side: the 2014 edition, as the 1997 and 2006 ones);
- bidirectional repeatability R_i = max(2 s_up_i + 2 s_down_i + |B_i|, R_up_i, R_down_i).

For the axis:

- B = max |B_i|, B_mean = mean of the signed B_i;
- R_up = max R_up_i, R_down = max R_down_i, R = max R_i;
- E_up = max x_up_i - min x_up_i (E_down alike); E = max over i of both
  x_up_i and x_down_i minus the min over i of both;
- M = max x_i - min x_i;
- A_up = max(x_up_i + 2 s_up_i) - min(x_up_i - 2 s_up_i) (A_down alike);
  A = max over i and both directions of (x + 2 s) minus the min of (x - 2 s).

All figures are in um. The input is either a table with columns
``target_mm, direction, cycle, deviation_um`` or the laser-interferometer
runs that ``cmmpose calibrate map`` takes (linear optics;
:func:`cmmpose.calibration.interferometer.positional_deviations`).
"""

from __future__ import annotations

import csv
import logging
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path

import numpy as np

from ..calibration.interferometer.air import THESIS_AIR_UNCERTAINTY, refractivity_uncertainty
from ..calibration.interferometer.processing import positional_deviations
from ..calibration.interferometer.runfile import MAGIC, InterferometerRun, read_run
from .._json import dumps as strict_json
from ..errors import (Error, InputError, InputTypeError, MapError, MissingFileError, PositioningError, read_input,
                      read_lines)
from ..evaluation.plots import new_figure, save_plot

__all__ = [
    "ISO230_2_CLAUSE",
    "COLUMNS",
    "PositioningError",
    "PositioningData",
    "TargetResult",
    "PositioningResult",
    "evaluate_iso230_2",
    "read_positioning_csv",
    "positioning_from_interferometer",
    "load_positioning",
]

_log = logging.getLogger("cmmpose.standards")

#: What the evaluation follows (docs/standards.md).
ISO230_2_CLAUSE = "ISO 230-2:2014, clause 3 (terms and definitions of the positioning parameters), coverage 2 s"
#: Columns of the positioning table.
COLUMNS = ("target_mm", "direction", "cycle", "deviation_um")
#: ISO 230-2's standard test: 5 cycles in each direction.
STANDARD_CYCLES = 5
#: The figures of the axis, in the order they are printed.
AXIS_KEYS = ("A", "A_up", "A_down", "B", "B_mean", "E", "E_up", "E_down", "M", "R", "R_up", "R_down")
#: Decimal places of a target position when grouping rows (1 nm).
_TARGET_DECIMALS = 6


@dataclass(frozen=True)
class PositioningData:
    """The rows of a positioning test.

    Attributes
    ----------
    target_mm : ndarray (N,)
        Target position P_i of each approach, mm.
    direction : ndarray of int (N,)
        +1 (approach moving towards +axis) or -1.
    cycle : ndarray of int (N,)
        Cycle number j of the approach.
    deviation_um : ndarray (N,)
        Positional deviation x_ij = actual - target position, um.
    source : str
        Where the rows come from (a file name), for messages.
    rows : ndarray of int (N,)
        The file line (or row number) of each approach, for messages.
    """

    target_mm: np.ndarray
    direction: np.ndarray
    cycle: np.ndarray
    deviation_um: np.ndarray
    source: str = "data"
    rows: np.ndarray | None = None


@dataclass(frozen=True)
class TargetResult:
    """ISO 230-2 figures at one target position, um (``target_mm`` in mm).

    Attributes
    ----------
    target_mm : float
    n_up, n_down : int
        Cycles approached from each direction.
    mean_up, mean_down : float
        Mean unidirectional positional deviations x_up_i, x_down_i, um.
    mean : float
        Mean bidirectional positional deviation (x_up_i + x_down_i) / 2, um.
    reversal : float
        B_i = x_up_i - x_down_i, um.
    s_up, s_down : float
        Sample standard deviations (n - 1) of the cycles, um.
    R_up, R_down : float
        Unidirectional repeatability 4 s, um.
    R : float
        Bidirectional repeatability max(2 s_up + 2 s_down + |B_i|, R_up, R_down), um.
    """

    target_mm: float
    n_up: int
    n_down: int
    mean_up: float
    mean_down: float
    mean: float
    reversal: float
    s_up: float
    s_down: float
    R_up: float
    R_down: float
    R: float

    def to_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class PositioningResult:
    """ISO 230-2 positioning figures of one axis (:func:`evaluate_iso230_2`).

    Attributes
    ----------
    targets : tuple of TargetResult
        Per target, ascending position.
    A, A_up, A_down : float
        Bi- and unidirectional accuracy of positioning, um.
    B : float
        Reversal value of the axis, max |B_i|, um.
    B_mean : float
        Mean reversal value, mean of the signed B_i, um.
    E, E_up, E_down : float
        Bi- and unidirectional systematic positional deviation, um.
    M : float
        Range of the mean bidirectional positional deviation, um.
    R, R_up, R_down : float
        Bi- and unidirectional repeatability of positioning, um.
    cycles : int
        Fewest cycles of any target and direction.
    source : str
        Where the data came from.
    test_uncertainty_um : float or None
        Expanded uncertainty (k = 2) of the measurement of a deviation, um, when
        known (given, or the interferometer's air correction over the travel);
        ISO 230-2 asks for it to be stated with the results.
    test_uncertainty_note : str
        What ``test_uncertainty_um`` covers.
    notes : tuple of str
        Departures from the standard test (fewer than 5 cycles, ...).
    """

    targets: tuple[TargetResult, ...]
    A: float
    A_up: float
    A_down: float
    B: float
    B_mean: float
    E: float
    E_up: float
    E_down: float
    M: float
    R: float
    R_up: float
    R_down: float
    cycles: int
    source: str = "data"
    test_uncertainty_um: float | None = None
    test_uncertainty_note: str = ""
    notes: tuple[str, ...] = field(default=())

    @property
    def axis_values(self) -> dict[str, float]:
        """The axis figures (``AXIS_KEYS``), um."""
        return {k: getattr(self, k) for k in AXIS_KEYS}

    def to_dict(self) -> dict:
        """The axis figures at the top level (um, rounded to 0.1 nm), then the
        per-target figures, the clause, the coverage and the notes."""
        return {**{k: round(v, 4) for k, v in self.axis_values.items()}, "unit": "um",
                "standard": ISO230_2_CLAUSE, "coverage": "2 s (R = 4 s)", "cycles": self.cycles,
                "source": self.source,
                "test_uncertainty_um": None if self.test_uncertainty_um is None else round(self.test_uncertainty_um, 4),
                "test_uncertainty_note": self.test_uncertainty_note,
                "targets": [t.to_dict() for t in self.targets], "notes": list(self.notes)}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def to_markdown(self) -> str:
        """A report section: the axis figures, the per-target table, the clause and the notes."""
        axis = " | ".join(f"{v:.2f}" for v in self.axis_values.values())
        lines = [f"## ISO 230-2 positioning: {self.source}", "",
                 f"{ISO230_2_CLAUSE}; {self.cycles} cycles; um.", "",
                 "| " + " | ".join(AXIS_KEYS) + " |", "|" + "---|" * len(AXIS_KEYS), f"| {axis} |", "",
                 "| target (mm) | n up/down | mean up | mean down | mean | B_i | s up | s down | R up | R down | R_i |",
                 "|" + "---|" * 11]
        lines += [f"| {r.target_mm:.3f} | {r.n_up}/{r.n_down} | {r.mean_up:+.2f} | {r.mean_down:+.2f} | {r.mean:+.2f} | "
                  f"{r.reversal:+.2f} | {r.s_up:.2f} | {r.s_down:.2f} | {r.R_up:.2f} | {r.R_down:.2f} | {r.R:.2f} |"
                  for r in self.targets]
        if self.test_uncertainty_um is not None:
            lines += ["", f"Test uncertainty U (k = 2) = {self.test_uncertainty_um:.2f} um: {self.test_uncertainty_note}."]
        lines += [f"- {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def __rich__(self):
        from rich.markup import escape
        from rich.table import Table

        t = Table(title=f"ISO 230-2 positioning: {escape(str(self.source))}")  # a file's name: text, not markup
        for name in ("target (mm)", "n up/down", "mean up", "mean down", "mean", "B_i", "s up", "s down",
                     "R up", "R down", "R_i"):
            t.add_column(name, justify="right")
        for r in self.targets:
            t.add_row(f"{r.target_mm:.3f}", f"{r.n_up}/{r.n_down}",
                      *(f"{v:+.2f}" for v in (r.mean_up, r.mean_down, r.mean, r.reversal)),
                      *(f"{v:.2f}" for v in (r.s_up, r.s_down, r.R_up, r.R_down, r.R)))
        axis = "  ".join(f"{k} {v:.2f}" for k, v in self.axis_values.items())
        caption = [f"axis (um): {axis}", f"{ISO230_2_CLAUSE}; deviations in um"]
        if self.test_uncertainty_um is not None:
            caption.append(f"test uncertainty U (k = 2) = {self.test_uncertainty_um:.2f} um: {self.test_uncertainty_note}")
        caption += [escape(str(n)) for n in self.notes]
        t.caption = "\n".join(caption)
        return t

    def plot(self, path: str | PathLike | None = None, data: PositioningData | None = None):
        """Mean deviations of both directions with their +-2 s bands, the
        reversal and (given ``data``) every approach; saved to ``path`` if given.

        Parameters
        ----------
        path : str or PathLike, optional
            Image file to write (PNG, PDF, SVG).
        data : PositioningData, optional
            The rows evaluated, to show every approach.

        Returns
        -------
        matplotlib.figure.Figure
        """
        x = np.array([r.target_mm for r in self.targets])
        fig = new_figure(figsize=(8, 4.5))
        ax = fig.subplots()
        for name, mean, s, colour in (("up (+1)", [r.mean_up for r in self.targets], [r.s_up for r in self.targets], "C0"),
                                      ("down (-1)", [r.mean_down for r in self.targets], [r.s_down for r in self.targets], "C3")):
            mean, s = np.asarray(mean), np.asarray(s)
            ax.plot(x, mean, "-o", color=colour, label=f"mean {name}")
            ax.fill_between(x, mean - 2 * s, mean + 2 * s, color=colour, alpha=0.15, label=f"+-2 s {name}")
        if data is not None:
            for d, colour in ((1, "C0"), (-1, "C3")):
                sel = data.direction == d
                ax.plot(data.target_mm[sel], data.deviation_um[sel], ".", color=colour, alpha=0.5, ms=4)
        ax.plot(x, [r.mean for r in self.targets], "k--", lw=1, label="mean bidirectional")
        ax.set_xlabel("target position (mm)")
        ax.set_ylabel("positional deviation (um)")
        ax.set_title(f"ISO 230-2: A {self.A:.2f}, E {self.E:.2f}, R {self.R:.2f}, B {self.B:.2f}, M {self.M:.2f} um")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=2)
        fig.tight_layout()
        return save_plot(fig, path)


def _array(name: str, values, source: str) -> np.ndarray:
    try:
        a = np.array(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PositioningError(f"{source}: {name} cannot be read as numbers ({exc})") from None
    if a.ndim != 1:
        raise PositioningError(f"{source}: {name} must be 1-D, got shape {a.shape}")
    return a


def _where(data: PositioningData, i: int) -> str:
    line = int(data.rows[i]) if data.rows is not None else i
    return f"{data.source}: {'line' if data.rows is not None else 'row'} {line}"


def _check(data: PositioningData) -> PositioningData:
    """Validated copies of the columns (the caller's arrays are not modified)."""
    src = data.source
    cols = {name: _array(name, getattr(data, name), src) for name in COLUMNS}
    n = len(cols["target_mm"])
    for name, a in cols.items():
        if len(a) != n:
            raise PositioningError(f"{src}: {name} has {len(a)} rows, target_mm has {n}")
    rows = None if data.rows is None else np.asarray(data.rows, dtype=np.int64)
    if rows is not None and len(rows) != n:
        raise PositioningError(f"{src}: rows has {len(rows)} entries, target_mm has {n}")
    checked = PositioningData(cols["target_mm"], cols["direction"], cols["cycle"], cols["deviation_um"], src, rows)
    if n == 0:
        raise PositioningError(f"{src}: no rows")
    for name, a in cols.items():
        bad = np.flatnonzero(~np.isfinite(a))
        if len(bad):
            raise PositioningError(f"{_where(checked, int(bad[0]))}: {name} is not finite ({a[bad[0]]})")
    bad = np.flatnonzero((cols["direction"] != 1) & (cols["direction"] != -1))
    if len(bad):
        raise PositioningError(f"{_where(checked, int(bad[0]))}: direction must be +1 or -1, got {cols['direction'][bad[0]]:g}")
    bad = np.flatnonzero(cols["cycle"] != np.round(cols["cycle"]))
    if len(bad):
        raise PositioningError(f"{_where(checked, int(bad[0]))}: cycle must be an integer, got {cols['cycle'][bad[0]]:g}")
    return PositioningData(cols["target_mm"], cols["direction"].astype(np.int64), cols["cycle"].astype(np.int64),
                           cols["deviation_um"], src, rows)


def evaluate_iso230_2(data: PositioningData, *, test_uncertainty_um: float | None = None,
                      test_uncertainty_note: str = "") -> PositioningResult:
    """ISO 230-2:2014 positioning figures of one axis (module docstring;
    docs/standards.md).

    Parameters
    ----------
    data : PositioningData
        Every approach: target (mm), direction (+1/-1), cycle, deviation (um).
        Built by :func:`read_positioning_csv`, :func:`positioning_from_interferometer`
        or :func:`load_positioning`, or directly.
    test_uncertainty_um : float, optional
        Expanded uncertainty (k = 2) of a measured deviation, um, stated with
        the results (ISO 230-2 asks for it; the standard's figures do not use it).
    test_uncertainty_note : str
        What that uncertainty covers.

    Returns
    -------
    PositioningResult

    Raises
    ------
    PositioningError
        One target; a target with a direction missing or approached once in a
        direction (no standard deviation: one cycle); a (target, direction,
        cycle) given twice; non-finite or malformed values. The message names
        the source and the target or row.
    """
    if not isinstance(data, PositioningData):
        raise InputTypeError(f"data: expected a PositioningData, got {type(data).__name__}")
    d = _check(data)
    src = d.source
    key = np.round(d.target_mm, _TARGET_DECIMALS)
    targets, t_idx = np.unique(key, return_inverse=True)
    m = len(targets)
    if m < 2:
        raise PositioningError(f"{src}: ISO 230-2 needs at least 2 target positions, found 1 ({targets[0]:g} mm)")
    # Group g = 2 * target + (0 up, 1 down).
    g = 2 * t_idx + (d.direction == -1)
    order = np.lexsort((d.cycle, g))
    dup = np.flatnonzero((np.diff(g[order]) == 0) & (np.diff(d.cycle[order]) == 0))
    if len(dup):
        i, first = int(order[dup[0] + 1]), int(order[dup[0]])
        what = "line" if d.rows is not None else "row"
        raise PositioningError(f"{_where(d, i)}: target {d.target_mm[i]:g} mm, direction {d.direction[i]:+d}, "
                               f"cycle {d.cycle[i]} is given twice ({what}s "
                               f"{int(d.rows[first]) if d.rows is not None else first} and "
                               f"{int(d.rows[i]) if d.rows is not None else i})")
    count = np.bincount(g, minlength=2 * m).reshape(m, 2)
    for k in range(m):  # per target: a handful
        for j, name in ((0, "+1 (up)"), (1, "-1 (down)")):
            if count[k, j] == 0:
                raise PositioningError(f"{src}: target {targets[k]:g} mm has no approach in direction {name}; "
                                       "ISO 230-2 needs both directions at every target")
            if count[k, j] == 1:
                raise PositioningError(f"{src}: target {targets[k]:g} mm is approached once in direction {name}: "
                                       "one cycle gives no standard deviation; ISO 230-2 needs repeated cycles (5)")
    total = np.bincount(g, weights=d.deviation_um, minlength=2 * m).reshape(m, 2)
    mean = total / count  # divided by the number of cycles
    resid = d.deviation_um - mean.reshape(-1)[g]
    s = np.sqrt(np.bincount(g, weights=resid ** 2, minlength=2 * m).reshape(m, 2) / (count - 1))
    mean_up, mean_down = mean[:, 0], mean[:, 1]
    s_up, s_down = s[:, 0], s[:, 1]
    bi = 0.5 * (mean_up + mean_down)
    rev = mean_up - mean_down
    r_up, r_down = 4 * s_up, 4 * s_down
    r_bi = np.maximum.reduce([2 * s_up + 2 * s_down + np.abs(rev), r_up, r_down])
    hi, lo = mean + 2 * s, mean - 2 * s
    cycles = int(count.min())
    notes = []
    if cycles < STANDARD_CYCLES:
        notes.append(f"{cycles} cycles where the standard test has {STANDARD_CYCLES}: s is less certain")
        _log.info("%s: %d cycles, fewer than the standard %d", src, cycles, STANDARD_CYCLES)
    if len(np.unique(count)) > 1:
        notes.append(f"unequal cycles: {int(count.min())} to {int(count.max())} approaches per target and direction")
    per_target = tuple(
        TargetResult(float(targets[k]), int(count[k, 0]), int(count[k, 1]), float(mean_up[k]), float(mean_down[k]),
                     float(bi[k]), float(rev[k]), float(s_up[k]), float(s_down[k]), float(r_up[k]), float(r_down[k]),
                     float(r_bi[k]))
        for k in range(m))
    if test_uncertainty_um is not None:
        u = float(test_uncertainty_um)
        if not (np.isfinite(u) and u >= 0):
            raise InputError(f"test_uncertainty_um: expected a finite value >= 0 um, got {test_uncertainty_um!r}")
        test_uncertainty_um = u
    return PositioningResult(
        targets=per_target,
        A=float(hi.max() - lo.min()), A_up=float(hi[:, 0].max() - lo[:, 0].min()),
        A_down=float(hi[:, 1].max() - lo[:, 1].min()),
        B=float(np.abs(rev).max()), B_mean=float(rev.mean()),
        E=float(mean.max() - mean.min()), E_up=float(np.ptp(mean_up)), E_down=float(np.ptp(mean_down)),
        M=float(np.ptp(bi)), R=float(r_bi.max()), R_up=float(r_up.max()), R_down=float(r_down.max()),
        cycles=cycles, source=src, test_uncertainty_um=test_uncertainty_um,
        test_uncertainty_note=str(test_uncertainty_note), notes=tuple(notes))


def read_positioning_csv(path: str | PathLike) -> PositioningData:
    """Read a positioning table: a header line with the columns
    ``target_mm, direction, cycle, deviation_um`` (any order, other columns
    ignored), then one approach per line; lines starting with ``#`` are comments.

    Parameters
    ----------
    path : str or PathLike
        The CSV file.

    Returns
    -------
    PositioningData
        With ``rows`` the file's line numbers.

    Raises
    ------
    PositioningError
        A missing column or a value that is not a number, naming the file and line.
    """
    path = Path(path)
    try:
        lines = read_lines(path, "positioning file")
    except MapError as exc:
        raise PositioningError(str(exc)) from None
    numbered = [(i, ln) for i, ln in enumerate(lines, start=1) if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise PositioningError(f"{path}: empty: expected a header line with columns {', '.join(COLUMNS)}")
    header_line, header = numbered[0]
    names = [c.strip() for c in next(csv.reader([header]))]
    repeated = sorted({c for c in names if names.count(c) > 1})
    if repeated:
        raise PositioningError(f"{path}:{header_line}: column(s) {', '.join(repeated)} repeated (columns "
                               + "; ".join(f"{c} at {', '.join(str(j + 1) for j, n in enumerate(names) if n == c)}"
                                           for c in repeated) + "): which one holds the values is ambiguous")
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise PositioningError(f"{path}:{header_line}: missing column(s) {', '.join(missing)} "
                               f"(expected {', '.join(COLUMNS)}; got {', '.join(names)})")
    col = {c: names.index(c) for c in COLUMNS}
    values = {c: [] for c in COLUMNS}
    line_numbers = []
    for lineno, text in numbered[1:]:
        fields = [f.strip() for f in next(csv.reader([text]))]
        if len(fields) != len(names):
            raise PositioningError(f"{path}:{lineno}: {len(fields)} fields, the header has {len(names)}")
        for c, j in col.items():
            try:
                values[c].append(float(fields[j]))
            except ValueError:
                raise PositioningError(f"{path}:{lineno}: {c} = {fields[j]!r} is not a number") from None
        line_numbers.append(lineno)
    return PositioningData(*(np.array(values[c], dtype=float) for c in COLUMNS), source=str(path),
                           rows=np.array(line_numbers, dtype=np.int64))


def positioning_from_interferometer(run, *, air_correction: bool = True, material: str = "keep",
                                    expansion_ppm_per_C: float | None = None) -> tuple[PositioningData, float, str]:
    """The approaches of a linear interferometer run (the files ``cmmpose
    calibrate map`` takes) as positioning data.

    Parameters
    ----------
    run : InterferometerRun
        Linear optics; its repeats are the cycles.
    air_correction : bool
        Correct the readings for the refractive index of air.
    material : {'keep', 'normalise'}
        Keep the machine's temperature, or normalise displacements to 20 C.
    expansion_ppm_per_C : float, optional
        Scale expansion, ppm per C, with ``material='normalise'``.

    Returns
    -------
    data : PositioningData
        Deviations in um (actual - target, relative to home).
    test_uncertainty_um : float
        U (k = 2) of the air correction over the run's longest distance from
        home, um (2 u_N L; the weather-station budget of thesis line 768).
    note : str
        What that uncertainty covers.
    """
    if not isinstance(run, InterferometerRun):
        raise InputTypeError(f"run: expected an InterferometerRun, got {type(run).__name__}")
    dev = positional_deviations(run, air_correction=air_correction, material=material,
                                expansion_ppm_per_C=expansion_ppm_per_C)
    label = run.source or run.name
    travel = float(np.max(np.abs(run.target_mm - run.home_mm)))
    u_n = refractivity_uncertainty(*THESIS_AIR_UNCERTAINTY)
    u = 2.0 * u_n * travel * 1e-3
    note = (f"refractive index of air only: 2 x {u_n:.2f} ppm over {travel:g} mm (weather station of thesis "
            "line 768); the laser, alignment (cosine) and dead-path terms are not included")
    return PositioningData(run.target_mm.copy(), run.direction.copy(), run.repeat.copy(), dev, label), u, note


def load_positioning(path: str | PathLike, *, air_correction: bool = True) -> tuple[PositioningData, float | None, str]:
    """Positioning data from a file: an interferometer run (recognised by its
    first line) or a positioning CSV (:func:`read_positioning_csv`).

    Parameters
    ----------
    path : str or PathLike
    air_correction : bool
        Interferometer runs: correct for the refractive index of air.

    Returns
    -------
    data : PositioningData
    test_uncertainty_um : float or None
        U (k = 2), um, for interferometer runs; None for a table.
    note : str
    """
    path = Path(path)
    try:  # the one door in: a FIFO or a device refused, never waited on
        first = read_input(path, "positioning file", error=PositioningError).split(b"\n", 1)[0]
        first = first.decode("utf-8", "replace").strip()
    except MissingFileError:
        raise PositioningError(f"{path}: cannot read (No such file or directory)") from None
    if first.startswith(f"# {MAGIC}"):
        try:
            data, u, note = positioning_from_interferometer(read_run(path), air_correction=air_correction)
            return replace(data, source=str(path)), u, note
        except PositioningError:
            raise
        except Error as exc:
            raise PositioningError(str(exc) if str(path) in str(exc) else f"{path}: {exc}") from None
    return read_positioning_csv(path), None, ""
