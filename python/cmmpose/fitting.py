"""Least-squares fits of measured artefacts: spheres (geometric, Rust core:
rust/core/src/fit/sphere.rs) and planes (total least squares). Lengths in mm,
angles in degrees."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property

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


@dataclass(frozen=True, eq=False)
class SphereFits(Mapping):
    """Spheres fitted to labelled groups of points (:func:`fit_spheres`): one
    array per field with one entry per label, and a mapping label ->
    :class:`SphereFit` built on demand.

    Attributes
    ----------
    labels : ndarray (K,)
        The distinct labels, ascending; entry k of every per-sphere array
        belongs to ``labels[k]``.
    centre : ndarray (K, 3)
        Centres, mm.
    radius : ndarray (K,)
        Radii, mm (the fixed one if given).
    rms : ndarray (K,)
        Root mean square of each sphere's inlier residuals, mm.
    form : ndarray (K,)
        Largest minus smallest inlier residual, mm.
    n_points : ndarray (K,) of int64
        Inliers used.
    covariance : ndarray (K, 4, 4)
        Covariance of (centre x, y, z, radius), mm^2.
    polar_coverage : ndarray (K,)
        Half-angle of the cap each sphere's points cover, degrees.
    iterations : ndarray (K,) of int64
        Levenberg-Marquardt iterations of each final fit.
    converged : ndarray (K,) of bool
        The stopping rule was met before the iteration cap.
    rejected : ndarray (K,) of int64
        Points set aside by the robust option.
    error : ndarray (K,) of object
        None for a fitted sphere; for one that could not be fitted (only with
        ``on_error='return'``) the exception (:class:`InputError` or
        :class:`GeometryError`) saying why. Such a sphere has NaN in the
        float fields, zero counts and ``converged`` False.
    residuals : ndarray (N,)
        Signed distance of every input point from its label's sphere, mm
        (outward positive), in the input's point order; NaN for the points of
        a sphere that could not be fitted.
    inlier : ndarray (N,) of bool
        Whether each input point was used in its sphere's final fit.

    Notes
    -----
    As a mapping it behaves like the dict ``label -> SphereFit`` (or the
    exception of a sphere that could not be fitted), in ascending label
    order: ``fits[label]``, ``len(fits)``, ``for label in fits``,
    ``fits.items()``. Each :class:`SphereFit` is built when asked for, from
    the arrays.
    """

    labels: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    rms: np.ndarray
    form: np.ndarray
    n_points: np.ndarray
    covariance: np.ndarray
    polar_coverage: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    rejected: np.ndarray
    error: np.ndarray
    residuals: np.ndarray
    inlier: np.ndarray
    # Row k of the input points of sphere k: rows[_bounds[k]:_bounds[k + 1]]
    # of the input, or of the input in label order when _order (the stable
    # argsort of the labels) is given.
    _bounds: np.ndarray = field(repr=False)
    _order: np.ndarray | None = field(repr=False)

    @cached_property
    def _index(self) -> dict:
        # Python scalars hash like NumPy's, so fits[np.int32(3)] finds 3.
        return {label: k for k, label in enumerate(self.labels.tolist())}

    @property
    def ok(self) -> np.ndarray:
        """Whether each sphere was fitted, (K,) bool (False where ``error`` is set)."""
        return np.array([e is None for e in self.error], dtype=bool)

    @property
    def centre_uncertainty(self) -> np.ndarray:
        """Standard uncertainty of the centre coordinates, mm (K, 3)."""
        return np.sqrt(np.diagonal(self.covariance, axis1=1, axis2=2)[:, :3])

    @property
    def radius_uncertainty(self) -> np.ndarray:
        """Standard uncertainty of the radii, mm (K,) (0 for a fixed radius)."""
        return np.sqrt(self.covariance[:, 3, 3])

    def positions(self, labels) -> np.ndarray:
        """Entry of each of ``labels`` in the per-sphere arrays, (M,) int64:
        ``fits.centre[fits.positions(labels)]`` are their centres (mm).

        Raises
        ------
        KeyError
            A label that no point carried.
        """
        labels = np.asarray(labels)
        pos = np.searchsorted(self.labels, labels)
        found = pos < len(self.labels)
        found[found] = self.labels[pos[found]] == labels[found]
        if not found.all():
            raise KeyError(labels[~found][0].item())
        return pos.astype(np.int64)

    def rows(self, label) -> np.ndarray | slice:
        """Where the points of ``label`` are in the input (ascending): a
        slice when the input was in label order, else an index array."""
        k = self._index[label]
        lo, hi = int(self._bounds[k]), int(self._bounds[k + 1])
        return slice(lo, hi) if self._order is None else self._order[lo:hi]

    def __getitem__(self, label) -> SphereFit | Exception:
        k = self._index[label]
        if self.error[k] is not None:
            return self.error[k]
        rows = self.rows(label)
        # Copies, so that a SphereFit does not share memory with these arrays.
        return SphereFit(
            centre=self.centre[k].copy(), radius=float(self.radius[k]), residuals=np.array(self.residuals[rows]),
            inlier=np.array(self.inlier[rows]), rms=float(self.rms[k]), form=float(self.form[k]),
            n_points=int(self.n_points[k]), covariance=self.covariance[k].copy(),
            polar_coverage=float(self.polar_coverage[k]), iterations=int(self.iterations[k]),
            converged=bool(self.converged[k]), rejected=int(self.rejected[k]))

    def __iter__(self) -> Iterator:
        return iter(self._index)

    def __len__(self) -> int:
        return len(self.labels)

    def __contains__(self, label) -> bool:
        try:
            return label in self._index
        except TypeError:  # an unhashable key is no label
            return False


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
                max_iterations: int = 100, min_coverage: float = 2.0, on_error: str = "raise") -> SphereFits:
    """One sphere per label, fitted in parallel.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points, mm.
    labels : array_like, shape (N,)
        Which sphere each point belongs to (e.g. scan ids), in any order.
    radius, reject, max_iterations, min_coverage
        As in :func:`fit_sphere` (radius in mm, min_coverage in degrees).
    on_error : {'raise', 'return'}
        A label whose points cannot be fitted raises its error naming the
        label, or stays in the result with its exception in ``error`` (and
        as ``fits[label]``) and NaN fields.

    Returns
    -------
    SphereFits
        One array per field, one entry per label in ascending label order
        (``centre`` (K, 3) mm, ``radius`` (K,) mm, ...), per-point
        ``residuals`` (mm) and ``inlier`` in the input's order; also a
        mapping label -> :class:`SphereFit` (each equal to
        :func:`fit_sphere` on that label's points, residuals in their input
        order).

    Raises
    ------
    InputError
        Bad points, labels or options; with ``on_error='raise'``, a label with
        too few points or a non-finite coordinate.
    GeometryError
        With ``on_error='raise'``, a label whose points do not define a sphere.
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
        order, sorted_labels, sorted_pts = None, labels, pts
    else:
        order = np.argsort(labels, kind="stable")
        sorted_labels, sorted_pts = labels[order], np.ascontiguousarray(pts[order])
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]]) if len(labels) else np.array([], int)
    bounds = np.r_[starts, len(labels)].astype(np.int64)
    d = _core.fit_spheres(sorted_pts, bounds, *opts)
    unique = sorted_labels[starts]
    error = np.empty(len(unique), dtype=object)
    error[:] = d.pop("error")
    if on_error == "raise":
        for k, e in enumerate(error):
            if e is not None:
                raise type(e)(f"sphere {unique[k].item()!r}: {e}")
    if order is not None:
        # Per-point fields back in the input's order.
        for name in ("residuals", "inlier"):
            sorted_values = d[name]
            d[name] = np.empty_like(sorted_values)
            d[name][order] = sorted_values
    return SphereFits(labels=unique, error=error, _bounds=bounds, _order=order, **d)


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
