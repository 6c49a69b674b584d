"""What the digitizer-alignment solvers share (thesis chapter 4, section 5.3).

The thesis's standard poses, the E313 rotation and its derivatives, the checks
of the maps, temperatures, covariances and uncertainties a solver is given,
scanner points in machine coordinates (compensated with the map, or the
error-free model without one) and the chi-square tail of the consistency checks.

Units: mm for lengths, degrees for angles (radians only inside), degrees C
for temperatures; covariances in the square of those units.
"""

from __future__ import annotations

import numpy as np

from ... import _core
from ...compensation import compensate, uncompensated
from ...errormap import ErrorMap, ErrorMapSet
from ...errors import InputError, InputTypeError
from ...pose import pose_tuple
from ...temperature import TemperaturePolicy


#: The thesis's three alignments for the mount offset (section 5.3): W along +X
#: at gamma 0 and 90 degrees, W along +Y at gamma 0 (alpha, beta, gamma in degrees).
STANDARD_POSES = ((90.0, 90.0, 0.0), (90.0, 90.0, 90.0), (180.0, 90.0, 0.0))


def e313_matrix(pose) -> np.ndarray:
    """The E313 rotation of ``pose`` (alpha, beta, gamma in degrees), (3, 3)."""
    return np.asarray(_core.euler313(*pose_tuple(pose)))


def e313_derivatives(pose) -> np.ndarray:
    """dE313/d(alpha, beta, gamma), (3, 3, 3) per degree, index [angle] -> (3, 3)."""
    p = np.array(pose_tuple(pose), dtype=float)
    h = 1e-3  # deg: central difference, truncation ~ (h rad)^2 ~ 3e-10 relative
    out = np.empty((3, 3, 3))
    for j in range(3):  # three angles, not points
        d = np.zeros(3)
        d[j] = h
        out[j] = (e313_matrix(p + d) - e313_matrix(p - d)) / (2 * h)
    return out


def check_map(maps, temperature):
    """Refuse maps that are neither an ErrorMap nor an ErrorMapSet, a set without a temperature, and a temperature
    without maps."""
    if maps is None:
        if temperature is not None:
            raise InputError("temperature: only meaningful with maps")
        return
    if not isinstance(maps, (ErrorMap, ErrorMapSet)):
        raise InputTypeError(f"maps: expected an ErrorMap or ErrorMapSet, got {type(maps).__name__}")
    if isinstance(maps, ErrorMapSet) and temperature is None:
        raise InputError("temperature: an ErrorMapSet needs the machine temperature (C), one value or one per point")


def as_temperature(temperature, n: int):
    """None, one float, or an (n,) float array (C)."""
    if temperature is None:
        return None
    if np.ndim(temperature) == 0:
        try:
            return float(temperature)
        except (TypeError, ValueError):
            raise InputError(f"temperature: expected a number (C) or an (N,) array, got {temperature!r}") from None
    t = np.asarray(temperature, dtype=float)
    if t.shape != (n,):
        raise InputError(f"temperature: expected one value or one per point, shape ({n},), got {t.shape}")
    return t


def single_map(maps, temperature, policy: TemperaturePolicy) -> ErrorMap:
    """The map at the (mean) temperature, for evaluating e(S) and R(S) at one reading."""
    if isinstance(maps, ErrorMap):
        return maps
    return maps.at(float(np.mean(temperature)), out_of_range=policy.out_of_range,
                   temperature_tolerance=policy.temperature_tolerance)


def machine_points(uv, scales, pose, offset, maps, temperature, policy: TemperaturePolicy) -> np.ndarray:
    """Scanner points in machine coordinates (mm): compensated with the map, or
    the error-free model S + E313 ((u, v, 0) - l1) without one."""
    if maps is None:
        return uncompensated(uv, scales, pose, offset)
    return compensate(uv, scales, maps, pose, offset, temperature, temperature_policy=policy)


def as_covariance(name: str, c, n: int) -> np.ndarray:
    """``c`` as a finite, symmetric, positive semi-definite (n, n) covariance (symmetrised); ``name`` words the
    error."""
    a = np.asarray(c, dtype=float)
    if a.shape != (n, n):
        raise InputError(f"{name}: expected a ({n}, {n}) covariance, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        # The usual way here: a vernier fit of three points without a stated
        # point uncertainty has no residuals to estimate one from.
        raise InputError(f"{name}: expected finite entries, got {a.tolist()} (a vernier fit of 3 points has no "
                         "Type A uncertainty: give its point_uncertainty)")
    # Symmetric to rounding relative to the largest entry (computed covariances
    # carry rounding-level asymmetry in near-zero off-diagonal terms).
    if not np.allclose(a, a.T, rtol=1e-9, atol=1e-12 * np.abs(a).max()):
        raise InputError(f"{name}: covariance must be symmetric")
    if np.linalg.eigvalsh(a).min() < -1e-12 * max(1.0, np.abs(a).max()):
        raise InputError(f"{name}: covariance must be positive semi-definite")
    return 0.5 * (a + a.T)


def uncertainty_triple(name: str, u) -> np.ndarray:
    """One or three standard uncertainties >= 0 (mm) as a (3,) array."""
    a = np.broadcast_to(np.asarray(u, dtype=float), (3,)).copy() if np.ndim(u) == 0 else np.asarray(u, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputError(f"{name}: expected one or three standard uncertainties >= 0 (mm), got {u!r}")
    return a


def chi2_sf(x: float, k: int) -> float:
    """P(chi^2_k > x) (scipy.special.chdtrc); 1 for k <= 0 or x <= 0."""
    if k <= 0:
        return 1.0
    if x <= 0:
        return 1.0
    from scipy.special import chdtrc  # SciPy is imported on first use, not with cmmpose

    return float(chdtrc(k, x))


def pose_name(pose) -> str:
    """The pose as '(alpha, beta, gamma)' in degrees, for messages."""
    a, b, g = pose_tuple(pose)
    return f"({a:g}, {b:g}, {g:g})"
