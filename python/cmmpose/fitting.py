"""Least-squares fits of measured artefacts: spheres (geometric, Rust core:
rust/core/src/fit/sphere.rs) and planes (total least squares). Lengths in mm,
angles in degrees."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from ._arrays import as_rows
from .errors import InputError


@dataclass(frozen=True)
class SphereFit:
    """A fitted sphere.

    Attributes
    ----------
    centre : ndarray (3,)
        Centre, mm.
    radius : float
        Radius, mm (the fixed one if given).
    residuals : ndarray (N,)
        Signed distance of every input point from the sphere, mm (outward positive).
    inlier : ndarray (N,) of bool
        False for points rejected by the robust option.
    rms : float
        Root mean square of the inliers' residuals, mm (the thesis's "Fit").
    form : float
        Largest minus smallest inlier residual, mm.
    n_points : int
        Inliers used.
    covariance : ndarray (4, 4)
        Covariance of (centre x, y, z, radius), mm^2, from s^2 (J^T J)^-1.
    polar_coverage : float
        Half-angle of the cap the points cover, degrees (180: whole sphere).
    iterations : int
        Levenberg-Marquardt iterations of the final fit.
    converged : bool
        The stopping rule was met before the iteration cap.
    rejected : int
        Points set aside by the robust option.
    """

    centre: np.ndarray
    radius: float
    residuals: np.ndarray
    inlier: np.ndarray
    rms: float
    form: float
    n_points: int
    covariance: np.ndarray
    polar_coverage: float
    iterations: int
    converged: bool
    rejected: int

    @classmethod
    def _from(cls, d: dict) -> SphereFit:
        return cls(**{**d, "centre": np.asarray(d["centre"])})

    @property
    def centre_uncertainty(self) -> np.ndarray:
        """Standard uncertainty of the centre coordinates, mm (3,)."""
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def radius_uncertainty(self) -> float:
        """Standard uncertainty of the radius, mm (0 for a fixed radius)."""
        return float(np.sqrt(self.covariance[3, 3]))


@dataclass(frozen=True)
class PlaneFit:
    """A fitted plane: ``point`` (centroid, mm), unit ``normal`` (largest
    component positive), signed ``residuals`` (mm), ``inlier`` mask, ``rms`` and
    ``form`` (mm), ``n_points``, in-plane ``axes`` (2, 3) with (axes[0], axes[1],
    normal) right-handed, ``tilt_covariance`` (2, 2) of the normal's tilt
    about the two axes (rad^2), ``rejected`` count."""

    point: np.ndarray
    normal: np.ndarray
    residuals: np.ndarray
    inlier: np.ndarray
    rms: float
    form: float
    n_points: int
    axes: np.ndarray
    tilt_covariance: np.ndarray
    rejected: int


def _check(radius, reject, max_iterations, min_coverage):
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius: must be a positive length in mm, got {radius}")
    if reject is not None and not (np.isfinite(reject) and reject > 0):
        raise InputError(f"reject: must be a positive multiple of the robust sigma, got {reject}")
    if int(max_iterations) < 1:
        raise InputError(f"max_iterations: must be at least 1, got {max_iterations}")
    return (None if radius is None else float(radius), None if reject is None else float(reject),
            int(max_iterations), float(min_coverage))


def fit_sphere(points, radius: float | None = None, *, reject: float | None = None, max_iterations: int = 100,
               min_coverage: float = 2.0) -> SphereFit:
    """Orthogonal (geometric) least-squares sphere.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points on the sphere, mm.
    radius : float, optional
        Fix the radius (mm) and fit only the centre.
    reject : float, optional
        Robust fit: set aside points farther than ``reject`` x 1.4826 MAD of the
        residuals and refit (e.g. 3.5 removes bar and stand points).
    max_iterations : int
        Levenberg-Marquardt iteration cap.
    min_coverage : float
        Smallest polar coverage (degrees) accepted as a fittable cap.

    Returns
    -------
    SphereFit

    Raises
    ------
    InputError
        Fewer than 4 points, NaN or inf (naming the row), bad options.
    GeometryError
        Coplanar or collinear points, a cap too small to fit, no convergence.
    """
    opts = _check(radius, reject, max_iterations, min_coverage)
    return SphereFit._from(_core.fit_sphere(as_rows("points", points, 3), *opts))


def fit_spheres(points, labels, radius: float | None = None, *, reject: float | None = None,
                max_iterations: int = 100, min_coverage: float = 2.0, on_error: str = "raise"):
    """One sphere per label, fitted in parallel.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points, mm.
    labels : array_like, shape (N,)
        Which sphere each point belongs to (e.g. scan ids).
    radius, reject, max_iterations, min_coverage
        As in :func:`fit_sphere`.
    on_error : {'raise', 'return'}
        A group that cannot be fitted raises its error naming the label, or
        appears in the result as the exception instead of a SphereFit.

    Returns
    -------
    dict
        label -> SphereFit (or exception), in ascending label order. Each fit's
        residuals follow the order of that label's points in the input.
    """
    if on_error not in ("raise", "return"):
        raise InputError(f"on_error: expected 'raise' or 'return', got {on_error!r}")
    opts = _check(radius, reject, max_iterations, min_coverage)
    pts = as_rows("points", points, 3)
    labels = np.asarray(labels)
    if labels.shape != (len(pts),):
        raise InputError(f"labels: expected shape ({len(pts)},), got {labels.shape}")
    if len(labels) < 2 or bool(np.all(labels[1:] >= labels[:-1])):
        # Runs store points scan by scan: already in order, no sort or copy.
        sorted_labels, sorted_pts = labels, pts
    else:
        order = np.argsort(labels, kind="stable")
        sorted_labels, sorted_pts = labels[order], np.ascontiguousarray(pts[order])
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]]) if len(labels) else np.array([], int)
    bounds = np.r_[starts, len(labels)].astype(np.int64)
    results = _core.fit_spheres(sorted_pts, bounds, *opts)
    out = {}
    for label, r in zip(sorted_labels[starts].tolist(), results):
        if isinstance(r, Exception):
            if on_error == "raise":
                raise type(r)(f"sphere {label!r}: {r}")
            out[label] = r
        else:
            out[label] = SphereFit._from(r)
    return out


def fit_plane(points, *, reject: float | None = None) -> PlaneFit:
    """Total least-squares plane through (N, 3) points (mm); see :class:`PlaneFit`.

    Raises
    ------
    InputError
        Fewer than 3 points, NaN or inf.
    GeometryError
        Collinear or coincident points.
    """
    if reject is not None and not (np.isfinite(reject) and reject > 0):
        raise InputError(f"reject: must be a positive multiple of the robust sigma, got {reject}")
    d = _core.fit_plane(as_rows("points", points, 3), None if reject is None else float(reject))
    return PlaneFit(**{**d, "point": np.asarray(d["point"]), "normal": np.asarray(d["normal"]), "axes": np.asarray(d["axes"])})
