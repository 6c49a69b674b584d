"""Thermal selection: the machine temperature at each point's time stamp from
the thermocouple log (thesis section 6.4; docs/conventions.md, Interpolation).

The log functions and the temperature policy live in :mod:`cmmpose.temperature`
(one home: import them from there); this module keeps
:func:`select_map_temperature`, which checks temperatures against the range of
an :class:`~cmmpose.ErrorMapSet`, refusing or clamping.

Units: times in s, temperatures in degrees C, temperature differences in K.
Rows in messages are counted from 0.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errormap import ErrorMapSet
from ..errors import ClampWarning, InputError, InputTypeError, OutOfRangeError

__all__ = ["select_map_temperature"]


# -- maps ---------------------------------------------------------------------------
def select_map_temperature(temperatures, error_map_set: ErrorMapSet, *, out_of_range: str = "raise"):
    """Check temperatures against the range an error map set covers.

    Parameters
    ----------
    temperatures : float or array_like, shape (N,) or (N, 3)
        Machine temperatures, degrees C (e.g. from :func:`cmmpose.temperature.temperatures_at`).
    error_map_set : ErrorMapSet
        The maps; their temperatures (``ErrorMapSet.temperatures``, degrees C)
        span the covered range.
    out_of_range : {'raise', 'clamp'}
        A temperature below the lowest or above the highest map temperature
        raises ``OutOfRangeError`` naming the first such row and value and the
        range; or is clamped to the range with a ``ClampWarning`` giving the
        count.

    Returns
    -------
    temperatures : ndarray, same shape as the input
        Degrees C, within the maps' range (a new array).
    clamped : int
        How many values were clamped (0 with ``'raise'``).

    Raises
    ------
    InputError
        Not numbers, NaN or infinite values (naming the row), not an
        ErrorMapSet, a bad ``out_of_range``.
    OutOfRangeError
        A temperature outside the maps' range, with ``out_of_range='raise'``.
    """
    if not isinstance(error_map_set, ErrorMapSet):
        raise InputTypeError(f"error_map_set: expected a cmmpose.ErrorMapSet, got {type(error_map_set).__name__}")
    if out_of_range not in ("raise", "clamp"):
        raise InputError(f"out_of_range: expected one of 'raise', 'clamp', got {out_of_range!r}")
    clamp = out_of_range == "clamp"
    try:
        temp = np.array(temperatures, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"temperatures: cannot be read as numbers in C ({exc})") from None
    if temp.ndim > 2:
        raise InputError(f"temperatures: expected a number, shape (N,) or (N, 3), got shape {temp.shape}")
    flat = temp.reshape(temp.shape[0] if temp.ndim else 1, -1)
    rows = ~np.isfinite(flat).all(axis=1)
    if rows.any():
        r = int(np.argmax(rows))
        raise InputError(f"temperatures: row {r} is {_fmt_row(flat[r])}; temperatures must be finite (C)")
    temps = [float(x) for x in error_map_set.temperatures]
    lo, hi = temps[0], temps[-1]
    out = (flat < lo) | (flat > hi)
    n_out = int(out.any(axis=1).sum())
    if n_out and not clamp:
        r = int(np.argmax(out.any(axis=1)))
        where = f"row {r}" if temp.ndim else "the temperature"
        col = int(np.argmax(out[r]))
        axis = f" ({'XYZ'[col]} axis)" if flat.shape[1] == 3 and temp.ndim == 2 else ""
        raise OutOfRangeError(
            f"{where}{axis}: temperature {flat[r, col]:g} C is outside the maps' range [{lo:g}, {hi:g}] C "
            f"(maps at {', '.join(f'{x:g}' for x in temps)} C; {n_out} of {flat.shape[0]} rows outside)",
            what="temperature", value=float(flat[r, col]), allowed=(float(lo), float(hi)), unit="C",
            option="out_of_range", remedy="clamp_temperature")
    if n_out:
        temp = np.clip(temp, lo, hi)
        warnings.warn(f"clamped {n_out} of {flat.shape[0]} temperatures into the maps' range [{lo:g}, {hi:g}] C",
                      ClampWarning, stacklevel=2)
    return temp, n_out


def _fmt_row(row: np.ndarray) -> str:
    return f"{row[0]}" if row.shape[0] == 1 else "(" + ", ".join(f"{x:g}" for x in row) + ")"
