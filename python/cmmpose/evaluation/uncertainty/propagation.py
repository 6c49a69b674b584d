"""What the two propagations of an input's uncertainty through compensation and sphere fitting share: the problem
(one scan's data and nominal parameters, checked once), its uncertain parameters, and the results they return
(a centre's or a length's uncertainty, with the budget).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

from ..._arrays import as_rows, as_triple, as_vector
from ..._validate import finite
from ...compensation import compensate
from ...errormap import ErrorMap, ErrorMapSet
from ...errors import InputError, InputTypeError
from ...fitting import fit_sphere
from ...pose import pose_tuple
from .gum import Budget, Input

PARAMETERS = ("alpha", "beta", "gamma", "U1", "V1", "W1", "temperature")
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
        return budget_from(f"sphere centre {'xyz'[j]}", self.inputs, {k: float(v[j]) for k, v in self.sensitivities.items()})

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
        return budget_from("ballbar length", self.inputs, dict(self.sensitivities))

    def to_dict(self) -> dict:
        return {"method": self.method, "length": self.length, "standard_uncertainty": self.standard_uncertainty,
                "centres": self.centres.tolist(), "n_trials": self.n_trials,
                "contributions": {k: math.sqrt(v) for k, v in self.contributions.items()}}


def budget_from(name: str, inputs: Mapping[str, tuple], sens: Mapping[str, float]) -> Budget:
    rows = []
    for key, (value, u, unit) in inputs.items():
        label = {"noise": "scanner noise on v (all points, via the fit)", "noise 1": "scanner noise on v, ball 1",
                 "noise 2": "scanner noise on v, ball 2"}.get(key, f"pose {key}" if key in ("alpha", "beta", "gamma")
                                                          else f"mount offset {key}" if key in ("U1", "V1", "W1") else key)
        note = "effective coefficient: linearised fit" if key.startswith("noise") else "central difference through compensate + fit_sphere"
        rows.append(Input(label, value, u, unit, sens[key], note))
    return Budget(name, tuple(rows), "mm", "linear propagation (GUM eq. 10) through cmmpose.compensate and cmmpose.fit_sphere")


class FitProblem:
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
        i = PARAMETERS.index(name)
        return self.pose[i] if i < 3 else self.offset[i - 3] if i < 6 else self.mean_temperature

    def points(self, uv=None, dpose=(0.0, 0.0, 0.0), doffset=(0.0, 0.0, 0.0), dT=0.0) -> np.ndarray:
        t = None if self.temperature is None else self.temperature + dT
        return compensate(self.uv if uv is None else uv, self.scales, self.error_map, tuple(self.pose + dpose),
                          tuple(self.offset + doffset), t, out_of_range=self.out_of_range)

    def centre(self, **kw) -> np.ndarray:
        return fit_sphere(self.points(**kw), self.radius).centre

    def shifted(self, name: str, h: float) -> dict:
        i = PARAMETERS.index(name)
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


def check_input_u(u_noise, u_pose_deg, u_offset, u_temperature, problem: FitProblem) -> dict[str, float]:
    un = finite("u_noise", u_noise)
    up = as_triple("u_pose_deg", u_pose_deg)
    uo = as_triple("u_offset", u_offset)
    ut = finite("u_temperature", u_temperature)
    if min(un, ut, *up, *uo) < 0:
        raise InputError("u_noise, u_pose_deg, u_offset, u_temperature: standard uncertainties must be >= 0")
    if problem.temperature is None and ut > 0:
        raise InputError("u_temperature: needs a temperature (an ErrorMapSet and its temperature), got temperature=None")
    return {"noise": un, **dict(zip(PARAMETERS[:3], up)), **dict(zip(PARAMETERS[3:6], uo)), "temperature": ut}


def inputs_record(p: FitProblem, u: dict[str, float], u_noise_key=("noise",)) -> dict[str, tuple]:
    rec = {k: (0.0, u["noise"], "mm") for k in u_noise_key}
    for k in PARAMETERS:
        if k == "temperature" and p.temperature is None:
            continue
        rec[k] = (float(p.value(k)), u[k], _UNITS[k])
    return rec


def ball_pair(uv1, scales1, uv2, scales2, error_map, pose, offset, temperature, temperature2, out_of_range, radius):
    p1 = FitProblem(uv1, scales1, error_map, pose, offset, temperature, out_of_range, radius, "1")
    p2 = FitProblem(uv2, scales2, error_map, pose, offset, temperature if temperature2 is None else temperature2,
                  out_of_range, radius, "2")
    if (p1.temperature is None) != (p2.temperature is None):
        raise InputError("temperature, temperature2: give both or neither")
    return p1, p2
