"""Linear-axis positioning results and the canonical error map: the part
shared by the exchange formats of docs/formats.md (ISO 230-2 style CSV,
:mod:`cmmpose.formats.iso230`; LinuxCNC compensation tables, :mod:`cmmpose.formats.linuxcnc`).

A linear-axis result gives, per carriage and target position, the mean
positional deviation for each approach direction, deviation = actual position
minus target (scale) position. That is the sign of the map's linear
components: the carriage's true position is its scale reading plus delta
(docs/interferometer.md, eq. 1). A map holds one value per position, so an
import keeps the **bidirectional mean** (up + down) / 2; the reversal value
(up - down) cannot be kept in the map and is logged (a warning above
``reversal_limit_um``) and summarised in the map's ``source``.

Units: positions in mm, deviations in um, as in the map tables; the format
modules convert their own units (e.g. LinuxCNC machine units) when they read
or write, and nowhere else.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..errormap import CARRIAGES, ErrorMap
from ..errors import InputError, InputTypeError, MapError

__all__ = ["AxisResult", "build_map", "linear_components", "REVERSAL_LIMIT_UM", "POSITION_TOLERANCE_MM"]

_log = logging.getLogger(__name__)

#: Reversal values (|up - down|, um) above this are logged as warnings: the
#: map keeps the mean, so each direction is off by half the reversal.
REVERSAL_LIMIT_UM = 1.0

#: Targets this close outside a base map's range (mm) count as its ends: the
#: rounding of printed positions (e.g. inches converted to mm), not data
#: outside the map.
POSITION_TOLERANCE_MM = 1e-3


@dataclass(frozen=True)
class AxisResult:
    """Mean positional deviations of one carriage, per target and approach direction.

    Parameters
    ----------
    axis : str
        The carriage, ``'X'``, ``'Y'`` or ``'Z'``.
    target_mm : ndarray, shape (n,)
        Target positions (scale readings), mm, strictly increasing, n >= 2.
    up_um : ndarray, shape (n,)
        Mean deviation (actual - target) approaching in the positive direction, um.
    down_um : ndarray, shape (n,)
        Mean deviation approaching in the negative direction, um.
    where : str
        The file the result was read from, first in messages.
    lines : tuple of int
        Line of the file of each target (for messages), same length as ``target_mm``.
    """

    axis: str
    target_mm: np.ndarray
    up_um: np.ndarray
    down_um: np.ndarray
    where: str
    lines: tuple[int, ...]

    @property
    def mean_um(self) -> np.ndarray:
        """Bidirectional mean deviation (up + down) / 2, um: what the map keeps."""
        return 0.5 * (self.up_um + self.down_um)

    @property
    def reversal_um(self) -> np.ndarray:
        """Reversal value up - down, um (ISO 230-2's B at each target)."""
        return self.up_um - self.down_um


def _report_reversal(result: AxisResult, limit_um: float) -> str:
    """Log the largest reversal of ``result``; return a short summary for ``source``."""
    b = result.reversal_um
    i = int(np.argmax(np.abs(b)))
    text = f"{result.axis} max |reversal| {abs(b[i]):.3g} um at {result.target_mm[i]:g} mm"
    if abs(b[i]) > limit_um:
        _log.warning("%s: %s exceeds %g um; the map keeps the bidirectional mean, so each approach "
                     "direction is off by up to %.3g um", result.where, text, limit_um, abs(b[i]) / 2)
    else:
        _log.info("%s: %s (the map keeps the bidirectional mean)", result.where, text)
    return text


def build_map(results: Mapping[str, AxisResult], *, source: str, base: ErrorMap | None = None,
              temperature: float | None = None, ranges=None, hold_ends: bool = False,
              reversal_limit_um: float = REVERSAL_LIMIT_UM) -> ErrorMap:
    """An error map whose linear components come from linear-axis results.

    Parameters
    ----------
    results : mapping of str to AxisResult
        Results per carriage (``'X'``, ``'Y'``, ``'Z'``); any may be missing.
    source : str
        What the results are (e.g. the file), for the map's ``source``.
    base : ErrorMap, optional
        Without a base: delta_x of X, delta_y of Y, delta_z of Z are the
        results' bidirectional means (um) at their targets (mm); every other
        component and the squareness are zero, and a carriage without a result
        has an all-zero table over ``ranges``. With a base: a copy of it in
        which only the linear component of each carriage with a result is
        replaced, the results interpolated linearly onto the base's grid (mm);
        carriages without a result keep the base's component.
    temperature : float, optional
        Temperature of the map, degrees C (default: the base's, else none).
    ranges : sequence of 3 (lo, hi), optional
        Range of the all-zero table of a carriage without a result, mm
        (default: the ranges of ``ErrorMap.zero()``). Unused with a base.
    hold_ends : bool, optional
        With a base whose grid runs beyond a result's targets: hold the
        result's end values there (logged) instead of raising ``MapError``.
    reversal_limit_um : float, optional
        Reversal values above this (um) are logged as warnings.

    Returns
    -------
    ErrorMap

    Raises
    ------
    MapError
        A target outside the base's range (naming the file and line), or a
        base grid beyond the results' targets without ``hold_ends``.
    InputError
        A carriage name other than X, Y, Z, or a base that is not an ErrorMap.
    """
    unknown = [a for a in results if a not in CARRIAGES]
    if unknown:
        raise InputError(f"results: carriage(s) {', '.join(map(repr, unknown))} are not 'X', 'Y' or 'Z'")
    if base is not None and not isinstance(base, ErrorMap):
        raise InputTypeError(f"base: expected an ErrorMap, got {type(base).__name__}")
    summaries = [_report_reversal(results[a], reversal_limit_um) for a in CARRIAGES if a in results]
    missing = [a for a in CARRIAGES if a not in results]
    tables = []
    if base is None:
        zero_ranges = ErrorMap.zero().ranges if ranges is None else list(ranges)
        for k, axis in enumerate(CARRIAGES):
            if axis in results:
                r = results[axis]
                table = np.zeros((len(r.target_mm), 7))
                table[:, 0] = r.target_mm
                table[:, 1 + k] = r.mean_um
            else:
                lo, hi = zero_ranges[k]
                table = np.array([[lo] + [0.0] * 6, [hi] + [0.0] * 6], dtype=float)
                _log.info("%s: no %s results: every %s component is zero over %g..%g mm", source, axis, axis, lo, hi)
            tables.append(table)
        squareness = (0.0, 0.0, 0.0)
        label = f"{source} (linear components, bidirectional mean; other components zero)"
    else:
        for k, axis in enumerate(CARRIAGES):
            table = np.array(base.table(axis), dtype=float)
            if axis in results:
                table[:, 1 + k] = _onto_grid(results[axis], table[:, 0], hold_ends)
            else:
                _log.info("%s: no %s results: the base map's delta_%s of %s is kept", source, axis, axis.lower(), axis)
            tables.append(table)
        squareness = base.squareness
        if temperature is None:
            temperature = base.temperature
        label = f"{source} (linear components, bidirectional mean) merged into {base.source or 'a base map'}"
    if missing:
        label += f"; no results for {', '.join(missing)}"
    if summaries:
        label += "; " + ", ".join(summaries)
    error_map = ErrorMap(*tables, squareness, temperature, source=label)
    if base is not None and base.kinematics not in ("thesis", "custom"):
        error_map = error_map.with_kinematics(base.kinematics)  # the base's machine configuration is kept
    return error_map


def _onto_grid(result: AxisResult, grid: np.ndarray, hold_ends: bool) -> np.ndarray:
    """The result's mean deviation (um) interpolated linearly at the base grid positions ``grid`` (mm)."""
    lo, hi = float(grid[0]), float(grid[-1])
    t = result.target_mm
    for pos, line in zip(t, result.lines):
        if pos < lo - POSITION_TOLERANCE_MM or pos > hi + POSITION_TOLERANCE_MM:
            raise MapError(f"{result.where}:{line}: {result.axis} target {pos:g} mm is outside the base map's "
                           f"{result.axis} range {lo:g}..{hi:g} mm")
    beyond = (grid < t[0] - POSITION_TOLERANCE_MM) | (grid > t[-1] + POSITION_TOLERANCE_MM)
    if beyond.any():
        message = (f"{result.where}: the {result.axis} targets span {t[0]:g}..{t[-1]:g} mm but the base map's "
                   f"{result.axis} grid runs {lo:g}..{hi:g} mm ({int(beyond.sum())} grid positions beyond the targets)")
        if not hold_ends:
            raise MapError(message + "; hold_ends=True (--hold-ends) holds the end values there")
        _log.warning("%s; the end values are held there", message)
    return np.interp(grid, t, result.mean_um)


def linear_components(error_map: ErrorMap) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The linear component of each carriage: delta_x of X, delta_y of Y, delta_z of Z.

    Parameters
    ----------
    error_map : ErrorMap
        The map.

    Returns
    -------
    dict of str to (ndarray, ndarray)
        Per carriage, its grid positions (mm) and linear deviation (um).
    """
    if not isinstance(error_map, ErrorMap):
        raise InputTypeError(f"error_map: expected an ErrorMap, got {type(error_map).__name__}")
    out = {}
    for k, axis in enumerate(CARRIAGES):
        table = error_map.table(axis)
        out[axis] = (np.array(table[:, 0], dtype=float), np.array(table[:, 1 + k], dtype=float))
    return out
