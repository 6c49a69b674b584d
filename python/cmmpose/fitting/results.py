"""What the fits return: a sphere (its centre, radius and their covariance), spheres fitted in one call, a plane."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


def _correlation(cov: np.ndarray) -> np.ndarray:
    """Multiple correlation between the radius and the centre of (..., 4, 4)
    covariances: the largest correlation of the radius with any combination
    of the centre coordinates. NaN where the radius was fixed or the
    covariance is not finite."""
    cov = np.asarray(cov, dtype=float)
    out = np.full(cov.shape[:-2], np.nan)
    var_r = cov[..., 3, 3]
    ok = np.isfinite(cov).all(axis=(-1, -2)) & (var_r > 0)
    if ok.any():
        c = cov[ok]
        s = c[:, :3, 3]
        rho2 = np.einsum("ki,ki->k", s, np.linalg.solve(c[:, :3, :3], s[..., None])[..., 0]) / c[:, 3, 3]
        out[ok] = np.sqrt(np.clip(rho2, 0.0, 1.0))
    return out


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
        Half-angle of the cap the points cover (the cap angle), degrees (180:
        whole sphere).
    iterations : int
        Levenberg-Marquardt iterations of the final fit.
    converged : bool
        The stopping rule was met before the iteration cap.
    rejected : int
        Points set aside by the robust option.

    Notes
    -----
    :attr:`centre_radius_correlation` tells how well a free-radius fit
    determines the centre (docs/fitting.md, Conditioning).
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

    @property
    def centre_radius_correlation(self) -> float:
        """Multiple correlation (0..1) between the fitted radius and centre,
        from the covariance: the largest correlation of the radius with any
        combination of the centre coordinates (on a cap, the centre's
        component along the cap axis). Fixing the radius shrinks that
        combination's variance by 1 - rho^2. NaN for a fixed radius."""
        return float(_correlation(self.covariance))


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

    @property
    def centre_radius_correlation(self) -> np.ndarray:
        """Centre-radius multiple correlation of each sphere, (K,) (NaN for a
        fixed radius or a failed fit); see :attr:`SphereFit.centre_radius_correlation`."""
        return _correlation(self.covariance)

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
