"""Whether a fit is to be believed: the conditioning of a free radius, a point far from the rest, a unit slip,
an rms or a radius that no scanner on this artefact gives (docs/fitting.md, "Sanity checks"); warnings and
errors that say why.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np

from .._core import fit_sphere as core_fit_sphere  # the Rust fits (cmmpose._core)
from .._validate import LENGTH_UNIT_NAMES, length_unit_slip
from ..errors import GeometryError, IllConditionedFit, ImplausibleFit
from .results import SphereFit

_log = logging.getLogger("cmmpose.fitting")

#: A free-radius fit warns (:class:`IllConditionedFit`) when the centre-radius
#: correlation exceeds this: fixing the radius would then shrink the variance
#: of the centre along the cap axis by 1 / (1 - 0.99^2) = 50 (its standard
#: uncertainty by 7x). A uniform cap reaches it at a 53 degree half-angle;
#: docs/fitting.md.
ILL_CONDITIONED_CORRELATION = 0.99

#: A point this many times farther from the points' median than the typical
#: point makes the rest look collinear or coplanar to the fit's moments: the
#: degenerate-geometry error then names it instead (:func:`far_point`).
FAR_POINT_RATIO = 1e4

#: A sphere fit warns (:class:`ImplausibleFit`) when its rms exceeds this
#: fraction of the radius. Scanners used on spheres scatter by well under 1 %
#: of the radius (the NIST DMG scans: 0.1-0.2 mm on 50 mm, 0.2-0.4 %; a CMM
#: line scanner: microns on millimetres); at 10 % the points no longer
#: describe one sphere (a raw scan with its stand and background, another
#: unit, another radius) and the centre is whatever the rest pulls it to.
MAX_RMS_FRACTION = 0.10

#: A fixed-radius fit warns (:class:`ImplausibleFit`) when a free-radius fit of
#: the same points has an rms this many times smaller: fixing the radius then
#: adds a misfit larger than the scanner's own scatter (sqrt(1.5^2 - 1) = 1.1
#: times it). With the right calibrated radius the two agree to a few percent
#: (the NIST DMG scans: at most 1.02); 1 mm off on 50 mm already gives 1.9.
RADIUS_MISFIT_RMS_RATIO = 1.5

#: ... and when that free radius differs from the fixed one by more than this
#: fraction of it: no scanner bias reaches it (coating, incidence, mixed
#: pixels: the NIST DMG scans' free radii lie within 0.33 % of 50 mm, a CMM
#: scanner's within tens of microns), a wrong radius (a diameter, another
#: sphere's, another unit) or points not on the sphere do.
RADIUS_MISFIT_FRACTION = 0.02


def ill_conditioned(rho: float, cap: float, what: str) -> str:
    gain = 1.0 / np.sqrt(max(1.0 - rho * rho, 1e-300))
    return (f"{what}: the free-radius centre is ill-determined (centre-radius correlation {rho:.4f} over a "
            f"{cap:.1f} deg cap: the centre moves with the radius, its uncertainty along the cap axis "
            f"{gain:.0f}x what a fixed radius gives); fit with the radius fixed at its calibrated value "
            f"(radius=...)")


def warn_conditioning(fit: SphereFit, free: bool) -> None:
    if not free:
        return
    rho = fit.centre_radius_correlation
    if rho > ILL_CONDITIONED_CORRELATION:
        msg = ill_conditioned(rho, fit.polar_coverage, "sphere fit")
        _log.warning("%s", msg)
        warnings.warn(msg, IllConditionedFit, stacklevel=3)


def far_point(rows: np.ndarray, message: str, row_of=lambda k: k) -> str:
    """``message`` (a degenerate-geometry error) or, when one point lies
    :data:`FAR_POINT_RATIO` times farther from the points' median than the
    typical point does, a message naming its row (``row_of(index)``): a
    single 1e12 mm outlier makes the moments of the rest look collinear, and
    "collinear" would send the user looking for the wrong fault."""
    if len(rows) < 5 or not any(w in message for w in ("collinear", "coplanar", "coincide")):
        return message
    d = np.linalg.norm(rows - np.median(rows, axis=0), axis=1)
    typical = max(float(np.median(d)), 1e-300)
    k = int(np.argmax(d))
    if not d[k] > FAR_POINT_RATIO * typical:
        return message
    span = float(np.max(rows.max(axis=0) - rows.min(axis=0)))
    far = int(np.sum(d > FAR_POINT_RATIO * typical))
    x, y, z = rows[k]
    more = f" ({far} points are that far)" if far > 1 else ""
    return (f"row {row_of(k)}: ({x:.6g}, {y:.6g}, {z:.6g}) mm lies {d[k]:.3g} mm from the points' median, "
            f"{d[k] / typical:.3g} times the typical point's {typical:.3g} mm{more}: the coordinates span an "
            f"absurd range ({span:.3g} mm) and the fit cannot see the shape of the rest; remove the row or check "
            f"its units")


def unit_hint(rows: np.ndarray, radius: float) -> tuple[str, str | None]:
    """A sentence on the points' units when they span far less than the
    sphere (a scan in metres read as mm) and the likely unit (or None): a
    scan that sees a sphere spans at least about its radius, so points
    spanning under half of it, at the scale of another unit, are in that
    unit. An error that names the unit carries how to read the points in it
    as its remedy (``remedy='units'``, ``value`` the unit)."""
    span = float(np.max(np.ptp(rows, axis=0))) if len(rows) else 0.0
    if not (span > 0) or span >= 0.5 * radius:
        return "", None
    need = 2.0 * radius / span  # the factor that makes the points span the sphere's diameter
    slip = length_unit_slip(need, 3.0)  # within a factor 4: a scan need not span the whole diameter
    if slip is None:
        return (f"; the points span only {span:.3g} mm against the sphere's {2 * radius:g} mm diameter: are the "
                f"points and the radius in the same unit (mm)?"), None
    return (f"; the points span only {span:.3g} mm against the sphere's {2 * radius:g} mm diameter: the "
            f"coordinates look like {LENGTH_UNIT_NAMES[slip[0]]} ({span * slip[1]:.4g} mm if they are): convert "
            f"them to mm"), slip[0]


def coverage_error(rows: np.ndarray, radius: float, coverage: float, min_coverage: float, what: str) -> GeometryError:
    hint, unit = unit_hint(rows, radius)
    return GeometryError(f"{what}: polar coverage {coverage:.3g} deg is below min_coverage = {min_coverage:g} deg with "
                         f"the radius fixed at {radius:g} mm: the points are too small a cap of that sphere for its "
                         f"centre to mean anything{hint}", what="units" if unit else None, value=unit,
                         remedy="units" if unit else None)


def _implausible(rows: np.ndarray, fit: SphereFit, fixed: bool, what: str) -> str | None:
    """Why ``fit`` (of ``rows``, its inliers) is implausible, or None:
    its rms over :data:`MAX_RMS_FRACTION` of the radius, or (a fixed radius)
    a free-radius fit of the same points that fits far better with a
    radius far from the fixed one. Run in Rust, once more per fit."""
    radius, rms = float(fit.radius), float(fit.rms)
    reasons = []
    if rms > MAX_RMS_FRACTION * radius:
        reasons.append(f"the rms {rms:.4g} mm is {100 * rms / radius:.0f} % of the {radius:g} mm radius (over "
                       f"{100 * MAX_RMS_FRACTION:g} %): the points do not lie on one sphere")
    if fixed and len(rows) >= 4:
        try:
            free = core_fit_sphere(np.ascontiguousarray(rows), radius=None, reject=None, rule=None,
                                    max_iterations=100, min_coverage=0.0, samples=1, seed=0, start="algebraic")
        except Exception:  # noqa: BLE001 - no free fit, no comparison (the fixed fit stands)
            free = None
        if free is not None and np.isfinite(free["radius"]) and free["rms"] >= 0:
            rf, sf = float(free["radius"]), float(free["rms"])
            if rms > RADIUS_MISFIT_RMS_RATIO * sf and abs(rf - radius) > RADIUS_MISFIT_FRACTION * radius:
                ratio = radius / rf
                guess = " (twice the points' radius: a diameter?)" if abs(ratio - 2) < 0.1 else ""
                reasons.append(f"the fixed radius {radius:g} mm misfits the points: a free-radius fit of the same "
                               f"points gives {rf:.4g} mm with rms {sf:.4g} mm against {rms:.4g} mm{guess}")
    if not reasons:
        return None
    hint, _ = unit_hint(rows, radius)
    return (f"{what}: " + "; ".join(reasons) + hint + ": check the radius, the units, and that the points are the "
            "sphere's alone (a raw scan needs segmentation or a rejection rule); the centre is not to be trusted")


def warn_implausible(rows: np.ndarray, fit: SphereFit, fixed: bool, what: str) -> None:
    msg = _implausible(rows, fit, fixed, what)
    if msg:
        _log.warning("%s", msg)
        warnings.warn(msg, ImplausibleFit, stacklevel=3)
