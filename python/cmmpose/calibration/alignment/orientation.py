"""The scanner's orientation on the mount: alpha, beta and gamma (thesis chapter 4).

- :func:`alpha_beta_from_vernier`: alpha, beta from optical-vernier points on
  the scan plane (eqs. 5-6, quadrant-safe form of docs/conventions.md, Frames);
- :func:`gamma_from_plane_scan`: gamma from a flat plane scanned while the
  machine moves (section 4.3: "scanning a planar surface while moving the CMM,
  and fitting the data");
- :func:`calibrated_pose`: the two combined into one pose with its 3 x 3
  covariance.

Units: mm for lengths, degrees for angles (radians only inside), degrees C
for temperatures; covariances in the square of those units (docs/calibration.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..._arrays import as_rows, as_triple
from ...compensation import compensate
from ...errors import CalibrationError, GeometryError, InputError
from ...fitting import PlaneFit, fit_plane
from ...pose import Pose
from ...temperature import TemperaturePolicy, as_policy
from .common import as_covariance, as_temperature, check_map, e313_matrix, machine_points, single_map


_DEG = math.pi / 180.0
#: Fewest points accepted for a plane scan.
MIN_PLANE_POINTS = 10
#: Scale readings that differ by less than this (mm) count as no motion.
MOTION_FLOOR_MM = 1e-6


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


def _w_side(n: np.ndarray, centred: np.ndarray, sv: np.ndarray, w_hint) -> float:
    """+1 or -1: the sign that turns the fitted plane normal ``n`` towards +w, from ``w_hint`` or else from
    the order of the (centred) vernier points (counter-clockwise seen from +w)."""
    if w_hint is not None:
        hint = np.asarray(as_triple("w_hint", w_hint))
        s = float(n @ hint)
        if np.linalg.norm(hint) == 0 or abs(s) < 0.1 * np.linalg.norm(hint):
            raise InputError(f"w_hint: {hint.tolist()} lies (within 6 degrees) in the scan plane; it cannot tell "
                             "the +w side")
        return 1.0 if s > 0 else -1.0
    # Newell's vector area of the polygon p0 -> p1 -> ... -> p0: along +w for counter-clockwise points.
    area = 0.5 * np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)
    s = float(n @ area)
    if abs(s) <= 1e-3 * sv[0] * sv[1] / len(centred):
        raise GeometryError(
            "points: their order does not tell which side of the scan plane +w is on (the polygon they "
            "trace has no area); order them counter-clockwise seen from +w or give w_hint")
    return 1.0 if s > 0 else -1.0


def _alpha_beta(n: np.ndarray, cov_n: np.ndarray) -> tuple[float, float, np.ndarray]:
    """alpha, beta (degrees) of the scan-plane normal ``n`` (eqs. 5-6, quadrant-safe) and their (2, 2)
    covariance, deg^2, from the normal's ``cov_n``; W along Z: alpha 0 by convention, its variance inf."""
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
    return alpha, beta, cov_ab


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
    check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = as_temperature(temperature, n_pts)
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
    n = _w_side(n, centred, sv, w_hint) * n
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
        rot = single_map(maps, temperature, policy).rotation_error(raw.mean(axis=0)[None, :])[0]
        n = rot.T @ n
        n = n / np.linalg.norm(n)
        cov_n = rot.T @ cov_n @ rot
    alpha, beta, cov_ab = _alpha_beta(n, cov_n)
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
        return machine_points(self.uv, self.scales, (self.alpha, self.beta, gamma), self.offset,
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


def _plane_scan_inputs(uv, scales, alpha, beta, step) -> tuple[np.ndarray, np.ndarray, float, float]:
    """:func:`gamma_from_plane_scan`'s points, scale readings, alpha and beta, checked (enough finite rows, a
    grid step in (0, 30] degrees, motion during the scan)."""
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
    return uv, scales, alpha, beta


def _unit_normal(normal) -> np.ndarray:
    """``normal`` as a unit vector (the zero vector refused)."""
    nv = np.asarray(as_triple("normal", normal))
    if np.linalg.norm(nv) == 0:
        raise InputError("normal: must not be the zero vector")
    return nv / np.linalg.norm(nv)


def _gamma_grid(alpha: float, beta: float, nv, gamma0, step: float) -> np.ndarray:
    """The gammas of the initial search, degrees: the whole circle, or within 90 degrees of ``gamma0``; with a
    normal ``nv`` only those at which the scanner faces it (none: CalibrationError)."""
    if gamma0 is None:
        grid = np.arange(-180.0, 180.0, step)
    else:
        g0 = float(gamma0)
        if not np.isfinite(g0):
            raise InputError(f"gamma0: must be finite, got {gamma0}")
        grid = g0 + np.arange(-90.0 + step / 2, 90.0, step)
    if nv is not None:
        e_v = np.array([e313_matrix((alpha, beta, g))[:, 1] for g in grid])  # (grid, 3), not points
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
    return grid


def _alpha_beta_sensitivity(problem: _PlaneProblem, gamma: float) -> np.ndarray:
    """d gamma / d (alpha, beta) at the solution ``gamma`` (numerical): the solution moved by one
    Gauss-Newton step (exact to second order) for alpha, beta +- h."""
    h = 0.01
    sens = np.zeros(2)
    for j in range(2):  # two angles
        sol = []
        for sgn in (1.0, -1.0):
            d = np.array([problem.alpha, problem.beta])
            d[j] += sgn * h
            p = _PlaneProblem(problem.uv, problem.scales, d[0], d[1], problem.normal, problem.offset, problem.maps,
                              problem.temperature, problem.policy)
            sol.append(gamma + p.step(gamma)[0])
        sens[j] = (sol[0] - sol[1]) / (2 * h)
    return sens


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
    uv, scales, alpha, beta = _plane_scan_inputs(uv, scales, alpha, beta, step)
    check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = as_temperature(temperature, len(uv))
    nv = None if normal is None else _unit_normal(normal)
    l1 = (0.0, 0.0, 0.0) if offset is None else as_triple("offset", offset)
    ab_cov = None if alpha_beta_covariance is None else as_covariance("alpha_beta_covariance", alpha_beta_covariance, 2)
    if nv is None:
        w = e313_matrix((alpha, beta, 0.0))[:, 2]
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

    grid = _gamma_grid(alpha, beta, nv, gamma0, step)
    costs = np.array([coarse.cost(g) for g in grid])  # one kernel call per candidate
    start = float(grid[int(np.argmin(costs))])
    gamma, var, rms, n_fit, iterations = _solve_gamma(problem, start)
    opposite_rms = None
    if nv is not None:
        _check_normal(problem.points(gamma), nv, rms)
        opposite_rms = _PlaneProblem(uv, scales, alpha, beta, -nv, l1, maps, temperature, policy).cost(gamma + 180.0)
    if nv is None and abs(float(np.asarray(n_fit) @ e313_matrix((alpha, beta, gamma))[:, 2])) > 0.95:
        # The best "plane" is the scan plane itself: the motion hardly left it, so every gamma fits.
        raise CalibrationError(
            "gamma: the points lie in the scan plane (the machine hardly moved across it, along w), so every "
            "gamma fits them; sweep across the scan plane, or give `normal`")

    sens = _alpha_beta_sensitivity(problem, gamma)
    noise_u = math.degrees(math.sqrt(var))
    total_var = noise_u**2 + (float(sens @ ab_cov @ sens) if ab_cov is not None else 0.0)
    n_out = np.asarray(n_fit, dtype=float)
    if n_out @ e313_matrix((alpha, beta, gamma))[:, 1] < 0:
        n_out = -n_out
    return GammaAlignment(gamma=_wrap180(gamma), uncertainty=math.sqrt(total_var), noise_uncertainty=noise_u,
                          sensitivity=sens, alpha=alpha, beta=beta, normal=n_out, rms=rms, n_points=len(uv),
                          method="fitted plane" if nv is None else "known normal", iterations=iterations,
                          opposite_rms=opposite_rms)


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
