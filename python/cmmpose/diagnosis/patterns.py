"""Where the compensation model fails: residual patterns at every level of a
run, each tied to a quantity that could explain it (issue 6, item 2).

Three levels of observables, all in micrometres:

- ``length``: ballbar length deviation from the mean length, one value per
  position, against the bar's direction cosines (signed, squared, products),
  its midpoint, the mean time and the mean temperature of its scans;
- ``scan``: per sphere scan, the centre deviation from the mean of the scans
  of the same physical ball (only balls scanned at least twice), the radius
  deviation (from the calibrated radius, or from the mean radius) and the
  form, against pose, sweep direction, sweep speed, sweep axis and position;
- ``point``: per point, the sphere-fit residual against u, v, the incidence
  angle, D, E, F, time and temperature.

For every (observable, quantity) pair a low-order model is fitted by least
squares: one linear term for a direction shape (``dx``, ``dx^2``,
``dx*dy``: the shape itself is the physics), linear + quadratic for other
continuous quantities, group means for categorical ones (pose, sweep axis).
Its strength is the fraction of variance explained (R^2) with an F-test
p-value; the amplitude is the peak-to-peak of the fitted pattern over the
data (um). A pattern is *significant* when its p-value is below
``alpha / m`` (Bonferroni over the m patterns tested). Patterns are ranked
significant first, then by R^2 x amplitude. What it finds
(:class:`~cmmpose.diagnosis.pattern_results.Pattern`,
:class:`~cmmpose.diagnosis.pattern_results.Patterns`) is in
:mod:`cmmpose.diagnosis.pattern_results`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from numbers import Real

import numpy as np

from .. import _core, effects
from ..errors import InputError, InputTypeError
from ..run import Run
from .pattern_results import Pattern, Patterns

__all__ = ["find_patterns", "f_test_p_value"]

#: Quantile bins of a point-level quantity for the binned means (plots, amplitude).
POINT_BINS = 24
#: Highest polynomial degree of a continuous quantity (linear + quadratic).
_MAX_CONTINUOUS_DEGREE = 2
_UM = 1000.0  # mm -> um
_SAME = 1e-9  # quantities closer than this (in their own unit) are equal


# -- statistics -------------------------------------------------------------------
def f_test_p_value(f: float, df1: int, df2: int) -> float:
    """Upper tail probability of the F distribution (as scipy.stats.f.sf).

    Parameters
    ----------
    f : float
        The F statistic (dimensionless, >= 0; inf gives 0).
    df1, df2 : int
        Numerator and denominator degrees of freedom (>= 1, dimensionless).

    Returns
    -------
    float
        P(F(df1, df2) > f), dimensionless in [0, 1].
    """
    if df1 < 1 or df2 < 1:
        raise InputError(f"f_test_p_value: degrees of freedom must be >= 1, got {df1}, {df2}")
    if not f > 0.0:  # 0 or NaN: nothing explained
        return 1.0
    if math.isinf(f):
        return 0.0
    # scipy.special, not scipy.stats: the same regularised incomplete beta,
    # without a second of importing the distributions module.
    from scipy.special import fdtrc

    return float(min(1.0, max(0.0, fdtrc(df1, df2, f))))


@dataclass(frozen=True)
class _Fit:
    r2: float
    p: float
    df1: int
    df2: int
    fitted: np.ndarray  # model at each observation, um


def _anova(y: np.ndarray, fitted: np.ndarray, df1: int) -> _Fit | None:
    """R^2 and F-test of a model with ``df1`` terms beyond the intercept whose
    least-squares predictions are ``fitted``; None when it cannot be tested."""
    n = len(y)
    df2 = n - df1 - 1
    if df1 < 1 or df2 < 1:
        return None
    sst = float(np.sum((y - y.mean()) ** 2))
    if not sst > 0.0:
        return None
    sse = float(np.sum((y - fitted) ** 2))
    ssr = max(sst - sse, 0.0)
    r2 = ssr / sst
    f = math.inf if sse <= 0.0 else (ssr / df1) / (sse / df2)
    return _Fit(r2, f_test_p_value(f, df1, df2), df1, df2, fitted)


def _poly_design(x: np.ndarray, degree: int, centre: float, scale: float) -> np.ndarray:
    z = (x - centre) / scale  # standardised so the normal equations stay well conditioned
    return np.column_stack([z**k for k in range(degree + 1)])


def _fit_poly(x: np.ndarray, y: np.ndarray, degree: int):
    """Least-squares polynomial of ``degree`` in x; returns (fit, evaluate).

    Solved by the normal equations of the standardised powers, formed from
    power sums (one pass per power instead of a least-squares solve over
    half a million design rows): with z standardised the Gram matrix of 1,
    z, z^2 stays well conditioned, and the F-test's residual sum of squares
    is stationary at the solution, so rounding in the coefficients barely
    reaches it. An ill-conditioned Gram matrix (a quantity with a few
    extreme values) falls back to the rank-revealing least squares."""
    centre = float(np.mean(x))
    scale = float(np.std(x)) or 1.0
    z = (x - centre) / scale
    powers = [np.ones_like(z), z]  # z^k, k = 0 .. 2 degree
    for _ in range(2, 2 * degree + 1):
        powers.append(powers[-1] * z)
    sums = np.array([float(np.sum(p)) for p in powers])
    gram = sums[np.add.outer(np.arange(degree + 1), np.arange(degree + 1))]
    if np.linalg.cond(gram) < 1e8:
        coef = np.linalg.solve(gram, np.array([float(np.sum(y * powers[k])) for k in range(degree + 1)]))
        fitted = coef[-1] * np.ones_like(z)
        for c in coef[-2::-1]:  # Horner
            fitted = fitted * z + c
    else:
        coef, *_ = np.linalg.lstsq(_poly_design(x, degree, centre, scale), y, rcond=None)
        fitted = None

    def evaluate(xe: np.ndarray) -> np.ndarray:
        return _poly_design(np.asarray(xe, dtype=float), degree, centre, scale) @ coef

    return _anova(y, evaluate(x) if fitted is None else fitted, degree), evaluate


def _degree(x: np.ndarray, shape: bool) -> int:
    """Polynomial degree a quantity supports: 1 for a direction shape, else up
    to quadratic, limited by its number of distinct values (0: untestable)."""
    sample = x if len(x) < 5000 else x[:: max(1, len(x) // 5000)]
    # Values closer than 1e-9 (nm, ns, ...) are one value: differences from a
    # scan mean leave rounding noise where the quantity is really constant.
    distinct = len(np.unique(np.round(sample / _SAME)))
    return min(1 if shape else _MAX_CONTINUOUS_DEGREE, distinct - 1)


# -- hints: which physics could make each pattern -------------------------------------
# Each quantity's hint: the effects that declare it (their ``hints``, in the registry's order, joined by "or") put
# into the causes outside the effect library (drift, the map itself).
_LENGTH_TEMPLATES = {
    **{a: f"{{effects}}, or drift along {a[1]} between the two balls' scans" for a in ("dx", "dy", "dz")},
    **{f"d{a}^2": "{effects}" for a in "xyz"},
    "dx*dy": "{effects}", "dy*dz": "{effects}", "dz*dx": "{effects}",
    **{f"mid {a}": f"error varying along {a}: {{effects}}, map error" for a in "xyz"},
    "time": "thermal: {effects}",
    "temperature": "thermal: {effects}",
}
_POINT_TEMPLATES = {
    "u": "{effects}",
    "v": "{effects}",
    "incidence": "{effects}",
    **{f"{c} in scan": f"machine error varying within a ball along {a}: map interpolation, {{effects}}"
       for c, a in zip("DEF", "xyz")},
    "t in scan": "drift, or {effects}, during the sweep",
    "temperature": "thermal: temperature sensitivity of scanner or machine",
}


def _hints(kind: str, templates: dict[str, str]) -> dict[str, str]:
    """Quantity -> hint, from the effect files' declared ``hints`` (cmmpose.effects)."""
    out = {}
    for quantity, template in templates.items():
        named = [cls.hints[kind][quantity] for cls in effects.available().values()
                 if quantity in cls.hints.get(kind, {})]
        text = " or ".join(dict.fromkeys(named))  # one phrase once, in the registry's order
        out[quantity] = template.format(effects=text) if text else template.replace("{effects}", "no library effect")
    return out


_LENGTH_HINTS = _hints("length", _LENGTH_TEMPLATES)
_POINT_HINTS = _hints("point", _POINT_TEMPLATES)


def _scan_hint(observable: str, quantity: str, calibrated: bool) -> str:
    if observable.startswith("sphere centre"):
        return {"pose": "alignment or mount offset error",
                "sweep direction": "scanner latency",
                "sweep speed": "scanner latency",
                "sweep axis": "scanner latency or alignment error"}.get(quantity, "scan-to-scan drift")
    if observable.startswith("sphere radius"):
        if quantity == "(all scans)":
            return "scanner scale/incidence error (with a calibrated radius)"
        return {"pose": "scanner depth/lateral scale or incidence error (depends on the view)",
                "sweep direction": "scanner latency with non-uniform motion",
                "sweep speed": "scanner latency or vibration",
                "sweep axis": "scanner latency or vibration"}.get(
                    quantity, "scanner scale/incidence error" + (" (with a calibrated radius)" if calibrated else ""))
    return {"pose": "scanner incidence-angle error or scanner scale (depends on the view)",
            "sweep direction": "scanner latency with non-uniform motion",
            "sweep speed": "vibration or latency during the sweep",
            "sweep axis": "vibration or latency during the sweep"}.get(
                quantity, "scanner incidence-angle error or scanner scale, local machine error")


# -- checking the inputs ---------------------------------------------------------------
def _check_inputs(run, xyz, fits, temperature, nominal_radius, alpha):
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    n = run.n_points
    try:
        xyz = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"xyz: cannot be read as float64 numbers ({exc})") from None
    if xyz.shape != (n, 3):
        raise InputError(f"xyz: expected shape ({n}, 3) (one row per point of the run, mm), got {xyz.shape}")
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        r = int(np.argmax(bad))
        raise InputError(f"xyz: row {r} is not finite ({xyz[r]}); compensate with nan_policy='raise'")
    if not isinstance(fits, Mapping):
        raise InputTypeError(f"fits: expected a dict scan_id -> SphereFit (cmmpose.fit_spheres), got {type(fits).__name__}")
    if temperature is not None:
        try:
            temperature = np.asarray(temperature, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"temperature: cannot be read as float64 numbers, C ({exc})") from None
        if temperature.ndim == 0:
            temperature = np.full(n, float(temperature))
        if temperature.shape != (n,):
            raise InputError(f"temperature: expected one value or shape ({n},) (C per point), got {temperature.shape}")
        bad = ~np.isfinite(temperature)
        if bad.any():
            r = int(np.argmax(bad))
            raise InputError(f"temperature: row {r} is not finite ({temperature[r]}), C")
    if nominal_radius is not None:
        if isinstance(nominal_radius, bool) or not isinstance(nominal_radius, (Real, np.floating, np.integer)) \
                or not (math.isfinite(float(nominal_radius)) and float(nominal_radius) > 0):
            raise InputError(f"nominal_radius: expected a positive ball radius in mm, got {nominal_radius!r}")
        nominal_radius = float(nominal_radius)
    if isinstance(alpha, bool) or not isinstance(alpha, (Real, np.floating)) or not 0.0 < float(alpha) < 1.0:
        raise InputError(f"alpha: expected a significance level in (0, 1), got {alpha!r}")
    return xyz, temperature, nominal_radius, float(alpha)


def scan_sphere_fits(run: Run, fits: Mapping):
    """Per scan with points (ascending scan id): the fit, checked against the
    points; the per-point residual and inlier arrays in run.points order."""
    sid = run.points["scan_id"]
    order = np.argsort(sid, kind="stable")
    ids, counts = np.unique(sid, return_counts=True)
    res_parts, inl_parts, scan_fits = [], [], []
    for s, c in zip(ids.tolist(), counts.tolist()):
        f = fits.get(s, fits.get(np.int32(s)))
        if f is None:
            raise InputError(f"fits: no sphere fit for scan {s} ({c} points); pass fit_spheres(xyz, run.points['scan_id'])")
        if isinstance(f, BaseException):
            raise InputError(f"fits: scan {s} could not be fitted ({f})")
        try:
            residuals = np.asarray(f.residuals, dtype=np.float64)
            centre = np.asarray(f.centre, dtype=np.float64)
            radius, form = float(f.radius), float(f.form)
        except (AttributeError, TypeError, ValueError):
            raise InputError(f"fits: scan {s}: expected a SphereFit (centre, radius, form, residuals), "
                             f"got {type(f).__name__}") from None
        if residuals.shape != (c,):
            raise InputError(f"fits: scan {s}: {residuals.shape[0] if residuals.ndim else 0} residuals for {c} points; "
                             "the fits must come from the same xyz")
        if centre.shape != (3,):
            raise InputError(f"fits: scan {s}: centre must have 3 coordinates (mm), got shape {centre.shape}")
        if not (np.isfinite(residuals).all() and np.isfinite(centre).all() and math.isfinite(radius) and math.isfinite(form)):
            raise InputError(f"fits: scan {s}: the fit holds NaN or inf")
        inlier = getattr(f, "inlier", None)
        inlier = np.ones(c, bool) if inlier is None else np.asarray(inlier, dtype=bool)
        if inlier.shape != (c,):
            raise InputError(f"fits: scan {s}: inlier mask of shape {inlier.shape} for {c} points")
        res_parts.append(residuals)
        inl_parts.append(inlier)
        scan_fits.append((centre, radius, form))
    residual = np.empty(len(sid))
    inlier = np.empty(len(sid), bool)
    if len(sid):
        residual[order] = np.concatenate(res_parts)
        inlier[order] = np.concatenate(inl_parts)
    centres = np.array([c for c, _, _ in scan_fits]).reshape(-1, 3)
    radii = np.array([r for _, r, _ in scan_fits])
    forms = np.array([f for _, _, f in scan_fits])
    return ids, counts, centres, radii, forms, residual, inlier


# -- the three levels -----------------------------------------------------------------
def continuous_pattern(level, observable, quantity, unit, x, y, hint, *, shape=False) -> Pattern | None:
    """Polynomial pattern of y (um) in x over individual observations."""
    degree = _degree(x, shape)
    if degree < 1:
        return None
    fit, _ = _fit_poly(x, y, degree)
    if fit is None:
        return None
    return Pattern(level, observable, quantity, unit, "linear" if degree == 1 else "quadratic", fit.r2, fit.p,
                   (fit.df1, fit.df2), len(y), float(np.ptp(fit.fitted)), hint, x=x, y=y, fitted=fit.fitted)


def categorical_pattern(level, observable, quantity, labels, y, hint) -> Pattern | None:
    """Group-means pattern of y (um) over category ``labels``."""
    names, inverse = np.unique(np.asarray(labels).astype(str), return_inverse=True)
    k = len(names)
    try:  # numeric labels (position, pose id) in numeric order, not as text
        rank = np.argsort(np.argsort([int(v) for v in names], kind="stable"))
        names, inverse = names[np.argsort(rank)], rank[inverse]
    except ValueError:
        pass
    if k < 2:
        return None
    counts = np.bincount(inverse, minlength=k)
    means = np.bincount(inverse, weights=y, minlength=k) / counts
    fit = _anova(y, means[inverse], k - 1)
    if fit is None:
        return None
    return Pattern(level, observable, quantity, "", "group means", fit.r2, fit.p, (fit.df1, fit.df2), len(y),
                   float(np.ptp(means)), hint, x=names.astype(object), y=means, fitted=means, counts=counts)


def _binned(level, observable, quantity, unit, x, y, hint) -> Pattern | None:
    """Polynomial pattern fitted to all points, reported on quantile bins (plots,
    amplitude) so half a million points stay cheap to keep and to draw."""
    degree = _degree(x, False)
    if degree < 1:
        return None
    fit, evaluate = _fit_poly(x, y, degree)
    if fit is None:
        return None
    edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, POINT_BINS + 1)))
    b = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(len(edges) - 2, 0))
    nb = int(b.max()) + 1
    counts = np.bincount(b, minlength=nb)
    keep = counts > 0
    xm = np.bincount(b, weights=x, minlength=nb)[keep] / counts[keep]
    ym = np.bincount(b, weights=y, minlength=nb)[keep] / counts[keep]
    y2 = np.bincount(b, weights=y * y, minlength=nb)[keep] / counts[keep]
    c = counts[keep]
    se = np.sqrt(np.maximum(y2 - ym**2, 0.0) * c / np.maximum(c - 1, 1) / c)
    fitted = evaluate(xm)
    return Pattern(level, observable, quantity, unit, "linear" if degree == 1 else "quadratic", fit.r2, fit.p,
                   (fit.df1, fit.df2), len(y), float(np.ptp(fitted)), hint, x=xm, y=ym, fitted=fitted,
                   y_err=se, counts=c)


def _scan_rows(run: Run, ids: np.ndarray) -> np.ndarray:
    """Row of each scan id of ``ids`` in the scans table (Run checks they exist)."""
    row_of = {s: i for i, s in enumerate(run.scans["scan_id"].tolist())}
    return np.array([row_of[s] for s in ids.tolist()], dtype=np.int64)


def length_shape_patterns(direction, midpoint, dev) -> list:
    """The length deviations ``dev`` (um, P) against the bar's direction
    cosines (``direction``, P x 3: scale as squares, squareness as products)
    and its mid-point along each axis (``midpoint``, P x 3, mm)."""
    obs = "ballbar length deviation"
    dx, dy, dz = np.asarray(direction).T
    shapes = [("dx", dx), ("dy", dy), ("dz", dz), ("dx^2", dx**2), ("dy^2", dy**2), ("dz^2", dz**2),
              ("dx*dy", dx * dy), ("dy*dz", dy * dz), ("dz*dx", dz * dx)]
    out = [continuous_pattern("length", obs, q, "1", x, dev, _LENGTH_HINTS[q], shape=True) for q, x in shapes]
    out += [continuous_pattern("length", obs, f"mid {a}", "mm", midpoint[:, j], dev, _LENGTH_HINTS[f"mid {a}"])
            for j, a in enumerate("xyz")]
    return out


def ranked_patterns(found, alpha: float) -> tuple[tuple, float]:
    """The patterns tested (None for one that could not be), each marked
    significant against alpha over their number (Bonferroni), ranked
    significant first, then by R^2 x amplitude; and the threshold."""
    found = [p for p in found if p is not None]
    threshold = alpha / max(len(found), 1)
    ranked = sorted((_with_significance(p, threshold) for p in found),
                    key=lambda p: (not p.significant, -p.score, p.p_value))
    return tuple(ranked), threshold


def _length_level(run, ids, counts, centres, scan_t, scan_temp):
    """Ballbar lengths per position (mean centre of each ball's scans) and their patterns
    (none for an artefact run: its balls are not bar ends)."""
    if isinstance(run.artefact.get("definition"), dict):
        return None, []
    scans = run.scans
    at = _scan_rows(run, ids)
    pos, ball = scans["position"][at], scans["ball"][at]
    use = (pos >= 0) & np.isin(ball, (1, 2))
    balls: dict[tuple[int, int], list[int]] = {}
    for k in np.flatnonzero(use).tolist():
        balls.setdefault((int(pos[k]), int(ball[k])), []).append(k)
    positions = sorted(p for p, b in balls if b == 1 and (p, 2) in balls)
    if len(positions) < 3:
        return None, []

    def mean_centre(ks):
        w = counts[ks].astype(float)
        return (centres[ks] * w[:, None]).sum(axis=0) / w.sum()

    c1 = np.array([mean_centre(balls[(p, 1)]) for p in positions])
    c2 = np.array([mean_centre(balls[(p, 2)]) for p in positions])
    bar = c2 - c1
    length = np.linalg.norm(bar, axis=1)
    direction = bar / length[:, None]
    midpoint = (c1 + c2) / 2.0

    def per_position(values):
        out = []
        for p in positions:
            ks = balls[(p, 1)] + balls[(p, 2)]
            w = counts[ks].astype(float)
            out.append(float((values[ks] * w).sum() / w.sum()))
        return np.array(out)

    time_s = per_position(scan_t)
    temp = per_position(scan_temp) if scan_temp is not None else np.full(len(positions), np.nan)
    dev = (length - length.mean()) * _UM
    table = {"position": np.array(positions), "length_mm": length, "deviation_um": dev, "direction": direction,
             "midpoint": midpoint, "time_s": time_s, "temperature_C": temp}

    out = length_shape_patterns(direction, midpoint, dev)
    obs = "ballbar length deviation"
    out.append(continuous_pattern("length", obs, "time", "s", time_s, dev, _LENGTH_HINTS["time"]))
    if scan_temp is not None:
        out.append(continuous_pattern("length", obs, "temperature", "C", temp, dev, _LENGTH_HINTS["temperature"]))
    return table, out


def _scan_level(run, ids, counts, centres, radii, forms, nominal_radius):
    scans = run.scans
    at = _scan_rows(run, ids)
    quantities = {
        "pose": scans["pose_id"][at].astype(str),
        "sweep direction": np.where(scans["sweep_direction"][at] > 0, "+", "-"),
        "sweep axis": scans["sweep_axis"][at].astype(str),
        "position": scans["position"][at].astype(str),
    }
    speed = scans["sweep_speed"][at].astype(float)
    out: list[Pattern | None] = []

    def against(observable, y, hint_of, rows=slice(None), skip=()):
        for q, labels in quantities.items():
            if q not in skip:
                out.append(categorical_pattern("scan", observable, q, labels[rows], y, hint_of(q)))
        # Speed is continuous; with two speeds this is the two-group test.
        out.append(continuous_pattern("scan", observable, "sweep speed", "mm/s", speed[rows], y, hint_of("sweep speed")))

    # Centre deviation from the mean of the scans of the same physical ball.
    key = np.array([f"{f}|{p}|{b}" for f, p, b in zip(scans["feature"][at], scans["position"][at], scans["ball"][at])])
    _, ball_of, per_ball = np.unique(key, return_inverse=True, return_counts=True)
    repeated = per_ball[ball_of] >= 2
    if repeated.sum() >= 3:
        w = counts.astype(float)
        mean = np.stack([np.bincount(ball_of, weights=centres[:, j] * w) / np.bincount(ball_of, weights=w)
                         for j in range(3)], axis=1)
        dev = (centres - mean[ball_of]) * _UM
        for j, a in enumerate("xyz"):
            obs = f"sphere centre deviation {a}"
            # position is constant per ball: its group means are 0 by construction
            against(obs, dev[repeated, j], lambda q, obs=obs: _scan_hint(obs, q, False), rows=repeated,
                    skip=("position",))

    calibrated = nominal_radius is not None
    ref = nominal_radius if calibrated else float(np.average(radii, weights=counts))
    rdev = (radii - ref) * _UM
    obs = "sphere radius deviation" + (" from nominal" if calibrated else " from mean")
    if calibrated and len(rdev) >= 2:
        out.append(mean_offset_pattern("scan", obs, rdev, _scan_hint(obs, "(all scans)", True)))
    against(obs, rdev, lambda q: _scan_hint(obs, q, calibrated))
    against("sphere form", forms * _UM, lambda q: _scan_hint("sphere form", q, calibrated))
    return out


def mean_offset_pattern(level, observable, y, hint) -> Pattern | None:
    """A constant offset of y (um) from zero: one-sample F (= t^2) test."""
    n = len(y)
    ss0 = float(np.sum(y**2))
    sse = float(np.sum((y - y.mean()) ** 2))
    if not ss0 > 0.0:
        return None
    ssr = ss0 - sse
    f = math.inf if sse <= 0.0 else ssr / (sse / (n - 1))
    mean = float(y.mean())
    return Pattern(level, observable, "(all scans)", "", "mean", ssr / ss0, f_test_p_value(f, 1, n - 1),
                   (1, n - 1), n, abs(mean), hint, x=np.array(["all scans"], dtype=object), y=np.array([mean]),
                   fitted=np.array([mean]), counts=np.array([n]))


def _incidence(run, xyz, ids, centres):
    """Angle (degrees) between each point's outward sphere normal and the beam
    direction towards the sensor (the pose's v axis; the scanner looks along -v)."""
    scan_index = np.searchsorted(ids, run.points["scan_id"])
    pose_of_scan = run.scans["pose_id"][_scan_rows(run, ids)]
    poses = run.poses
    v_axis = {int(p): _core.euler313(float(a), float(b), float(g))[:, 1]
              for p, a, b, g in zip(poses["pose_id"], poses["alpha"], poses["beta"], poses["gamma"])}
    beam_of_scan = np.array([v_axis[int(p)] for p in pose_of_scan]).reshape(-1, 3)
    normal = xyz - centres[scan_index]
    norm = np.linalg.norm(normal, axis=1)
    cos = np.einsum("ij,ij->i", normal, beam_of_scan[scan_index]) / np.where(norm > 0, norm, 1.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _point_level(run, xyz, ids, counts, centres, residual, inlier, temperature):
    p = run.points
    keep = inlier
    y = residual[keep] * _UM
    # Each sphere fit leaves residuals with zero mean and no linear trend in x, y, z
    # within its scan, so scale readings and time only tell something within a
    # scan: they are taken from the scan's mean (D, E, F) and first point (t).
    scan_index = np.searchsorted(ids, p["scan_id"])

    def within(values):
        return values - (np.bincount(scan_index, weights=values, minlength=len(ids)) / counts)[scan_index]

    t_start = np.full(len(ids), np.inf)
    np.minimum.at(t_start, scan_index, p["t"])
    quantities = [("u", "mm", p["u"]), ("v", "mm", p["v"]), ("incidence", "degree", _incidence(run, xyz, ids, centres)),
                  ("D in scan", "mm", within(p["D"])), ("E in scan", "mm", within(p["E"])),
                  ("F in scan", "mm", within(p["F"])), ("t in scan", "s", p["t"] - t_start[scan_index])]
    if temperature is not None:
        quantities.append(("temperature", "C", temperature))
    obs = "point fit residual"
    return [_binned("point", obs, q, unit, np.asarray(x, dtype=float)[keep], y, _POINT_HINTS[q])
            for q, unit, x in quantities]


# -- entry point ----------------------------------------------------------------------
def find_patterns(run: Run, xyz, fits, *, temperature=None, nominal_radius: float | None = None,
                  alpha: float = 1e-3) -> Patterns:
    """Residual patterns of a run at the length, scan and point levels, ranked.

    Parameters
    ----------
    run : cmmpose.Run
        The measurement run (points, scans, poses).
    xyz : array_like, shape (N, 3)
        Compensated machine coordinates of every point, mm, in the row order
        of ``run.points``.
    fits : dict of int -> SphereFit
        ``cmmpose.fit_spheres(xyz, run.points['scan_id'])``: one fit per scan
        id with points (centre and radius in mm, residuals in mm in the order
        of that scan's points).
    temperature : float or array_like, shape (N,), optional
        Machine temperature at each point, degrees C (one value for all).
        Adds the temperature quantities.
    nominal_radius : float, optional
        Calibrated ball radius, mm. Radius deviations are taken from it (and
        a constant offset is tested); without it, from the mean radius.
    alpha : float
        Family-wise significance level (dimensionless); each pattern is
        significant when p < alpha / (number of patterns tested).

    Returns
    -------
    Patterns
        Ranked patterns, ``.strongest``, ``.summary()``, ``.to_dict()``.

    Raises
    ------
    InputError
        ``run`` not a Run, ``xyz`` of the wrong shape or not finite, a scan
        with points but no fit (or a failed fit, or residuals that do not
        match its points), a non-finite temperature, a non-positive radius.
    """
    xyz, temperature, nominal_radius, alpha = _check_inputs(run, xyz, fits, temperature, nominal_radius, alpha)
    ids, counts, centres, radii, forms, residual, inlier = scan_sphere_fits(run, fits)
    if len(ids) == 0:
        raise InputError("run: has no points, nothing to diagnose")
    sid_index = np.searchsorted(ids, run.points["scan_id"])
    scan_t = np.bincount(sid_index, weights=run.points["t"], minlength=len(ids)) / counts
    scan_temp = (np.bincount(sid_index, weights=temperature, minlength=len(ids)) / counts
                 if temperature is not None else None)

    lengths, found = _length_level(run, ids, counts, centres, scan_t, scan_temp)
    found += _scan_level(run, ids, counts, centres, radii, forms, nominal_radius)
    found += _point_level(run, xyz, ids, counts, centres, residual, inlier, temperature)
    ranked, threshold = ranked_patterns(found, alpha)
    rms = float(np.sqrt(np.mean(residual[inlier] ** 2)) * _UM) if inlier.any() else float("nan")
    return Patterns(ranked, alpha, threshold, lengths, rms)


def _with_significance(p: Pattern, threshold: float) -> Pattern:
    return replace(p, significant=bool(p.p_value < threshold))
