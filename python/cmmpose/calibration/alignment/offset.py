"""The mount offset U1, V1, W1 (thesis section 5.3, eqs. 16-24).

- :func:`mount_offset` (:class:`MountOffsetFit`): U1, V1, W1 from two or more
  alignments by generalised least squares, with residuals and a chi-square
  consistency check;
- :func:`mount_offset_closed_form` (:class:`ClosedFormOffset`): eqs. 19-20 and
  the corrected eq. 21 for the thesis's three standard alignments, with the
  GUM budget of eqs. 22-24.

Units: mm for lengths, degrees for angles; covariances in the square of those
units (docs/calibration.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..._arrays import as_triple
from ...errors import CalibrationError, GeometryError, InputError, InputTypeError
from ...pose import MountOffset
from .common import STANDARD_POSES, chi2_sf, e313_derivatives, e313_matrix, pose_name
from .reference import ReferenceReading


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
    poses = ", ".join(pose_name(a.pose) for a in items)
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
    _check_limits(tolerance, max_residual, significance)
    y = np.stack([a.position for a in items])  # (K, 3)
    lev = np.stack([a.lever for a in items])  # (K, 3, 3)
    c_fit = np.stack([a.fit_covariance for a in items])
    p_cov = np.stack([a.pose_covariance for a in items])
    jac_s = np.stack([a.pose_jacobian for a in items])  # (K, 3, 3) mm/deg
    d_e = np.stack([e313_derivatives(a.pose) for a in items])  # (K, angle, 3, 3)
    rot = lev @ np.linalg.inv(np.stack([e313_matrix(a.pose) for a in items]))  # R_k (identity without a map)
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
                f"alignments: the {k} poses {', '.join(pose_name(a.pose) for a in items)} do not determine the "
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
    p_val = chi2_sf(chi2, dof)
    std_res = resid / _residual_sd(a_mat, cov_k, cov_x)
    result = MountOffsetFit(
        offset=MountOffset(*(float(v) for v in x[3:])), covariance=cov_x[3:, 3:].copy(), centre=x[:3].copy(),
        centre_covariance=cov_x[:3, :3].copy(), full_covariance=cov_x, residuals=resid,
        standardised_residuals=std_res, chi2=chi2, dof=dof, p_value=p_val, contributions=contrib,
        poses=tuple(a.pose for a in items))
    _check_agreement(result, tolerance, max_residual, significance)
    return result


def _check_limits(tolerance, max_residual, significance) -> None:
    """:func:`mount_offset`'s limits: each None or a positive number (significance in (0, 1))."""
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"tolerance: must be a positive number of standard deviations or None, got {tolerance}")
    if max_residual is not None and not (np.isfinite(max_residual) and max_residual > 0):
        raise InputError(f"max_residual: must be a positive length in mm or None, got {max_residual}")
    if significance is not None and not (0 < significance < 1):
        raise InputError(f"significance: must be in (0, 1) or None, got {significance}")


def _residual_sd(a_mat: np.ndarray, cov_k: np.ndarray, cov_x: np.ndarray) -> np.ndarray:
    """The standard deviation of each residual component, (K, 3) mm: the diagonal of the residual covariance
    C - A cov_x A^T (NaN where it vanishes: a component the fit reproduces exactly)."""
    k = len(a_mat)
    a_flat = a_mat.reshape(3 * k, 6)
    var_r = np.einsum("kii->ki", cov_k).reshape(3 * k) - np.einsum("ij,jk,ik->i", a_flat, cov_x, a_flat)
    floor = 1e-12 * max(float(np.max(np.einsum("kii->ki", cov_k))), 1e-300)
    return np.where(var_r > floor, np.sqrt(np.clip(var_r, 0.0, None)), np.nan).reshape(k, 3)


def _check_agreement(fit: MountOffsetFit, tolerance, max_residual, significance) -> None:
    """CalibrationError naming the worst alignment when the alignments disagree beyond ``tolerance``
    (standard deviations), ``max_residual`` (mm) or the chi-square test at ``significance``."""
    resid, std_res, chi2, dof, p_val = fit.residuals, fit.standardised_residuals, fit.chi2, fit.dof, fit.p_value
    score = np.nan_to_num(np.abs(std_res), nan=0.0)
    worst = np.unravel_index(int(np.argmax(score)), score.shape)
    worst_mm = np.unravel_index(int(np.argmax(np.abs(resid))), resid.shape)
    too_many_sd = tolerance is not None and score[worst] > tolerance
    too_far = max_residual is not None and abs(resid[worst_mm]) > max_residual
    rejected = significance is not None and dof > 0 and p_val < significance
    if too_many_sd or too_far or rejected:
        bad = worst if too_many_sd or not too_far else worst_mm
        why = (f"alignment {bad[0]} at pose {pose_name(fit.poses[bad[0]])} is off by "
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
                raise InputError(f"s{k}: the closed form needs alignment {k} at pose {pose_name(std)} (within "
                                 f"{pose_tolerance:g} deg), got {pose_name(s.pose)}; use mount_offset() for "
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
