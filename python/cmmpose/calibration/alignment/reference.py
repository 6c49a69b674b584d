"""D0, E0, F0 from a reference-sphere scan (thesis section 4.4, eq. 14).

:func:`reference_centre_reading` (:class:`ReferenceReading`): the scale reading
at which the laser origin sits at the reference-sphere centre, with its
covariance.

Units: mm for lengths, degrees for angles, degrees C for temperatures;
covariances in the square of those units (docs/calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._arrays import as_rows, as_triple
from ...errors import InputError
from ...fitting import SphereFit, fit_sphere
from ...pose import pose_tuple
from ...temperature import TemperaturePolicy, as_policy
from .common import (as_covariance, as_temperature, check_map, e313_matrix, machine_points, single_map,
                     uncertainty_triple)


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
            cov = as_covariance("covariance", covariance, 3)
        elif uncertainty is not None:
            cov = np.diag(uncertainty_triple("uncertainty", uncertainty) ** 2)
        else:
            raise InputError("reading: state its uncertainty (mm) or covariance (mm^2)")
        pc = np.zeros((3, 3)) if pose_covariance is None else as_covariance("pose_covariance", pose_covariance, 3)
        return cls(pose=p, reading=s, covariance=cov, fit_covariance=cov.copy(), pose_covariance=pc,
                   pose_jacobian=np.zeros((3, 3)), position=s.copy(), lever=e313_matrix(p),
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


def _reading_at_centre(m, c_y: np.ndarray, lever: np.ndarray, e313: np.ndarray, l1) -> np.ndarray:
    """The reading S at which the laser origin S + e(S) - R(S) E313 l1 is at the centre c = c_Y - lever l1,
    with the map ``m`` (fixed point; e and R change by ppm per mm); ``l1`` None: the origin itself."""
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
    return s


def _pose_jacobian(centre_of, p) -> np.ndarray:
    """d reading / d pose, (3, 3) mm per degree: numerical, central differences of 0.01 deg of the sphere
    centre ``centre_of(angles)`` fits."""
    h = 0.01
    jac = np.empty((3, 3))
    for j in range(3):  # three angles
        d = np.zeros(3)
        d[j] = h
        plus = np.asarray(centre_of(tuple(np.add(p, d))).centre)
        minus = np.asarray(centre_of(tuple(np.subtract(p, d))).centre)
        jac[:, j] = (plus - minus) / (2 * h)
    return jac


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
    check_map(maps, temperature)
    policy = as_policy(temperature_policy)
    temperature = as_temperature(temperature, len(uv))
    p = pose_tuple(pose)
    pc = np.zeros((3, 3)) if pose_covariance is None else as_covariance("pose_covariance", pose_covariance, 3)
    extra = None if reading_uncertainty is None else uncertainty_triple("reading_uncertainty", reading_uncertainty)
    zero = (0.0, 0.0, 0.0)

    def centre_of(angles, l1=zero):
        y = machine_points(uv, scales, angles, l1, maps, temperature, policy)
        return fit_sphere(y, radius, reject=reject)

    fit = centre_of(p)
    c_y = np.asarray(fit.centre, dtype=float)
    e313 = e313_matrix(p)
    l1 = None if offset is None else np.asarray(as_triple("offset", offset))
    if maps is None:
        # Error-free model: the points for l1 are those for 0 moved by -E313 l1.
        reading, position, lever = c_y.copy(), c_y.copy(), e313
        t_mean = None
    else:
        m = single_map(maps, temperature, policy)
        # lever = d centre / d(-l1): R(S) E313 averaged the way the fit averages
        # the scan's points (numerical; the centre is linear in l1).
        big = 100.0
        lever = np.column_stack([(c_y - np.asarray(centre_of(p, tuple(big * np.eye(3)[j])).centre)) / big
                                 for j in range(3)])  # three directions
        position = c_y
        reading = _reading_at_centre(m, c_y, lever, e313, l1)
        t_mean = float(np.mean(temperature)) if temperature is not None else m.temperature
    jac = _pose_jacobian(centre_of, p)
    fit_cov = _sandwich_centre_covariance(machine_points(uv, scales, p, zero, maps, temperature, policy), fit,
                                          radius is not None)
    if extra is not None:
        fit_cov = fit_cov + np.diag(extra**2)
    cov = fit_cov + jac @ pc @ jac.T
    centre = None if l1 is None else position - lever @ l1
    return ReferenceReading(pose=p, reading=reading, covariance=cov, fit_covariance=fit_cov, pose_covariance=pc,
                            pose_jacobian=jac, position=position, lever=lever, centre=centre, fit=fit,
                            temperature=t_mean)
