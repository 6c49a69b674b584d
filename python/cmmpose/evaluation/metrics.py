"""Ballbar figures of merit (thesis chapter 6). Lengths in mm."""

from __future__ import annotations

import numpy as np

from ..errors import InputError

#: Expansion coefficient of the steel ballbar, 1/K (thesis section 6.4.1, Table 21).
STEEL_EXPANSION = 12e-6
#: The same, ppm/K (the unit of every expansion argument and option).
STEEL_EXPANSION_PPM_PER_K = 12.0


def _lengths(lengths, minimum: int = 2) -> np.ndarray:
    a = np.asarray(lengths, dtype=float)
    if a.ndim != 1 or len(a) < minimum:
        raise InputError(f"lengths: expected at least {minimum} lengths in a 1-D array (mm), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"lengths: non-finite value at position {int(np.flatnonzero(~np.isfinite(a))[0])}")
    return a


def rms_accuracy_error(lengths) -> float:
    """Rms accuracy error (thesis eq. 36): sample standard deviation (n - 1) of the
    ballbar lengths, mm."""
    return float(np.std(_lengths(lengths), ddof=1))


def b89_value(lengths) -> float:
    """ASME B89.4.1 style value: the largest |L_i - mean length|, mm."""
    a = _lengths(lengths)
    return float(np.max(np.abs(a - a.mean())))


def improvement(uncompensated: float, compensated: float) -> float:
    """1 - compensated / uncompensated (a fraction; thesis Tables 19-20 give it in %)."""
    if not (np.isfinite(uncompensated) and uncompensated > 0 and np.isfinite(compensated)):
        raise InputError(f"improvement: needs a positive uncompensated figure, got {uncompensated}, {compensated}")
    return 1.0 - compensated / uncompensated


def length_at_20c(length, temperature, expansion: float = STEEL_EXPANSION):
    """Length at the standard 20 C: L / (1 + expansion (T - 20)) (thesis section 6.4.1).

    Parameters
    ----------
    length : float or array_like
        Measured length, mm.
    temperature : float or array_like
        Part temperature, degrees C.
    expansion : float
        Linear expansion coefficient of the part, 1/K (steel 12e-6).
    """
    return np.asarray(length, dtype=float) / (1.0 + expansion * (np.asarray(temperature, dtype=float) - 20.0))
