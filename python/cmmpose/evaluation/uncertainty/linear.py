"""Propagation by the law of propagation of uncertainty (GUM eq. 10 / 13), with sensitivity coefficients from
the kernels by central differences.
"""

from __future__ import annotations

import math

import numpy as np

from ..._validate import finite
from ...errors import InputError
from .propagation import (PARAMETERS, CentreUncertainty, FitProblem, LengthUncertainty, ball_pair, check_input_u,
                          inputs_record)


def _sensitivity(f, p: FitProblem, name: str, steps: dict[str, float]) -> np.ndarray:
    """Central difference of f(**shift) in parameter ``name`` (one-sided at a temperature end)."""
    h = steps["pose" if name in PARAMETERS[:3] else "offset" if name in PARAMETERS[3:6] else "temperature"]
    lo, hi = (p.temperature_steps(h) if name == "temperature" else (-h, h))
    return (np.asarray(f(**p.shifted(name, hi))) - np.asarray(f(**p.shifted(name, lo)))) / (hi - lo)


def _steps(step_pose_deg, step_offset, step_temperature) -> dict[str, float]:
    steps = {"pose": finite("step_pose_deg", step_pose_deg), "offset": finite("step_offset", step_offset),
             "temperature": finite("step_temperature", step_temperature)}
    if min(steps.values()) <= 0:
        raise InputError(f"step_pose_deg, step_offset, step_temperature: steps must be positive, got {steps}")
    return steps


def linear_sphere_centre_uncertainty(uv, scales, error_map, pose, offset, temperature=None, *, u_noise: float = 0.008,
                                     u_pose_deg=(0.0, 0.0, 0.0), u_offset=(0.0, 0.0, 0.0), u_temperature: float = 0.0,
                                     radius: float | None = None, step_pose_deg: float = 1e-3, step_offset: float = 1e-3,
                                     step_temperature: float = 0.05, out_of_range: str = "raise") -> CentreUncertainty:
    """Linear (GUM law of propagation) uncertainty of a fitted sphere centre for
    the same inputs as :func:`monte_carlo_sphere_centre`.

    cov = cov_noise + sum_k s_k s_k^T u_k^2 over k = alpha, beta, gamma, U1,
    V1, W1, temperature, where

    - cov_noise propagates independent noise ``u_noise`` on every v through the
      linearised geometric fit: u^2 N A^T diag(a_i^2) A N with A = [n_i, 1]
      (outward normals at the fitted sphere; without the 1 for a fixed radius),
      N = (A^T A)^-1 and a_i = n_i . dX_i/dv_i (dX/dv from the compensation).
      This is not the fit's own ``covariance`` (s^2 N from the residuals, a Type
      A estimate that assumes equal radial noise at every point): noise along v
      projects onto the normal by a different amount at each point;
    - s_k = d(centre)/d(input k) by central differences through
      :func:`cmmpose.compensate` and :func:`cmmpose.fit_sphere`.

    Parameters
    ----------
    uv, scales, error_map, pose, offset, temperature, u_noise, u_pose_deg, u_offset, u_temperature, radius, out_of_range
        As in :func:`monte_carlo_sphere_centre`.
    step_pose_deg : float
        Difference step of each pose angle, degrees (default 1e-3: the centre
        moves ~5 um, far above the fit's convergence and far inside the range
        where the centre is linear in the angle; 1e-2 to 1e-5 give the same
        coefficients to 7 digits on the simulated reference scan).
    step_offset : float
        Difference step of U1, V1, W1, mm (default 1e-3; the compensation is
        affine in the offset, so only the fit's nonlinearity is probed).
    step_temperature : float
        Difference step of the temperature, K (default 0.05). The maps are
        linear in temperature between map temperatures, so the difference is
        exact inside an interval; a step straddling a map temperature gives the
        mean of the two slopes; at either end of the map set a one-sided
        difference is used.

    Returns
    -------
    CentreUncertainty
        ``centre`` of the unperturbed fit, ``covariance`` (mm^2),
        ``contributions`` and ``sensitivities`` per input; ``budget('x')`` etc.
    """
    p = FitProblem(uv, scales, error_map, pose, offset, temperature, out_of_range, radius)
    u = check_input_u(u_noise, u_pose_deg, u_offset, u_temperature, p)
    steps = _steps(step_pose_deg, step_offset, step_temperature)
    centre = p.centre()
    unit_noise = p.noise_covariance(1.0)  # centre covariance per (1 mm noise)^2
    contributions = {"noise": unit_noise * u["noise"] ** 2}
    sens = {"noise": np.sqrt(np.diag(unit_noise))}
    for name in PARAMETERS:
        if name == "temperature" and p.temperature is None:
            continue
        s = _sensitivity(p.centre, p, name, steps)
        sens[name] = s
        contributions[name] = np.outer(s, s) * u[name] ** 2
    cov = sum(contributions.values())
    return CentreUncertainty("linear", centre, cov, None, contributions, sens, inputs_record(p, u))


def linear_ballbar_length_uncertainty(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature=None, *,
                                      temperature2=None, u_noise: float = 0.008, u_pose_deg=(0.0, 0.0, 0.0),
                                      u_offset=(0.0, 0.0, 0.0), u_temperature: float = 0.0,
                                      radius: float | None = None, step_pose_deg: float = 1e-3,
                                      step_offset: float = 1e-3, step_temperature: float = 0.05,
                                      out_of_range: str = "raise") -> LengthUncertainty:
    """Linear (GUM law of propagation) uncertainty of a ballbar length for the
    same inputs as :func:`monte_carlo_ballbar_length`.

    u^2(L) = e^T cov_noise,1 e + e^T cov_noise,2 e + sum_k (dL/dx_k)^2 u_k^2,
    e = (c2 - c1)/L; the noise covariances as in
    :func:`linear_sphere_centre_uncertainty`, dL/dx_k by central differences of
    the length through compensation and both fits (pose, offset and
    temperature shifted together for both balls; steps as there).

    Returns
    -------
    LengthUncertainty
        ``length`` from the unperturbed data, ``contributions`` (variances,
        mm^2), ``sensitivities``; ``budget()`` gives the GUM table.
    """
    p1, p2 = ball_pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius)
    u = check_input_u(u_noise, u_pose_deg, u_offset, u_temperature, p1)
    steps = _steps(step_pose_deg, step_offset, step_temperature)
    c1, c2 = p1.centre(), p2.centre()
    length = float(np.linalg.norm(c2 - c1))
    e = (c2 - c1) / length
    contributions, sens = {}, {}
    for key, p in (("noise 1", p1), ("noise 2", p2)):
        s2 = float(e @ p.noise_covariance(1.0) @ e)
        sens[key] = math.sqrt(s2)
        contributions[key] = s2 * u["noise"] ** 2

    def length_of(**shift):
        return np.linalg.norm(p2.centre(**shift) - p1.centre(**shift))

    for name in PARAMETERS:
        if name == "temperature" and p1.temperature is None:
            continue
        if name == "temperature":
            # the same step must be valid for both scans
            lo1, hi1 = p1.temperature_steps(steps["temperature"])
            lo2, hi2 = p2.temperature_steps(steps["temperature"])
            lo, hi = max(lo1, lo2), min(hi1, hi2)
            if hi - lo <= 0:
                raise InputError("step_temperature: no common difference step fits both scans inside the maps' range")
            s = float((length_of(dT=hi) - length_of(dT=lo)) / (hi - lo))
        else:
            s = float(_sensitivity(length_of, p1, name, steps))
        sens[name] = s
        contributions[name] = (s * u[name]) ** 2
    return LengthUncertainty("linear", length, math.sqrt(sum(contributions.values())), np.stack([c1, c2]), None,
                             contributions, sens, inputs_record(p1, u, ("noise 1", "noise 2")))
