"""The uncertainty of a sphere centre fitted to compensated points that carry
their own (``compensate(..., uncertainty=..., uncertainty_detail='split')``),
keeping the part common to nearby points whole instead of shrinking it with
1/sqrt(n) (docs/uncertainty.md, section 5 "Per point", The centre of a
fitted sphere).

The centre's covariance is the sum of two parts:

- independent (the scanner's noise): propagated through the least-squares
  fit linearised at its solution. With the outward normals n_i, the design
  A = [n_i^T, 1] (no 1 column for a fixed radius) and N = (A^T A)^-1, a
  point's move dx_i moves the centre and radius by N A^T (n_i . dx_i), so
  cov = N A^T diag(n_i^T S_i n_i) A N, S_i the point's independent
  covariance;
- common (maps, temperature, pose, scanner scale, model): the points' mean
  common covariance, taken as fully correlated within the patch. A shared
  translation t of every point moves the fitted centre by t exactly (the
  fit's map sums to the identity over the points), so a common error that
  is one translation over the patch passes to the centre whole. This holds
  while the sphere is small against the distances over which the
  sensitivities change: a rotation error w moves points at the arm p by
  w x p, which differs across a sphere of radius r by |w| r, small against
  |w| |p| for r << |p| (a 12.5 mm ball at arms of 100-1000 mm).

Units: mm and mm^2.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError, InputTypeError
from .fitting import E3125Result, SphereFit, e3125, fit_sphere
from .point_uncertainty import UncertainPoints, covariance_matrices

__all__ = ["CentreCovariance", "UncertainSphere", "sphere_centre_uncertainty", "fit_uncertain_sphere",
           "e3125_uncertain"]


@dataclass(frozen=True)
class CentreCovariance:
    """A fitted centre's covariance from its points' uncertainty.

    Attributes
    ----------
    independent : ndarray (3, 3)
        The points' independent part (scanner noise) through the fit, mm^2.
    common : ndarray (3, 3)
        The points' mean common part (maps, temperature, pose, scanner scale,
        model), passed to the centre whole, mm^2.
    shrunk : ndarray (3, 3)
        What the fit gives when every point's whole covariance is taken as
        independent (the common part shrunk with about 1/n): for comparison
        only, it under-states the centre's uncertainty, mm^2.
    n_points : int
        The points the fit used.
    """

    independent: np.ndarray
    common: np.ndarray
    shrunk: np.ndarray
    n_points: int

    @property
    def covariance(self) -> np.ndarray:
        """The centre's covariance, independent + common, mm^2 (3, 3)."""
        return self.independent + self.common

    @property
    def u(self) -> np.ndarray:
        """Standard uncertainty (k = 1) of the centre's X, Y, Z, mm (3,)."""
        return np.sqrt(np.diag(self.covariance))

    def to_dict(self) -> dict:
        """JSON-ready (mm, mm^2)."""
        return {"u_mm": self.u.tolist(), "covariance_mm2": self.covariance.tolist(),
                "independent_mm2": self.independent.tolist(), "common_mm2": self.common.tolist(),
                "n_points": self.n_points}


def _split(points: UncertainPoints) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(points, UncertainPoints):
        raise InputTypeError(f"points: expected UncertainPoints (compensate(..., uncertainty=...)), "
                             f"got {type(points).__name__}")
    if points.common is None:
        raise InputError("points: the fit needs the split of each point's covariance; compensate with "
                         "uncertainty_detail='split'")
    return points.independent, points.common


def _fit_map_covariance(x: np.ndarray, centre: np.ndarray, cov: np.ndarray, fixed_radius: bool) -> np.ndarray:
    """N A^T diag(n_i^T S_i n_i) A N of the linearised geometric fit (mm^2,
    3 x 3 of the centre): ``x`` (n, 3) the points used, ``cov`` (n, 6) their
    covariance entries."""
    d = x - centre
    n = d / np.linalg.norm(d, axis=1)[:, None]
    a = n if fixed_radius else np.column_stack([n, np.ones(len(n))])
    s = np.einsum("ni,nij,nj->n", n, covariance_matrices(cov), n)  # variance along each normal, mm^2
    inv = np.linalg.inv(a.T @ a)
    return (inv @ (a.T * s) @ a @ inv)[:3, :3]


def sphere_centre_uncertainty(points: UncertainPoints, fit: SphereFit, *, fixed_radius: bool | None = None
                              ) -> CentreCovariance:
    """The centre covariance of ``fit``, a sphere fitted to ``points.xyz``.

    Parameters
    ----------
    points : UncertainPoints
        Compensated points with ``uncertainty_detail='split'`` (mm, mm^2);
        the same rows the fit was given.
    fit : SphereFit
        The fit (its ``inlier`` mask picks the points it used).
    fixed_radius : bool, optional
        Whether the radius was fixed; None: a fit whose radius has no
        uncertainty (``fit.covariance[3, 3] == 0``) is taken as fixed.

    Returns
    -------
    CentreCovariance
        ``independent`` through the fit, ``common`` the points' mean common
        covariance (docs/uncertainty.md, section 5), ``shrunk`` for comparison.

    Raises
    ------
    InputError
        Points without the split, or a fit of another number of points.
    """
    independent, common = _split(points)
    inlier = np.asarray(fit.inlier, dtype=bool)
    if len(inlier) != len(points):
        raise InputError(f"fit: made of {len(inlier)} points, points has {len(points)} (give the rows fitted)")
    if fixed_radius is None:
        fixed_radius = bool(fit.covariance[3, 3] == 0.0)
    x, c = points.xyz[inlier], np.asarray(fit.centre, dtype=float)
    ind = _fit_map_covariance(x, c, independent[inlier], fixed_radius)
    total = _fit_map_covariance(x, c, points.covariance[inlier], fixed_radius)
    mean_common = covariance_matrices(common[inlier].mean(axis=0)[None, :])[0]
    return CentreCovariance(ind, mean_common, total, int(inlier.sum()))


@dataclass(frozen=True)
class UncertainSphere:
    """A sphere fitted to uncertain points and its centre's covariance.

    Attributes
    ----------
    fit : SphereFit or E3125Result
        The fit; an ``E3125Result`` carries ``covariance`` and
        ``centre_uncertainty`` from ``centre`` below.
    centre : CentreCovariance
        The centre's covariance, independent and common parts, mm^2.
    """

    fit: SphereFit | E3125Result
    centre: CentreCovariance


def fit_uncertain_sphere(points: UncertainPoints, radius: float | None = None, **options) -> UncertainSphere:
    """:func:`cmmpose.fit_sphere` of ``points.xyz`` (``radius`` mm, ``options``
    as it takes them) with the centre's covariance from the points'
    uncertainty (:func:`sphere_centre_uncertainty`)."""
    _split(points)
    fit = fit_sphere(points.xyz, radius, **options)
    return UncertainSphere(fit, sphere_centre_uncertainty(points, fit, fixed_radius=radius is not None))


def e3125_uncertain(points: UncertainPoints, radius: float, scanner_origin=(0.0, 0.0, 0.0), *, start=None
                    ) -> UncertainSphere:
    """:func:`cmmpose.e3125` of ``points.xyz`` (the ASTM E3125-style centre,
    radius fixed, mm) with its ``covariance`` and ``centre_uncertainty``
    from the points' uncertainty, the common part kept whole, instead of the
    fit's residuals (noise only)."""
    _split(points)
    res = e3125(points.xyz, radius, scanner_origin, start=start)
    cc = sphere_centre_uncertainty(points, res.segmentation.fit, fixed_radius=True)
    return UncertainSphere(replace(res, covariance=cc.covariance, centre_uncertainty=cc.u), cc)
