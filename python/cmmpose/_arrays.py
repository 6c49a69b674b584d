"""Input conversion at the Python/Rust boundary: float64, C-contiguous, the
right shape. Arrays already in that form pass through without a copy; others
are converted explicitly here and nowhere else."""

import math

import numpy as np

from .errors import InputError


def _real(name: str, a):
    """Refuse what float64 conversion would silently change: complex numbers
    (the imaginary part dropped), booleans and strings (numbers by accident)."""
    kind = getattr(getattr(a, "dtype", None), "kind", None)
    if kind is None and not isinstance(a, (int, float)):
        kind = np.asarray(a).dtype.kind if not isinstance(a, (str, bytes)) else "U"
    if kind == "c":
        raise InputError(f"{name}: complex numbers are not coordinates (got dtype complex); pass the real part "
                         f"explicitly if that is what you mean")
    if kind in ("b", "U", "S"):
        raise InputError(f"{name}: expected numbers, got {'booleans' if kind == 'b' else 'text'}")
    return a


def as_rows(name: str, a, cols: int) -> np.ndarray:
    """``a`` as an (N, cols) float64 C-contiguous array (no copy if it is one)."""
    _real(name, a)
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as float64 numbers ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise InputError(f"{name}: expected shape (N, {cols}), got {arr.shape}")
    return np.ascontiguousarray(arr)


def as_vector(name: str, a, n: int) -> np.ndarray:
    """``a`` as an (n,) float64 contiguous array."""
    _real(name, a)
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as float64 numbers ({exc})") from None
    if arr.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {arr.shape}")
    return np.ascontiguousarray(arr)


def as_triple(name: str, a) -> tuple[float, float, float]:
    """Three finite floats (booleans and text are refused, not read as numbers)."""
    if isinstance(a, (tuple, list)) and len(a) == 3 and all(type(x) is float or type(x) is int for x in a):
        # The common case (plain numbers, a MountOffset) without NumPy's object round trip.
        vals = (float(a[0]), float(a[1]), float(a[2]))
        if not all(map(math.isfinite, vals)):
            raise InputError(f"{name}: values must be finite, got {vals}")
        return vals
    if isinstance(a, (str, bytes)) or any(isinstance(x, (bool, np.bool_, str, bytes)) for x in np.ravel(
            np.asarray(a, dtype=object))):
        raise InputError(f"{name}: expected three numbers, got {a!r}")
    try:
        vals = tuple(float(x) for x in a)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected three numbers, got {a!r}") from None
    if len(vals) != 3:
        raise InputError(f"{name}: expected three numbers, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise InputError(f"{name}: values must be finite, got {vals}")
    return vals  # type: ignore[return-value]
