"""Least-squares fits of measured artefacts: spheres (geometric, Rust core:
rust/core/src/fit/sphere.rs) with robust rules and a high-breakdown start,
the ASTM E3125-style segmentation of a sphere from a raw scan
(rust/core/src/fit/segment.rs), and planes (total least squares). Lengths in
mm, angles in degrees; docs/fitting.md describes the rules."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from . import _core
from ._arrays import as_rows
from ._validate import LENGTH_UNIT_NAMES, length_unit_slip, vector3
from .errors import GeometryError, IllConditionedFit, ImplausibleFit, InputError

_log = logging.getLogger(__name__)

#: A free-radius fit warns (:class:`IllConditionedFit`) when the centre-radius
#: correlation exceeds this: fixing the radius would then shrink the variance
#: of the centre along the cap axis by 1 / (1 - 0.99^2) = 50 (its standard
#: uncertainty by 7x). A uniform cap reaches it at a 53 degree half-angle;
#: docs/fitting.md.
ILL_CONDITIONED_CORRELATION = 0.99

#: A point this many times farther from the points' median than the typical
#: point makes the rest look collinear or coplanar to the fit's moments: the
#: degenerate-geometry error then names it instead (:func:`_far_point`).
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



RULES = ("none", "mad", "e3125")
STARTS = ("algebraic", "lmeds")


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


def _check(radius, reject, rule, max_iterations, min_coverage, samples, seed) -> dict:
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


def _start(start) -> dict:
    """``start`` as the extension's keywords: a method name, or a centre (mm)."""
    if start is None:
        return dict(start="algebraic")
    if isinstance(start, str):
        if start not in STARTS:
            raise InputError(f"start: expected 'algebraic', 'lmeds' or a centre (x, y, z) in mm, got {start!r}")
        return dict(start=start)
    return dict(start="centre", centre=tuple(vector3("start", start, unit="mm").tolist()))


def _ill_conditioned(rho: float, cap: float, what: str) -> str:
    gain = 1.0 / np.sqrt(max(1.0 - rho * rho, 1e-300))
    return (f"{what}: the free-radius centre is ill-determined (centre-radius correlation {rho:.4f} over a "
            f"{cap:.1f} deg cap: the centre moves with the radius, its uncertainty along the cap axis "
            f"{gain:.0f}x what a fixed radius gives); fit with the radius fixed at its calibrated value "
            f"(radius=...)")


def _warn_conditioning(fit: SphereFit, free: bool) -> None:
    if not free:
        return
    rho = fit.centre_radius_correlation
    if rho > ILL_CONDITIONED_CORRELATION:
        msg = _ill_conditioned(rho, fit.polar_coverage, "sphere fit")
        _log.warning("%s", msg)
        warnings.warn(msg, IllConditionedFit, stacklevel=3)


def _far_point(rows: np.ndarray, message: str, row_of=lambda k: k) -> str:
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


def _unit_hint(rows: np.ndarray, radius: float) -> tuple[str, str | None]:
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


def _coverage_error(rows: np.ndarray, radius: float, coverage: float, min_coverage: float, what: str) -> GeometryError:
    hint, unit = _unit_hint(rows, radius)
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
            free = _core.fit_sphere(np.ascontiguousarray(rows), radius=None, reject=None, rule=None,
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
    hint, _ = _unit_hint(rows, radius)
    return (f"{what}: " + "; ".join(reasons) + hint + ": check the radius, the units, and that the points are the "
            "sphere's alone (a raw scan needs segmentation or a rejection rule); the centre is not to be trusted")


def _warn_implausible(rows: np.ndarray, fit: SphereFit, fixed: bool, what: str) -> None:
    msg = _implausible(rows, fit, fixed, what)
    if msg:
        _log.warning("%s", msg)
        warnings.warn(msg, ImplausibleFit, stacklevel=3)


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
    opts = _check(radius, reject, rule, max_iterations, min_coverage, samples, seed)
    rows = as_rows("points", points, 3)
    try:
        raw = _core.fit_sphere(rows, **opts, **_start(start))
    except GeometryError as exc:
        text = _far_point(rows, str(exc))
        if radius is not None and text == str(exc) and "polar coverage" in text:
            hint, unit = _unit_hint(rows, float(radius))
            raise GeometryError(text + hint, what="units" if unit else None, value=unit,
                                remedy="units" if unit else None) from None
        raise GeometryError(text) from None
    fit = SphereFit._from(raw)
    _warn_conditioning(fit, radius is None)
    _warn_implausible(rows[fit.inlier], fit, radius is not None, "sphere fit")
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
    opts = _check(radius, reject, rule, max_iterations, min_coverage, samples, seed)
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
    d = _core.fit_spheres(sorted_pts, bounds, **opts, **_start(start))
    unique = sorted_labels[starts]
    error = np.empty(len(unique), dtype=object)
    error[:] = d.pop("error")
    for k, e in enumerate(error):  # a degenerate sphere that is one far point: name its row (of the input)
        if isinstance(e, GeometryError):
            lo = int(bounds[k])
            text = _far_point(sorted_pts[lo:bounds[k + 1]], str(e),
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
            msg = _ill_conditioned(float(rho[k]), float(fits.polar_coverage[k]),
                                   f"{len(bad)} of {len(unique)} spheres ({names}; worst {unique[k].item()!r})")
            _log.warning("%s", msg)
            warnings.warn(msg, IllConditionedFit, stacklevel=2)
    return fits


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
    _check(radius, reject, rule, max_iterations, 0.0, samples, seed)
    if int(max_rounds) < 1:
        raise InputError(f"max_rounds: must be at least 1, got {max_rounds}")
    start = None if start is None else tuple(vector3("start", start, unit="mm").tolist())
    d = _core.segment_sphere(pts, float(radius), origin, start=start, half_angle=float(half_angle), rule=rule,
                             reject=None if reject is None else float(reject), max_rounds=int(max_rounds),
                             samples=int(samples), seed=int(seed), max_iterations=int(max_iterations))
    fit = SphereFit._from(d["fit"])
    if not d["converged"]:
        _log.warning("segment_sphere: the region still changed after %d fits (max_rounds)", d["rounds"])
    used = pts[fit.inlier]
    # The region fits run without a coverage floor (a first region may be a
    # sliver); the answer needs the same cap as any fit (fit_sphere's 2 deg).
    if not fit.polar_coverage >= min_coverage:
        raise _coverage_error(pts, float(radius), float(fit.polar_coverage), float(min_coverage), "segment_sphere")
    _warn_implausible(used, fit, True, "segment_sphere")
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
