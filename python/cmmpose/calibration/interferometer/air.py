"""The refractive index of air for laser-interferometer readings (thesis section 3.3, lines 758-772).

The refractivity of air (:func:`refractivity`, :func:`refractive_index`), the
wavelength correction of a reading (:func:`correction_factor`,
:func:`correct_reading`) and its GUM uncertainty
(:func:`refractive_index_budget`, :func:`refractivity_uncertainty`).

Units: temperatures degrees C, pressure mmHg, humidity % RH, refractivity
N = (n - 1) * 1e6 (ppm), wavelengths nm. Line numbers are those of the
thesis's plain text (data/SOURCES.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..._validate import nonnegative, positive
from ...errors import InputError

#: Standard air of the GUM evaluation (thesis line 770): T = 20 C, P = 760 mmHg, H = 50 % RH.
#: An interferometer without weather-station compensation converts fringes with
#: the wavelength in this air (``reading_basis: standard_air``).
STANDARD_AIR = (20.0, 760.0, 50.0)

#: Vacuum wavelength of the HeNe line, nm (thesis line 756: "nominal wavelength
#: of 0.633 um"; HP laser heads: 632.991 nm). The constants of the section 3.3
#: formula are for this line.
HENE_VACUUM_WAVELENGTH_NM = 632.991

# Constants of the HP formula (thesis line 762, after Kneppers 1999).
_A = 0.3836391  # ppm per mmHg
_B0 = 0.817  # 1 / mmHg (times 1e-6)
_B1 = 0.0133  # 1 / (mmHg C) (times 1e-6)
_C = 0.0036610  # 1 / C
_HUM = 3.033e-3  # ppm per % RH
_K = 0.057627  # 1 / C

#: Sensitivity coefficients of n as printed in the GUM formula of thesis line 768,
#: ppm per unit, "evaluated at T = 20 C, P = 760 mm Hg, and H = 50 % RH" (line 770),
#: with the printed signs. The formula's own derivatives there are
#: dN/dT = -0.958 ppm/C, dN/dP = +0.358 ppm/mmHg, dN/dH = -0.0096 ppm/%RH
#: (:func:`refractivity_partials`): the printed magnitudes are rounded up
#: (0.38 is the leading constant 0.3836 without the 1 + 0.003661 T divisor) and
#: the printed signs of T and P are swapped; only the squares enter u_N.
THESIS_SENSITIVITIES_PPM = {"air_temperature_C": 0.97, "pressure_mmHg": -0.38, "humidity_percent": 0.01}

#: Air changes the thesis deems possible during a calibration (lines 770-772):
#: 1 C, 2.5 mmHg and 10 % RH. Used as the default standard uncertainties of the
#: weather-station inputs (T in C, P in mmHg, H in % RH).
THESIS_AIR_UNCERTAINTY = (1.0, 2.5, 10.0)

#: The thesis's "reasonable estimate of the total laser interferometer
#: calibration uncertainty", ppm (line 772). For comparison only: the GUM
#: formula of line 768 gives 1.36 ppm for THESIS_AIR_UNCERTAINTY (2.02 ppm as a
#: plain sum of the three effects), so 2.5 ppm is a rounded-up bound.
THESIS_TOTAL_UNCERTAINTY_PPM = 2.5


def _air_arrays(air_temperature_C, pressure_mmHg, humidity_percent):
    try:
        t, p, h = (np.asarray(v, dtype=np.float64) for v in (air_temperature_C, pressure_mmHg, humidity_percent))
    except (TypeError, ValueError) as exc:
        raise InputError(f"air: temperature (C), pressure (mmHg) and humidity (% RH) must be numbers ({exc})") from None
    for name, v in (("air_temperature_C", t), ("pressure_mmHg", p), ("humidity_percent", h)):
        if not np.isfinite(v).all():
            raise InputError(f"{name}: must be finite, got {v}")
    try:
        t, p, h = np.broadcast_arrays(t, p, h)
    except ValueError:
        raise InputError(f"air: shapes {t.shape}, {p.shape}, {h.shape} do not broadcast") from None
    return t, p, h


def _out(v: np.ndarray):
    return float(v) if np.ndim(v) == 0 else v


def refractivity(air_temperature_C, pressure_mmHg, humidity_percent):
    """Refractivity N = (n - 1) * 1e6 of air for the HeNe line, thesis section 3.3.

    The formula "used by HP" (thesis line 762, after Kneppers 1999; an Edlen
    1966 form for 633 nm)::

        N = 0.3836391 * P * [1 + 1e-6 * P * (0.817 - 0.0133 * T)] / (1 + 0.0036610 * T)
            - 3.033e-3 * H * exp(0.057627 * T)                              (line 762)

    "where N is (n - 1) * 10^6 where n is the refractive index, P is the air
    pressure in mm Hg, T is the temperature in C, and H is the relative
    humidity in percent" (line 764).

    Misprint: line 762 prints ``1 + 10^6 * P * (0.817 - 0.0133 * T)``; the
    factor is 10^-6 (with 10^6, N would be about 1e11 instead of about 271;
    the Edlen form has the same 1e-6 pressure correction). With 1e-6, N at
    20 C, 760 mmHg, 50 % RH is 271.31, the accepted value for 633 nm.

    Parameters
    ----------
    air_temperature_C : float or array_like
        Air temperature T, degrees C.
    pressure_mmHg : float or array_like
        Air pressure P, mmHg (1 hPa = 0.750062 mmHg).
    humidity_percent : float or array_like
        Relative humidity H, % RH (0..100).

    Returns
    -------
    float or ndarray
        N in ppm (parts per million), broadcast over the inputs.
    """
    t, p, h = _air_arrays(air_temperature_C, pressure_mmHg, humidity_percent)
    n = _A * p * (1.0 + 1e-6 * p * (_B0 - _B1 * t)) / (1.0 + _C * t) - _HUM * h * np.exp(_K * t)
    return _out(n)


def refractive_index(air_temperature_C, pressure_mmHg, humidity_percent):
    """Refractive index n = 1 + N * 1e-6 of air (thesis line 762; see :func:`refractivity`).

    Parameters as :func:`refractivity` (T in C, P in mmHg, H in % RH).
    Returns n (dimensionless), float or ndarray.
    """
    return _out(1.0 + 1e-6 * np.asarray(refractivity(air_temperature_C, pressure_mmHg, humidity_percent)))


def refractivity_partials(air_temperature_C=20.0, pressure_mmHg=760.0, humidity_percent=50.0):
    """Analytic sensitivity coefficients of N (thesis line 762) at the given air.

    Parameters
    ----------
    air_temperature_C, pressure_mmHg, humidity_percent : float
        Where to evaluate: T in C, P in mmHg, H in % RH (default the standard
        air of thesis line 770).

    Returns
    -------
    dict
        ``{"air_temperature_C": dN/dT (ppm per C), "pressure_mmHg": dN/dP
        (ppm per mmHg), "humidity_percent": dN/dH (ppm per % RH)}``. At 20 C,
        760 mmHg, 50 % RH: -0.958, +0.358, -0.0096 (n falls as the air warms,
        rises with pressure, falls with humidity).
    """
    t, p, h = (float(v) for v in _air_arrays(air_temperature_C, pressure_mmHg, humidity_percent))
    den = 1.0 + _C * t
    num = 1.0 + 1e-6 * p * (_B0 - _B1 * t)
    d_t = _A * p * ((-1e-6 * p * _B1) * den - num * _C) / den**2 - _HUM * h * _K * math.exp(_K * t)
    d_p = _A * (1.0 + 2e-6 * p * (_B0 - _B1 * t)) / den
    d_h = -_HUM * math.exp(_K * t)
    return {"air_temperature_C": d_t, "pressure_mmHg": d_p, "humidity_percent": d_h}


def wavelength_in_air_nm(vacuum_wavelength_nm, air_temperature_C, pressure_mmHg, humidity_percent):
    """Wavelength in air, nm: lambda_vac / n (n from :func:`refractive_index`).

    Parameters: vacuum wavelength in nm (a HeNe line; the formula's constants
    are for 633 nm), T in C, P in mmHg, H in % RH.
    """
    lam = positive("vacuum_wavelength_nm", vacuum_wavelength_nm)
    return _out(lam / np.asarray(refractive_index(air_temperature_C, pressure_mmHg, humidity_percent)))


#: How the instrument turned fringe counts into the recorded linear reading:
#: ``standard_air`` (wavelength in the standard air of STANDARD_AIR: no
#: weather-station compensation), ``vacuum`` (vacuum wavelength) or
#: ``compensated`` (already corrected with the weather station, as the
#: thesis's HP display did, line 758).
READING_BASES = ("standard_air", "vacuum", "compensated")


def _basis_index(basis: str) -> float | None:
    if basis == "standard_air":
        return float(refractive_index(*STANDARD_AIR))
    if basis == "vacuum":
        return 1.0
    if basis == "compensated":
        return None
    raise InputError(f"reading_basis: expected one of {READING_BASES}, got {basis!r}")


def correction_factor(air_temperature_C, pressure_mmHg, humidity_percent, basis: str = "standard_air"):
    """Factor that turns a linear reading into the true displacement: n_basis / n_air.

    An interferometer counts fringes of the wavelength in the air it works in,
    lambda_vac / n_air, but converts them with lambda_vac / n_basis; the true
    displacement is therefore ``reading * n_basis / n_air``. Warm or thin air
    (n_air < n_basis) makes the uncorrected reading short by about
    (N_basis - N_air) ppm.

    Parameters
    ----------
    air_temperature_C, pressure_mmHg, humidity_percent : float or array_like
        The air along the beam: T in C, P in mmHg, H in % RH.
    basis : {'standard_air', 'vacuum', 'compensated'}
        See ``READING_BASES``. ``compensated`` gives 1 (nothing left to correct).

    Returns
    -------
    float or ndarray
        Dimensionless factor (1 + a few ppm).
    """
    n_air = np.asarray(refractive_index(air_temperature_C, pressure_mmHg, humidity_percent))
    n_basis = _basis_index(basis)
    return _out(np.ones_like(n_air) if n_basis is None else n_basis / n_air)


def correct_reading(reading, air_temperature_C, pressure_mmHg, humidity_percent, basis: str = "standard_air"):
    """Wavelength-corrected linear reading: ``reading * n_basis / n_air`` (same unit as ``reading``).

    See :func:`correction_factor` (T in C, P in mmHg, H in % RH). Apply it to
    the reading as the instrument counted it (from where it was zeroed), before
    any other arithmetic.
    """
    r = np.asarray(reading, dtype=np.float64)
    return _out(r * np.asarray(correction_factor(air_temperature_C, pressure_mmHg, humidity_percent, basis)))


def refractive_index_budget(
    u_air_temperature_C: float = THESIS_AIR_UNCERTAINTY[0],
    u_pressure_mmHg: float = THESIS_AIR_UNCERTAINTY[1],
    u_humidity_percent: float = THESIS_AIR_UNCERTAINTY[2],
    *,
    at: Sequence[float] | None = None,
):
    """GUM budget of the refractivity N, thesis line 768 (GUM eq. 10, uncorrelated inputs)::

        u_N^2 = (0.97e-6)^2 u_T^2 + (-0.38e-6)^2 u_P^2 + (0.01e-6)^2 u_H^2      (line 768)

    evaluated at T = 20 C, P = 760 mmHg, H = 50 % RH (line 770). The relative
    standard uncertainty of a corrected length is u_N (ppm).

    Parameters
    ----------
    u_air_temperature_C : float
        Standard uncertainty of the air temperature, C.
    u_pressure_mmHg : float
        Standard uncertainty of the pressure, mmHg.
    u_humidity_percent : float
        Standard uncertainty of the relative humidity, % RH.
    at : (T C, P mmHg, H % RH), optional
        None (default): the printed coefficients of line 768
        (``THESIS_SENSITIVITIES_PPM``). Given: the formula's analytic
        derivatives at that air (:func:`refractivity_partials`).

    Returns
    -------
    cmmpose.evaluation.uncertainty.Budget
        Budget in ppm; ``combined_standard_uncertainty`` is u_N.
    """
    from ...evaluation.uncertainty import Budget, Input

    us = {
        "air_temperature_C": nonnegative("u_air_temperature_C", u_air_temperature_C),
        "pressure_mmHg": nonnegative("u_pressure_mmHg", u_pressure_mmHg),
        "humidity_percent": nonnegative("u_humidity_percent", u_humidity_percent),
    }
    if at is None:
        coeffs, where, values = THESIS_SENSITIVITIES_PPM, "printed coefficients, thesis line 768", STANDARD_AIR
    else:
        try:
            values = tuple(float(v) for v in at)
        except (TypeError, ValueError):
            raise InputError(f"at: expected (T C, P mmHg, H %RH), got {at!r}") from None
        if len(values) != 3:
            raise InputError(f"at: expected (T C, P mmHg, H %RH), got {len(values)} values")
        coeffs = refractivity_partials(*values)
        where = f"derivatives of line 762 at {values[0]:g} C, {values[1]:g} mmHg, {values[2]:g} %RH"
    names = {"air_temperature_C": ("air temperature T", "C"), "pressure_mmHg": ("air pressure P", "mmHg"),
             "humidity_percent": ("relative humidity H", "%RH")}
    inputs = [Input(names[k][0], v, us[k], names[k][1], coeffs[k], note=where) for k, v in zip(names, values)]
    return Budget("N = (n - 1) 1e6, refractivity of air", tuple(inputs), "ppm",
                  source="Harris thesis section 3.3, lines 762-772 (GUM eq. 10)")


def refractivity_uncertainty(u_air_temperature_C: float = THESIS_AIR_UNCERTAINTY[0],
                             u_pressure_mmHg: float = THESIS_AIR_UNCERTAINTY[1],
                             u_humidity_percent: float = THESIS_AIR_UNCERTAINTY[2],
                             *, at: Sequence[float] | None = None) -> float:
    """u_N in ppm by thesis line 768 (see :func:`refractive_index_budget`; u_T in C,
    u_P in mmHg, u_H in % RH). The thesis's defaults give 1.36 ppm."""
    return refractive_index_budget(u_air_temperature_C, u_pressure_mmHg, u_humidity_percent,
                                   at=at).combined_standard_uncertainty
