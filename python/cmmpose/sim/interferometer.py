"""Simulated laser-interferometer runs (thesis section 3.3) from a truth map.

For every map component of a truth :class:`~cmmpose.ErrorMap` the simulator
produces the raw run an interferometer would record on that machine
(:class:`cmmpose.calibration.interferometer.InterferometerRun`): the carriage
steps outward from home and back, several repeats, with

- the truth component, zero at home (thesis line 703);
- the air: its real T, P, H differ from standard air (default 23 C, 750 mmHg,
  40 % RH: n is 6.3 ppm lower) and drift slowly during the run; the weather
  station records them (plus an optional station error);
- linear readings as the uncorrected instrument reports them: fringes of the
  real wavelength in air, converted with the wavelength of the reading basis
  (default standard air), so they are short by about 6 ppm of the travel
  (5.7 um at 900 mm); straightness and angular readings carry the same ppm
  scale error of their own (tiny) value;
- a reversal: the +1 approach reads the truth + r/2, the -1 approach - r/2;
- independent Gaussian noise per reading (defaults: the thesis's resolutions,
  0.1 um linear, line 756, and 0.1 arc-second angular, line 774; 0.2 um
  straightness).

What the analysis must not see (the truth) is returned apart, as a dict.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..calibration.interferometer.air import HENE_VACUUM_WAVELENGTH_NM, READING_BASES, STANDARD_AIR, refractive_index
from ..calibration.interferometer.runfile import InterferometerRun
from ..errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap
from ..errors import InputError, InputTypeError
from .._validate import triple

__all__ = [
    "DEFAULT_AIR",
    "DEFAULT_AIR_DRIFT",
    "DEFAULT_NOISE",
    "DEFAULT_REVERSAL",
    "READING_DECIMALS",
    "STATION_DECIMALS",
    "interferometer_components",
    "simulate_interferometer_run",
    "simulate_interferometer_runs",
]

#: Real air of the simulated calibration: T (C), P (mmHg), H (% RH). Its
#: refractivity is 6.28 ppm below standard air (20 C, 760 mmHg, 50 % RH).
DEFAULT_AIR = (23.0, 750.0, 40.0)
#: Change of the air over a run (first to last reading, linear in time): C, mmHg, % RH.
DEFAULT_AIR_DRIFT = (0.3, 1.0, 2.0)
#: Standard deviation of one reading, by optics: um (linear, straightness), arc-second (angular).
DEFAULT_NOISE = {"linear": 0.1, "straightness": 0.2, "angular": 0.1}
#: Reversal (+1 approach minus -1 approach), by optics: um or arc-second.
DEFAULT_REVERSAL = {"linear": 0.8, "straightness": 0.4, "angular": 0.3}
#: Decimals recorded with ``quantise=True``: readings to 0.1 um (linear, in mm:
#: 4 decimals; thesis line 756) and 0.1 arc-second (line 774); the weather
#: station to 0.01 C, 0.01 mmHg, 0.1 % RH; material temperature to 0.01 C.
READING_DECIMALS = {"linear": 4, "straightness": 1, "angular": 1}
STATION_DECIMALS = (2, 2, 1, 2)


def interferometer_components(include_roll: bool = True) -> list[tuple[str, str]]:
    """(carriage, component) of every run of a full calibration: per carriage
    the linear, two straightness and three (two without roll) angular runs."""
    out = []
    for c in CARRIAGES:
        for comp in ("dx", "dy", "dz", "ex", "ey", "ez"):
            if not include_roll and comp == "e" + c.lower():
                continue
            out.append((c, comp))
    return out


def _optics(carriage: str, component: str) -> tuple[str, dict]:
    if component not in ("dx", "dy", "dz", "ex", "ey", "ez"):
        raise InputError(f"component: expected one of dx, dy, dz, ex, ey, ez, got {component!r}")
    axis = component[1].upper()
    if component[0] == "e":
        return "angular", {"rotation_axis": axis}
    if axis == carriage:
        return "linear", {}
    return "straightness", {"error_axis": axis}


def _by_optics(name: str, value, default: Mapping[str, float], optics: str) -> float:
    if value is None:
        return float(default[optics])
    if isinstance(value, Mapping):
        return float(value.get(optics, default[optics]))
    v = float(value)
    if not np.isfinite(v):
        raise InputError(f"{name}: must be finite, got {v}")
    return v


def _targets(table: np.ndarray, targets, home, carriage: str):
    """The target positions (sorted, within the truth's range), home (the target nearest 0 by default; the first
    or the last) and the targets in the order they are visited from home with the outward direction:
    (grid, home, outward, direction)."""
    grid = np.unique(np.asarray(table[:, 0] if targets is None else targets, dtype=np.float64))
    if len(grid) < 2 or not np.isfinite(grid).all():
        raise InputError("targets: need at least two finite target positions")
    lo, hi = table[0, 0], table[-1, 0]
    if grid[0] < lo or grid[-1] > hi:
        raise InputError(f"targets: {grid[0]:g}..{grid[-1]:g} mm is outside the truth's {carriage} range {lo:g}..{hi:g} mm")
    if home is None:
        home = float(grid[np.argmin(np.abs(grid))])
    home = float(home)
    if home == grid[0]:
        return grid, home, grid, 1
    if home == grid[-1]:
        return grid, home, grid[::-1], -1
    raise InputError(f"home: {home:g} mm must be the first or last target ({grid[0]:g} or {grid[-1]:g} mm)")


def _program(outward: np.ndarray, s_out: int, repeats: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each repeat out and back: the target, the direction of approach and the repeat of each reading."""
    tgt, dirs, reps = [], [], []
    for r in range(1, repeats + 1):
        tgt += list(outward) + list(outward[::-1])
        dirs += [s_out] * len(outward) + [-s_out] * len(outward)
        reps += [r] * (2 * len(outward))
    return np.array(tgt), np.array(dirs, dtype=np.int64), np.array(reps, dtype=np.int64)


def _air(air, air_drift, station_error, frac: np.ndarray) -> tuple[tuple, tuple]:
    """The air the beam crossed at each reading (temperature C, pressure mmHg, humidity % RH: the mean plus its drift
    over the run, ``frac`` from -0.5 to 0.5) and what the weather station recorded (off by its error)."""
    t_air = air[0] + air_drift[0] * frac
    p_air = air[1] + air_drift[1] * frac
    h_air = air[2] + air_drift[2] * frac
    return (t_air, p_air, h_air), (t_air + station_error[0], p_air + station_error[1], h_air + station_error[2])


def _reading(optics: str, travel, value, n_air, reading_basis: str, rec) -> tuple[np.ndarray, np.ndarray]:
    """What the laser displays, and the index ratio behind it: linear optics count the carriage's displacement from
    home (``travel`` mm plus the error ``value`` um) in wavelengths of the reading basis's air (standard air,
    vacuum, or the station's recorded air); the other optics read ``value`` scaled by the air's index against
    standard air's."""
    n_std = float(refractive_index(*STANDARD_AIR))
    if optics != "linear":
        scale = n_air / n_std
        return value * scale, scale
    n_basis = {"standard_air": n_std, "vacuum": 1.0}.get(reading_basis)
    if n_basis is None:  # compensated with the station's (recorded) air
        n_basis = np.asarray(refractive_index(*rec))
    displacement = travel + value / 1000.0  # true carriage displacement from home, mm
    reading = displacement * n_air / n_basis  # fringes of lambda_vac/n_air counted with lambda_vac/n_basis
    return reading, n_air / n_basis


def simulate_interferometer_run(
    truth: ErrorMap,
    carriage: str,
    component: str,
    *,
    air: Sequence[float] = DEFAULT_AIR,
    air_drift: Sequence[float] = DEFAULT_AIR_DRIFT,
    station_error: Sequence[float] = (0.0, 0.0, 0.0),
    material_temperature: float | None = None,
    material_drift: float = 0.1,
    repeats: int = 3,
    noise: float | Mapping[str, float] | None = None,
    reversal: float | Mapping[str, float] | None = None,
    targets: Sequence[float] | None = None,
    home: float | None = None,
    reading_basis: str = "standard_air",
    wavelength_vacuum_nm: float = HENE_VACUUM_WAVELENGTH_NM,
    quantise: bool = True,
    seed: int | np.random.SeedSequence = 0,
) -> tuple[InterferometerRun, dict]:
    """One raw run of ``component`` of ``carriage`` on a machine whose errors are ``truth``.

    Parameters
    ----------
    truth : ErrorMap
        The machine's real errors (um, arc-seconds).
    carriage : {'X', 'Y', 'Z'}
    component : {'dx', 'dy', 'dz', 'ex', 'ey', 'ez'}
        The optics follow: linear for d<carriage>, straightness for the other
        deltas, angular for the angles (the roll as if from a level).
    air : (T C, P mmHg, H % RH)
        Mean real air during the run.
    air_drift : (C, mmHg, % RH)
        Change of the real air from the first to the last reading (linear in time).
    station_error : (C, mmHg, % RH)
        Weather-station error: recorded = real + this.
    material_temperature : float, optional
        Mean machine temperature, C; default the truth map's (20 if it has none).
    material_drift : float
        Change of the material temperature over the run, C.
    repeats : int
        Repeats (the thesis averaged three or five, line 822).
    noise, reversal : float or mapping optics -> float, optional
        Standard deviation of one reading and the reversal (+1 minus -1
        approach), um or arc-seconds; defaults ``DEFAULT_NOISE``, ``DEFAULT_REVERSAL``.
    targets : sequence of float, optional
        Target positions, mm; default the truth table's grid of the carriage.
    home : float, optional
        Home target, mm, at one end of the targets; default the target nearest
        0 (machine home). The run starts there.
    reading_basis : {'standard_air', 'vacuum', 'compensated'}
        How the simulated instrument converts fringes (linear optics).
    wavelength_vacuum_nm : float
        Recorded in the run header.
    quantise : bool
        Record readings and the weather station at the instrument's resolution
        (``READING_DECIMALS``, ``STATION_DECIMALS``; adds 0.03 um or
        0.03 arc-second of rounding noise), as a real run file would.
    seed : int or numpy.random.SeedSequence

    Returns
    -------
    (InterferometerRun, dict)
        The run, and its truth: ``positions`` (mm), ``values`` (the truth
        component zero at home, um or arc-second), ``reversal``, ``noise``,
        ``repeats``, ``air_mean`` (real), ``index_error_ppm`` (how far the
        linear readings are scaled by the air: (n_air / n_basis - 1) * 1e6,
        mean over the run), ``carriage``, ``component``, ``optics``.
    """
    if not isinstance(truth, ErrorMap):
        raise InputTypeError(f"truth: expected an ErrorMap, got {type(truth).__name__}")
    carriage = str(carriage).upper()
    if carriage not in CARRIAGES:
        raise InputError(f"carriage: expected X, Y or Z, got {carriage!r}")
    optics, axes = _optics(carriage, component)
    if reading_basis not in READING_BASES:
        raise InputError(f"reading_basis: expected one of {READING_BASES}, got {reading_basis!r}")
    repeats = int(repeats)
    if repeats < 1:
        raise InputError(f"repeats: must be >= 1, got {repeats}")
    air = triple("air", air)
    air_drift = triple("air_drift", air_drift)
    station_error = triple("station_error", station_error)
    sigma = _by_optics("noise", noise, DEFAULT_NOISE, optics)
    rev = _by_optics("reversal", reversal, DEFAULT_REVERSAL, optics)
    if sigma < 0:
        raise InputError(f"noise: must be >= 0, got {sigma}")
    rng = np.random.default_rng(seed)

    table = truth.table(carriage)
    grid, home, outward, s_out = _targets(table, targets, home, carriage)
    col = TABLE_COLUMNS.index(component + ("_um" if component[0] == "d" else "_arcsec"))
    true_at = np.interp(grid, table[:, 0], table[:, col])
    true_home = float(np.interp(home, table[:, 0], table[:, col]))

    tgt, dirs, reps = _program(outward, s_out, repeats)
    k = len(tgt)
    frac = np.linspace(-0.5, 0.5, k)
    (t_air, p_air, h_air), rec = _air(air, air_drift, station_error, frac)
    if material_temperature is None:
        material_temperature = 20.0 if truth.temperature is None else truth.temperature
    tm = float(material_temperature) + float(material_drift) * frac

    value = np.interp(tgt, grid, true_at) - true_home + dirs * rev / 2.0 + rng.normal(0.0, sigma, k)
    n_air = np.asarray(refractive_index(t_air, p_air, h_air))
    reading, scale = _reading(optics, tgt - home, value, n_air, reading_basis, rec)
    if quantise:
        reading = np.round(reading, READING_DECIMALS[optics])
        rec = tuple(np.round(v, d) for v, d in zip(rec, STATION_DECIMALS))
        tm = np.round(tm, STATION_DECIMALS[3])
    extra = {"wavelength_vacuum_nm": wavelength_vacuum_nm, "reading_basis": reading_basis} if optics == "linear" else {}
    name = f"{component}({carriage}) {optics}"
    run = InterferometerRun(
        carriage, optics, tgt, reading, reps, dirs, rec[0], rec[1], rec[2], tm, **axes, **extra,
        metadata={"simulated_by": "cmmpose.sim.interferometer"}, source=f"simulated {name}")
    info = {
        "carriage": carriage, "component": component, "optics": optics, "positions": grid,
        "values": true_at - true_home, "reversal": rev, "noise": sigma, "repeats": repeats, "home": home,
        "air_mean": (float(t_air.mean()), float(p_air.mean()), float(h_air.mean())),
        "index_error_ppm": float(np.mean(scale - 1.0) * 1e6),
        "material_temperature": float(tm.mean()),
    }
    return run, info


def simulate_interferometer_runs(
    truth: ErrorMap,
    *,
    include_roll: bool = True,
    components: Sequence[tuple[str, str]] | None = None,
    seed: int = 0,
    **options,
) -> tuple[list[InterferometerRun], dict[str, dict]]:
    """Raw runs for every component of ``truth`` (a full calibration).

    Parameters
    ----------
    truth : ErrorMap
        E.g. ``cmmpose.ErrorMapSet.thesis().maps[0]`` (20 C).
    include_roll : bool
        Simulate the three rolls too (True, default) or leave them unmeasured
        as the thesis did (line 793).
    components : sequence of (carriage, component), optional
        Default :func:`interferometer_components` (``include_roll``).
    seed : int
        One seed for the whole calibration; each run gets its own stream.
    options
        Passed to :func:`simulate_interferometer_run` (air, noise, reversal,
        repeats, station_error, ...).

    Returns
    -------
    (list of InterferometerRun, dict)
        The runs, and their truths keyed 'dx(X)', 'dy(X)', ...
    """
    comps = list(components) if components is not None else interferometer_components(include_roll)
    seqs = np.random.SeedSequence(int(seed)).spawn(len(comps))
    runs, truths = [], {}
    for (c, comp), s in zip(comps, seqs):
        run, info = simulate_interferometer_run(truth, c, comp, seed=s, **options)
        runs.append(run)
        truths[f"{comp}({c})"] = info
    return runs, truths
