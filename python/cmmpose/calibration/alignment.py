"""Digitizer alignment calibration (thesis chapter 4 and section 5.3).

Solvers, each returning its result with a standard uncertainty:

- :func:`alpha_beta_from_vernier`: alpha, beta from optical-vernier points on
  the scan plane (eqs. 5-6, quadrant-safe form of docs/conventions.md, Frames);
- :func:`gamma_from_plane_scan`: gamma from a flat plane scanned while the
  machine moves (section 4.3: "scanning a planar surface while moving the CMM,
  and fitting the data");
- :func:`calibrated_pose`: the two combined into one pose with its 3 x 3
  covariance;
- :func:`reference_centre_reading`: D0, E0, F0, the scale reading at which the
  laser origin sits at the reference-sphere centre (section 4.4, eq. 14);
- :func:`mount_offset`: U1, V1, W1 from two or more alignments by generalised
  least squares, with residuals and a chi-square consistency check;
- :func:`mount_offset_closed_form`: eqs. 19-20 and the corrected eq. 21 for the
  thesis's three standard alignments, with the GUM budget of eqs. 22-24.

Units: mm for lengths, degrees for angles (radians only inside), degrees C
for temperatures; covariances in the square of those units. Conventions,
methods and their uncertainties: docs/calibration.md ("Alignment").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._arrays import as_rows, as_triple
from ..compensation import compensate, uncompensated
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import CalibrationError, GeometryError, InputError, InputTypeError
from ..fitting import PlaneFit, SphereFit, fit_plane, fit_sphere
from ..pose import MountOffset, Pose, pose_tuple
from ..temperature import TemperaturePolicy, as_policy

__all__ = [
    "CalibrationError",
    "STANDARD_POSES",
    "VernierAlignment",
    "alpha_beta_from_vernier",
    "GammaAlignment",
    "gamma_from_plane_scan",
    "CalibratedPose",
    "calibrated_pose",
    "ReferenceReading",
    "reference_centre_reading",
    "MountOffsetFit",
    "mount_offset",
    "ClosedFormOffset",
    "mount_offset_closed_form",
]


#: The thesis's three alignments for the mount offset (section 5.3): W along +X
#: at gamma 0 and 90 degrees, W along +Y at gamma 0 (alpha, beta, gamma in degrees).
STANDARD_POSES = ((90.0, 90.0, 0.0), (90.0, 90.0, 90.0), (180.0, 90.0, 0.0))

_DEG = math.pi / 180.0
#: Fewest points accepted for a plane scan.
MIN_PLANE_POINTS = 10
#: Scale readings that differ by less than this (mm) count as no motion.
MOTION_FLOOR_MM = 1e-6


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def _e313(pose) -> np.ndarray:
    return np.asarray(_core.euler313(*pose_tuple(pose)))


def _e313_derivatives(pose) -> np.ndarray:
    """dE313/d(alpha, beta, gamma), (3, 3, 3) per degree, index [angle] -> (3, 3)."""
    p = np.array(pose_tuple(pose), dtype=float)
    h = 1e-3  # deg: central difference, truncation ~ (h rad)^2 ~ 3e-10 relative
    out = np.empty((3, 3, 3))
    for j in range(3):  # three angles, not points
        d = np.zeros(3)
        d[j] = h
        out[j] = (_e313(p + d) - _e313(p - d)) / (2 * h)
    return out


def _check_map(maps, temperature):
    if maps is None:
        if temperature is not None:
            raise InputError("temperature: only meaningful with maps")
        return
    if not isinstance(maps, (ErrorMap, ErrorMapSet)):
        raise InputTypeError(f"maps: expected an ErrorMap or ErrorMapSet, got {type(maps).__name__}")
    if isinstance(maps, ErrorMapSet) and temperature is None:
        raise InputError("temperature: an ErrorMapSet needs the machine temperature (C), one value or one per point")


def _temperature(temperature, n: int):
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


def _single_map(maps, temperature, policy: TemperaturePolicy) -> ErrorMap:
    """The map at the (mean) temperature, for evaluating e(S) and R(S) at one reading."""
    if isinstance(maps, ErrorMap):
        return maps
    return maps.at(float(np.mean(temperature)), out_of_range=policy.out_of_range,
                   temperature_tolerance=policy.temperature_tolerance)


def _machine_points(uv, scales, pose, offset, maps, temperature, policy: TemperaturePolicy) -> np.ndarray:
    """Scanner points in machine coordinates (mm): compensated with the map, or
    the error-free model S + E313 ((u, v, 0) - l1) without one."""
    if maps is None:
        return uncompensated(uv, scales, pose, offset)
    return compensate(uv, scales, maps, pose, offset, temperature, temperature_policy=policy)


def _covariance(name: str, c, n: int) -> np.ndarray:
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


def _uncertainty_triple(name: str, u) -> np.ndarray:
    a = np.broadcast_to(np.asarray(u, dtype=float), (3,)).copy() if np.ndim(u) == 0 else np.asarray(u, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputError(f"{name}: expected one or three standard uncertainties >= 0 (mm), got {u!r}")
    return a


def _chi2_sf(x: float, k: int) -> float:
    """P(chi^2_k > x) (scipy.special.chdtrc); 1 for k <= 0 or x <= 0."""
    if k <= 0:
        return 1.0
    if x <= 0:
        return 1.0
    from scipy.special import chdtrc  # SciPy is imported on first use, not with cmmpose

    return float(chdtrc(k, x))


def _pose_name(pose) -> str:
    a, b, g = pose_tuple(pose)
    return f"({a:g}, {b:g}, {g:g})"


# ---------------------------------------------------------------------------
# 1. alpha, beta from optical-vernier points (thesis eqs. 5-6)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class VernierAlignment:
    """alpha and beta of the scan plane from optical-vernier points.

    Attributes
    ----------
    alpha, beta : float
        Euler angles, degrees (beta = acos n_z, alpha = atan2(n_x, -n_y)).
    covariance : ndarray (2, 2)
        Covariance of (alpha, beta), deg^2 (first-order analytic propagation
        of the plane fit's tilt covariance). alpha's variance is inf when the
        normal is along Z (alpha undefined, set to 0).
    normal : ndarray (3,)
        The scan-plane normal w in machine axes (unit), oriented as described
        in :func:`alpha_beta_from_vernier`.
    normal_covariance : ndarray (3, 3)
        Covariance of ``normal`` (dimensionless^2), in the plane perpendicular to it.
    fit : PlaneFit
        The plane fitted to the points (machine coordinates, mm).
    sigma : float
        The point uncertainty along the normal the covariance rests on, mm
        (``point_uncertainty`` if given, else the fit's residual standard deviation).
    """

    alpha: float
    beta: float
    covariance: np.ndarray
    normal: np.ndarray
    normal_covariance: np.ndarray
    fit: PlaneFit
    sigma: float

    @property
    def uncertainty(self) -> np.ndarray:
        """Standard uncertainties of (alpha, beta), degrees."""
        return np.sqrt(np.diag(self.covariance))

    def pose(self, gamma: float = 0.0) -> Pose:
        """The pose with this alpha, beta and the given gamma (degrees)."""
        return Pose(self.alpha, self.beta, float(gamma))


def alpha_beta_from_vernier(points, *, w_hint=None, point_uncertainty: float | None = None, maps=None,
                            temperature=None, min_spread: float = 1.0,
                            temperature_policy: TemperaturePolicy | None = None) -> VernierAlignment:
    """alpha, beta (degrees) of the scan plane from three or more optical-vernier points.

    The CMM is moved until the laser line falls on the fixed vernier (HSV),
    at three or more well-spaced places in the field of view (thesis section
    4.3). The recorded positions lie on a plane parallel to the scan plane; its
    normal is the scanner's w axis: beta = acos(n_z), alpha = atan2(n_x, -n_y)
    (eqs. 5-6 in the quadrant-safe form of docs/conventions.md, Frames; eq. 6 as
    printed loses the quadrant).

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Machine positions, mm, at which the line fell on the vernier (N >= 3);
        scale readings D, E, F if ``maps`` is given (they are then
        compensated to positions S + e(S) first).
    w_hint : array_like, shape (3,), optional
        A direction (any length, machine axes) on the +w side of the scan plane,
        e.g. the nominal W of the trunnion index: the normal is turned to have a
        positive component along it. It must be at least 6 degrees out of
        the plane. Without it, the point order decides: the points, taken in
        order as a polygon, go counter-clockwise seen from +w (u towards v, as
        w = u x v).
    point_uncertainty : float, optional
        Standard uncertainty of one vernier position along the normal, mm
        (Type B: the vernier's null). Default: estimated from the fit's
        residuals (Type A, N - 3 degrees of freedom; undefined, NaN, for N = 3).
    maps : ErrorMap or ErrorMapSet, optional
        Treat ``points`` as scale readings and compensate them: positions
        S + e(S), and the normal turned back by the ram's rotation R(S) at
        their mean (the pose is the orientation before R: docs/conventions.md,
        The compensation).
    temperature : float or array_like of shape (N,), optional
        Machine temperature, C, for ``maps``.
    min_spread : float
        Smallest rms distance of the points from their best-fit line, mm;
        closer to a line the normal is not determined.

    temperature_policy : TemperaturePolicy, optional
        Temperatures outside the maps (docs/conventions.md): the default
        raises; ``TemperaturePolicy(out_of_range='clamp')`` holds the edge map.
    Returns
    -------
    VernierAlignment

    Raises
    ------
    InputError
        Fewer than 3 points, NaN or inf, bad options.
    GeometryError
        Collinear points (or within ``min_spread`` of a line); points whose
        order does not tell the +w side and no ``w_hint``.

    Notes
    -----
    The uncertainty is propagated analytically to first order: the plane fit
    gives the tilt covariance of the normal about its two in-plane axes, the
    gradients of beta = acos n_z and alpha = atan2(n_x, -n_y) carry it to
    (alpha, beta). Inputs are never modified.
    """
    pts = as_rows("points", points, 3)
    n_pts = len(pts)
    if n_pts < 3:
        raise InputError(f"points: the vernier needs at least 3 points on the scan plane, got {n_pts}")
    if not np.all(np.isfinite(pts)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(pts), axis=1))[0])
        raise InputError(f"points: row {bad} is not finite ({pts[bad].tolist()})")
    if not (np.isfinite(min_spread) and min_spread >= 0):
        raise InputError(f"min_spread: must be a length >= 0 in mm, got {min_spread}")
    if point_uncertainty is not None and not (np.isfinite(point_uncertainty) and point_uncertainty > 0):
        raise InputError(f"point_uncertainty: must be a positive length in mm, got {point_uncertainty}")
    _check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = _temperature(temperature, n_pts)
    raw = pts
    if maps is not None:
        pts = compensate(np.zeros((n_pts, 2)), pts, maps, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), temperature,
                         temperature_policy=policy)
    centred = pts - pts.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    off_line = sv[1] / math.sqrt(n_pts)
    if off_line <= max(min_spread, 1e-9 * max(sv[0], 1.0)):
        raise GeometryError(
            f"points: the {n_pts} vernier points are collinear (rms distance from their best-fit line "
            f"{off_line:.4g} mm, less than min_spread {min_spread:g} mm): the scan-plane normal is not "
            "determined; take the points well spread in both directions of the field of view")
    fit = fit_plane(pts)
    n = np.asarray(fit.normal, dtype=float)
    if w_hint is not None:
        hint = np.asarray(as_triple("w_hint", w_hint))
        s = float(n @ hint)
        if np.linalg.norm(hint) == 0 or abs(s) < 0.1 * np.linalg.norm(hint):
            raise InputError(f"w_hint: {hint.tolist()} lies (within 6 degrees) in the scan plane; it cannot tell "
                             "the +w side")
        sign = 1.0 if s > 0 else -1.0
    else:
        # Newell's vector area of the polygon p0 -> p1 -> ... -> p0: along +w for counter-clockwise points.
        area = 0.5 * np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)
        s = float(n @ area)
        if abs(s) <= 1e-3 * sv[0] * sv[1] / n_pts:
            raise GeometryError(
                "points: their order does not tell which side of the scan plane +w is on (the polygon they "
                "trace has no area); order them counter-clockwise seen from +w or give w_hint")
        sign = 1.0 if s > 0 else -1.0
    n = sign * n
    axes = np.asarray(fit.axes, dtype=float)
    if point_uncertainty is not None:
        sigma = float(point_uncertainty)
        spread = ((centred @ axes.T) ** 2).sum(axis=0)  # mm^2 along the two in-plane axes
        tilt_cov = np.diag(sigma**2 / spread)
    else:
        dof = n_pts - 3
        sigma = float(np.sqrt(np.sum(np.asarray(fit.residuals) ** 2) / dof)) if dof > 0 else float("nan")
        tilt_cov = np.asarray(fit.tilt_covariance, dtype=float)
    cov_n = axes.T @ tilt_cov @ axes
    if maps is not None:
        # The plane found is the true scan plane, R(S) E313 w: the ram's rotation at
        # the vernier readings is part of it. The pose is E313 before R
        # (docs/conventions.md, The compensation), so turn it back by R at the
        # mean reading (up to ~10 a-s with the thesis maps).
        rot = _single_map(maps, temperature, policy).rotation_error(raw.mean(axis=0)[None, :])[0]
        n = rot.T @ n
        n = n / np.linalg.norm(n)
        cov_n = rot.T @ cov_n @ rot
    nx, ny, nz = n
    beta = math.degrees(math.acos(min(1.0, max(-1.0, nz))))
    rho2 = nx * nx + ny * ny
    if rho2 < 1e-18:
        alpha = 0.0
        # W along Z: alpha is undefined (0 by convention); beta is the tilt's size, ~ its rms.
        cov_ab = np.array([[np.inf, 0.0], [0.0, float(np.trace(cov_n)) / _DEG**2]])
    else:
        alpha = math.degrees(math.atan2(nx, -ny))
        d_alpha = np.array([-ny, nx, 0.0]) / rho2  # d atan2(n_x, -n_y)
        d_beta = np.array([0.0, 0.0, -1.0 / math.sqrt(rho2)])  # d acos(n_z), |n| = 1
        g = np.vstack([d_alpha, d_beta]) / _DEG
        cov_ab = g @ cov_n @ g.T
    return VernierAlignment(alpha=alpha, beta=beta, covariance=cov_ab, normal=n, normal_covariance=cov_n,
                            fit=fit, sigma=sigma)


# ---------------------------------------------------------------------------
# 2. gamma from a plane scanned while the machine moves (section 4.3)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class GammaAlignment:
    """gamma from a plane scan.

    Attributes
    ----------
    gamma : float
        Third Euler angle, degrees, in (-180, 180].
    uncertainty : float
        Standard uncertainty of gamma, degrees: the scan's noise and, if
        ``alpha_beta_covariance`` was given, alpha and beta propagated.
    noise_uncertainty : float
        The scan noise's share alone, degrees (least-squares covariance).
    sensitivity : ndarray (2,)
        d gamma / d alpha and d gamma / d beta (numerical: one Gauss-Newton
        step from the solution at alpha, beta +- 0.01 deg), 1.
    alpha, beta : float
        The angles gamma was solved with, degrees.
    normal : ndarray (3,)
        The plane's normal in machine axes: the given one, or the fitted one
        turned towards the scanner (positive along v).
    rms : float
        Root mean square distance of the points from the plane at the solution, mm.
    n_points : int
        Points used.
    method : str
        ``"known normal"`` or ``"fitted plane"``.
    iterations : int
        Gauss-Newton iterations.
    opposite_rms : float or None
        With a given normal: the rms distance of the points from a plane with
        the opposite normal at gamma + 180 deg, mm (None without a normal).
        Turning the scanner 180 deg about w and flipping the normal maps a
        scan whose sweeps run along the face onto itself, so there this is
        about ``rms``: only the sign of ``normal`` picks the branch
        (:attr:`branch_from_normal`). A sweep with motion along the normal
        tells them apart (then it is far larger).
    """

    gamma: float
    uncertainty: float
    noise_uncertainty: float
    sensitivity: np.ndarray
    alpha: float
    beta: float
    normal: np.ndarray
    rms: float
    n_points: int
    method: str
    iterations: int
    opposite_rms: float | None = None

    @property
    def branch_from_normal(self) -> bool:
        """True when the scan fits gamma + 180 deg with the opposite normal as
        well (within 3 times ``rms``): the 180 degree branch then rests on
        the given normal being the face's outward one, which the scan cannot
        check (a nominal ``gamma0`` or other alignments can)."""
        return self.opposite_rms is not None and self.opposite_rms <= 3.0 * self.rms


class _PlaneProblem:
    """The points of a plane scan as a function of gamma; the objective and one
    Gauss-Newton step of the plane-with-gamma least-squares problem."""

    def __init__(self, uv, scales, alpha, beta, normal, offset, maps, temperature, policy):
        self.uv, self.scales = uv, scales
        self.alpha, self.beta = alpha, beta
        self.normal = normal
        self.offset, self.maps, self.temperature, self.policy = offset, maps, temperature, policy

    def points(self, gamma: float) -> np.ndarray:
        return _machine_points(self.uv, self.scales, (self.alpha, self.beta, gamma), self.offset,
                               self.maps, self.temperature, self.policy)

    def cost(self, gamma: float) -> float:
        x = self.points(gamma)
        if self.normal is None:
            return fit_plane(x).rms
        r = x @ self.normal
        return float(np.sqrt(np.mean((r - r.mean()) ** 2)))

    def step(self, gamma: float):
        """(delta gamma in degrees, variance of gamma in rad^2, rms, fitted normal, explained fraction)."""
        h = 1e-3
        x = self.points(gamma)
        dx = (self.points(gamma + h) - self.points(gamma - h)) / (2 * h * _DEG)  # mm/rad
        if self.normal is None:
            f = fit_plane(x)
            n, c = np.asarray(f.normal), np.asarray(f.point)
            axes = np.asarray(f.axes)
            basis = np.column_stack([np.ones(len(x)), (x - c) @ axes.T])
        else:
            n, c = self.normal, x.mean(axis=0)
            basis = np.ones((len(x), 1))
        rho = (x - c) @ n
        g = dx @ n
        q, _ = np.linalg.qr(basis)
        g_perp = g - q @ (q.T @ g)
        rho_perp = rho - q @ (q.T @ rho)
        denom = float(g_perp @ g_perp)
        g_c = g - g.mean()
        frac = math.sqrt(denom / float(g_c @ g_c)) if float(g_c @ g_c) > 0 else 0.0
        dof = len(x) - basis.shape[1] - 1
        s2 = float(rho_perp @ rho_perp) / dof
        delta = -float(g_perp @ rho_perp) / denom if denom > 0 else 0.0
        rms = float(np.sqrt(np.mean(rho_perp**2)))
        return math.degrees(delta), (s2 / denom if denom > 0 else math.inf), rms, n, frac


def _solve_gamma(problem: _PlaneProblem, gamma: float, max_iter: int = 30):
    for it in range(1, max_iter + 1):  # iterations, each a kernel call over all points
        delta, var, rms, n, frac = problem.step(gamma)
        if frac < 1e-3:
            raise CalibrationError(
                "gamma: the plane scan does not determine gamma (its effect is "
                f"{frac:.2g} of what a tilt of the plane can absorb). A single straight sweep over a plane of "
                "unknown orientation always looks flat: give the plane's normal (normal=...) or add a sweep "
                "along another axis")
        gamma += delta
        if abs(delta) < max(1e-8, 1e-3 * math.degrees(math.sqrt(var))):  # far inside the uncertainty
            break
    else:
        raise CalibrationError(
            f"gamma: Gauss-Newton did not converge in {max_iter} iterations (last step {delta:.3g} deg)")
    _, var, rms, n, _ = problem.step(gamma)
    return gamma, var, rms, n, it


#: Largest angle (degrees) between the given normal and the plane the points
#: lie on at the solution before the normal counts as another face's: far
#: above a real face's flatness over a scan (0.01 deg is 10 um over 60 mm),
#: far below a mistyped axis (45-90 deg).
NORMAL_MISMATCH_DEG = 1.0


def _check_normal(points: np.ndarray, normal: np.ndarray, rms: float) -> None:
    """Raise if the points at the solved gamma lie on a plane tilted from
    ``normal``: the sweep moved along the given normal, so no gamma puts the
    points on a plane with it and the solution is only the least bad one."""
    free = fit_plane(points)
    tilt = math.degrees(math.acos(min(1.0, abs(float(np.asarray(free.normal) @ normal)))))
    if tilt > NORMAL_MISMATCH_DEG and rms > 3.0 * free.rms:
        raise CalibrationError(
            f"gamma: the plane-scan points lie on a plane whose normal is {tilt:.1f} deg from the given normal "
            f"{np.round(normal, 6).tolist()} (rms about a plane with the given normal {rms * 1e3:.0f} um, about "
            f"their own best plane {free.rms * 1e3:.1f} um): the sweep moved along the given normal; is it the "
            "scanned face's outward normal, in machine axes?")


def _wrap180(a: float) -> float:
    a = math.fmod(a + 180.0, 360.0)
    a = a + 360.0 if a <= 0 else a
    return a - 180.0


def gamma_from_plane_scan(uv, scales, alpha: float, beta: float, *, normal=None, gamma0: float | None = None,
                          offset=None, maps=None, temperature=None, alpha_beta_covariance=None,
                          step: float = 2.0, temperature_policy: TemperaturePolicy | None = None) -> GammaAlignment:
    """gamma (degrees) from a flat plane scanned while the machine moves.

    With alpha and beta known, every profile is a straight line in the scan
    plane; where it lands in machine coordinates depends on gamma, which
    rotates the profile about w. Two ways to pin it down (docs/calibration.md):

    - the plane's normal is known (``normal``; e.g. the granite table, or a
      face probed with the touch probe): gamma makes every point lie on a plane
      with that normal;
    - the normal is unknown: the points must lie on one plane of any
      orientation. A single straight sweep cannot decide this (the profiles of
      one sweep are translates of one line and lie on a plane for every gamma);
      two sweeps along different axes over the same plane can.

    gamma is found on a grid (``step`` degrees) and refined by Gauss-Newton on
    the joint least-squares problem (gamma and the plane), whose covariance is
    the stated uncertainty.

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Scan-plane coordinates u, v of the points, mm.
    scales : array_like, shape (N, 3)
        Scale readings D, E, F at each point, mm. They must change during the scan.
    alpha, beta : float
        Calibrated alpha and beta, degrees (:func:`alpha_beta_from_vernier`).
    normal : array_like, shape (3,), optional
        The plane's outward normal (pointing towards the scanner), machine axes.
        It also resolves the 180 degree ambiguity: the scanner sees only a face
        whose normal has a positive component along v.
    gamma0 : float, optional
        Nominal gamma, degrees (the trunnion index): the solution is searched
        within +-90 degrees of it. Default: the whole circle. With a normal
        and sweeps along the face, only this can catch an inward normal (the
        scan fits gamma + 180 deg with it equally well: see
        ``GammaAlignment.opposite_rms``).
    offset : MountOffset or sequence of 3 float, optional
        Mount offset l1, mm (default 0). Only the map's rotation R(S) acts on
        it, but R changes along a sweep: with a map give the nominal offset.
    maps : ErrorMap or ErrorMapSet, optional
        Compensate the points with the machine's map (recommended: squareness
        skews the sweep direction otherwise).
    temperature : float or array_like of shape (N,), optional
        Machine temperature, C, for ``maps``.
    alpha_beta_covariance : array_like, shape (2, 2), optional
        Covariance of (alpha, beta), deg^2 (``VernierAlignment.covariance``),
        propagated into the uncertainty.
    step : float
        Grid step of the initial search, degrees.

    temperature_policy : TemperaturePolicy, optional
        Temperatures outside the maps (docs/conventions.md): the default
        raises; ``TemperaturePolicy(out_of_range='clamp')`` holds the edge map.
    Returns
    -------
    GammaAlignment

    Raises
    ------
    InputError
        Fewer than 10 points, mismatched lengths, NaN or inf, bad options.
    CalibrationError
        No motion (all scale readings equal); a scan that does not determine
        gamma (a single straight sweep without ``normal``); no gamma within the
        search window makes the scanner face ``normal``; the points lie on a
        plane more than 1 degree from ``normal`` at the best gamma (the sweep
        moved along it: a wrong normal). One straight sweep cannot tell a
        wrong normal perpendicular to its motion from the right one; sweeps
        along two axes of the face can (any other normal has a component
        along one of them).
    """
    uv = as_rows("uv", uv, 2)
    scales = as_rows("scales", scales, 3)
    if len(uv) != len(scales):
        raise InputError(f"uv and scales: expected the same number of rows, got {len(uv)} and {len(scales)}")
    if len(uv) < MIN_PLANE_POINTS:
        raise InputError(f"uv: a plane scan needs at least {MIN_PLANE_POINTS} points, got {len(uv)}")
    for name, a in (("uv", uv), ("scales", scales)):
        if not np.all(np.isfinite(a)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
            raise InputError(f"{name}: row {bad} is not finite ({a[bad].tolist()})")
    alpha, beta = (float(x) for x in as_triple("alpha, beta", (alpha, beta, 0.0))[:2])
    if not (np.isfinite(step) and 0 < step <= 30):
        raise InputError(f"step: expected a grid step in (0, 30] degrees, got {step}")
    travel = np.ptp(scales, axis=0)
    if travel.max() <= MOTION_FLOOR_MM:
        raise CalibrationError(
            f"gamma: the plane scan has no motion: all {len(scales)} scale readings are equal "
            f"(D, E, F = {scales[0].tolist()} mm). gamma needs the machine to move while the plane is "
            "scanned (thesis section 4.3)")
    _check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = _temperature(temperature, len(uv))
    if normal is not None:
        nv = np.asarray(as_triple("normal", normal))
        if np.linalg.norm(nv) == 0:
            raise InputError("normal: must not be the zero vector")
        nv = nv / np.linalg.norm(nv)
    else:
        nv = None
    l1 = (0.0, 0.0, 0.0) if offset is None else as_triple("offset", offset)
    ab_cov = None if alpha_beta_covariance is None else _covariance("alpha_beta_covariance", alpha_beta_covariance, 2)
    if nv is None:
        w = _e313((alpha, beta, 0.0))[:, 2]
        across = float(np.ptp(scales @ w))
        if across <= 1e-3:
            raise CalibrationError(
                f"gamma: the machine moved only within the scan plane (travel along w {across:.2g} mm): every "
                "point lies in the scan plane whatever gamma is; sweep across it (along w), or give `normal`")
    problem = _PlaneProblem(uv, scales, alpha, beta, nv, l1, maps, temperature, policy)
    # The grid search needs no more than a few thousand points: an even subsample.
    idx = np.unique(np.linspace(0, len(uv) - 1, min(len(uv), 2000)).astype(np.int64))
    t_sub = temperature[idx] if isinstance(temperature, np.ndarray) else temperature
    coarse = _PlaneProblem(uv[idx], scales[idx], alpha, beta, nv, l1, maps, t_sub, policy)

    if gamma0 is None:
        grid = np.arange(-180.0, 180.0, step)
    else:
        g0 = float(gamma0)
        if not np.isfinite(g0):
            raise InputError(f"gamma0: must be finite, got {gamma0}")
        grid = g0 + np.arange(-90.0 + step / 2, 90.0, step)
    if nv is not None:
        e_v = np.array([_e313((alpha, beta, g))[:, 1] for g in grid])  # (grid, 3), not points
        grid = grid[e_v @ nv > 0]
        if len(grid) == 0:
            raise CalibrationError(
                f"gamma: at every gamma within 90 deg of the nominal gamma0 {float(gamma0):g} deg the scanner "
                f"would look at the back of a face whose outward normal is {(np.round(nv, 6) + 0.0).tolist()} (v . normal "
                f"<= 0); is `normal` the outward normal of the scanned face (pointing towards the scanner), or is "
                f"it {(np.round(-nv, 6) + 0.0).tolist()}?"
                if gamma0 is not None else
                "gamma: no gamma turns the scanner towards the plane; is `normal` the outward normal of the "
                "scanned face (pointing towards the scanner)?")
    costs = np.array([coarse.cost(g) for g in grid])  # one kernel call per candidate
    start = float(grid[int(np.argmin(costs))])
    gamma, var, rms, n_fit, iterations = _solve_gamma(problem, start)
    opposite_rms = None
    if nv is not None:
        _check_normal(problem.points(gamma), nv, rms)
        opposite_rms = _PlaneProblem(uv, scales, alpha, beta, -nv, l1, maps, temperature, policy).cost(gamma + 180.0)
    if nv is None and abs(float(np.asarray(n_fit) @ _e313((alpha, beta, gamma))[:, 2])) > 0.95:
        # The best "plane" is the scan plane itself: the motion hardly left it, so every gamma fits.
        raise CalibrationError(
            "gamma: the points lie in the scan plane (the machine hardly moved across it, along w), so every "
            "gamma fits them; sweep across the scan plane, or give `normal`")

    # Sensitivities to alpha and beta (numerical): the solution moved by one
    # Gauss-Newton step (exact to second order) for alpha, beta +- h.
    h = 0.01
    sens = np.zeros(2)
    for j in range(2):  # two angles
        sol = []
        for sgn in (1.0, -1.0):
            d = np.array([alpha, beta])
            d[j] += sgn * h
            p = _PlaneProblem(uv, scales, d[0], d[1], nv, l1, maps, temperature, policy)
            sol.append(gamma + p.step(gamma)[0])
        sens[j] = (sol[0] - sol[1]) / (2 * h)
    noise_u = math.degrees(math.sqrt(var))
    total_var = noise_u**2 + (float(sens @ ab_cov @ sens) if ab_cov is not None else 0.0)
    n_out = np.asarray(n_fit, dtype=float)
    if n_out @ _e313((alpha, beta, gamma))[:, 1] < 0:
        n_out = -n_out
    return GammaAlignment(gamma=_wrap180(gamma), uncertainty=math.sqrt(total_var), noise_uncertainty=noise_u,
                          sensitivity=sens, alpha=alpha, beta=beta, normal=n_out, rms=rms, n_points=len(uv),
                          method="fitted plane" if nv is None else "known normal", iterations=iterations,
                          opposite_rms=opposite_rms)


# ---------------------------------------------------------------------------
# the pose with its covariance
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibratedPose:
    """A calibrated pose and its covariance.

    Attributes
    ----------
    pose : Pose
        alpha, beta, gamma in degrees.
    covariance : ndarray (3, 3)
        Covariance of (alpha, beta, gamma), deg^2.
    """

    pose: Pose
    covariance: np.ndarray

    @property
    def uncertainty(self) -> np.ndarray:
        """Standard uncertainties of alpha, beta, gamma, degrees."""
        return np.sqrt(np.diag(self.covariance))


def calibrated_pose(vernier: VernierAlignment, gamma: GammaAlignment) -> CalibratedPose:
    """Combine alpha, beta (vernier) and gamma (plane scan) into one pose with its
    full covariance (deg^2): gamma depends on alpha and beta through its
    ``sensitivity``, so cov(gamma, alpha/beta) = s . cov(alpha, beta).

    Raises
    ------
    InputError
        ``gamma`` was solved with other alpha, beta than ``vernier`` gives.
    """
    if not isinstance(vernier, VernierAlignment) or not isinstance(gamma, GammaAlignment):
        raise InputError("calibrated_pose: expected a VernierAlignment and a GammaAlignment")
    if abs(vernier.alpha - gamma.alpha) > 1e-9 or abs(vernier.beta - gamma.beta) > 1e-9:
        raise InputError(
            f"gamma was solved with alpha, beta = {gamma.alpha:g}, {gamma.beta:g} deg, the vernier gives "
            f"{vernier.alpha:g}, {vernier.beta:g} deg: solve gamma with the vernier's angles")
    j = np.array([[1.0, 0.0], [0.0, 1.0], list(gamma.sensitivity)])
    cov = j @ vernier.covariance @ j.T
    cov[2, 2] += gamma.noise_uncertainty**2
    return CalibratedPose(Pose(vernier.alpha, vernier.beta, gamma.gamma), cov)


# ---------------------------------------------------------------------------
# 3. D0, E0, F0 from a reference-sphere scan (section 4.4, eq. 14)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ReferenceReading:
    """One alignment: the scale reading at which the laser origin sits at the
    reference-sphere centre.

    Attributes
    ----------
    pose : tuple of 3 float
        (alpha, beta, gamma), degrees.
    reading : ndarray (3,)
        D0, E0, F0, mm (thesis section 4.4; D_k, E_k, F_k of section 5.3).
    covariance : ndarray (3, 3)
        Total covariance of ``reading``, mm^2: the sphere fit's (the
        heteroscedasticity-consistent sandwich estimate from its Jacobian and
        residuals), any stated extra terms, and the pose's uncertainty propagated.
    fit_covariance : ndarray (3, 3)
        The same without the pose term, mm^2.
    pose_covariance : ndarray (3, 3)
        Covariance of the pose angles the scan was processed with, deg^2.
    pose_jacobian : ndarray (3, 3)
        d position / d (alpha, beta, gamma), mm/deg (numerical; the same as
        d reading / d pose to first order in the map's angles).
    position : ndarray (3,)
        The centre c_Y of the sphere fitted to the points taken with l1 = 0,
        mm: the mount point's position (S + e(S)) when the laser origin is at
        the sphere centre, up to R. Equal to ``reading`` without a map.
    lever : ndarray (3, 3)
        d centre / d(-l1): the sphere centre is ``position - lever @ l1``.
        E313 without a map, about R(S) E313 with one.
    centre : ndarray (3,) or None
        The sphere centre in machine coordinates, mm (given an offset).
    fit : SphereFit or None
        The sphere fit (machine coordinates for l1 = 0, mm).
    temperature : float or None
        Mean machine temperature, C.
    """

    pose: tuple
    reading: np.ndarray
    covariance: np.ndarray
    fit_covariance: np.ndarray
    pose_covariance: np.ndarray
    pose_jacobian: np.ndarray
    position: np.ndarray
    lever: np.ndarray
    centre: np.ndarray | None = None
    fit: SphereFit | None = None
    temperature: float | None = None

    @property
    def uncertainty(self) -> np.ndarray:
        """Standard uncertainties of D0, E0, F0, mm."""
        return np.sqrt(np.diag(self.covariance))

    @classmethod
    def from_reading(cls, pose, reading, uncertainty=None, *, covariance=None, pose_covariance=None,
                     temperature: float | None = None) -> ReferenceReading:
        """An alignment measured elsewhere (e.g. by the scanner's own software).

        Parameters
        ----------
        pose : Pose or sequence of 3 float
            Degrees.
        reading : array_like, shape (3,)
            D0, E0, F0, mm.
        uncertainty : float or array_like of shape (3,), optional
            Standard uncertainties of D0, E0, F0, mm (uncorrelated).
        covariance : array_like, shape (3, 3), optional
            Instead of ``uncertainty``: the full covariance, mm^2.
        pose_covariance : array_like, shape (3, 3), optional
            Covariance of the pose, deg^2 (acts through the lever E313 l1 only:
            the reading's own dependence on the pose is unknown here).
        temperature : float, optional
            C.
        """
        p = pose_tuple(pose)
        s = np.asarray(as_triple("reading", reading))
        if covariance is not None and uncertainty is not None:
            raise InputError("give uncertainty or covariance, not both")
        if covariance is not None:
            cov = _covariance("covariance", covariance, 3)
        elif uncertainty is not None:
            cov = np.diag(_uncertainty_triple("uncertainty", uncertainty) ** 2)
        else:
            raise InputError("reading: state its uncertainty (mm) or covariance (mm^2)")
        pc = np.zeros((3, 3)) if pose_covariance is None else _covariance("pose_covariance", pose_covariance, 3)
        return cls(pose=p, reading=s, covariance=cov, fit_covariance=cov.copy(), pose_covariance=pc,
                   pose_jacobian=np.zeros((3, 3)), position=s.copy(), lever=_e313(p),
                   temperature=None if temperature is None else float(temperature))


def _sandwich_centre_covariance(points: np.ndarray, fit: SphereFit, fixed_radius: bool) -> np.ndarray:
    """Covariance of the fitted centre (mm^2, 3 x 3), heteroscedasticity-consistent:
    (J^T J)^-1 (sum r_i^2 J_i^T J_i) (J^T J)^-1 N / (N - p), J_i the gradient of
    point i's residual. The scanner's noise is along v, not the surface normal,
    so the normal residuals' variance changes over the cap and s^2 (J^T J)^-1
    overstates the centre's scatter (by about 20 % on a reference-sphere cap)."""
    keep = np.asarray(fit.inlier, dtype=bool)
    d = points[keep] - fit.centre
    n = d / np.linalg.norm(d, axis=1)[:, None]
    jac = -n if fixed_radius else np.column_stack([-n, -np.ones(len(n))])
    r = np.asarray(fit.residuals)[keep]
    a = np.linalg.inv(jac.T @ jac)
    meat = (jac * (r**2)[:, None]).T @ jac
    m, k = jac.shape
    return (a @ meat @ a)[:3, :3] * (m / max(m - k, 1))


def reference_centre_reading(uv, scales, pose, offset=None, maps=None, temperature=None, *,
                             pose_covariance=None, reading_uncertainty=None, radius: float | None = None,
                             reject: float | None = None,
                             temperature_policy: TemperaturePolicy | None = None) -> ReferenceReading:
    """D0, E0, F0: the scale reading at which the laser origin sits at the
    reference-sphere centre (thesis section 4.4, eq. 14; the D_k, E_k, F_k of
    eqs. 16-18).

    The laser origin at reading S is L(S) = S + e(S) - R(S) E313 l1 and the
    points are X = L(S) + R(S) E313 (u, v, 0). The sphere is fitted to the
    points taken with l1 = 0, Y = S + e(S) + R(S) E313 (u, v, 0); its centre
    c_Y is linear in l1: the true centre is c = c_Y - lever l1, with
    ``lever`` = d c / d(-l1) found by refitting (R(S) E313 as the fit
    averages it; E313 exactly without a map). The reading is the S with
    L(S) = c (fixed-point iteration). Without a map, e = 0 and R = I: S = c_Y
    exactly, whatever l1, and S = c + E313 l1 gives eqs. 16-18 for the three
    standard poses. With a map but no ``offset``, S solves S + e(S) = c_Y,
    off by (R(S) E313 - lever) l1: the change of R between the scan and S,
    below 0.5 um with the thesis maps; give ``offset`` for the exact reading.
    The mount-offset solvers use ``position`` (= c_Y) and ``lever``, which
    need no offset.

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Scan-plane coordinates of the sphere points, mm.
    scales : array_like, shape (N, 3)
        Scale readings D, E, F at each point, mm.
    pose : Pose or sequence of 3 float
        Calibrated pose (alpha, beta, gamma), degrees.
    offset : MountOffset or sequence of 3 float, optional
        Mount offset l1, mm: to report the sphere ``centre`` and, with a map,
        the exact reading (see above). Not needed for :func:`mount_offset`.
    maps : ErrorMap or ErrorMapSet, optional
        The machine's map: compensate the scan (recommended).
    temperature : float or array_like of shape (N,), optional
        Machine temperature, C, for ``maps``.
    pose_covariance : array_like, shape (3, 3), optional
        Covariance of the pose, deg^2 (``CalibratedPose.covariance``),
        propagated into ``covariance`` through the numerical ``pose_jacobian``.
    reading_uncertainty : float or array_like of shape (3,), optional
        Further standard uncertainties of D0, E0, F0, mm, added in quadrature
        (e.g. scale error over the range, thesis section 5.3).
    radius : float, optional
        Known sphere radius, mm (fit only the centre).
    reject : float, optional
        Robust fit threshold, as in :func:`cmmpose.fit_sphere`.

    temperature_policy : TemperaturePolicy, optional
        Temperatures outside the maps (docs/conventions.md): the default
        raises; ``TemperaturePolicy(out_of_range='clamp')`` holds the edge map.
    Returns
    -------
    ReferenceReading

    Raises
    ------
    InputError
        Mismatched lengths, NaN or inf, fewer than 4 points, bad options.
    GeometryError
        Points that do not determine a sphere.
    """
    uv = as_rows("uv", uv, 2)
    scales = as_rows("scales", scales, 3)
    if len(uv) != len(scales):
        raise InputError(f"uv and scales: expected the same number of rows, got {len(uv)} and {len(scales)}")
    if len(uv) < 4:
        raise InputError(f"uv: a sphere needs at least 4 points, got {len(uv)}")
    _check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = _temperature(temperature, len(uv))
    p = pose_tuple(pose)
    pc = np.zeros((3, 3)) if pose_covariance is None else _covariance("pose_covariance", pose_covariance, 3)
    extra = None if reading_uncertainty is None else _uncertainty_triple("reading_uncertainty", reading_uncertainty)
    zero = (0.0, 0.0, 0.0)

    def centre_of(angles, l1=zero):
        y = _machine_points(uv, scales, angles, l1, maps, temperature, policy)
        return fit_sphere(y, radius, reject=reject)

    fit = centre_of(p)
    c_y = np.asarray(fit.centre, dtype=float)
    e313 = _e313(p)
    l1 = None if offset is None else np.asarray(as_triple("offset", offset))
    if maps is None:
        # Error-free model: the points for l1 are those for 0 moved by -E313 l1.
        reading, position, lever = c_y.copy(), c_y.copy(), e313
        t_mean = None
    else:
        m = _single_map(maps, temperature, policy)
        # lever = d centre / d(-l1): R(S) E313 averaged the way the fit averages
        # the scan's points (numerical; the centre is linear in l1).
        big = 100.0
        lever = np.column_stack([(c_y - np.asarray(centre_of(p, tuple(big * np.eye(3)[j])).centre)) / big
                                 for j in range(3)])  # three directions
        position = c_y
        # The reading S at which the laser origin S + e(S) - R(S) E313 l1 is at the
        # centre c = c_Y - lever l1 (fixed point; e and R change by ppm per mm).
        if l1 is None:
            target, s = c_y, c_y.copy()
        else:
            target = c_y - lever @ l1
            s = target + e313 @ l1
        for _ in range(20):
            s_new = target - m.position_error(s[None, :])[0]
            if l1 is not None:
                s_new = s_new + m.rotation_error(s[None, :])[0] @ e313 @ l1
            done = np.abs(s_new - s).max() < 1e-12
            s = s_new
            if done:
                break
        reading = s
        t_mean = float(np.mean(temperature)) if temperature is not None else m.temperature
    # d reading / d pose, numerical (central differences, 0.01 deg).
    h = 0.01
    jac = np.empty((3, 3))
    for j in range(3):  # three angles
        d = np.zeros(3)
        d[j] = h
        plus = np.asarray(centre_of(tuple(np.add(p, d))).centre)
        minus = np.asarray(centre_of(tuple(np.subtract(p, d))).centre)
        jac[:, j] = (plus - minus) / (2 * h)
    fit_cov = _sandwich_centre_covariance(_machine_points(uv, scales, p, zero, maps, temperature, policy), fit,
                                          radius is not None)
    if extra is not None:
        fit_cov = fit_cov + np.diag(extra**2)
    cov = fit_cov + jac @ pc @ jac.T
    centre = None if l1 is None else position - lever @ l1
    return ReferenceReading(pose=p, reading=reading, covariance=cov, fit_covariance=fit_cov, pose_covariance=pc,
                            pose_jacobian=jac, position=position, lever=lever, centre=centre, fit=fit,
                            temperature=t_mean)


# ---------------------------------------------------------------------------
# 4. the mount offset U1, V1, W1 (section 5.3, eqs. 16-21)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class MountOffsetFit:
    """U1, V1, W1 and the sphere centre from K alignments by generalised least squares.

    Attributes
    ----------
    offset : MountOffset
        U1, V1, W1, mm.
    covariance : ndarray (3, 3)
        Covariance of U1, V1, W1, mm^2 (from the stated reading and pose
        covariances: the GUM law of propagation, exact for this linear model).
    centre : ndarray (3,)
        The reference-sphere centre in machine coordinates, mm (the D0, E0, F0
        of eqs. 16-18).
    centre_covariance : ndarray (3, 3)
        mm^2.
    full_covariance : ndarray (6, 6)
        Of (centre, U1, V1, W1), mm^2.
    residuals : ndarray (K, 3)
        Reading minus model per alignment, mm: how far the alignments disagree.
    standardised_residuals : ndarray (K, 3)
        Each residual divided by its own standard deviation under the stated
        uncertainties (the diagonal of C - A cov A^T), 1; nan where that is
        zero (a component the fit reproduces exactly).
    chi2 : float
        Sum of the squared residuals whitened by each alignment's covariance.
    dof : int
        3 K - 6.
    p_value : float
        P(chi^2_dof > chi2): small when the alignments disagree more than
        their stated uncertainties allow (1 when dof = 0).
    contributions : ndarray (K, 3)
        Each alignment's share of the standard uncertainty of U1, V1, W1, mm
        (root-sum-square over alignments gives the uncertainty).
    poses : tuple
        The K poses, degrees.
    """

    offset: MountOffset
    covariance: np.ndarray
    centre: np.ndarray
    centre_covariance: np.ndarray
    full_covariance: np.ndarray
    residuals: np.ndarray
    standardised_residuals: np.ndarray
    chi2: float
    dof: int
    p_value: float
    contributions: np.ndarray
    poses: tuple

    @property
    def uncertainty(self) -> np.ndarray:
        """Standard uncertainties of U1, V1, W1, mm."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def birge_ratio(self) -> float:
        """sqrt(chi2 / dof) (nan for dof = 0): about 1 when the stated uncertainties fit the scatter."""
        return math.sqrt(self.chi2 / self.dof) if self.dof > 0 else float("nan")


def _as_alignments(alignments) -> list[ReferenceReading]:
    try:
        items = list(alignments)
    except TypeError:
        raise InputError("alignments: expected a sequence of ReferenceReading") from None
    for k, a in enumerate(items):
        if not isinstance(a, ReferenceReading):
            raise InputTypeError(f"alignments[{k}]: expected a ReferenceReading, got {type(a).__name__} "
                             "(use ReferenceReading.from_reading for readings measured elsewhere)")
    return items


#: Largest noise amplification of the mount offset accepted: the standard
#: uncertainty of U1, V1 or W1 per unit (uncorrelated) uncertainty of the
#: readings, sqrt of the largest diagonal entry of (A^T A)^-1 for the
#: unweighted design A (columns: identity for the centre, the levers ~ E313
#: for l1; dimensionless). The thesis's three poses give 0.93; two poses never
#: determine l1 (the part along their relative rotation axis trades off
#: against the centre along it; the map's rotations leave only ~1e-7 of the
#: design to tell them, amplification ~1e6). At 100, readings good to 10 um
#: would give an offset good to no better than 1 mm: not a calibration.
MAX_OFFSET_AMPLIFICATION = 100.0


def _check_offset_design(a_flat: np.ndarray, items: list[ReferenceReading]) -> None:
    """Raise ``GeometryError`` naming the undetermined part of l1 when the
    poses' design amplifies the readings' noise beyond MAX_OFFSET_AMPLIFICATION."""
    _, sv, vt = np.linalg.svd(a_flat, full_matrices=False)
    with np.errstate(divide="ignore"):
        inv2 = np.where(sv > 1e-300, 1.0 / sv**2, np.inf)
    amp = float(np.sqrt(np.max((vt[:, 3:] ** 2 * inv2[:, None]).sum(axis=0))))
    if amp <= MAX_OFFSET_AMPLIFICATION:
        return
    k = len(items)
    poses = ", ".join(_pose_name(a.pose) for a in items)
    free = int(np.sum(sv < 1.0 / MAX_OFFSET_AMPLIFICATION))
    u_read = float(np.median([np.sqrt(np.max(np.diag(a.fit_covariance))) for a in items]))
    size = ("the uncertainty of U1, V1, W1 would have no practical bound" if amp > 1e8 else
            f"U1, V1, W1 would be uncertain by up to {amp:.3g} times the readings' uncertainty"
            + (f", about {amp * u_read:.3g} mm" if u_read > 0 else ""))
    if free == 1:
        null = vt[-1]
        a_dir = null[3:] / max(float(np.linalg.norm(null[3:])), 1e-300)
        m_dir = null[:3] / max(float(np.linalg.norm(null[:3])), 1e-300)
        big = int(np.argmax(np.abs(a_dir)))
        what = (("U1", "V1", "W1")[big] if abs(a_dir[big]) > 0.95 else
                f"the part of (U1, V1, W1) along {(np.round(a_dir, 3) + 0.0).tolist()}")
        raise GeometryError(
            f"alignments: the {k} poses {poses} do not determine the mount offset: {what} is not determined. "
            f"The poses are all turned from each other about one machine axis, "
            f"{(np.round(np.sign(m_dir[np.argmax(np.abs(m_dir))]) * m_dir, 3) + 0.0).tolist()}, and the offset along it "
            f"trades off against the sphere centre along it ({size}); add an alignment turned about another "
            "machine axis, as the thesis's three (W along X at gamma 0 and 90 turn about X, W along Y turns about "
            "Z)")
    raise GeometryError(
        f"alignments: the {k} poses {poses} do not determine the mount offset: {free} combinations of U1, V1, "
        f"W1 and the sphere centre are not determined, the poses hardly turn the scanner relative to each other "
        f"({size}); align at poses turned about two different machine axes, as the thesis's three (W along X at "
        "gamma 0 and 90, W along Y)")


def mount_offset(alignments, *, tolerance: float | None = 4.0, max_residual: float | None = None,
                 significance: float | None = None, pose_uncertainty: bool = True) -> MountOffsetFit:
    """U1, V1, W1 from two or more alignments by generalised least squares.

    Each alignment k at pose k gives the position of the mount point when the
    laser origin sits at the sphere centre c: ``position_k = c + lever_k l1``
    (without a map: D_k = c + E313_k l1, eqs. 16-18). The unknowns c (3) and
    l1 (3) are common to all; with K alignments there are 3 K equations and
    3 K - 6 degrees of freedom (three for the thesis's three alignments,
    whose closed form eqs. 19-21 uses six of the nine equations). Each
    alignment is weighted by its covariance: the fit's, and the pose's acting
    on both the reading and the lever (``d(position - lever l1)/d pose``,
    evaluated at the solution, iterated).

    Parameters
    ----------
    alignments : sequence of ReferenceReading
        From :func:`reference_centre_reading` or ``ReferenceReading.from_reading``.
    tolerance : float or None
        Largest acceptable standardised residual (a residual component in
        units of its own standard deviation under the stated uncertainties).
        Alignments that disagree by more raise ``CalibrationError``. None: no limit.
    max_residual : float or None
        Also raise when a residual component exceeds this many mm. None: no limit.
    significance : float or None
        Also raise when the chi-square test rejects consistency at this level
        (e.g. 0.001). None: report only.
    pose_uncertainty : bool
        Include the alignments' pose covariances (default). False: readings only.

    Returns
    -------
    MountOffsetFit

    Raises
    ------
    InputError
        Fewer than 2 alignments, bad items or options.
    GeometryError
        Poses that do not determine l1: any two poses (the part of l1 along
        their relative rotation axis is free), all poses turned about one
        machine axis, or a design that amplifies the readings' uncertainty
        more than ``MAX_OFFSET_AMPLIFICATION`` times; the message names the
        free component and the axis.
    CalibrationError
        Alignments that disagree beyond ``tolerance`` (or ``max_residual``,
        ``significance``);
        a covariance that is not positive definite.
    """
    items = _as_alignments(alignments)
    k = len(items)
    if k < 2:
        raise InputError(f"alignments: the mount offset needs at least 2 alignments (3 to check them), got {k}")
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"tolerance: must be a positive number of standard deviations or None, got {tolerance}")
    if max_residual is not None and not (np.isfinite(max_residual) and max_residual > 0):
        raise InputError(f"max_residual: must be a positive length in mm or None, got {max_residual}")
    if significance is not None and not (0 < significance < 1):
        raise InputError(f"significance: must be in (0, 1) or None, got {significance}")
    y = np.stack([a.position for a in items])  # (K, 3)
    lev = np.stack([a.lever for a in items])  # (K, 3, 3)
    c_fit = np.stack([a.fit_covariance for a in items])
    p_cov = np.stack([a.pose_covariance for a in items])
    jac_s = np.stack([a.pose_jacobian for a in items])  # (K, 3, 3) mm/deg
    d_e = np.stack([_e313_derivatives(a.pose) for a in items])  # (K, angle, 3, 3)
    rot = lev @ np.linalg.inv(np.stack([_e313(a.pose) for a in items]))  # R_k (identity without a map)
    a_mat = np.concatenate([np.broadcast_to(np.eye(3), (k, 3, 3)), lev], axis=2)  # (K, 3, 6)
    _check_offset_design(a_mat.reshape(3 * k, 6), items)

    l1 = np.zeros(3)
    use_pose = pose_uncertainty and np.any(p_cov != 0)
    for _ in range(4 if use_pose else 1):  # the pose term depends on l1: iterate
        cov_k = c_fit.copy()
        if use_pose:
            d_lever = np.einsum("kij,kajb,b->kia", rot, d_e, l1)  # d(lever l1)/d angle, (K, 3, 3)
            g = jac_s - d_lever
            cov_k = cov_k + g @ p_cov @ np.transpose(g, (0, 2, 1))
        try:
            chol = np.linalg.cholesky(cov_k)
        except np.linalg.LinAlgError:
            bad = [j for j in range(k) if np.linalg.eigvalsh(cov_k[j]).min() <= 0]
            raise CalibrationError(
                f"alignments {bad}: reading covariance is not positive definite; state the readings' "
                "uncertainties (mm)") from None
        aw = np.linalg.solve(chol, a_mat).reshape(3 * k, 6)
        yw = np.linalg.solve(chol, y[:, :, None]).reshape(3 * k)
        u, sv, vt = np.linalg.svd(aw, full_matrices=False)
        if sv[-1] <= 1e-10 * sv[0]:
            null = vt[-1, 3:]
            raise GeometryError(
                f"alignments: the {k} poses {', '.join(_pose_name(a.pose) for a in items)} do not determine the "
                f"mount offset (U1, V1, W1 along {np.round(null / max(np.linalg.norm(null), 1e-300), 3).tolist()} "
                "is free); add an alignment with W along another machine axis, as the thesis's three "
                "(W along X at gamma 0 and 90, W along Y)")
        x = vt.T @ ((u.T @ yw) / sv)
        cov_x = (vt.T / sv**2) @ vt
        l1 = x[3:]
    gain = cov_x @ aw.T  # (6, 3K): x = gain @ yw, whitened inputs have unit covariance
    contrib = np.sqrt((gain[3:].reshape(3, k, 3) ** 2).sum(axis=2)).T  # (K, 3)
    model = np.einsum("kij,j->ki", a_mat, x)
    resid = y - model
    white = np.linalg.solve(chol, resid[:, :, None])[:, :, 0]
    chi2 = float((white**2).sum())
    dof = 3 * k - 6
    p_val = _chi2_sf(chi2, dof)
    # Residual covariance C - A cov_x A^T (per component: its diagonal).
    a_flat = a_mat.reshape(3 * k, 6)
    var_r = np.einsum("kii->ki", cov_k).reshape(3 * k) - np.einsum("ij,jk,ik->i", a_flat, cov_x, a_flat)
    floor = 1e-12 * max(float(np.max(np.einsum("kii->ki", cov_k))), 1e-300)
    sd_r = np.where(var_r > floor, np.sqrt(np.clip(var_r, 0.0, None)), np.nan).reshape(k, 3)
    std_res = resid / sd_r
    result = MountOffsetFit(
        offset=MountOffset(*(float(v) for v in x[3:])), covariance=cov_x[3:, 3:].copy(), centre=x[:3].copy(),
        centre_covariance=cov_x[:3, :3].copy(), full_covariance=cov_x, residuals=resid,
        standardised_residuals=std_res, chi2=chi2, dof=dof, p_value=p_val, contributions=contrib,
        poses=tuple(a.pose for a in items))
    score = np.nan_to_num(np.abs(std_res), nan=0.0)
    worst = np.unravel_index(int(np.argmax(score)), score.shape)
    worst_mm = np.unravel_index(int(np.argmax(np.abs(resid))), resid.shape)
    too_many_sd = tolerance is not None and score[worst] > tolerance
    too_far = max_residual is not None and abs(resid[worst_mm]) > max_residual
    rejected = significance is not None and dof > 0 and p_val < significance
    if too_many_sd or too_far or rejected:
        bad = worst if too_many_sd or not too_far else worst_mm
        why = (f"alignment {bad[0]} at pose {_pose_name(items[bad[0]].pose)} is off by "
               f"{np.round(resid[bad[0]] * 1000, 1).tolist()} um in D, E, F "
               f"({np.round(std_res[bad[0]], 1).tolist()} standard deviations)")
        limit = (f"more than the tolerance of {tolerance:g} standard deviations" if too_many_sd else
                 f"more than max_residual {max_residual:g} mm" if too_far else
                 f"the chi-square test rejects them at significance {significance:g}")
        raise CalibrationError(
            f"alignments disagree: {why}, {limit} (chi-square {chi2:.4g} for {dof} degrees of freedom, "
            f"p = {p_val:.3g}, against the stated uncertainties). Check that the trunnion was seated, the "
            "sphere did not move and each pose is right, that the readings were compensated with the "
            "machine's error map (uncompensated, its errors alone make alignments disagree by up to ~0.1 mm), "
            "or raise tolerance")
    return result


@dataclass(frozen=True)
class ClosedFormOffset:
    """U1, V1, W1 by the thesis's closed form (eqs. 19, 20 and 21 corrected).

    Attributes
    ----------
    offset : MountOffset
        U1, V1, W1, mm.
    centre : ndarray (3,)
        The sphere centre D0, E0, F0 of eq. 16, mm.
    covariance : ndarray (3, 3) or None
        Covariance of U1, V1, W1, mm^2 (GUM eq. 13 with the readings'
        covariances; None when none were stated). The poses count as exact.
    checks : dict
        The three redundancies of the nine equations, mm (zero for consistent
        alignments): ``"D1 - D2"``, ``"F1 - F3"`` (thesis: "by inspection") and
        ``"W1(D) - W1(E)"``, the W1 of eqs. 16/18 in D minus that in E
        (E3 - E1 + U1).
    budget : dict or None
        Per output ``"U1"``, ``"V1"``, ``"W1"``: a list of
        ``(reading, sensitivity, u(reading) mm, |c u| mm)`` (GUM eq. 10, the
        form of eqs. 22-24).
    """

    offset: MountOffset
    centre: np.ndarray
    covariance: np.ndarray | None
    checks: dict
    budget: dict | None

    @property
    def uncertainty(self) -> np.ndarray | None:
        """Standard uncertainties of U1, V1, W1, mm (None if not stated)."""
        return None if self.covariance is None else np.sqrt(np.diag(self.covariance))


#: Sensitivities of (U1, V1, W1) to (D1, E1, F1, D2, E2, F2, D3, E3, F3): eqs. 19, 20
#: and W1 = D1 - D3 - U1 (eq. 21 corrected, docs/conventions.md, Misprints).
_CLOSED_FORM = np.array([
    [0.0, 0.5, -0.5, 0.0, -0.5, 0.5, 0.0, 0.0, 0.0],
    [0.0, 0.5, 0.5, 0.0, -0.5, -0.5, 0.0, 0.0, 0.0],
    [1.0, -0.5, 0.5, 0.0, 0.5, -0.5, -1.0, 0.0, 0.0],
])
_READING_NAMES = ("D1", "E1", "F1", "D2", "E2", "F2", "D3", "E3", "F3")


def mount_offset_closed_form(s1, s2, s3, *, uncertainties=None, pose_tolerance: float = 0.001) -> ClosedFormOffset:
    """U1, V1, W1 from the thesis's three standard alignments (section 5.3).

    U1 = (E1 - E2 + F2 - F1) / 2 (eq. 19), V1 = (E1 - E2 + F1 - F2) / 2
    (eq. 20), W1 = D1 - D3 - U1 (eq. 21 as printed, (D1 + 2 D3 - E2 + F2 -
    F1) / 2, is a misprint: docs/conventions.md, Misprints). The uncertainty is
    the GUM law of propagation (eqs. 22-24 generalised to correlated readings).

    Parameters
    ----------
    s1, s2, s3 : ReferenceReading or array_like of shape (3,)
        Readings D, E, F (mm) at alignments 1 (W along X, gamma 0: pose
        (90, 90, 0)), 2 (W along X, gamma 90: (90, 90, 90)) and 3 (W along Y,
        gamma 0: (180, 90, 0)). ReferenceReadings bring their covariance and
        must be at those poses; of a compensated one its ``position``
        S + e(S) is used (the map's rotation of the lever, R(S), is ignored as
        in the thesis: micrometres; :func:`mount_offset` includes it).
    uncertainties : array_like, shape (3,) or (3, 3), optional
        Standard uncertainties of D, E, F (mm), the same for all three readings
        or one row per reading; overrides the ReferenceReadings' covariances.
    pose_tolerance : float
        Largest difference between a ReferenceReading's pose and the standard
        pose, degrees. The closed form holds for the standard poses exactly: a
        pose off by d degrees moves the result by about d pi/180 x 300 mm
        (0.001 deg: 5 um; 0.03 deg: 0.16 mm). For calibrated poses use
        :func:`mount_offset`, which uses each alignment's own pose.

    Returns
    -------
    ClosedFormOffset
    """
    readings, covs = [], []
    for k, (s, std) in enumerate(zip((s1, s2, s3), STANDARD_POSES), start=1):
        if isinstance(s, ReferenceReading):
            dev = np.abs((np.asarray(s.pose) - np.asarray(std) + 180.0) % 360.0 - 180.0).max()
            if dev > pose_tolerance:
                raise InputError(f"s{k}: the closed form needs alignment {k} at pose {_pose_name(std)} (within "
                                 f"{pose_tolerance:g} deg), got {_pose_name(s.pose)}; use mount_offset() for "
                                 "calibrated or other poses")
            readings.append(np.asarray(s.position, dtype=float))
            covs.append(s.covariance)
        else:
            readings.append(np.asarray(as_triple(f"s{k}", s)))
            covs.append(None)
    y = np.concatenate(readings)
    if uncertainties is not None:
        u = np.asarray(uncertainties, dtype=float)
        if u.shape == (3,):
            u = np.tile(u, (3, 1))
        if u.shape != (3, 3) or not np.all(np.isfinite(u)) or np.any(u < 0):
            raise InputError("uncertainties: expected (3,) or (3, 3) standard uncertainties >= 0 (mm), "
                             f"got shape {u.shape}")
        covs = [np.diag(row**2) for row in u]
    x = _CLOSED_FORM @ y
    d1, e1, f1, d2, e2, f2, d3, e3, f3 = y
    centre = np.array([d1 - x[2], e1 - x[0], f1 - x[1]])  # eq. 16
    checks = {"D1 - D2": d1 - d2, "F1 - F3": f1 - f3, "W1(D) - W1(E)": x[2] - (e3 - e1 + x[0])}
    if any(c is None for c in covs):
        cov, budget = None, None
    else:
        big = np.zeros((9, 9))
        for k, c in enumerate(covs):
            big[3 * k:3 * k + 3, 3 * k:3 * k + 3] = c
        cov = _CLOSED_FORM @ big @ _CLOSED_FORM.T
        u_in = np.sqrt(np.diag(big))
        budget = {
            name: [(_READING_NAMES[j], float(_CLOSED_FORM[i, j]), float(u_in[j]),
                    float(abs(_CLOSED_FORM[i, j]) * u_in[j])) for j in range(9) if _CLOSED_FORM[i, j] != 0]
            for i, name in enumerate(("U1", "V1", "W1"))
        }
    return ClosedFormOffset(offset=MountOffset(*(float(v) for v in x)), centre=centre, covariance=cov,
                            checks=checks, budget=budget)
