"""Processing one laser-interferometer run into one map component (thesis section 3.3).

:func:`process_run` -> :class:`ProcessedRun`: air correction (linear optics
only), material temperature kept or normalised to 20 C, zero at home, repeats
and directions averaged, reversal and repeatability reported;
:func:`positional_deviations` gives the per-row deviations of a linear run.

Units: positions mm, map deltas um, angles arc-second, temperatures degrees C.
Line numbers are those of the thesis's plain text (data/SOURCES.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..._validate import nonnegative
from ...errors import InputError, InputTypeError
from .air import HENE_VACUUM_WAVELENGTH_NM, THESIS_AIR_UNCERTAINTY, correction_factor, refractivity_uncertainty
from .runfile import READING_UNIT, InterferometerRun

#: Vacuum wavelengths a HeNe run may declare, nm (around HENE_VACUUM_WAVELENGTH_NM).
_HENE_RANGE_NM = (632.0, 634.0)


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


def _expansion(material: str, expansion_ppm_per_C) -> float:
    """The scale's expansion coefficient, 1/C: 0 unless ``material`` is 'normalise', which requires it."""
    if material != "normalise":
        return 0.0
    if expansion_ppm_per_C is None:
        raise InputError("expansion_ppm_per_C: required with material='normalise' (e.g. 12 for steel, "
                         "thesis line 822)")
    return nonnegative("expansion_ppm_per_C", expansion_ppm_per_C) * 1e-6


def _air_uncertainty(air_uncertainty) -> tuple[float, float, float]:
    """``air_uncertainty`` as (u_T C, u_P mmHg, u_H %RH)."""
    try:
        u_air = tuple(float(v) for v in air_uncertainty)
    except (TypeError, ValueError):
        raise InputError(f"air_uncertainty: expected (u_T C, u_P mmHg, u_H %RH), got {air_uncertainty!r}") from None
    if len(u_air) != 3:
        raise InputError(f"air_uncertainty: expected 3 values (u_T C, u_P mmHg, u_H %RH), got {len(u_air)}")
    return u_air


def _direction_means(target: np.ndarray, direction: np.ndarray, err: np.ndarray):
    """Step 3 of :func:`process_run`: per target (ascending), the mean of the repeats in each direction, the
    pooled within-direction standard deviation of the repeats (NaN without repeats) and the repeats counted
    in both directions."""
    positions = np.unique(target)
    m = len(positions)
    fwd = np.empty(m)
    bwd = np.empty(m)
    rep = np.full(m, np.nan)
    counts = np.empty(m, dtype=np.int64)
    idx = np.searchsorted(positions, target)
    for k in range(m):
        sel = idx == k
        f = err[sel & (direction == 1)]
        b = err[sel & (direction == -1)]
        fwd[k], bwd[k] = f.mean(), b.mean()
        counts[k] = min(len(f), len(b))
        dof = (len(f) - 1) + (len(b) - 1)
        if dof > 0:
            rep[k] = math.sqrt((np.sum((f - f.mean()) ** 2) + np.sum((b - b.mean()) ** 2)) / dof)
    return positions, fwd, bwd, rep, counts


def _straightness_line(positions: np.ndarray, mean: np.ndarray, kind: str) -> np.ndarray:
    """Step 4 of :func:`process_run`: the ``'endpoint'`` or ``'least_squares'`` line through the mean
    component at each position."""
    if kind == "endpoint":
        slope = (mean[-1] - mean[0]) / (positions[-1] - positions[0])
        return mean[0] + slope * (positions - positions[0])
    return np.polyval(np.polyfit(positions, mean, 1), positions)


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
    alpha = _expansion(material, expansion_ppm_per_C)
    u_air = _air_uncertainty(air_uncertainty)

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

    positions, fwd, bwd, rep, counts = _direction_means(target, run.direction, err)
    m = len(positions)
    mean = 0.5 * (fwd + bwd)
    if straightness_line is not None:
        line = _straightness_line(positions, mean, straightness_line)
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
