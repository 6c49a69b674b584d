"""Input conversion at the Python/Rust boundary: float64, C-contiguous, the
right shape. Arrays already in that form pass through without a copy; others
are converted explicitly here and nowhere else."""

import numpy as np

from .errors import InputError


def as_rows(name: str, a, cols: int) -> np.ndarray:
    """``a`` as an (N, cols) float64 C-contiguous array (no copy if it is one)."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as float64 numbers ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise InputError(f"{name}: expected shape (N, {cols}), got {arr.shape}")
    return np.ascontiguousarray(arr)


def as_vector(name: str, a, n: int) -> np.ndarray:
    """``a`` as an (n,) float64 contiguous array."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as float64 numbers ({exc})") from None
    if arr.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {arr.shape}")
    return np.ascontiguousarray(arr)


def as_triple(name: str, a) -> tuple[float, float, float]:
    """Three finite floats."""
    try:
        vals = tuple(float(x) for x in a)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected three numbers, got {a!r}") from None
    if len(vals) != 3:
        raise InputError(f"{name}: expected three numbers, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise InputError(f"{name}: values must be finite, got {vals}")
    return vals  # type: ignore[return-value]
