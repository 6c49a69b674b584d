"""Measurement uncertainty (GUM): a small toolkit for uncertainty budgets, the
thesis's budgets as code, and propagation through compensation and sphere
fitting, by Monte Carlo (GUM Supplement 1) and by the law of propagation of
uncertainty (GUM eq. 10 / 13) with sensitivity coefficients from the kernels.

Thesis references are to section and line of its plain text (data/SOURCES.md).
Units: the thesis budgets are in um; the propagation functions work in the
package's units (mm, degrees, degrees C) and return mm and mm^2.
See docs/uncertainty.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

from .._arrays import as_rows, as_triple, as_vector
from .._validate import finite
from ..compensation import compensate
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError, OutOfRangeError, quoting
from ..fitting import fit_sphere
from ..pose import pose_tuple

__all__ = [
    "Input",
    "Budget",
    "CentreUncertainty",
    "LengthUncertainty",
    "mount_offset_budgets",
    "sphere_centre_budget",
    "ballbar_length_budget",
    "uncertainty_of_mean",
    "THESIS_SCALE_ERRORS_UM",
    "monte_carlo_sphere_centre",
    "monte_carlo_ballbar_length",
    "linear_sphere_centre_uncertainty",
    "linear_ballbar_length_uncertainty",
]

THESIS = "J. O. Harris, PhD thesis (McMaster)"


# ---------------------------------------------------------------------------
# GUM toolkit
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Input:
    """One input quantity of an uncertainty budget (GUM 4.1).

    Parameters
    ----------
    name : str
        What the input is (e.g. "E1: digitizer probing").
    value : float
        Its estimate x_i, in ``unit`` (0 for an error term whose expectation is zero).
    standard_uncertainty : float
        Its standard uncertainty u(x_i) >= 0, in ``unit``.
    unit : str
        Unit of ``value`` and ``standard_uncertainty`` (e.g. "um", "deg", "mm", "K").
    sensitivity : float
        Sensitivity coefficient c_i = df/dx_i, in (budget unit) per ``unit``;
        its sign is kept for the record, only |c_i u_i| enters the budget.
    note : str
        Where the number comes from.
    """

    name: str
    value: float
    standard_uncertainty: float
    unit: str
    sensitivity: float = 1.0
    note: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"Input.name: expected a non-empty string, got {self.name!r}")
        object.__setattr__(self, "value", finite(f"Input {self.name!r} value", self.value))
        u = finite(f"Input {self.name!r} standard_uncertainty", self.standard_uncertainty)
        if u < 0:
            raise InputError(f"Input {self.name!r}: standard_uncertainty must be >= 0, got {u}")
        object.__setattr__(self, "standard_uncertainty", u)
        object.__setattr__(self, "sensitivity", finite(f"Input {self.name!r} sensitivity", self.sensitivity))

    @property
    def contribution(self) -> float:
        """|c_i| u(x_i): this input's uncertainty contribution, in the budget's unit."""
        return abs(self.sensitivity) * self.standard_uncertainty

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "standard_uncertainty": self.standard_uncertainty,
                "unit": self.unit, "sensitivity": self.sensitivity, "contribution": self.contribution,
                "note": self.note}


@dataclass(frozen=True)
class Budget:
    """An uncertainty budget for uncorrelated inputs (GUM eq. 10):
    u_c(y) = sqrt(sum_i (c_i u(x_i))^2).

    Parameters
    ----------
    name : str
        The measurand (e.g. "U1").
    inputs : sequence of Input
        The input quantities; each contribution c_i u(x_i) is in ``unit``.
    unit : str
        Unit of the measurand and of the combined uncertainty (e.g. "um", "mm").
    source : str
        Where the budget comes from (thesis section, equation, lines).
    printed : float, optional
        The combined standard uncertainty the source prints, in ``unit``, kept
        for comparison (shown by :meth:`table`; never used in a calculation).
    """

    name: str
    inputs: tuple[Input, ...]
    unit: str
    source: str = ""
    printed: float | None = None

    def __post_init__(self) -> None:
        inputs = tuple(self.inputs)
        if not inputs:
            raise InputError(f"Budget {self.name!r}: needs at least one Input")
        bad = [type(i).__name__ for i in inputs if not isinstance(i, Input)]
        if bad:
            raise InputError(f"Budget {self.name!r}: inputs must be Input objects, got {bad[0]}")
        object.__setattr__(self, "inputs", inputs)
        if self.printed is not None:
            object.__setattr__(self, "printed", finite(f"Budget {self.name!r} printed", self.printed))

    @property
    def variance(self) -> float:
        """u_c^2 = sum (c_i u_i)^2, in ``unit`` squared."""
        return float(sum(i.contribution ** 2 for i in self.inputs))

    @property
    def combined_standard_uncertainty(self) -> float:
        """u_c = sqrt(sum (c_i u_i)^2), in ``unit`` (GUM eq. 10, uncorrelated inputs)."""
        return math.sqrt(self.variance)

    def expanded_uncertainty(self, k: float = 2.0) -> float:
        """U = k u_c, in ``unit``; k = 2 gives about 95 % coverage for a normal distribution."""
        k = finite("k", k)
        if k <= 0:
            raise InputError(f"k: the coverage factor must be positive, got {k}")
        return k * self.combined_standard_uncertainty

    def shares(self) -> list[float]:
        """Each input's share of the variance, (c_i u_i)^2 / u_c^2 (0..1), in input order."""
        var = self.variance
        return [(i.contribution ** 2 / var if var > 0 else 0.0) for i in self.inputs]

    def table(self, digits: int = 3) -> str:
        """The budget as a plain-text table (one row per input, then u_c and U).

        Parameters
        ----------
        digits : int
            Significant digits of the numbers.
        """
        g = f"{{:.{int(digits)}g}}".format
        head = ["input", "value", "u(x_i)", "unit", "c_i", f"|c_i| u(x_i) [{self.unit}]", "share"]
        rows = [[i.name, f"{i.value:.6g}", g(i.standard_uncertainty), i.unit, g(i.sensitivity), g(i.contribution),
                 f"{100 * s:.1f} %"] for i, s in zip(self.inputs, self.shares())]
        widths = [max(len(r[j]) for r in [head, *rows]) for j in range(len(head))]
        left = {0, 3}

        def line(r):
            return "  ".join(c.ljust(w) if j in left else c.rjust(w) for j, (c, w) in enumerate(zip(r, widths)))

        out = [f"Uncertainty budget: {self.name}" + (f"  ({self.source})" if self.source else ""), line(head),
               "-" * len(line(head)), *map(line, rows), "-" * len(line(head)),
               f"combined standard uncertainty u_c = {g(self.combined_standard_uncertainty)} {self.unit}",
               f"expanded uncertainty U (k = 2)   = {g(self.expanded_uncertainty(2.0))} {self.unit}"]
        if self.printed is not None:
            out.append(f"source prints u_c = {self.printed:g} {self.unit}")
        return "\n".join(out)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict:
        """Plain dict (JSON-serialisable) with the inputs, u_c and U (k = 2)."""
        return {"name": self.name, "unit": self.unit, "source": self.source, "printed": self.printed,
                "inputs": [i.to_dict() for i in self.inputs],
                "combined_standard_uncertainty": self.combined_standard_uncertainty,
                "expanded_uncertainty_k2": self.expanded_uncertainty(2.0)}


def uncertainty_of_mean(uncertainties, correlation: float = 0.0) -> float:
    """Standard uncertainty of the plain mean of k determinations (GUM eq. 13).

    u^2(mean) = (1/k^2) sum_i sum_j r_ij u_i u_j with r_ii = 1 and r_ij = ``correlation``.

    Parameters
    ----------
    uncertainties : array_like, shape (k,)
        Standard uncertainty of each determination, any unit (the result has the same).
    correlation : float
        Correlation coefficient between any two determinations, 0 (independent:
        u/sqrt(k) for equal u) to 1 (fully correlated: the mean of the u_i).

    Returns
    -------
    float
    """
    u = np.asarray(uncertainties, dtype=float)
    if u.ndim != 1 or len(u) == 0 or not np.all(np.isfinite(u)) or np.any(u < 0):
        raise InputError(f"uncertainties: expected a non-empty 1-D array of finite values >= 0, got {uncertainties!r}")
    r = finite("correlation", correlation)
    if not 0.0 <= r <= 1.0:
        raise InputError(f"correlation: must be between 0 and 1, got {r}")
    var = (1 - r) * np.sum(u ** 2) + r * np.sum(u) ** 2
    return float(np.sqrt(var) / len(u))


# ---------------------------------------------------------------------------
# The thesis's budgets
# ---------------------------------------------------------------------------

#: Worst-case scale errors (um, X, Y, Z) over a 404 mm length at each map
#: temperature, thesis section 6.4.1, lines 1751-1753.
THESIS_SCALE_ERRORS_UM: dict[float, tuple[float, float, float]] = {
    20.0: (12.0, 18.0, 6.0),
    25.0: (21.0, 30.0, 12.0),
    30.0: (26.0, 38.0, 20.0),
}

# Combined standard uncertainties the thesis prints (um), keyed as used below.
_PRINTED_OFFSET = {"U1": 35.1, "V1": 35.1, "W1": 39.9}  # eqs. 22-24, lines 1467, 1473, 1481
_PRINTED_LENGTH = {
    # (compensated, temperature or None, n_positions) -> um
    (True, None, 1): 20.0,   # 6.2.3, lines 1625, 1635, 1637
    (True, None, 8): 7.0,    # 6.2.3, line 1637; 404.084 +- 0.007 mm, line 1681
    (True, None, 20): 5.0,   # 6.3.1 "22 +- 5 um" line 1661; Tables 19 and 21, lines 1736-1738, 1763-1765
    (True, None, 60): 3.0,   # Table 19 all temperatures, line 1739; Table 21, line 1766 (0.005/sqrt(3), line 1772)
    (False, 20.0, 1): 26.0,  # 6.4.1, line 1753; 6.2.3, lines 1623, 1633
    (False, 25.0, 1): 41.0,  # 6.4.1, line 1753
    (False, 30.0, 1): 52.0,  # 6.4.1, line 1753
    (False, 20.0, 20): 6.0,  # Tables 19 and 21, lines 1736, 1763; 6.3.1 "71 +- 6 um" line 1661
    (False, 25.0, 20): 10.0,  # Tables 19 and 21, lines 1737, 1764
    (False, 30.0, 20): 12.0,  # Tables 19 and 21, lines 1738, 1765
}


def _reading(label: str, scale_axis: str, digitizer: float, fit_per_axis: float, scale: float, c: float) -> list[Input]:
    """The three error terms of one scale reading of an alignment (section 5.3, lines 1452-1458)."""
    return [
        Input(f"{label}: digitizer probing", 0.0, digitizer, "um", c, "Hyscan 45C probing uncertainty, 1 sigma (Table 17, line 1268)"),
        Input(f"{label}: sphere-centre fit", 0.0, fit_per_axis, "um", c, "10 um per centre spread over 3 axes: 10/sqrt(3) (line 1452)"),
        Input(f"{label}: {scale_axis} scale error", 0.0, scale, "um", c, "scale error over the range used (lines 1452, 1456)"),
    ]


def mount_offset_budgets(*, digitizer: float = 9.0, sphere_fit: float = 10.0, scale=(2.0, 16.5, 1.0),
                         model: str = "printed") -> dict[str, Budget]:
    """Uncertainty budgets of the mount offset U1, V1, W1 (thesis section 5.3, eqs. 19-24).

    Every scale reading D, E, F of an alignment carries three uncorrelated error
    terms: the digitizer's probing uncertainty, the sphere-centre fit's share
    per axis (``sphere_fit``/sqrt(3)) and that axis's scale error.

    Parameters
    ----------
    digitizer : float
        Digitizer probing uncertainty, um (thesis: 9).
    sphere_fit : float
        Sphere-centre fit uncertainty, um, as a 3-D value (thesis: 10; 10/sqrt(3)
        per axis, printed as 5.8).
    scale : sequence of 3 float
        Scale error of the X, Y, Z scale over the range used, um (thesis: 2, 16.5, 1).
    model : {'printed', 'corrected'}
        ``'printed'``: U1 and V1 from eqs. 19-20 (eqs. 22-23); W1 as eq. 24 is
        numbered, 5/4 u^2(D1) + 1/4 u^2(E1) + u^2(F1) (the form the thesis puts
        numbers into). ``'corrected'``: W1 = D1 - D3 - U1 (eq. 21 is
        misprinted: docs/conventions.md, Misprints), propagated from its six
        readings. U1 and V1 are the same.

    Returns
    -------
    dict
        ``{"U1": Budget, "V1": Budget, "W1": Budget}`` in um. Each budget's
        ``printed`` is the value the thesis prints (35.1, 35.1, 39.9 um), which
        eqs. 22-24 as printed do not give: they give 15.8, 15.8 and 19.0 um
        (docs/uncertainty.md, "The mount-offset figures").
    """
    dig = finite("digitizer", digitizer)
    fit = finite("sphere_fit", sphere_fit)
    sx, sy, sz = as_triple("scale", scale)
    if min(dig, fit, sx, sy, sz) < 0:
        raise InputError("digitizer, sphere_fit, scale: uncertainties must be >= 0 (um)")
    if model not in ("printed", "corrected"):
        raise InputError(f"model: expected 'printed' or 'corrected', got {model!r}")
    per_axis = fit / math.sqrt(3.0)
    axis = {"D": ("X", sx), "E": ("Y", sy), "F": ("Z", sz)}

    def reading(name: str, c: float) -> list[Input]:
        a, s = axis[name[0]]
        return _reading(name, a, dig, per_axis, s, c)

    src = "thesis section 5.3"
    u1 = [*reading("E1", 0.5), *reading("E2", -0.5), *reading("F2", 0.5), *reading("F1", -0.5)]
    v1 = [*reading("E1", 0.5), *reading("E2", -0.5), *reading("F1", 0.5), *reading("F2", -0.5)]
    if model == "printed":
        # Eq. 24 as numbered (line 1479): 5/4 u^2(D1) + 1/4 u^2(E1) + u^2(F1), i.e. effective
        # coefficients sqrt(5)/2, 1/2 and 1 on one reading of each axis.
        w1 = [*reading("D1 (x5/4 in variance)", math.sqrt(5.0) / 2), *reading("E1 (x1/4)", 0.5), *reading("F1 (x1)", 1.0)]
        w_src = f"{src}, eq. 24 as numbered, lines 1475-1481"
    else:
        w1 = [*reading("D1", 1.0), *reading("D3", -1.0), *reading("E1", -0.5), *reading("E2", 0.5),
              *reading("F2", -0.5), *reading("F1", 0.5)]
        w_src = f"{src}, W1 = D1 - D3 - U1 (eqs. 16, 18, 19; docs/conventions.md, Misprints)"
    return {
        "U1": Budget("U1", tuple(u1), "um", f"{src}, eqs. 19 and 22, lines 1446, 1460-1467", _PRINTED_OFFSET["U1"]),
        "V1": Budget("V1", tuple(v1), "um", f"{src}, eqs. 20 and 23, lines 1448, 1469-1473", _PRINTED_OFFSET["V1"]),
        "W1": Budget("W1", tuple(w1), "um", w_src, _PRINTED_OFFSET["W1"]),
    }


def sphere_centre_budget(*, digitizer: float = 9.0, sphere_fit: float = 10.0) -> Budget:
    """Uncertainty of one compensated sphere centre (thesis section 6.2.3, line 1637).

    u_p^2 = 9^2 + 10^2: the digitizer's point accuracy and the sphere-centre fit.

    Parameters
    ----------
    digitizer : float
        Digitizer point accuracy, um (thesis: 9, Hymarc).
    sphere_fit : float
        Sphere-centre fit algorithm uncertainty, um (thesis: 10, Rosenfeld 1996).

    Returns
    -------
    Budget
        In um; u_c = 13.45 um, which the thesis prints (rounded up) as 14 um.
    """
    dig, fit = finite("digitizer", digitizer), finite("sphere_fit", sphere_fit)
    if min(dig, fit) < 0:
        raise InputError("digitizer, sphere_fit: uncertainties must be >= 0 (um)")
    printed = 14.0 if (dig, fit) == (9.0, 10.0) else None
    return Budget("sphere centre (compensated)", (
        Input("digitizer point accuracy", 0.0, dig, "um", 1.0, "Hymarc, 1 sigma (Table 17, line 1268)"),
        Input("sphere-centre fit", 0.0, fit, "um", 1.0, "NIST algorithm, 'Fit' column of Figure C-2 (Rosenfeld 1996)"),
    ), "um", "thesis section 6.2.3, line 1637", printed)


def ballbar_length_budget(n_positions: int = 1, compensated: bool = True, *, temperature: float = 20.0,
                          digitizer: float = 9.0, sphere_fit: float = 10.0, scale=None) -> Budget:
    """Uncertainty of a ballbar length, or of the mean of ``n_positions`` lengths.

    Compensated (section 6.2.3, line 1637): each of the two centres has
    u_p^2 = 9^2 + 10^2, so u_L^2 = 2 u_p^2 for one length. Uncompensated
    (section 6.4.1, lines 1751-1753): u^2 = 9^2 + 10^2 + s_X^2 + s_Y^2 + s_Z^2
    with the worst-case scale errors s at the temperature (the thesis counts the
    digitizer and fit terms once here, not per ball; reproduced as printed).
    The mean of n uncorrelated lengths divides by sqrt(n): every input gets the
    sensitivity 1/sqrt(n) (n repetitions of it, each with sensitivity 1/n).

    Parameters
    ----------
    n_positions : int
        Lengths averaged (1 for a single length; thesis 8 in section 6.2, 20 per
        temperature in 6.3 and 6.4).
    compensated : bool
        Compensated (6.2.3) or uncompensated (6.4.1) data.
    temperature : float
        Machine temperature, degrees C, choosing the scale errors of the
        uncompensated budget (20, 25 or 30; ignored when compensated or when
        ``scale`` is given).
    digitizer : float
        Digitizer point accuracy, um (thesis: 9).
    sphere_fit : float
        Sphere-centre fit uncertainty, um (thesis: 10).
    scale : sequence of 3 float, optional
        Scale errors of X, Y, Z over the length, um (uncompensated only);
        default ``THESIS_SCALE_ERRORS_UM[temperature]``.

    Returns
    -------
    Budget
        In um, with ``printed`` set where the thesis prints this figure.
    """
    if isinstance(n_positions, bool) or not isinstance(n_positions, (int, np.integer)) or n_positions < 1:
        raise InputError(f"n_positions: expected a positive integer, got {n_positions!r}")
    n = int(n_positions)
    dig, fit = finite("digitizer", digitizer), finite("sphere_fit", sphere_fit)
    if min(dig, fit) < 0:
        raise InputError("digitizer, sphere_fit: uncertainties must be >= 0 (um)")
    c = 1.0 / math.sqrt(n)
    mean = f"mean of {n} positions" if n > 1 else "single position"
    default = (dig, fit) == (9.0, 10.0)
    if compensated:
        inputs = tuple(
            Input(f"ball {b}: {what}", 0.0, u, "um", c, note)
            for b in (1, 2)
            for what, u, note in (("digitizer point accuracy", dig, "Hymarc (line 1637)"),
                                  ("sphere-centre fit", fit, "Rosenfeld 1996 (line 1637)"))
        )
        printed = _PRINTED_LENGTH.get((True, None, n)) if default else None
        return Budget(f"ballbar length, compensated, {mean}", inputs, "um", "thesis section 6.2.3, line 1637", printed)
    t = finite("temperature", temperature)
    if scale is None:
        if t not in THESIS_SCALE_ERRORS_UM:
            raise InputError(f"temperature: the thesis gives scale errors at 20, 25 and 30 C only, got {t}; pass scale=(sX, sY, sZ) in um")
        s, note = THESIS_SCALE_ERRORS_UM[t], f"worst case at {t:g} C (lines 1751-1753)"
        printed = _PRINTED_LENGTH.get((False, t, n)) if default else None
    else:
        s, note, printed = as_triple("scale", scale), "given", None
        if min(s) < 0:
            raise InputError("scale: uncertainties must be >= 0 (um)")
    inputs = (
        Input("digitizer point accuracy", 0.0, dig, "um", c, "along the bar only (line 1751)"),
        Input("sphere-centre fit", 0.0, fit, "um", c, "not split into axes (line 1753)"),
        *(Input(f"{a} scale error", 0.0, v, "um", c, note) for a, v in zip("XYZ", s)),
    )
    label = f"{t:g} C" if scale is None else "given scale errors"
    return Budget(f"ballbar length, uncompensated, {label}, {mean}", inputs, "um",
                  "thesis section 6.4.1, lines 1751-1753", printed)


# ---------------------------------------------------------------------------
# Propagation through compensation and fitting
# ---------------------------------------------------------------------------

_PARAMS = ("alpha", "beta", "gamma", "U1", "V1", "W1", "temperature")
_UNITS = {"alpha": "deg", "beta": "deg", "gamma": "deg", "U1": "mm", "V1": "mm", "W1": "mm", "temperature": "K"}


def _probability(p) -> float:
    p = finite("p", p)
    if not 0 < p < 1:
        raise InputError(f"p: coverage probability must be between 0 and 1, got {p}")
    return p


def _quantile_interval(samples: np.ndarray, p: float) -> np.ndarray:
    p = _probability(p)
    return np.quantile(samples, [(1 - p) / 2, (1 + p) / 2], axis=0)


def _normal_quantile(p: float) -> float:
    """z with P(|Z| <= z) = p for a standard normal Z."""
    return NormalDist().inv_cdf((1 + _probability(p)) / 2)


@dataclass(frozen=True)
class CentreUncertainty:
    """Uncertainty of a fitted sphere centre.

    Attributes
    ----------
    method : str
        ``"monte carlo"`` or ``"linear"``.
    centre : ndarray (3,)
        Monte Carlo: mean of the trial centres; linear: the centre fitted to the
        unperturbed data. mm.
    covariance : ndarray (3, 3)
        Covariance of the centre, mm^2.
    trials : ndarray (M, 3) or None
        Monte Carlo trial centres, mm.
    contributions : dict of str -> ndarray (3, 3)
        Linear: covariance contributed by each input (``noise``, ``alpha``,
        ``beta``, ``gamma``, ``U1``, ``V1``, ``W1``, ``temperature``), mm^2.
    sensitivities : dict of str -> ndarray (3,)
        Linear: d(centre)/d(input) in mm per deg, mm per mm, mm per K. For
        ``noise`` the effective coefficient sqrt(cov_noise_ii)/u_noise.
    inputs : dict of str -> tuple (value, standard uncertainty, unit)
        The inputs as propagated.
    """

    method: str
    centre: np.ndarray
    covariance: np.ndarray
    trials: np.ndarray | None = None
    contributions: Mapping[str, np.ndarray] = field(default_factory=dict)
    sensitivities: Mapping[str, np.ndarray] = field(default_factory=dict)
    inputs: Mapping[str, tuple] = field(default_factory=dict)

    @property
    def standard_uncertainty(self) -> np.ndarray:
        """Standard uncertainty of x, y, z, mm (3,)."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def n_trials(self) -> int:
        """Monte Carlo trials (0 for the linear method)."""
        return 0 if self.trials is None else len(self.trials)

    def expanded_uncertainty(self, k: float = 2.0) -> np.ndarray:
        """k times the standard uncertainties, mm (3,)."""
        k = finite("k", k)
        if k <= 0:
            raise InputError(f"k: the coverage factor must be positive, got {k}")
        return k * self.standard_uncertainty

    def coverage_interval(self, p: float = 0.95) -> np.ndarray:
        """Per-axis coverage interval, (2, 3) mm: Monte Carlo the probabilistically
        symmetric interval from the trial quantiles (GUM S1 7.7); linear
        centre +- z_p u (normal distribution)."""
        if self.trials is not None:
            return _quantile_interval(self.trials, p)
        z = _normal_quantile(p)
        return np.stack([self.centre - z * self.standard_uncertainty, self.centre + z * self.standard_uncertainty])

    def budget(self, axis) -> Budget:
        """The linear result as a GUM budget for one coordinate (``'x'``, ``'y'``, ``'z'`` or 0-2), mm."""
        if self.method != "linear":
            raise InputError("budget: a Monte Carlo result has no sensitivity coefficients; use linear_sphere_centre_uncertainty")
        j = {"x": 0, "y": 1, "z": 2}.get(axis, axis)
        if j not in (0, 1, 2):
            raise InputError(f"axis: expected 'x', 'y', 'z' or 0-2, got {axis!r}")
        return _budget_from(f"sphere centre {'xyz'[j]}", self.inputs, {k: float(v[j]) for k, v in self.sensitivities.items()})

    def to_dict(self) -> dict:
        return {"method": self.method, "centre": self.centre.tolist(), "covariance": self.covariance.tolist(),
                "standard_uncertainty": self.standard_uncertainty.tolist(), "n_trials": self.n_trials,
                "contributions": {k: np.sqrt(np.diag(v)).tolist() for k, v in self.contributions.items()}}


@dataclass(frozen=True)
class LengthUncertainty:
    """Uncertainty of a ballbar length (distance between two fitted centres).

    Attributes
    ----------
    method : str
        ``"monte carlo"`` or ``"linear"``.
    length : float
        Monte Carlo: mean of the trial lengths; linear: the length from the
        unperturbed data. mm.
    standard_uncertainty : float
        mm.
    trials : ndarray (M,) or None
        Monte Carlo trial lengths, mm.
    centres : ndarray (2, 3)
        Centres of ball 1 and ball 2 (Monte Carlo: trial means), mm.
    contributions : dict of str -> float
        Linear: variance contributed by each input, mm^2 (``noise 1``,
        ``noise 2`` and the common ``alpha`` ... ``temperature``).
    sensitivities : dict of str -> float
        Linear: d(length)/d(input), mm per deg, mm per mm, mm per K (noise: effective).
    inputs : dict of str -> tuple (value, standard uncertainty, unit)
    """

    method: str
    length: float
    standard_uncertainty: float
    centres: np.ndarray
    trials: np.ndarray | None = None
    contributions: Mapping[str, float] = field(default_factory=dict)
    sensitivities: Mapping[str, float] = field(default_factory=dict)
    inputs: Mapping[str, tuple] = field(default_factory=dict)

    @property
    def n_trials(self) -> int:
        return 0 if self.trials is None else len(self.trials)

    def expanded_uncertainty(self, k: float = 2.0) -> float:
        """k u, mm."""
        k = finite("k", k)
        if k <= 0:
            raise InputError(f"k: the coverage factor must be positive, got {k}")
        return k * self.standard_uncertainty

    def coverage_interval(self, p: float = 0.95) -> np.ndarray:
        """(2,) mm: trial quantiles (Monte Carlo) or length +- z_p u (linear)."""
        if self.trials is not None:
            return _quantile_interval(self.trials, p)
        z = _normal_quantile(p)
        return np.array([self.length - z * self.standard_uncertainty, self.length + z * self.standard_uncertainty])

    def budget(self) -> Budget:
        """The linear result as a GUM budget, mm."""
        if self.method != "linear":
            raise InputError("budget: a Monte Carlo result has no sensitivity coefficients; use linear_ballbar_length_uncertainty")
        return _budget_from("ballbar length", self.inputs, dict(self.sensitivities))

    def to_dict(self) -> dict:
        return {"method": self.method, "length": self.length, "standard_uncertainty": self.standard_uncertainty,
                "centres": self.centres.tolist(), "n_trials": self.n_trials,
                "contributions": {k: math.sqrt(v) for k, v in self.contributions.items()}}


def _budget_from(name: str, inputs: Mapping[str, tuple], sens: Mapping[str, float]) -> Budget:
    rows = []
    for key, (value, u, unit) in inputs.items():
        label = {"noise": "scanner noise on v (all points, via the fit)", "noise 1": "scanner noise on v, ball 1",
                 "noise 2": "scanner noise on v, ball 2"}.get(key, f"pose {key}" if key in ("alpha", "beta", "gamma")
                                                          else f"mount offset {key}" if key in ("U1", "V1", "W1") else key)
        note = "effective coefficient: linearised fit" if key.startswith("noise") else "central difference through compensate + fit_sphere"
        rows.append(Input(label, value, u, unit, sens[key], note))
    return Budget(name, tuple(rows), "mm", "linear propagation (GUM eq. 10) through cmmpose.compensate and cmmpose.fit_sphere")


class _Problem:
    """One scan's data and nominal compensation parameters, validated once."""

    def __init__(self, uv, scales, error_map, pose, offset, temperature, out_of_range, radius, label=""):
        self.label = label
        self.uv = as_rows(f"uv{label}", uv, 2)
        self.scales = as_rows(f"scales{label}", scales, 3)
        if len(self.uv) != len(self.scales):
            raise InputError(f"uv{label} and scales{label}: need the same number of rows, got {len(self.uv)} and {len(self.scales)}")
        if not isinstance(error_map, (ErrorMap, ErrorMapSet)):
            raise InputTypeError(f"error_map: expected an ErrorMap or ErrorMapSet, got {type(error_map).__name__}")
        if isinstance(error_map, ErrorMapSet) and temperature is None:
            raise InputError("temperature: required with an ErrorMapSet (degrees C)")
        if isinstance(error_map, ErrorMap) and temperature is not None:
            raise InputError("temperature: only meaningful with an ErrorMapSet; an ErrorMap has one temperature")
        self.error_map = error_map
        self.pose = np.array(pose_tuple(pose))
        self.offset = np.array(as_triple("offset", offset))
        if temperature is None:
            self.temperature = None
        elif np.ndim(temperature) > 0:
            self.temperature = as_vector(f"temperature{label}", temperature, len(self.uv))
            if not np.all(np.isfinite(self.temperature)):
                raise InputError(f"temperature{label}: values must be finite")
        else:
            self.temperature = finite(f"temperature{label}", temperature)
        if out_of_range not in ("raise", "clamp"):
            raise InputError(f"out_of_range: expected 'raise' or 'clamp', got {out_of_range!r}")
        self.out_of_range = out_of_range
        self.radius = radius

    @property
    def mean_temperature(self) -> float:
        return float("nan") if self.temperature is None else float(np.mean(self.temperature))

    def value(self, name: str) -> float:
        i = _PARAMS.index(name)
        return self.pose[i] if i < 3 else self.offset[i - 3] if i < 6 else self.mean_temperature

    def points(self, uv=None, dpose=(0.0, 0.0, 0.0), doffset=(0.0, 0.0, 0.0), dT=0.0) -> np.ndarray:
        t = None if self.temperature is None else self.temperature + dT
        return compensate(self.uv if uv is None else uv, self.scales, self.error_map, tuple(self.pose + dpose),
                          tuple(self.offset + doffset), t, out_of_range=self.out_of_range)

    def centre(self, **kw) -> np.ndarray:
        return fit_sphere(self.points(**kw), self.radius).centre

    def shifted(self, name: str, h: float) -> dict:
        i = _PARAMS.index(name)
        if i < 3:
            return {"dpose": h * np.eye(3)[i]}
        if i < 6:
            return {"doffset": h * np.eye(3)[i - 3]}
        return {"dT": h}

    def temperature_steps(self, h: float) -> tuple[float, float]:
        """(minus, plus) steps for the temperature difference: central inside the
        map set, one-sided at its ends."""
        lo, hi = self.error_map.temperatures[0], self.error_map.temperatures[-1]
        tmin, tmax = float(np.min(self.temperature)), float(np.max(self.temperature))
        down, up = tmin - h >= lo, tmax + h <= hi
        if down and up:
            return -h, h
        if up:
            return 0.0, h
        if down:
            return -h, 0.0
        raise InputError(f"step_temperature: {h} K does not fit between the data's temperatures and the maps' range {lo}-{hi} C")

    def noise_covariance(self, u_noise: float) -> np.ndarray:
        """Covariance (3, 3) mm^2 of the fitted centre from independent noise u_noise (mm)
        on every v, by the linearised geometric fit: cov = u^2 N A^T diag(a^2) A N with
        A = [n_i, 1] (n_i outward normals at the fit), N = (A^T A)^-1, a_i = n_i . dX_i/dv_i."""
        x = self.points()
        fit = fit_sphere(x, self.radius)
        # The compensation is affine in (u, v) for fixed scale readings, so a 1 mm
        # forward difference gives dX/dv exactly (to rounding).
        uv = self.uv.copy()
        uv[:, 1] += 1.0
        g = self.points(uv=uv) - x
        n = x - fit.centre
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        a = np.einsum("ij,ij->i", n, g)
        A = n if self.radius is not None else np.column_stack([n, np.ones(len(n))])
        N = np.linalg.inv(A.T @ A)
        cov = u_noise ** 2 * N @ (A.T @ (A * (a ** 2)[:, None])) @ N
        return cov[:3, :3]


def _check_u(u_noise, u_pose_deg, u_offset, u_temperature, problem: _Problem) -> dict[str, float]:
    un = finite("u_noise", u_noise)
    up = as_triple("u_pose_deg", u_pose_deg)
    uo = as_triple("u_offset", u_offset)
    ut = finite("u_temperature", u_temperature)
    if min(un, ut, *up, *uo) < 0:
        raise InputError("u_noise, u_pose_deg, u_offset, u_temperature: standard uncertainties must be >= 0")
    if problem.temperature is None and ut > 0:
        raise InputError("u_temperature: needs a temperature (an ErrorMapSet and its temperature), got temperature=None")
    return {"noise": un, **dict(zip(_PARAMS[:3], up)), **dict(zip(_PARAMS[3:6], uo)), "temperature": ut}


def _check_trials(trials) -> int:
    if isinstance(trials, bool) or not isinstance(trials, (int, np.integer)) or trials < 2:
        raise InputError(f"trials: expected an integer >= 2, got {trials!r}")
    return int(trials)


def _draws(rng, m: int, u: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Common (systematic) perturbations of all trials at once: pose (M, 3) deg,
    offset (M, 3) mm, temperature (M,) K."""
    dpose = rng.normal(size=(m, 3)) * np.array([u[k] for k in _PARAMS[:3]])
    doff = rng.normal(size=(m, 3)) * np.array([u[k] for k in _PARAMS[3:6]])
    dT = rng.normal(size=m) * u["temperature"]
    return dpose, doff, dT


def _trial_centre(p: _Problem, work: np.ndarray, v0: np.ndarray, noise: np.ndarray, dpose, doff, dT, k: int) -> np.ndarray:
    work[:, 1] = v0 + noise
    try:
        return p.centre(uv=work, dpose=dpose, doffset=doff, dT=dT)
    except OutOfRangeError as exc:
        message, fields = quoting(exc, f"Monte Carlo trial {k}{p.label and ' (ball ' + p.label + ')'}: temperature "
                                  f"offset {dT:+.4g} K: ", " (use out_of_range='clamp' or a smaller u_temperature)")
        raise OutOfRangeError(message, **fields) from None


def _inputs_record(p: _Problem, u: dict[str, float], u_noise_key=("noise",)) -> dict[str, tuple]:
    rec = {k: (0.0, u["noise"], "mm") for k in u_noise_key}
    for k in _PARAMS:
        if k == "temperature" and p.temperature is None:
            continue
        rec[k] = (float(p.value(k)), u[k], _UNITS[k])
    return rec


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
    p = _Problem(uv, scales, error_map, pose, offset, temperature, out_of_range, radius)
    u = _check_u(u_noise, u_pose_deg, u_offset, u_temperature, p)
    m = _check_trials(trials)
    rng = np.random.default_rng(rng)
    dpose, doff, dT = _draws(rng, m, u)
    work, v0 = p.uv.copy(), p.uv[:, 1].copy()
    centres = np.empty((m, 3))
    for k in range(m):
        noise = rng.normal(0.0, u["noise"], len(v0)) if u["noise"] else 0.0
        centres[k] = _trial_centre(p, work, v0, noise, dpose[k], doff[k], dT[k], k)
    return CentreUncertainty("monte carlo", centres.mean(axis=0), np.cov(centres, rowvar=False), centres,
                             inputs=_inputs_record(p, u))


def _sensitivity(f, p: _Problem, name: str, steps: dict[str, float]) -> np.ndarray:
    """Central difference of f(**shift) in parameter ``name`` (one-sided at a temperature end)."""
    h = steps["pose" if name in _PARAMS[:3] else "offset" if name in _PARAMS[3:6] else "temperature"]
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
    p = _Problem(uv, scales, error_map, pose, offset, temperature, out_of_range, radius)
    u = _check_u(u_noise, u_pose_deg, u_offset, u_temperature, p)
    steps = _steps(step_pose_deg, step_offset, step_temperature)
    centre = p.centre()
    unit_noise = p.noise_covariance(1.0)  # centre covariance per (1 mm noise)^2
    contributions = {"noise": unit_noise * u["noise"] ** 2}
    sens = {"noise": np.sqrt(np.diag(unit_noise))}
    for name in _PARAMS:
        if name == "temperature" and p.temperature is None:
            continue
        s = _sensitivity(p.centre, p, name, steps)
        sens[name] = s
        contributions[name] = np.outer(s, s) * u[name] ** 2
    cov = sum(contributions.values())
    return CentreUncertainty("linear", centre, cov, None, contributions, sens, _inputs_record(p, u))


def _pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius):
    p1 = _Problem(uv1, scales1, error_map, pose, offset, temperature, out_of_range, radius, "1")
    p2 = _Problem(uv2, scales2, error_map, pose, offset, temperature if temperature2 is None else temperature2,
                  out_of_range, radius, "2")
    if (p1.temperature is None) != (p2.temperature is None):
        raise InputError("temperature, temperature2: give both or neither")
    return p1, p2


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
    p1, p2 = _pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius)
    u = _check_u(u_noise, u_pose_deg, u_offset, u_temperature, p1)
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
                             lengths, inputs=_inputs_record(p1, u))


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
    p1, p2 = _pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius)
    u = _check_u(u_noise, u_pose_deg, u_offset, u_temperature, p1)
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

    for name in _PARAMS:
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
                             contributions, sens, _inputs_record(p1, u, ("noise 1", "noise 2")))
