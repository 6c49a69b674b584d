"""Spheres fitted to points (geometric least squares in the Rust core, rust/core/src/fit/sphere.rs) with robust
rules and a high-breakdown start: one, or many in one call; and planes (total least squares).
"""

from __future__ import annotations

import logging
import warnings

import numpy as np

from .._core import fit_plane as core_fit_plane  # the Rust fits (cmmpose._core)
from .._core import fit_sphere as core_fit_sphere
from .._core import fit_spheres as core_fit_spheres
from .._arrays import as_rows
from .._validate import vector3
from ..errors import GeometryError, IllConditionedFit, InputError
from .plausibility import (ILL_CONDITIONED_CORRELATION, far_point, ill_conditioned, unit_hint, warn_conditioning,
                           warn_implausible)
from .results import PlaneFit, SphereFit, SphereFits

_log = logging.getLogger("cmmpose.fitting")

RULES = ("none", "mad", "e3125")
STARTS = ("algebraic", "lmeds")


def check_options(radius, reject, rule, max_iterations, min_coverage, samples, seed) -> dict:
    """The shared options as the extension's keywords, checked."""
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius: must be a positive length in mm, got {radius}")
    if reject is not None and not (np.isfinite(reject) and reject > 0):
        raise InputError(f"reject: must be a positive multiple of the rule's sigma, got {reject}")
    if rule is not None and rule not in RULES:
        raise InputError(f"rule: expected one of {', '.join(map(repr, RULES))}, got {rule!r}")
    if int(max_iterations) < 1:
        raise InputError(f"max_iterations: must be at least 1, got {max_iterations}")
    if int(samples) < 1:
        raise InputError(f"samples: the high-breakdown start needs at least 1 sample, got {samples}")
    if int(seed) < 0:
        raise InputError(f"seed: must be a non-negative integer, got {seed}")
    return dict(radius=None if radius is None else float(radius), reject=None if reject is None else float(reject),
                rule=rule, max_iterations=int(max_iterations), min_coverage=float(min_coverage),
                samples=int(samples), seed=int(seed))


def start_options(start) -> dict:
    """``start`` as the extension's keywords: a method name, or a centre (mm)."""
    if start is None:
        return dict(start="algebraic")
    if isinstance(start, str):
        if start not in STARTS:
            raise InputError(f"start: expected 'algebraic', 'lmeds' or a centre (x, y, z) in mm, got {start!r}")
        return dict(start=start)
    return dict(start="centre", centre=tuple(vector3("start", start, unit="mm").tolist()))


def fit_sphere(points, radius: float | None = None, *, reject: float | None = None, rule: str | None = None,
               start=None, samples: int = 500, seed: int = 0, max_iterations: int = 100,
               min_coverage: float = 2.0) -> SphereFit:
    """Orthogonal (geometric) least-squares sphere, optionally robust.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points on the sphere, mm.
    radius : float, optional
        Fix the radius (mm) and fit only the centre (the calibrated radius:
        a partial cap determines the centre far better so).
    reject : float, optional
        Multiple k of the rejection rule's sigma (dimensionless). Alone it
        selects ``rule='mad'`` (e.g. 3.5 removes bar and stand points).
    rule : {'none', 'mad', 'e3125'}, optional
        Outlier rule (docs/fitting.md). ``'mad'``: repeatedly set aside
        |r - median(r)| > k x 1.4826 MAD(r) and refit until the inliers stop
        changing (k = ``reject``, default 3.5). ``'e3125'``: the ASTM E3125
        single pass, set aside |r| > k s (s the sample standard deviation of
        the first fit's residuals, mm; k default 3) and refit once. Default:
        ``'mad'`` when ``reject`` is given, else ``'none'``.
    start : {'algebraic', 'lmeds'} or array_like (3,), optional
        Where the fit starts. ``'algebraic'`` (default): the algebraic sphere
        of all points. ``'lmeds'``: the high-breakdown least-median-of-squares
        sphere (random minimal samples, seeded); the least-squares fit then
        uses its inliers only, and a rule continues from there. Recovers the
        clean sphere with up to ~40-50 % of the points outliers. A centre
        (x, y, z) in mm: start from it.
    samples : int
        Minimal samples drawn by ``start='lmeds'``.
    seed : int
        Seed of those samples (the same seed, the same fit, on every machine).
    max_iterations : int
        Levenberg-Marquardt iteration cap.
    min_coverage : float
        Smallest polar coverage (degrees) accepted as a fittable cap.

    Returns
    -------
    SphereFit

    Warns
    -----
    IllConditionedFit
        A free radius with a centre-radius correlation above
        ``ILL_CONDITIONED_CORRELATION`` (0.99): the centre is ill-determined;
        fix the radius. Also logged (logger ``cmmpose.fitting``).
    ImplausibleFit
        An rms over ``MAX_RMS_FRACTION`` (10 %) of the radius, or a fixed
        radius the points disagree with: a free-radius fit of the same points
        fits ``RADIUS_MISFIT_RMS_RATIO`` (1.5) times better with a radius
        more than ``RADIUS_MISFIT_FRACTION`` (2 %) away (docs/fitting.md,
        Sanity checks). Also logged.

    Raises
    ------
    InputError
        Fewer than 4 points, NaN or inf (naming the row), bad options.
    GeometryError
        Coplanar or collinear points, a cap too small to fit (with a fixed
        radius, naming the points' likely unit when they span far less than
        the sphere: ``what='units'``, ``value`` the unit), no convergence,
        rejection leaving too few points.
    """
    opts = check_options(radius, reject, rule, max_iterations, min_coverage, samples, seed)
    rows = as_rows("points", points, 3)
    try:
        raw = core_fit_sphere(rows, **opts, **start_options(start))
    except GeometryError as exc:
        text = far_point(rows, str(exc))
        if radius is not None and text == str(exc) and "polar coverage" in text:
            hint, unit = unit_hint(rows, float(radius))
            raise GeometryError(text + hint, what="units" if unit else None, value=unit,
                                remedy="units" if unit else None) from None
        raise GeometryError(text) from None
    fit = SphereFit._from(raw)
    warn_conditioning(fit, radius is None)
    warn_implausible(rows[fit.inlier], fit, radius is not None, "sphere fit")
    return fit


def fit_spheres(points, labels, radius: float | None = None, *, reject: float | None = None,
                rule: str | None = None, start: str | None = None, samples: int = 500, seed: int = 0,
                max_iterations: int = 100, min_coverage: float = 2.0, on_error: str = "raise") -> SphereFits:
    """One sphere per label, fitted in parallel.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Points, mm.
    labels : array_like, shape (N,)
        Which sphere each point belongs to (e.g. scan ids), in any order.
    radius, reject, rule, samples, seed, max_iterations, min_coverage
        As in :func:`fit_sphere` (radius in mm, min_coverage in degrees).
    start : {'algebraic', 'lmeds'}, optional
        As in :func:`fit_sphere`; a starting centre belongs to one sphere and
        is refused here.
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

    Warns
    -----
    IllConditionedFit
        Once, naming the labels, when free-radius fits are ill-conditioned
        (as in :func:`fit_sphere`).

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
    opts = check_options(radius, reject, rule, max_iterations, min_coverage, samples, seed)
    if start is not None and not isinstance(start, str):
        raise InputError("start: a starting centre belongs to one sphere; fit_spheres takes 'algebraic' or 'lmeds'")
    pts = as_rows("points", points, 3)
    labels = np.asarray(labels)
    if labels.shape != (len(pts),):
        raise InputError(f"labels: expected shape ({len(pts)},), got {labels.shape}")
    if labels.dtype.kind in "fc" and not np.all(np.isfinite(labels)):
        # NaN != NaN: each NaN-labelled point would be a sphere of its own.
        bad = int(np.flatnonzero(~np.isfinite(labels))[0])
        raise InputError(f"labels: row {bad} is {labels[bad].item()}; every point needs a finite label "
                         f"({int(np.count_nonzero(~np.isfinite(labels)))} of {len(labels)} are not)")
    if len(labels) < 2 or bool(np.all(labels[1:] >= labels[:-1])):
        # Runs store points scan by scan: already in order, no sort or copy.
        order, sorted_labels, sorted_pts = None, labels, pts
    else:
        order = np.argsort(labels, kind="stable")
        sorted_labels, sorted_pts = labels[order], np.ascontiguousarray(pts[order])
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]]) if len(labels) else np.array([], int)
    bounds = np.r_[starts, len(labels)].astype(np.int64)
    d = core_fit_spheres(sorted_pts, bounds, **opts, **start_options(start))
    unique = sorted_labels[starts]
    error = np.empty(len(unique), dtype=object)
    error[:] = d.pop("error")
    for k, e in enumerate(error):  # a degenerate sphere that is one far point: name its row (of the input)
        if isinstance(e, GeometryError):
            lo = int(bounds[k])
            text = far_point(sorted_pts[lo:bounds[k + 1]], str(e),
                              lambda j: lo + j if order is None else int(order[lo + j]))
            error[k] = e if text == str(e) else GeometryError(text)
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
    fits = SphereFits(labels=unique, error=error, _bounds=bounds, _order=order, **d)
    if radius is None and len(unique):
        rho = fits.centre_radius_correlation
        bad = np.flatnonzero(rho > ILL_CONDITIONED_CORRELATION)
        if len(bad):
            k = bad[np.argmax(rho[bad])]
            names = ", ".join(repr(x) for x in unique[bad[:5]].tolist()) + (", ..." if len(bad) > 5 else "")
            msg = ill_conditioned(float(rho[k]), float(fits.polar_coverage[k]),
                                   f"{len(bad)} of {len(unique)} spheres ({names}; worst {unique[k].item()!r})")
            _log.warning("%s", msg)
            warnings.warn(msg, IllConditionedFit, stacklevel=2)
    return fits


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
    d = core_fit_plane(as_rows("points", points, 3), None if reject is None else float(reject))
    return PlaneFit(**{**d, "point": np.asarray(d["point"]), "normal": np.asarray(d["normal"]), "axes": np.asarray(d["axes"])})
