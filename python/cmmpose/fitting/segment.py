"""The ASTM E3125-style segmentation of a sphere from a raw scan (rust/core/src/fit/segment.rs): the points on
the sphere found, fitted, and the result as E3125 reports it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .._core import segment_sphere as core_segment_sphere  # the Rust fits (cmmpose._core)
from .._arrays import as_rows
from .._validate import vector3
from ..errors import InputError
from .plausibility import coverage_error, warn_implausible
from .results import SphereFit
from .sphere import RULES, check_options

_log = logging.getLogger("cmmpose.fitting")


@dataclass(frozen=True)
class SphereSegmentation:
    """A sphere segmented from a raw scan and fitted with its radius fixed
    (:func:`segment_sphere`).

    Attributes
    ----------
    fit : SphereFit
        The last region fit. ``fit.residuals`` covers every input point (mm);
        ``fit.inlier`` marks the points used (the same array as ``mask``);
        ``fit.rejected`` counts the region's points the rule set aside;
        ``fit.covariance`` gives the centre's uncertainty (mm^2).
    mask : ndarray (N,) of bool
        The points kept: in the converged region and passing the rule.
    region : ndarray (N,) of bool
        The converged region (cone and cylinder about the line of sight),
        before the rule.
    closest : int or None
        Row of the point nearest the scanner (None with a given start).
    initial_centre : ndarray (3,)
        First centre estimate, mm: one radius beyond the closest point along
        the line of sight, or the given start.
    first_centre : ndarray (3,)
        Centre fitted to the first region, mm.
    iterations : int
        Region fits made before the region stopped changing.
    converged : bool
        False when ``max_rounds`` ran out first.
    """

    fit: SphereFit
    mask: np.ndarray
    region: np.ndarray
    closest: int | None
    initial_centre: np.ndarray
    first_centre: np.ndarray
    iterations: int
    converged: bool

    @property
    def centre(self) -> np.ndarray:
        """Fitted centre, mm (3,)."""
        return self.fit.centre

    @property
    def n_points(self) -> int:
        """Points used in the final fit."""
        return self.fit.n_points


def segment_sphere(points, radius: float, scanner_origin=(0.0, 0.0, 0.0), *, start=None, half_angle: float = 60.0,
                   rule: str = "e3125", reject: float | None = None, max_rounds: int = 50, samples: int = 500,
                   seed: int = 0, max_iterations: int = 100, min_coverage: float = 2.0) -> SphereSegmentation:
    """Segment a sphere from a raw scan in the manner of ASTM E3125 and fit it
    with the radius fixed (docs/fitting.md, Segmentation).

    Closest-point start, then a cone (apex at the centre estimate, about the
    line of sight, ``half_angle``) and cylinder (radius ``radius`` x
    sin(half_angle) about the line of sight) region, fitted with the radius
    fixed and ``rule`` (one pass at 3 standard deviations), about the new
    centre again, until the region stops changing. The per-point work runs
    in Rust, in parallel.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The raw scan (sphere, stand, background), mm.
    radius : float
        Calibrated sphere radius, mm; fixed in every fit.
    scanner_origin : array_like (3,)
        The scanner's origin in the points' frame, mm.
    start : array_like (3,), optional
        Starting centre, mm, instead of the closest-point start.
    half_angle : float
        Half-angle of the cone, degrees in (0, 90] (60: the standard's
        120 degree cone).
    rule : {'e3125', 'mad', 'none'}
        Rejection rule of every region fit (as in :func:`fit_sphere`); the
        standard's single pass at 3 standard deviations by default.
    reject : float, optional
        Its multiple k (dimensionless; default 3 for 'e3125', 3.5 for 'mad').
    max_rounds : int
        Region fits allowed before giving up on convergence.
    samples, seed : int
        Minimal samples and seed of the least-median start in the first
        region (as ``start='lmeds'`` in :func:`fit_sphere`).
    max_iterations : int
        Levenberg-Marquardt steps allowed per fit.
    min_coverage : float
        Smallest polar coverage (degrees) of the final fit's points accepted,
        as in :func:`fit_sphere`.

    Returns
    -------
    SphereSegmentation

    Warns
    -----
    ImplausibleFit
        The final fit's rms is over ``MAX_RMS_FRACTION`` of the radius, or a
        free-radius fit of its points disagrees with the radius
        (docs/fitting.md, Sanity checks).

    Raises
    ------
    InputError
        Bad points (naming the row) or options, a scanner origin on a point.
    GeometryError
        A region with fewer than 4 points, a fit that fails, a final cap
        under ``min_coverage`` (naming the points' likely unit when they span
        far less than the sphere: ``what='units'``, ``value`` the unit).
    """
    pts = as_rows("points", points, 3)
    origin = tuple(vector3("scanner_origin", scanner_origin, unit="mm").tolist())
    if radius is None or not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius: the calibrated radius must be a positive length in mm, got {radius}")
    if rule is None:
        raise InputError(f"rule: expected one of {', '.join(map(repr, RULES))}, got None")
    check_options(radius, reject, rule, max_iterations, 0.0, samples, seed)
    if int(max_rounds) < 1:
        raise InputError(f"max_rounds: must be at least 1, got {max_rounds}")
    start = None if start is None else tuple(vector3("start", start, unit="mm").tolist())
    d = core_segment_sphere(pts, float(radius), origin, start=start, half_angle=float(half_angle), rule=rule,
                             reject=None if reject is None else float(reject), max_rounds=int(max_rounds),
                             samples=int(samples), seed=int(seed), max_iterations=int(max_iterations))
    fit = SphereFit._from(d["fit"])
    if not d["converged"]:
        _log.warning("segment_sphere: the region still changed after %d fits (max_rounds)", d["rounds"])
    used = pts[fit.inlier]
    # The region fits run without a coverage floor (a first region may be a
    # sliver); the answer needs the same cap as any fit (fit_sphere's 2 deg).
    if not fit.polar_coverage >= min_coverage:
        raise coverage_error(pts, float(radius), float(fit.polar_coverage), float(min_coverage), "segment_sphere")
    warn_implausible(used, fit, True, "segment_sphere")
    return SphereSegmentation(fit=fit, mask=fit.inlier, region=d["region"], closest=d["closest"],
                              initial_centre=np.asarray(d["initial_centre"]),
                              first_centre=np.asarray(d["first_centre"]), iterations=int(d["rounds"]),
                              converged=bool(d["converged"]))


@dataclass(frozen=True)
class E3125Result:
    """The centre of a sphere by the ASTM E3125-style procedure (:func:`e3125`).

    Attributes
    ----------
    centre : ndarray (3,)
        Centre, mm.
    radius : float
        The calibrated radius it was fitted with, mm.
    n_points : int
        Points used in the final fit.
    n_region : int
        Points in the converged cone-and-cylinder region (before the 3 s pass).
    n_raw : int
        Points in the raw scan.
    centre_uncertainty : ndarray (3,)
        Standard uncertainty of the centre coordinates from the fit, mm
        (noise only: no scanner or radius error).
    covariance : ndarray (3, 3)
        Covariance of the centre, mm^2.
    rms : float
        Root mean square of the final fit's residuals, mm.
    polar_coverage : float
        Cap half-angle of the points used, degrees.
    converged : bool
        The region stopped changing.
    segmentation : SphereSegmentation
        Everything else (masks, residuals, starts).
    """

    centre: np.ndarray
    radius: float
    n_points: int
    n_region: int
    n_raw: int
    centre_uncertainty: np.ndarray
    covariance: np.ndarray
    rms: float
    polar_coverage: float
    converged: bool
    segmentation: SphereSegmentation = field(repr=False)

    def to_dict(self) -> dict:
        """Plain JSON-ready values (lengths in mm)."""
        return {"centre_mm": self.centre.tolist(), "radius_mm": self.radius, "n_points": self.n_points,
                "n_region": self.n_region, "n_raw": self.n_raw,
                "centre_uncertainty_mm": self.centre_uncertainty.tolist(),
                "covariance_mm2": self.covariance.tolist(), "rms_mm": self.rms,
                "polar_coverage_deg": self.polar_coverage, "converged": self.converged}


def e3125(points, radius: float, scanner_origin=(0.0, 0.0, 0.0), *, start=None) -> E3125Result:
    """Sphere centre from a raw scan by the ASTM E3125-style procedure, in one
    call: :func:`segment_sphere` with the standard's choices (120 degree cone,
    radius fixed, single pass at 3 standard deviations).

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The raw scan, mm (convert other units before).
    radius : float
        Calibrated sphere radius, mm.
    scanner_origin : array_like (3,)
        The scanner's origin in the points' frame, mm.
    start : array_like (3,), optional
        Starting centre, mm, instead of the closest-point start.

    Returns
    -------
    E3125Result
        Centre (mm), radius (mm), points used, the centre's uncertainty (mm).

    Raises
    ------
    InputError, GeometryError
        As :func:`segment_sphere` (a cap under 2 degrees, e.g. a scan in
        metres read as mm, is a GeometryError).

    Warns
    -----
    ImplausibleFit
        As :func:`segment_sphere`: a wrong radius, a scan that is not one sphere.
    """
    s = segment_sphere(points, radius, scanner_origin, start=start)
    f = s.fit
    return E3125Result(centre=f.centre, radius=f.radius, n_points=f.n_points, n_region=int(s.region.sum()),
                       n_raw=len(s.mask), centre_uncertainty=f.centre_uncertainty, covariance=f.covariance[:3, :3].copy(),
                       rms=f.rms, polar_coverage=f.polar_coverage, converged=s.converged, segmentation=s)
