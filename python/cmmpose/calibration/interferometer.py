"""Error maps from laser-interferometer runs (thesis section 3.3).

The thesis measured its maps with an HP/Renishaw laser interferometer: the axis
is homed, the error terms are set to zero there, the carriage steps along the
axis and at every step the scale position and the interferometer reading are
recorded (thesis lines 703, 754-756); linear readings are corrected for the
refractive index of air from a weather station (lines 758-772); angular optics
replace the linear ones for the angles (line 774); roll is not measured and is
stored as 0 (line 793); the table is the average of three or five readings
(line 822). This module does the same from raw runs:

1. the refractive index of air of section 3.3 (:func:`refractivity`,
   :func:`refractive_index`), the wavelength correction of a reading
   (:func:`correction_factor`, :func:`correct_reading`) and its GUM
   uncertainty (:func:`refractive_index_budget`, :func:`refractivity_uncertainty`);
2. the raw run file (:class:`InterferometerRun`, ``read``/``write``;
   docs/interferometer.md);
3. processing of one run into one map component (:func:`process_run` ->
   :class:`ProcessedRun`): air correction (linear optics only), material
   temperature kept or normalised to 20 C, zero at home, repeats and
   directions averaged, reversal and repeatability reported;
4. assembly of the 18 carriage components and 3 squareness values into an
   :class:`~cmmpose.ErrorMap` (:func:`map_from_runs`, :func:`build_map`), and
   comparison of two maps (:func:`compare_maps`, :func:`plot_map_difference`).

Units: positions and linear readings mm, straightness readings and map
deltas um, angles arc-second, temperatures degrees C, pressure mmHg,
humidity % RH, refractivity N = (n - 1) * 1e6 (ppm). Line numbers are those
of the thesis's plain text (data/SOURCES.md).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np

from ..atomicfile import save_figure, write_text
from ..evaluation.plots import new_figure
from ..errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap
from ..errors import InputError, InputTypeError, InterferometerRunError, InterferometerWarning, MapError, read_lines
from .._validate import finite, nonnegative, positive, triple

__all__ = [
    "InterferometerRunError",
    "InterferometerWarning",
    "STANDARD_AIR",
    "HENE_VACUUM_WAVELENGTH_NM",
    "THESIS_SENSITIVITIES_PPM",
    "THESIS_AIR_UNCERTAINTY",
    "THESIS_TOTAL_UNCERTAINTY_PPM",
    "OPTICS",
    "READING_BASES",
    "refractivity",
    "refractive_index",
    "refractivity_partials",
    "wavelength_in_air_nm",
    "correction_factor",
    "correct_reading",
    "refractive_index_budget",
    "refractivity_uncertainty",
    "InterferometerRun",
    "read_run",
    "write_run",
    "run_columns",
    "ProcessedRun",
    "process_run",
    "positional_deviations",
    "MapBuild",
    "build_map",
    "map_from_runs",
    "MapComparison",
    "compare_maps",
    "plot_map_difference",
]


# ---------------------------------------------------------------------------
# 1. Refractive index of air (thesis section 3.3, lines 758-772)
# ---------------------------------------------------------------------------

#: Standard air of the GUM evaluation (thesis line 770): T = 20 C, P = 760 mmHg, H = 50 % RH.
#: An interferometer without weather-station compensation converts fringes with
#: the wavelength in this air (``reading_basis: standard_air``).
STANDARD_AIR = (20.0, 760.0, 50.0)

#: Vacuum wavelength of the HeNe line, nm (thesis line 756: "nominal wavelength
#: of 0.633 um"; HP laser heads: 632.991 nm). The constants of the section 3.3
#: formula are for this line.
HENE_VACUUM_WAVELENGTH_NM = 632.991
_HENE_RANGE_NM = (632.0, 634.0)

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
    from ..evaluation.uncertainty import Budget, Input

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


# ---------------------------------------------------------------------------
# 2. The raw run file
# ---------------------------------------------------------------------------

MAGIC = "cmmpose-interferometer-run"
VERSION = "1"
#: Optics of a run and the unit of its reading column.
OPTICS = ("linear", "straightness", "angular")
READING_UNIT = {"linear": "mm", "straightness": "um", "angular": "arcsec"}
_KNOWN_KEYS = ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis", "source")
_AIR_COLUMNS = ("air_temperature_C", "pressure_mmHg", "humidity_percent", "material_temperature_C")
# Plausible ranges: catch Kelvin, hPa or fractions instead of percent.
_RANGES = {
    "air_temperature_C": (0.0, 50.0, "an air temperature in C (Kelvin?)"),
    "pressure_mmHg": (400.0, 900.0, "a pressure in mmHg (hPa or kPa? 1 hPa = 0.750062 mmHg)"),
    "humidity_percent": (0.0, 100.0, "a relative humidity in % RH"),
    "material_temperature_C": (0.0, 50.0, "a material temperature in C (Kelvin?)"),
}


def run_columns(optics: str) -> tuple[str, ...]:
    """Column names of a run file with ``optics`` (the reading column carries the unit)."""
    if optics not in OPTICS:
        raise InputError(f"optics: expected one of {OPTICS}, got {optics!r}")
    return ("target_mm", f"reading_{READING_UNIT[optics]}", "repeat", "direction") + _AIR_COLUMNS


def _check_header(axis, optics, error_axis, rotation_axis, wavelength, basis, where) -> None:
    """Header-level rules; ``where(key)`` names the place of ``key``."""
    if axis not in CARRIAGES:
        raise InterferometerRunError(f"{where('axis')}: axis must be X, Y or Z, got {axis!r}")
    if optics not in OPTICS:
        raise InterferometerRunError(
            f"{where('optics')}: unknown optics {optics!r}; expected one of {', '.join(OPTICS)}")
    if optics == "straightness":
        if error_axis not in CARRIAGES:
            raise InterferometerRunError(
                f"{where('error_axis')}: straightness needs error_axis X, Y or Z (the direction of the measured "
                f"error), got {error_axis!r}")
        if error_axis == axis:
            raise InterferometerRunError(
                f"{where('error_axis')}: a straightness error of the {axis} carriage is across the axis; error_axis "
                f"must differ from {axis} (the error along the axis is the linear optics' job)")
    elif error_axis is not None:
        raise InterferometerRunError(f"{where('error_axis')}: error_axis is only for straightness optics, not {optics}")
    if optics == "angular":
        if rotation_axis not in CARRIAGES:
            raise InterferometerRunError(
                f"{where('rotation_axis')}: angular optics need rotation_axis X, Y or Z, got {rotation_axis!r}")
    elif rotation_axis is not None:
        raise InterferometerRunError(f"{where('rotation_axis')}: rotation_axis is only for angular optics, not {optics}")
    if optics == "linear":
        if wavelength is None:
            raise InterferometerRunError(f"{where('wavelength_vacuum_nm')}: linear optics need the laser's vacuum "
                                         f"wavelength ('# wavelength_vacuum_nm: {HENE_VACUUM_WAVELENGTH_NM}')")
        if basis is None:
            raise InterferometerRunError(f"{where('reading_basis')}: linear optics need the reading basis "
                                         f"('# reading_basis: ' one of {', '.join(READING_BASES)})")
    if wavelength is not None and not (math.isfinite(wavelength) and wavelength > 0):
        raise InterferometerRunError(f"{where('wavelength_vacuum_nm')}: must be a positive number of nm, got {wavelength}")
    if basis is not None and basis not in READING_BASES:
        raise InterferometerRunError(
            f"{where('reading_basis')}: unknown reading basis {basis!r}; expected one of {', '.join(READING_BASES)}")


def _check_rows(cols: dict[str, np.ndarray], reading_name: str, where) -> None:
    """Row-level rules; ``where(i)`` names row i (file:line or 'row i')."""
    n = len(cols["target_mm"])
    for name, arr in cols.items():
        if len(arr) != n:
            raise InterferometerRunError(f"{name}: expected {n} values like target_mm, got {len(arr)}")
    if n == 0:
        raise InterferometerRunError(f"{where(None)}: no readings")
    float_cols = ("target_mm", reading_name) + _AIR_COLUMNS
    for name in float_cols:
        bad = np.flatnonzero(~np.isfinite(cols[name]))
        if len(bad):
            raise InterferometerRunError(f"{where(int(bad[0]))}: {name} is not finite ({cols[name][bad[0]]})")
    bad = np.flatnonzero(cols["repeat"] < 1)
    if len(bad):
        raise InterferometerRunError(f"{where(int(bad[0]))}: repeat must be an integer >= 1, got {cols['repeat'][bad[0]]}")
    bad = np.flatnonzero((cols["direction"] != 1) & (cols["direction"] != -1))
    if len(bad):
        raise InterferometerRunError(f"{where(int(bad[0]))}: direction must be +1 or -1, got {cols['direction'][bad[0]]}")
    for name, (lo, hi, what) in _RANGES.items():
        v = cols[name]
        bad = np.flatnonzero((v < lo) | (v > hi))
        if len(bad):
            raise InterferometerRunError(
                f"{where(int(bad[0]))}: {name} = {v[bad[0]]:g} is not {what}; expected {lo:g}..{hi:g}")
    seen: dict[tuple, int] = {}
    for i, key in enumerate(zip(cols["target_mm"].tolist(), cols["direction"].tolist(), cols["repeat"].tolist())):
        if key in seen:
            raise InterferometerRunError(
                f"{where(i)}: duplicate reading: target {key[0]:g} mm, direction {key[1]:+d}, repeat {key[2]} "
                f"already at {where(seen[key])}")
        seen[key] = i
    first: dict[float, int] = {}
    dirs: dict[float, set] = {}
    for i, (t, d) in enumerate(zip(cols["target_mm"].tolist(), cols["direction"].tolist())):
        first.setdefault(t, i)
        dirs.setdefault(t, set()).add(d)
    if len(first) < 2:
        raise InterferometerRunError(f"{where(None)}: only one target ({next(iter(first)):g} mm); a run needs at least two")
    for t, ds in dirs.items():
        if len(ds) < 2:
            missing = "-1" if 1 in ds else "+1"
            raise InterferometerRunError(
                f"{where(first[t])}: target {t:g} mm has no reading in direction {missing}; every target needs both "
                f"directions (+1 and -1) to average them and report the reversal")


def _fmt(v: float) -> str:
    v = float(v)
    return repr(v).removesuffix(".0") if v.is_integer() else repr(v)


class InterferometerRun:
    """One raw interferometer run: one optics set-up on one carriage, several
    repeats in both directions (file format: docs/interferometer.md).

    Parameters
    ----------
    axis : {'X', 'Y', 'Z'}
        The carriage that moves (its scale reading is the target).
    optics : {'linear', 'straightness', 'angular'}
        Linear optics measure delta_axis (reading in mm: the displacement the
        laser counted); straightness optics measure delta_{error_axis}
        (reading in um); angular optics measure eps_{rotation_axis} (reading in
        arc-seconds, right-hand rule). Roll measured with levels may be stored
        as angular with ``rotation_axis == axis``.
    target_mm : array_like (N,)
        Scale reading of the carriage at the stop, mm. The first row's target
        is home, where the component is zero.
    reading : array_like (N,)
        The instrument's reading: mm (linear), um (straightness) or arc-second
        (angular), signed along the positive machine axis.
    repeat : array_like of int (N,)
        Repeat number, >= 1.
    direction : array_like of int (N,)
        +1 if the target was approached moving towards +axis, -1 otherwise.
        Every target needs both.
    air_temperature_C, pressure_mmHg, humidity_percent : array_like (N,)
        Weather station: air T (C), P (mmHg), H (% RH) at the reading.
    material_temperature_C : array_like (N,)
        Machine (scale) temperature at the reading, C.
    error_axis : {'X', 'Y', 'Z'}, optional
        Straightness only: direction of the measured error (not ``axis``).
    rotation_axis : {'X', 'Y', 'Z'}, optional
        Angular only: axis of the measured rotation.
    wavelength_vacuum_nm : float, optional
        Laser vacuum wavelength, nm; required for linear optics.
    reading_basis : {'standard_air', 'vacuum', 'compensated'}, optional
        How linear readings were converted from fringes (``READING_BASES``);
        required for linear optics.
    metadata : mapping of str to str, optional
        Other header lines (date, operator, instrument...), kept verbatim.
    source : str, optional
        Where the run came from (file); used in messages.
    """

    __slots__ = ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis",
                 "metadata", "source", "_cols")

    def __init__(self, axis, optics, target_mm, reading, repeat, direction, air_temperature_C, pressure_mmHg,
                 humidity_percent, material_temperature_C, *, error_axis=None, rotation_axis=None,
                 wavelength_vacuum_nm=None, reading_basis=None, metadata=None, source=None, _where=None):
        axis = str(axis).upper() if axis is not None else axis
        error_axis = None if error_axis is None else str(error_axis).upper()
        rotation_axis = None if rotation_axis is None else str(rotation_axis).upper()
        if wavelength_vacuum_nm is not None:
            try:
                wavelength_vacuum_nm = float(wavelength_vacuum_nm)
            except (TypeError, ValueError):
                raise InterferometerRunError(f"wavelength_vacuum_nm: expected a number, got {wavelength_vacuum_nm!r}") from None
        label = source or "run"
        where_key = _where[0] if _where else (lambda key: f"{label}: {key}")
        where_row = _where[1] if _where else (lambda i: label if i is None else f"{label}: row {i}")
        _check_header(axis, optics, error_axis, rotation_axis, wavelength_vacuum_nm, reading_basis, where_key)
        reading_name = f"reading_{READING_UNIT[optics]}"
        cols: dict[str, np.ndarray] = {}
        raw = {"target_mm": target_mm, reading_name: reading, "air_temperature_C": air_temperature_C,
               "pressure_mmHg": pressure_mmHg, "humidity_percent": humidity_percent,
               "material_temperature_C": material_temperature_C}
        for name, v in raw.items():
            try:
                arr = np.array(v, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise InterferometerRunError(f"{label}: {name} cannot be read as numbers ({exc})") from None
            if arr.ndim != 1:
                raise InterferometerRunError(f"{label}: {name} must be 1-D, got shape {arr.shape}")
            cols[name] = arr
        for name, v in (("repeat", repeat), ("direction", direction)):
            arr = np.asarray(v)
            if arr.ndim != 1:
                raise InterferometerRunError(f"{label}: {name} must be 1-D, got shape {arr.shape}")
            try:
                as_f = arr.astype(np.float64)
            except (TypeError, ValueError):
                raise InterferometerRunError(f"{label}: {name} must be integers, got {arr.dtype}") from None
            bad = np.flatnonzero(~np.isfinite(as_f) | (as_f != np.round(as_f)) | (np.abs(as_f) > 2.0**53))
            if len(bad):
                raise InterferometerRunError(f"{where_row(int(bad[0]))}: {name} must be an integer, got {arr[bad[0]]}")
            cols[name] = as_f.astype(np.int64)
        _check_rows(cols, reading_name, where_row)
        for arr in cols.values():
            arr.setflags(write=False)
        self.axis = axis
        self.optics = optics
        self.error_axis = error_axis
        self.rotation_axis = rotation_axis
        self.wavelength_vacuum_nm = wavelength_vacuum_nm
        self.reading_basis = reading_basis
        self.metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        for k in self.metadata:
            if k in _KNOWN_KEYS or k == MAGIC or not k or ":" in k or "\n" in k or "\n" in self.metadata[k]:
                raise InterferometerRunError(f"{label}: metadata key {k!r} is reserved or not a single-line key")
        self.source = source
        self._cols = cols

    # -- columns ---------------------------------------------------------------
    @property
    def target_mm(self) -> np.ndarray:
        return self._cols["target_mm"]

    @property
    def reading(self) -> np.ndarray:
        """Readings in ``reading_unit``."""
        return self._cols[f"reading_{self.reading_unit}"]

    @property
    def repeat(self) -> np.ndarray:
        return self._cols["repeat"]

    @property
    def direction(self) -> np.ndarray:
        return self._cols["direction"]

    @property
    def air_temperature_C(self) -> np.ndarray:
        return self._cols["air_temperature_C"]

    @property
    def pressure_mmHg(self) -> np.ndarray:
        return self._cols["pressure_mmHg"]

    @property
    def humidity_percent(self) -> np.ndarray:
        return self._cols["humidity_percent"]

    @property
    def material_temperature_C(self) -> np.ndarray:
        return self._cols["material_temperature_C"]

    # -- what the run measures --------------------------------------------------
    @property
    def reading_unit(self) -> str:
        """'mm' (linear), 'um' (straightness) or 'arcsec' (angular)."""
        return READING_UNIT[self.optics]

    @property
    def component(self) -> str:
        """Map component measured: 'dx', 'dy', 'dz', 'ex', 'ey' or 'ez' (of carriage ``axis``)."""
        if self.optics == "linear":
            return "d" + self.axis.lower()
        if self.optics == "straightness":
            return "d" + self.error_axis.lower()
        return "e" + self.rotation_axis.lower()

    @property
    def column(self) -> str:
        """The map table column (``cmmpose.TABLE_COLUMNS``) this run fills, e.g. 'dy_um'."""
        return self.component + ("_um" if self.component[0] == "d" else "_arcsec")

    @property
    def home_mm(self) -> float:
        """Home: the first row's target, mm."""
        return float(self.target_mm[0])

    @property
    def name(self) -> str:
        """E.g. 'dy(X) straightness' (component, carriage, optics)."""
        return f"{self.component}({self.axis}) {self.optics}"

    def __len__(self) -> int:
        return len(self.target_mm)

    def columns(self) -> dict[str, np.ndarray]:
        """The columns in file order (read-only arrays)."""
        return {c: self._cols[c] for c in run_columns(self.optics)}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, InterferometerRun):
            return NotImplemented
        same = all(getattr(self, a) == getattr(other, a) for a in
                   ("axis", "optics", "error_axis", "rotation_axis", "wavelength_vacuum_nm", "reading_basis", "metadata"))
        return same and self._cols.keys() == other._cols.keys() and all(
            self._cols[k].dtype == other._cols[k].dtype and np.array_equal(self._cols[k], other._cols[k])
            for k in self._cols)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        reps = len(np.unique(self.repeat))
        targets = np.unique(self.target_mm)
        src = f", source={self.source!r}" if self.source else ""
        return (f"InterferometerRun({self.name}; {len(targets)} targets {targets[0]:g}..{targets[-1]:g} mm, "
                f"{reps} repeats, {len(self)} readings{src})")

    # -- files -----------------------------------------------------------------
    @classmethod
    def read(cls, path: str | PathLike) -> InterferometerRun:
        """Read a run file (docs/interferometer.md); see :func:`read_run`."""
        return read_run(path)

    def write(self, path: str | PathLike) -> None:
        """Write the run file (docs/interferometer.md); read back it is equal."""
        write_run(self, path)


def read_run(path: str | PathLike) -> InterferometerRun:
    """Read an interferometer run file.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    InterferometerRun

    Raises
    ------
    InterferometerRunError
        (a ``cmmpose.MapError``) on any malformed content, naming the file and line.
    """
    path = Path(path)
    try:
        lines = read_lines(path)
    except InterferometerRunError:
        raise
    except MapError as exc:
        raise InterferometerRunError(str(exc)) from None
    if not lines or lines[0].strip() != f"# {MAGIC}: {VERSION}":
        got = lines[0].strip() if lines else "an empty file"
        raise InterferometerRunError(
            f"{path}:1: not a cmmpose interferometer run (first line must be '# {MAGIC}: {VERSION}', got {got!r})")
    meta: dict[str, tuple[str, int]] = {}
    header: tuple[str, ...] | None = None
    header_line = 0
    rows: list[list[str]] = []
    row_lines: list[int] = []
    for lineno, raw in enumerate(lines[1:], start=2):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if header is not None:
                continue  # comments after the column header are ignored
            key, sep, value = line[1:].partition(":")
            key = key.strip()
            if not sep or not key:
                continue  # a plain comment
            if key in meta:
                raise InterferometerRunError(f"{path}:{lineno}: header key {key!r} repeats line {meta[key][1]}")
            meta[key] = (value.strip(), lineno)
            continue
        fields = [f.strip() for f in line.split(",")]
        if header is None:
            header, header_line = tuple(fields), lineno
            continue
        rows.append(fields)
        row_lines.append(lineno)

    def where_key(key: str) -> str:
        return f"{path}:{meta[key][1]}" if key in meta else f"{path}: header line '# {key}: ...'"

    def value(key: str) -> str | None:
        return meta[key][0] if key in meta else None

    for key in ("axis", "optics"):
        if key not in meta:
            raise InterferometerRunError(f"{path}: header line '# {key}: <value>' is missing")
    optics = value("optics").lower()
    wavelength = value("wavelength_vacuum_nm")
    if wavelength is not None:
        try:
            wavelength = float(wavelength)
        except ValueError:
            raise InterferometerRunError(
                f"{where_key('wavelength_vacuum_nm')}: wavelength_vacuum_nm {wavelength!r} is not a number") from None
    basis = value("reading_basis")
    _check_header(value("axis").upper(), optics, None if value("error_axis") is None else value("error_axis").upper(),
                  None if value("rotation_axis") is None else value("rotation_axis").upper(), wavelength, basis,
                  where_key)
    expected = run_columns(optics)
    if header is None:
        raise InterferometerRunError(f"{path}: no column header row {','.join(expected)!r}")
    if header != expected:
        hint = ""
        if set(header) - set(expected) and any(h.startswith("reading_") for h in header):
            hint = f" ({optics} optics read in {READING_UNIT[optics]}: the column is 'reading_{READING_UNIT[optics]}')"
        raise InterferometerRunError(
            f"{path}:{header_line}: column header must be {','.join(expected)!r}, got {','.join(header)!r}{hint}")
    values: dict[str, list] = {c: [] for c in expected}
    for fields, lineno in zip(rows, row_lines):
        if len(fields) != len(expected):
            raise InterferometerRunError(f"{path}:{lineno}: expected {len(expected)} fields, got {len(fields)}")
        for name, text in zip(expected, fields):
            if name in ("repeat", "direction"):
                try:
                    v = int(text)
                except ValueError:
                    want = "+1 or -1" if name == "direction" else "an integer >= 1"
                    raise InterferometerRunError(f"{path}:{lineno}: {name} {text!r} is not {want}") from None
            else:
                try:
                    v = float(text)
                except ValueError:
                    raise InterferometerRunError(f"{path}:{lineno}: {name} {text!r} is not a number") from None
                if not math.isfinite(v):
                    raise InterferometerRunError(f"{path}:{lineno}: {name} is not finite ({text})")
            values[name].append(v)
    if not rows:
        raise InterferometerRunError(f"{path}: no readings after the column header (line {header_line})")
    metadata = {k: v for k, (v, _) in meta.items() if k not in _KNOWN_KEYS}
    where = (where_key, lambda i: str(path) if i is None else f"{path}:{row_lines[i]}")
    return InterferometerRun(
        value("axis").upper(), optics, values["target_mm"], values[expected[1]], values["repeat"],
        values["direction"], values["air_temperature_C"], values["pressure_mmHg"], values["humidity_percent"],
        values["material_temperature_C"], error_axis=value("error_axis"), rotation_axis=value("rotation_axis"),
        wavelength_vacuum_nm=wavelength, reading_basis=basis, metadata=metadata,
        source=value("source") or str(path), _where=where)


def write_run(run: InterferometerRun, path: str | PathLike) -> None:
    """Write ``run`` as a run file at ``path`` (floats as their shortest exact text)."""
    if not isinstance(run, InterferometerRun):
        raise InputTypeError(f"run: expected an InterferometerRun, got {type(run).__name__}")
    lines = [f"# {MAGIC}: {VERSION}", f"# axis: {run.axis}", f"# optics: {run.optics}"]
    if run.error_axis is not None:
        lines.append(f"# error_axis: {run.error_axis}")
    if run.rotation_axis is not None:
        lines.append(f"# rotation_axis: {run.rotation_axis}")
    if run.wavelength_vacuum_nm is not None:
        lines.append(f"# wavelength_vacuum_nm: {_fmt(run.wavelength_vacuum_nm)}")
    if run.reading_basis is not None:
        lines.append(f"# reading_basis: {run.reading_basis}")
    if run.source:
        lines.append(f"# source: {' '.join(str(run.source).split())}")
    lines += [f"# {k}: {v}" for k, v in run.metadata.items()]
    cols = run.columns()
    lines.append(",".join(cols))
    for i in range(len(run)):
        lines.append(",".join(
            (f"{int(a[i]):+d}" if name == "direction" else str(int(a[i])) if name == "repeat" else _fmt(a[i]))
            for name, a in cols.items()))
    write_text(path, "\n".join(lines) + "\n")


# ---------------------------------------------------------------------------
# 3. Processing one run
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ProcessedRun:
    """One map component from one run (:func:`process_run`).

    Arrays are per target, in ascending position; values in ``unit`` ('um'
    for deltas, 'arcsec' for angles).

    Attributes
    ----------
    axis : str
        Carriage ('X', 'Y', 'Z').
    optics : str
        'linear', 'straightness' or 'angular'.
    component : str
        'dx' ... 'ez'; ``column`` is the map table column (e.g. 'dx_um').
    unit : str
        'um' or 'arcsec'.
    positions_mm : ndarray (m,)
        Targets, mm, ascending.
    values : ndarray (m,)
        The component: mean of the two directions' repeat means, zero at home.
    forward, backward : ndarray (m,)
        Mean of the +1 and of the -1 approaches, with the same zero as ``values``.
    reversal : ndarray (m,)
        forward - backward (+1 approach minus -1 approach) per target.
    repeatability : ndarray (m,)
        Pooled sample standard deviation of the repeats within each direction
        (NaN where no direction has two repeats).
    repeats : ndarray of int (m,)
        Fewest repeats of the two directions per target.
    home_mm : float
        Home target (first row of the run), where ``values`` is zero.
    temperature : float
        Temperature of the component, C: the mean material temperature, or 20
        when normalised (``material == 'normalise'``).
    material_temperature_C : tuple (mean, min, max)
        Material temperature during the run, C.
    material : str
        'keep' or 'normalise'.
    air_corrected : bool
        Whether the wavelength correction was applied (linear optics with a
        basis other than 'compensated').
    index_correction_ppm : float
        Mean correction applied, (n_basis / n_air - 1) * 1e6 ppm (0 when none).
    air_mean : tuple (T C, P mmHg, H %RH)
        Mean air of the run.
    u_index_ppm : float
        GUM standard uncertainty u_N of the refractivity (thesis line 768), ppm
        (linear optics; 0 otherwise).
    wavelength_uncertainty : ndarray (m,)
        u_N times the distance from home, in ``unit`` (linear optics; zeros otherwise).
    source : str or None
        The run's source.
    """

    axis: str
    optics: str
    component: str
    unit: str
    positions_mm: np.ndarray
    values: np.ndarray
    forward: np.ndarray
    backward: np.ndarray
    reversal: np.ndarray
    repeatability: np.ndarray
    repeats: np.ndarray
    home_mm: float
    temperature: float
    material_temperature_C: tuple[float, float, float]
    material: str
    air_corrected: bool
    index_correction_ppm: float
    air_mean: tuple[float, float, float]
    u_index_ppm: float
    wavelength_uncertainty: np.ndarray
    source: str | None = None

    @property
    def column(self) -> str:
        """The map table column this component fills, e.g. 'dx_um'."""
        return self.component + ("_um" if self.unit == "um" else "_arcsec")

    @property
    def name(self) -> str:
        return f"{self.component}({self.axis}) {self.optics}"

    @property
    def max_reversal(self) -> float:
        """Largest |reversal|, in ``unit``."""
        return float(np.max(np.abs(self.reversal)))

    @property
    def max_repeatability(self) -> float:
        """Largest repeatability (NaN if none could be computed), in ``unit``."""
        r = self.repeatability[np.isfinite(self.repeatability)]
        return float(r.max()) if len(r) else float("nan")

    def table(self) -> str:
        """Plain-text table: position, value, reversal, repeatability, wavelength uncertainty."""
        u = self.unit
        head = f"{'position mm':>12} {'value ' + u:>13} {'reversal ' + u:>15} {'repeat. ' + u:>14} {'u(air) ' + u:>13}"
        rows = [f"{p:12.3f} {v:13.3f} {r:15.3f} {s:14.3f} {w:13.4f}" for p, v, r, s, w in
                zip(self.positions_mm, self.values, self.reversal, self.repeatability, self.wavelength_uncertainty)]
        corr = (f"air correction {self.index_correction_ppm:+.2f} ppm applied, u_N = {self.u_index_ppm:.2f} ppm"
                if self.air_corrected else "no air correction")
        t = self.material_temperature_C
        return "\n".join([f"{self.name} ({self.source or 'run'}): {corr}; material {t[0]:.2f} C "
                          f"({t[1]:.2f}..{t[2]:.2f}), map temperature {self.temperature:g} C", head, *rows])

    def __str__(self) -> str:
        return self.table()


_MATERIAL = ("keep", "normalise")
_LINES = (None, "endpoint", "least_squares")


def _linear_errors(run: InterferometerRun, corrected: bool, material: str, alpha: float,
                   label: str) -> tuple[np.ndarray, float]:
    """Steps 1 and 2 of :func:`process_run` for linear optics: the positional
    error of every row, um (laser displacement from home minus the target's
    distance from home), and the mean air correction applied, ppm."""
    target, home = run.target_mm, run.home_mm
    reading = np.asarray(run.reading, dtype=np.float64)
    if corrected:
        lo, hi = _HENE_RANGE_NM
        if not lo <= run.wavelength_vacuum_nm <= hi:
            raise InputError(
                f"{label}: wavelength_vacuum_nm = {run.wavelength_vacuum_nm:g} nm: the refractive-index formula "
                f"of thesis section 3.3 is for the HeNe line ({HENE_VACUUM_WAVELENGTH_NM} nm); pass "
                f"air_correction=False for readings corrected elsewhere")
        factor = np.asarray(correction_factor(run.air_temperature_C, run.pressure_mmHg, run.humidity_percent,
                                              run.reading_basis))
        reading = reading * factor
        correction_ppm = float(np.mean(factor - 1.0) * 1e6)
    else:
        correction_ppm = 0.0
    disp = reading - reading[target == home].mean()  # laser displacement from home, mm
    if material == "normalise":
        disp = disp / (1.0 + alpha * (run.material_temperature_C - 20.0))
    return (disp - (target - home)) * 1000.0, correction_ppm  # um


def positional_deviations(run: InterferometerRun, *, air_correction: bool = True, material: str = "keep",
                          expansion_ppm_per_C: float | None = None) -> np.ndarray:
    """The positional deviation of every row of a linear run, um: the air-
    corrected laser displacement from home minus the target's distance from
    home, i.e. actual minus commanded position (steps 1 and 2 of
    :func:`process_run`, without averaging). ISO 230-2 evaluates these
    (``cmmpose.standards.iso230_2``).

    Parameters
    ----------
    run : InterferometerRun
        Linear optics.
    air_correction : bool
        Correct the readings for the refractive index of air (as :func:`process_run`).
    material : {'keep', 'normalise'}
        Keep the machine's temperature or normalise the displacements to 20 C.
    expansion_ppm_per_C : float, optional
        Scale expansion coefficient, ppm per C; required with ``material='normalise'``.

    Returns
    -------
    ndarray (N,)
        um, in the run's row order.
    """
    if not isinstance(run, InterferometerRun):
        raise InputTypeError(f"run: expected an InterferometerRun, got {type(run).__name__}")
    label = run.source or run.name
    if run.optics != "linear":
        raise InputError(f"{label}: positional deviations need linear optics; this run is {run.optics} ({run.name})")
    if material not in _MATERIAL:
        raise InputError(f"material: expected 'keep' or 'normalise', got {material!r}")
    alpha = 0.0
    if material == "normalise":
        if expansion_ppm_per_C is None:
            raise InputError("expansion_ppm_per_C: required with material='normalise'")
        alpha = nonnegative("expansion_ppm_per_C", expansion_ppm_per_C) * 1e-6
    corrected = air_correction and run.reading_basis != "compensated"
    return _linear_errors(run, corrected, material, alpha, label)[0]


def process_run(
    run: InterferometerRun,
    *,
    air_correction: bool = True,
    material: str = "keep",
    expansion_ppm_per_C: float | None = None,
    air_uncertainty: Sequence[float] = THESIS_AIR_UNCERTAINTY,
    straightness_line: str | None = None,
) -> ProcessedRun:
    """Turn one raw run into one map component.

    Steps (docs/interferometer.md):

    1. Linear optics: each reading (mm) times n_basis / n_air of its own row's
       air (:func:`correction_factor`, thesis line 762), unless
       ``air_correction`` is False or the basis is 'compensated'. Straightness
       and angular readings are not corrected: both are differences of two
       beam paths through the same air, so the air changes them by the same
       few ppm *of the reading* (a few um or arc-seconds: 1e-5 um, 1e-5
       arc-second, far below the 0.1 um / 0.1 arc-second resolution of thesis
       lines 756 and 774), whereas a linear reading is wrong by ppm of the
       whole travel (5 ppm of 900 mm = 4.5 um).
    2. Linear optics: error = (laser displacement from home, optionally
       normalised to 20 C) - (target - home), in um. The displacement from home
       is the corrected reading minus the mean corrected reading at home.
       ``material='keep'`` (default) keeps the machine's own temperature, as the
       thesis's maps at 20, 25 and 30 C do (its X scale error grows from 43 to
       141 um at 900 mm, line 822): the component is labelled with the mean
       material temperature. ``material='normalise'`` divides each
       displacement by 1 + alpha (T_material - 20) (alpha =
       ``expansion_ppm_per_C``; the thesis's X scale bar is 12 ppm/C, line
       822), i.e. the error the machine would show at 20 C if its scale only
       expanded uniformly; the component is labelled 20 C. Other optics are
       used as read (their temperature dependence is not a uniform expansion).
    3. Mean of the repeats per target and direction; component = mean of the
       two directions; reversal = (+1 mean) - (-1 mean); repeatability =
       pooled within-direction standard deviation of the repeats.
    4. Straightness only, if asked: remove the ``'endpoint'`` or
       ``'least_squares'`` line (beam misalignment; it also removes any true
       slope, which belongs to the squareness measured separately).
    5. Zero at home (the first row's target): the map convention of thesis
       line 703.

    Parameters
    ----------
    run : InterferometerRun
    air_correction : bool
        Apply step 1 (default True). False shows what the uncorrected
        instrument would give.
    material : {'keep', 'normalise'}
        See step 2.
    expansion_ppm_per_C : float, optional
        Expansion coefficient of the scale, ppm per C (um/m/C); required with
        ``material='normalise'``.
    air_uncertainty : (u_T C, u_P mmHg, u_H %RH)
        Standard uncertainties of the weather-station inputs for the GUM
        budget (default ``THESIS_AIR_UNCERTAINTY``, thesis lines 770-772).
    straightness_line : {None, 'endpoint', 'least_squares'}
        See step 4.

    Returns
    -------
    ProcessedRun

    Raises
    ------
    InputError
        Bad options, or air correction of a laser that is not a HeNe (the
        section 3.3 constants are for 633 nm).
    """
    if not isinstance(run, InterferometerRun):
        raise InputTypeError(f"run: expected an InterferometerRun, got {type(run).__name__}")
    if material not in _MATERIAL:
        raise InputError(f"material: expected 'keep' or 'normalise', got {material!r}")
    if straightness_line not in _LINES:
        raise InputError(f"straightness_line: expected None, 'endpoint' or 'least_squares', got {straightness_line!r}")
    if straightness_line is not None and run.optics != "straightness":
        raise InputError(f"straightness_line: only for straightness optics; {run.name} is {run.optics}")
    alpha = 0.0
    if material == "normalise":
        if expansion_ppm_per_C is None:
            raise InputError("expansion_ppm_per_C: required with material='normalise' (e.g. 12 for steel, "
                             "thesis line 822)")
        alpha = nonnegative("expansion_ppm_per_C", expansion_ppm_per_C) * 1e-6
    try:
        u_air = tuple(float(v) for v in air_uncertainty)
    except (TypeError, ValueError):
        raise InputError(f"air_uncertainty: expected (u_T C, u_P mmHg, u_H %RH), got {air_uncertainty!r}") from None
    if len(u_air) != 3:
        raise InputError(f"air_uncertainty: expected 3 values (u_T C, u_P mmHg, u_H %RH), got {len(u_air)}")

    label = run.source or run.name
    t_air, p_air, h_air = run.air_temperature_C, run.pressure_mmHg, run.humidity_percent
    tm = run.material_temperature_C
    target = run.target_mm
    home = run.home_mm
    linear = run.optics == "linear"
    corrected = linear and air_correction and run.reading_basis != "compensated"
    if linear:
        err, correction_ppm = _linear_errors(run, corrected, material, alpha, label)
        unit = "um"
    else:
        err = np.asarray(run.reading, dtype=np.float64)
        correction_ppm = 0.0
        unit = READING_UNIT[run.optics] if run.optics == "angular" else "um"

    positions = np.unique(target)
    m = len(positions)
    fwd = np.empty(m)
    bwd = np.empty(m)
    rep = np.full(m, np.nan)
    counts = np.empty(m, dtype=np.int64)
    idx = np.searchsorted(positions, target)
    for k in range(m):
        sel = idx == k
        f = err[sel & (run.direction == 1)]
        b = err[sel & (run.direction == -1)]
        fwd[k], bwd[k] = f.mean(), b.mean()
        counts[k] = min(len(f), len(b))
        dof = (len(f) - 1) + (len(b) - 1)
        if dof > 0:
            rep[k] = math.sqrt((np.sum((f - f.mean()) ** 2) + np.sum((b - b.mean()) ** 2)) / dof)
    mean = 0.5 * (fwd + bwd)
    if straightness_line is not None:
        if straightness_line == "endpoint":
            slope = (mean[-1] - mean[0]) / (positions[-1] - positions[0])
            line = mean[0] + slope * (positions - positions[0])
        else:
            line = np.polyval(np.polyfit(positions, mean, 1), positions)
        mean, fwd, bwd = mean - line, fwd - line, bwd - line
    k_home = int(np.searchsorted(positions, home))
    zero = mean[k_home]
    u_n = refractivity_uncertainty(*u_air) if linear else 0.0
    w_unc = np.abs(positions - home) * u_n * 1e-3 if linear else np.zeros(m)  # mm * ppm -> um
    if material == "normalise":
        temperature = 20.0
    else:
        temperature = float(tm.mean())
    return ProcessedRun(
        axis=run.axis, optics=run.optics, component=run.component, unit=unit, positions_mm=positions,
        values=mean - zero, forward=fwd - zero, backward=bwd - zero, reversal=fwd - bwd, repeatability=rep,
        repeats=counts, home_mm=home, temperature=temperature,
        material_temperature_C=(float(tm.mean()), float(tm.min()), float(tm.max())), material=material,
        air_corrected=corrected, index_correction_ppm=correction_ppm,
        air_mean=(float(t_air.mean()), float(p_air.mean()), float(h_air.mean())), u_index_ppm=u_n,
        wavelength_uncertainty=w_unc, source=run.source)


# ---------------------------------------------------------------------------
# 4. Assembly and comparison
# ---------------------------------------------------------------------------

_COMPONENTS = ("dx", "dy", "dz", "ex", "ey", "ez")


@dataclass(frozen=True, eq=False)
class MapBuild:
    """The result of :func:`build_map`.

    Attributes
    ----------
    map : ErrorMap
        The assembled map (zero components where nothing was measured).
    runs : tuple of ProcessedRun
        The processed runs, by carriage and component.
    missing : tuple of str
        Components filled with zeros, e.g. ('ex(X)', 'ey(Y)', 'ez(Z)') when the
        rolls were not measured (thesis line 793).
    temperature : float or None
        The map's temperature, C.
    notes : tuple of str
        Everything that was warned about (missing components, truncated
        ranges, temperature spread).
    """

    map: ErrorMap
    runs: tuple[ProcessedRun, ...]
    missing: tuple[str, ...]
    temperature: float | None
    notes: tuple[str, ...] = field(default=())


def build_map(
    runs: Iterable[InterferometerRun | ProcessedRun],
    squareness: Sequence[float],
    temperature: float | None = None,
    *,
    air_correction: bool = True,
    material: str = "keep",
    expansion_ppm_per_C: float | None = None,
    air_uncertainty: Sequence[float] = THESIS_AIR_UNCERTAINTY,
    temperature_spread_C: float = 1.0,
    source: str | None = None,
) -> MapBuild:
    """Assemble runs into an ErrorMap: 18 carriage components + 3 squareness values.

    Parameters
    ----------
    runs : iterable of InterferometerRun or ProcessedRun
        At most one run per carriage and component; raw runs are processed
        with the options below (:func:`process_run`), processed ones are used
        as they are. Every carriage needs at least one run (its grid).
    squareness : (S_xy, S_yz, S_zx)
        Arc-seconds, thesis sign convention (Table 7; measured with a ballbar,
        line 703, not with the interferometer).
    temperature : float, optional
        Map temperature, C. Default: the mean of the runs' temperatures (their
        mean material temperatures, or 20 when normalised), rounded to 0.001 C.
    air_correction, material, expansion_ppm_per_C, air_uncertainty
        Passed to :func:`process_run` for raw runs.
    temperature_spread_C : float
        Warn when the runs' temperatures spread more than this, C.
    source : str, optional
        Source text of the map (default: a summary of the runs).

    Returns
    -------
    MapBuild
        ``.map`` is the ErrorMap. Each carriage's grid is the union of its
        runs' targets over their common range (components interpolated
        linearly, exact on shared targets); components without a run are zero
        and listed in ``.missing`` and in an :class:`InterferometerWarning`.

    Raises
    ------
    InterferometerRunError
        Two runs for one component, a carriage without runs, runs of one
        carriage without a common range, or runs processed with different
        material modes.
    """
    processed: list[ProcessedRun] = []
    for i, r in enumerate(list(runs)):
        if isinstance(r, InterferometerRun):
            processed.append(process_run(r, air_correction=air_correction, material=material,
                                         expansion_ppm_per_C=expansion_ppm_per_C, air_uncertainty=air_uncertainty))
        elif isinstance(r, ProcessedRun):
            processed.append(r)
        else:
            raise InputTypeError(f"runs[{i}]: expected an InterferometerRun or ProcessedRun, got {type(r).__name__}")
    sq = triple("squareness", squareness, unit="arc-seconds")
    by_key: dict[tuple[str, str], ProcessedRun] = {}
    for p in processed:
        key = (p.axis, p.component)
        if key in by_key:
            raise InterferometerRunError(
                f"two runs for {p.component}({p.axis}): {by_key[key].source or by_key[key].name} and "
                f"{p.source or p.name}; average them into one run or leave one out")
        by_key[key] = p
    modes = {p.material for p in processed}
    if len(modes) > 1:
        raise InterferometerRunError("runs mix material='keep' and material='normalise'; a map has one temperature")
    notes: list[str] = []
    tables = []
    missing: list[str] = []
    for c in CARRIAGES:
        mine = [by_key[(c, comp)] for comp in _COMPONENTS if (c, comp) in by_key]
        if not mine:
            raise InterferometerRunError(f"no run for the {c} carriage: its grid is unknown (give at least one run)")
        lo = max(float(p.positions_mm[0]) for p in mine)
        hi = min(float(p.positions_mm[-1]) for p in mine)
        if not lo < hi:
            raise InterferometerRunError(
                f"the {c} carriage runs have no common range: " +
                ", ".join(f"{p.name} {p.positions_mm[0]:g}..{p.positions_mm[-1]:g} mm" for p in mine))
        longer = [p.name for p in mine if p.positions_mm[0] < lo or p.positions_mm[-1] > hi]
        if longer:
            notes.append(f"{c} carriage: map truncated to the common range {lo:g}..{hi:g} mm of its runs "
                         f"(longer: {', '.join(longer)})")
        grid = np.unique(np.concatenate([p.positions_mm for p in mine]))
        grid = grid[(grid >= lo) & (grid <= hi)]
        table = np.zeros((len(grid), 7))
        table[:, 0] = grid
        for j, comp in enumerate(_COMPONENTS, start=1):
            p = by_key.get((c, comp))
            if p is None:
                missing.append(f"{comp}({c})")
                continue
            table[:, j] = np.interp(grid, p.positions_mm, p.values)
        tables.append(table)
    if missing:
        rolls = [m for m in missing if m in ("ex(X)", "ey(Y)", "ez(Z)")]
        extra = " (roll is usually measured with levels, if at all: the thesis stores it as 0, line 793)" if rolls else ""
        notes.append(f"not measured, stored as zero: {', '.join(missing)}{extra}")
    temps = [p.temperature for p in processed]
    if temperature is None:
        temperature = round(float(np.mean(temps)), 3)  # 1 mK: no float noise in the map file
    else:
        temperature = finite("temperature", temperature)
    spread = max(temps) - min(temps)
    if spread > temperature_spread_C:
        notes.append(f"the runs' temperatures spread {spread:.2f} C ({min(temps):.2f}..{max(temps):.2f} C); "
                     f"the map is labelled {temperature:g} C")
    for n in notes:
        warnings.warn(n, InterferometerWarning, stacklevel=3)
    if source is None:
        source = f"{len(processed)} interferometer runs at {temperature:.2f} C"
        if missing:
            source += f"; zero (not measured): {', '.join(missing)}"
    try:
        m = ErrorMap(*tables, sq, temperature, source=source)
    except MapError as exc:
        raise InterferometerRunError(f"the assembled map is invalid: {exc}") from None
    return MapBuild(map=m, runs=tuple(by_key[k] for c in CARRIAGES for k in [(c, comp) for comp in _COMPONENTS]
                                      if k in by_key),
                    missing=tuple(missing), temperature=temperature, notes=tuple(notes))


def map_from_runs(runs, squareness, temperature: float | None = None, **options) -> ErrorMap:
    """The ErrorMap of :func:`build_map` (same parameters; ``options`` are its
    keyword options). Missing components are zeros, named in an
    :class:`InterferometerWarning` and in the map's ``source``."""
    return build_map(runs, squareness, temperature, **options).map


@dataclass(frozen=True, eq=False)
class MapComparison:
    """Differences a - b of two maps (:func:`compare_maps`).

    Attributes
    ----------
    positions : dict carriage -> ndarray (m,)
        Common grid per carriage, mm: the union of both grids over the common range.
    differences : dict carriage -> ndarray (m, 6)
        a - b per component, columns dx, dy, dz (um), ex, ey, ez (arc-second)
        (``TABLE_COLUMNS[1:]``).
    max_difference : dict carriage -> dict column -> float
        Largest |a - b| per carriage and component (um or arc-second).
    squareness_difference : (float, float, float)
        a - b of S_xy, S_yz, S_zx, arc-seconds.
    temperature_difference : float or None
        a - b of the map temperatures, C (None if either has none).
    """

    positions: dict[str, np.ndarray]
    differences: dict[str, np.ndarray]
    max_difference: dict[str, dict[str, float]]
    squareness_difference: tuple[float, float, float]
    temperature_difference: float | None

    @property
    def max_um(self) -> float:
        """Largest |difference| of any delta, um."""
        return max(v for d in self.max_difference.values() for k, v in d.items() if k.endswith("_um"))

    @property
    def max_arcsec(self) -> float:
        """Largest |difference| of any angle or squareness, arc-seconds."""
        return max([v for d in self.max_difference.values() for k, v in d.items() if k.endswith("_arcsec")]
                   + [abs(s) for s in self.squareness_difference])

    def table(self) -> str:
        """Plain-text table of the max |difference| per carriage and component."""
        head = "carriage " + " ".join(f"{c:>10}" for c in TABLE_COLUMNS[1:])
        rows = [f"{c:<8} " + " ".join(f"{self.max_difference[c][k]:10.3f}" for k in TABLE_COLUMNS[1:])
                for c in CARRIAGES]
        sq = ", ".join(f"{v:g}" for v in self.squareness_difference)
        t = "n/a" if self.temperature_difference is None else f"{self.temperature_difference:+.3f} C"
        return "\n".join(["max |a - b|", head, *rows, f"squareness a - b (arc-second): {sq}; temperature a - b: {t}"])

    def __str__(self) -> str:
        return self.table()


def compare_maps(a: ErrorMap, b: ErrorMap) -> MapComparison:
    """Per-component differences a - b on a common grid.

    Per carriage the grid is the union of both maps' grids over their common
    range; both tables are interpolated linearly there (exact: the maps are
    piecewise linear in position). Deltas in um, angles in arc-seconds.

    Raises
    ------
    InputError
        Not ErrorMaps, or a carriage whose two ranges do not overlap.
    """
    for name, m in (("a", a), ("b", b)):
        if not isinstance(m, ErrorMap):
            raise InputTypeError(f"{name}: expected an ErrorMap, got {type(m).__name__}")
    positions, diffs, maxima = {}, {}, {}
    for c in CARRIAGES:
        ta, tb = a.table(c), b.table(c)
        lo, hi = max(ta[0, 0], tb[0, 0]), min(ta[-1, 0], tb[-1, 0])
        if not lo < hi:
            raise InputError(f"compare_maps: the {c} ranges {ta[0, 0]:g}..{ta[-1, 0]:g} and {tb[0, 0]:g}..{tb[-1, 0]:g}"
                             " mm do not overlap")
        grid = np.union1d(ta[:, 0], tb[:, 0])
        grid = grid[(grid >= lo) & (grid <= hi)]
        d = np.column_stack([np.interp(grid, ta[:, 0], ta[:, j]) - np.interp(grid, tb[:, 0], tb[:, j])
                             for j in range(1, 7)])
        positions[c], diffs[c] = grid, d
        maxima[c] = {k: float(np.max(np.abs(d[:, j]))) for j, k in enumerate(TABLE_COLUMNS[1:])}
    sq = tuple(float(x - y) for x, y in zip(a.squareness, b.squareness))
    dt = None if a.temperature is None or b.temperature is None else float(a.temperature - b.temperature)
    return MapComparison(positions, diffs, maxima, sq, dt)  # type: ignore[arg-type]


def plot_map_difference(a: ErrorMap, b: ErrorMap, path: str | PathLike | None = None, *,
                        labels: tuple[str, str] = ("a", "b"), title: str | None = None):
    """Difference plot a - b of two maps (e.g. interferometer-built minus truth).

    Three rows (X, Y, Z carriage, position in mm) by two columns (deltas in
    um, angles in arc-seconds); one line per component, its legend entry giving
    the max |difference|. The title gives the squareness and temperature
    differences. matplotlib is imported lazily (Agg canvas, no pyplot).

    Parameters
    ----------
    a, b : ErrorMap
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi).
    labels : (str, str)
        Names of a and b in the title.
    title : str, optional
        First line of the title.

    Returns
    -------
    matplotlib.figure.Figure
        3 x 2 axes.
    """
    cmp = compare_maps(a, b)
    fig = new_figure(figsize=(12.0, 9.0), layout="constrained")
    axes = fig.subplots(3, 2, squeeze=False)
    colour = {"x": "C0", "y": "C1", "z": "C2"}
    um = "\u00b5m"
    for row, c in enumerate(CARRIAGES):
        x = cmp.positions[c]
        for col, kind in enumerate(("d", "e")):
            ax = axes[row, col]
            for j, name in enumerate(TABLE_COLUMNS[1:]):
                if name[0] != kind:
                    continue
                comp = name.split("_")[0]
                sym = ("\u03b4" if kind == "d" else "\u03b5") + comp[1]
                ax.plot(x, cmp.differences[c][:, j], color=colour[comp[1]], marker="o", ms=2.5, lw=1.2,
                        label=f"{sym}({c}): max {cmp.max_difference[c][name]:.3g}")
            ax.axhline(0.0, color="0.5", lw=0.6, zorder=0)
            ax.grid(True, alpha=0.3)
            ax.set_xlabel(f"{c} position (mm)")
            ax.set_ylabel(f"{c} carriage: difference " + (f"({um})" if kind == "d" else "(arc-second)"))
            if row == 0:
                ax.set_title("linear and straightness" if kind == "d" else "angular", fontsize="medium")
            ax.legend(fontsize="small", loc="best")
    sq = ", ".join(f"{v:.3g}" for v in cmp.squareness_difference)
    t = "" if cmp.temperature_difference is None else f"; temperature {cmp.temperature_difference:+.2f} \u00b0C"
    text = (f"Map difference {labels[0]} - {labels[1]}: max {cmp.max_um:.3g} {um}, {cmp.max_arcsec:.3g} arc-second\n"
            f"squareness S_xy, S_yz, S_zx difference (arc-second): {sq}{t}")
    fig.suptitle(text if title is None else f"{title}\n{text}")
    if path is not None:
        if not isinstance(path, (str, PathLike)):
            raise InputTypeError(f"path: expected a file path or None, got {type(path).__name__}")
        save_figure(fig, path, dpi=150)
    return fig
