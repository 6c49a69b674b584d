"""Propagation by Monte Carlo (GUM Supplement 1): the inputs drawn, each trial compensated and fitted again."""

from __future__ import annotations

import numpy as np

from ...errors import InputError, OutOfRangeError, quoting
from .propagation import (PARAMETERS, CentreUncertainty, FitProblem, LengthUncertainty, ball_pair, check_input_u,
                          inputs_record)


def _check_trials(trials) -> int:
    if isinstance(trials, bool) or not isinstance(trials, (int, np.integer)) or trials < 2:
        raise InputError(f"trials: expected an integer >= 2, got {trials!r}")
    return int(trials)


def _draws(rng, m: int, u: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Common (systematic) perturbations of all trials at once: pose (M, 3) deg,
    offset (M, 3) mm, temperature (M,) K."""
    dpose = rng.normal(size=(m, 3)) * np.array([u[k] for k in PARAMETERS[:3]])
    doff = rng.normal(size=(m, 3)) * np.array([u[k] for k in PARAMETERS[3:6]])
    dT = rng.normal(size=m) * u["temperature"]
    return dpose, doff, dT


def _trial_centre(p: FitProblem, work: np.ndarray, v0: np.ndarray, noise: np.ndarray, dpose, doff, dT, k: int) -> np.ndarray:
    work[:, 1] = v0 + noise
    try:
        return p.centre(uv=work, dpose=dpose, doffset=doff, dT=dT)
    except OutOfRangeError as exc:
        message, fields = quoting(exc, f"Monte Carlo trial {k}{p.label and ' (ball ' + p.label + ')'}: temperature "
                                  f"offset {dT:+.4g} K: ", " (use out_of_range='clamp' or a smaller u_temperature)")
        raise OutOfRangeError(message, **fields) from None


def monte_carlo_sphere_centre(uv, scales, error_map, pose, offset, temperature=None, *, u_noise: float = 0.008,
                              u_pose_deg=(0.0, 0.0, 0.0), u_offset=(0.0, 0.0, 0.0), u_temperature: float = 0.0,
                              trials: int = 1000, rng=None, radius: float | None = None,
                              out_of_range: str = "raise") -> CentreUncertainty:
    """Monte Carlo propagation (GUM Supplement 1) of scanner noise, pose, mount
    offset and temperature uncertainty to a fitted sphere centre.

    Each trial draws, independently and normally distributed: noise on v of
    every point (sd ``u_noise``), one offset of each pose angle, of each mount
    offset component and of the temperature (the same for all points of the
    scan: a calibration or thermometer error); compensates the perturbed data
    with :func:`cmmpose.compensate` and fits with :func:`cmmpose.fit_sphere`.

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Scan-plane coordinates u, v of the scan, mm.
    scales : array_like, shape (N, 3)
        Scale readings D, E, F, mm.
    error_map : ErrorMap or ErrorMapSet
        The machine's maps.
    pose : Pose or sequence of 3 float
        Nominal pose alpha, beta, gamma, degrees.
    offset : MountOffset or sequence of 3 float
        Nominal mount offset U1, V1, W1, mm.
    temperature : float or array_like (N,), optional
        Machine temperature, degrees C (with an ErrorMapSet).
    u_noise : float
        Standard uncertainty of each v (depth) reading, mm (thesis: 0.008-0.009).
    u_pose_deg : sequence of 3 float
        Standard uncertainties of alpha, beta, gamma, degrees.
    u_offset : sequence of 3 float
        Standard uncertainties of U1, V1, W1, mm.
    u_temperature : float
        Standard uncertainty of the temperature, K.
    trials : int
        Number of Monte Carlo trials M (>= 2). The relative standard error of
        the resulting standard uncertainties is about 1/sqrt(2(M-1)).
    rng : numpy Generator or int, optional
        Random source or seed.
    radius : float, optional
        Fit with this fixed radius, mm.
    out_of_range : {'raise', 'clamp'}
        Passed to :func:`cmmpose.compensate` for every trial.

    Returns
    -------
    CentreUncertainty
        ``centre`` the mean of the trials, ``covariance`` their sample
        covariance (mm^2), ``trials`` (M, 3).
    """
    p = FitProblem(uv, scales, error_map, pose, offset, temperature, out_of_range, radius)
    u = check_input_u(u_noise, u_pose_deg, u_offset, u_temperature, p)
    m = _check_trials(trials)
    rng = np.random.default_rng(rng)
    dpose, doff, dT = _draws(rng, m, u)
    work, v0 = p.uv.copy(), p.uv[:, 1].copy()
    centres = np.empty((m, 3))
    for k in range(m):
        noise = rng.normal(0.0, u["noise"], len(v0)) if u["noise"] else 0.0
        centres[k] = _trial_centre(p, work, v0, noise, dpose[k], doff[k], dT[k], k)
    return CentreUncertainty("monte carlo", centres.mean(axis=0), np.cov(centres, rowvar=False), centres,
                             inputs=inputs_record(p, u))


def monte_carlo_ballbar_length(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature=None, *,
                               temperature2=None, u_noise: float = 0.008, u_pose_deg=(0.0, 0.0, 0.0),
                               u_offset=(0.0, 0.0, 0.0), u_temperature: float = 0.0, trials: int = 1000, rng=None,
                               radius: float | None = None, out_of_range: str = "raise") -> LengthUncertainty:
    """Monte Carlo propagation (GUM Supplement 1) to a ballbar length, the
    distance between the centres fitted to two scans.

    The noise on v is drawn independently for every point of both scans; the
    pose, mount offset and temperature perturbations of a trial are common to
    both balls (one digitizer calibration, one thermometer).

    Parameters
    ----------
    uv1, scales1 : array_like, shapes (N1, 2), (N1, 3)
        Scan of ball 1: u, v and scale readings, mm.
    uv2, scales2 : array_like, shapes (N2, 2), (N2, 3)
        Scan of ball 2, mm.
    error_map, pose, offset : as in :func:`monte_carlo_sphere_centre`
        Shared by both scans.
    temperature : float or array_like (N1,), optional
        Machine temperature during scan 1, degrees C.
    temperature2 : float or array_like (N2,), optional
        During scan 2; default ``temperature`` (which must then be a scalar).
    u_noise, u_pose_deg, u_offset, u_temperature, trials, rng, radius, out_of_range
        As in :func:`monte_carlo_sphere_centre`.

    Returns
    -------
    LengthUncertainty
        ``length`` the mean of the trial lengths, ``standard_uncertainty`` their
        sample standard deviation (mm), ``trials`` (M,), ``centres`` the mean
        trial centres (2, 3).
    """
    p1, p2 = ball_pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius)
    u = check_input_u(u_noise, u_pose_deg, u_offset, u_temperature, p1)
    m = _check_trials(trials)
    rng = np.random.default_rng(rng)
    dpose, doff, dT = _draws(rng, m, u)
    state = [(p, p.uv.copy(), p.uv[:, 1].copy()) for p in (p1, p2)]
    centres = np.empty((m, 2, 3))
    for k in range(m):
        for b, (p, work, v0) in enumerate(state):
            noise = rng.normal(0.0, u["noise"], len(v0)) if u["noise"] else 0.0
            centres[k, b] = _trial_centre(p, work, v0, noise, dpose[k], doff[k], dT[k], k)
    lengths = np.linalg.norm(centres[:, 1] - centres[:, 0], axis=1)
    return LengthUncertainty("monte carlo", float(lengths.mean()), float(lengths.std(ddof=1)), centres.mean(axis=0),
                             lengths, inputs=inputs_record(p1, u))
