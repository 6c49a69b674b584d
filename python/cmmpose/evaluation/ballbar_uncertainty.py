"""Uncertainties of the ballbar figures of :func:`cmmpose.evaluate`: every
length, the mean, the lengths and mean at 20 C, the rms accuracy error and the
B89 value, each with its standard uncertainty u, k = 2 and U = k u, and the
budget behind it (docs/uncertainty.md, "Uncertainty of an evaluation").

The terms (GUM eq. 10, uncorrelated inputs; um):

- Type A, scan-to-scan reproducibility: from the run's own data, the sample
  variance s_L^2 of its P lengths less the fits' mean share (the part of the
  spread the scanner noise already explains), max(s_L^2 - mean u_fit^2, 0);
  it carries whatever moves a ball's apparent centre from scan to scan
  (fixture, machine repeatability, the scan's own systematic errors) and the
  position-dependent residuals of the compensation. Random from length to
  length: divided by sqrt(P) in the mean.
- Scanner noise in both scan coordinates, via the sphere fits: the fits'
  covariances s^2 (J^T J)^-1 (from the residuals, so noise on u and v alike)
  of the two centres, along the bar: u_fit^2 = n^T (C_1 + C_2) n.
- Error maps: each axis's map scale is uncertain by ``u_map_ppm`` (default the
  refractive-index uncertainty of the interferometer's weather station,
  thesis line 768); a scale error e_j of axis j changes a length by
  e_j dL_j^2 / L (dL_j the bar's extent along j). Common to all lengths.
- Residual model error: ``u_model_ppm`` of the length (given by the user from
  a verification; 0, and then listed as left out, by default).
- Machine temperature: the reading's standard uncertainty ``u_temperature_K``
  times the compensated length's sensitivity to it (central or one-sided
  difference through the maps); for the lengths at 20 C the same reading is
  the part temperature, so its sensitivity there is c_T - L alpha.
- Expansion coefficient: ``u_expansion_ppm_per_K`` times L |T - 20| (lengths at 20 C).
- A diagnosis model's parameters (``maps`` a ``cmmpose.Model`` that holds
  their uncertainties, as ``cmmpose diagnose --save-model`` writes them): one
  row per parameter, its standard uncertainty times the figure's sensitivity
  to it (a difference of one step of the effect through the kernel and the
  sphere fits); common to all lengths, so not divided by sqrt(P) in the mean;
  taken as independent (the model file keeps no correlations).

The rms accuracy error and the B89 value describe the spread of the lengths;
their uncertainty is the Type A uncertainty of that statistic from P lengths:
s / sqrt(2 (P - 1)) for the sample standard deviation, and a parametric
bootstrap (normal lengths of sd s, fixed seed) for the largest |L - mean|.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ..calibration.interferometer.air import THESIS_AIR_UNCERTAINTY, refractivity_uncertainty
from .._json import dumps as strict_json
from ..errormap import ErrorMap, ErrorMapSet
from .._validate import nonnegative
from ..errors import Error, InputError, InputTypeError
from .ballbar import BallbarResult, Evaluation, machine_coordinates, machine_temperature
from ..fitting import fit_spheres
from ..temperature import LOG_HOLD, TEMPERATURE_TOLERANCE, TemperaturePolicy, as_policy
from ..run import Run
from .uncertainty import Budget, Input

__all__ = [
    "COVERAGE_FACTOR",
    "DEFAULT_U_TEMPERATURE_K",
    "DEFAULT_U_EXPANSION_PPM_PER_K",
    "default_map_ppm",
    "Figure",
    "ResultUncertainty",
    "EvaluationUncertainty",
    "evaluation_uncertainty",
]

_log = logging.getLogger("cmmpose")

COVERAGE_FACTOR = 2.0
#: Standard uncertainty of the machine-mean temperature reading, K.
DEFAULT_U_TEMPERATURE_K = 0.2
#: Standard uncertainty of a steel artefact's expansion coefficient, ppm/K.
DEFAULT_U_EXPANSION_PPM_PER_K = 1.0
#: Temperature step of the sensitivity, K.
_STEP_K = 0.5
#: Parametric bootstrap of the B89 value: draws and seed (deterministic).
_B89_DRAWS = 4000
_B89_SEED = 0xB89


def default_map_ppm() -> float:
    """The refractive-index uncertainty u_N of the interferometer calibration
    with the thesis's weather station, ppm (thesis line 768; about 1.4 ppm)."""
    return float(refractivity_uncertainty(*THESIS_AIR_UNCERTAINTY))


@dataclass(frozen=True)
class Figure:
    """One evaluated figure with its uncertainty.

    Attributes
    ----------
    name : str
        What it is (``'mean length'``, ``'length 3'``, ...).
    value : float
        The figure, in ``unit``.
    unit : str
        ``'mm'`` (lengths) or ``'um'`` (rms accuracy error, B89).
    u : float
        Standard uncertainty, um.
    k : float
        Coverage factor (2).
    budget : Budget or None
        The terms, um.
    """

    name: str
    value: float
    unit: str
    u: float
    k: float = COVERAGE_FACTOR
    budget: Budget | None = field(default=None, repr=False)

    @property
    def U(self) -> float:
        """Expanded uncertainty k u, um."""
        return self.k * self.u

    def to_dict(self) -> dict:
        digits = 5 if self.unit == "mm" else 3
        return {"name": self.name, "value": round(self.value, digits), "unit": self.unit, "u_um": round(self.u, 3),
                "k": self.k, "U_um": round(self.U, 3)}


@dataclass(frozen=True)
class ResultUncertainty:
    """Uncertainties of one ballbar result (uncompensated or compensated).

    Attributes
    ----------
    label : str
        The result's label.
    lengths : tuple of Figure
        Each position's length, mm (u in um).
    lengths_20c : tuple of Figure
        Each length at 20 C, mm (u in um).
    mean, mean_20c : Figure
        Mean length and mean length at 20 C, mm.
    rms_accuracy_error, b89 : Figure
        um.
    budgets : dict of str -> Budget
        ``'length'`` (a typical length: each term's rms over the positions),
        ``'mean length'``, ``'length at 20 C'``, ``'mean length at 20 C'``,
        ``'rms accuracy error'``, ``'B89'``; um.
    s_lengths_um : float
        Sample standard deviation of the lengths, um (P - 1 degrees of freedom).
    temperature_sensitivity_um_per_K : float
        Mean d(length)/d(machine temperature) through the maps, um/K.
    """

    label: str
    lengths: tuple[Figure, ...]
    lengths_20c: tuple[Figure, ...]
    mean: Figure
    mean_20c: Figure
    rms_accuracy_error: Figure
    b89: Figure
    budgets: dict
    s_lengths_um: float
    temperature_sensitivity_um_per_K: float

    @property
    def figures(self) -> tuple[Figure, ...]:
        """The summary figures: mean, mean at 20 C, rms accuracy error, B89."""
        return (self.mean, self.mean_20c, self.rms_accuracy_error, self.b89)

    def to_dict(self) -> dict:
        return {"label": self.label, "k": COVERAGE_FACTOR, "figures": [f.to_dict() for f in self.figures],
                "lengths": [f.to_dict() for f in self.lengths], "lengths_20C": [f.to_dict() for f in self.lengths_20c],
                "s_lengths_um": round(self.s_lengths_um, 3),
                "temperature_sensitivity_um_per_K": round(self.temperature_sensitivity_um_per_K, 4),
                "budgets": {k: b.to_dict() for k, b in self.budgets.items()}}


@dataclass(frozen=True)
class EvaluationUncertainty:
    """Uncertainties of an :class:`~cmmpose.Evaluation` (:func:`evaluation_uncertainty`).

    Attributes
    ----------
    results : tuple of ResultUncertainty
        One per result of the evaluation, in its order.
    inputs : dict
        The standard uncertainties used (K, ppm, ppm/K).
    left_out : tuple of str
        What the budgets do not contain.
    """

    results: tuple[ResultUncertainty, ...]
    inputs: dict
    left_out: tuple[str, ...]

    def __getitem__(self, label: str) -> ResultUncertainty:
        for r in self.results:
            if r.label == label:
                return r
        raise KeyError(label)

    def to_dict(self) -> dict:
        return {"coverage_factor": COVERAGE_FACTOR, "inputs": self.inputs, "left_out": list(self.left_out),
                "results": [r.to_dict() for r in self.results]}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def to_markdown(self) -> str:
        """A report section: the figures with u and U (k = 2), the budgets of a length and of the mean, and
        what the budgets leave out."""
        lines = ["## Uncertainties (k = 2)", "", "| result | figure | value | u (um) | U (um) |", "|---|---|---|---|---|"]
        for r in self.results:
            for f in (*r.figures, *r.lengths):
                value = f"{f.value:.4f} mm" if f.unit == "mm" else f"{f.value:.2f} um"
                lines.append(f"| {r.label} | {f.name} | {value} | {f.u:.2f} | {f.U:.2f} |")
        for r in self.results:
            for key in ("length", "mean length", "mean length at 20 C"):
                lines += ["", f"[{r.label}]", "```", r.budgets[key].table(), "```"]
        lines += ["", "Left out:"] + [f"- {x}" for x in self.left_out]
        return "\n".join(lines) + "\n"

    def __rich__(self):
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        t = Table(title="Ballbar figures with uncertainties (k = 2)")
        t.add_column("figure")
        for r in self.results:
            t.add_column(f"{r.label}\nvalue", justify="right")
            t.add_column("u (um)", justify="right")
            t.add_column("U, k=2 (um)", justify="right")
        for i, name in enumerate(("mean length (mm)", "mean length at 20 C (mm)", "rms accuracy error (um)", "B89 (um)")):
            cells = [name]
            for r in self.results:
                f = r.figures[i]
                cells += [f"{f.value:.4f}" if f.unit == "mm" else f"{f.value:.2f}", f"{f.u:.2f}", f"{f.U:.2f}"]
            t.add_row(*cells)
        t.add_section()
        for p in range(len(self.results[0].lengths)):
            cells = [self.results[0].lengths[p].name + " (mm)"]
            for r in self.results:
                f = r.lengths[p]
                cells += [f"{f.value:.4f}", f"{f.u:.2f}", f"{f.U:.2f}"]
            t.add_row(*cells)
        parts = [t]
        for r in self.results:
            for key in ("length", "mean length", "mean length at 20 C"):
                parts.append(Text(f"\n[{r.label}] " + r.budgets[key].table()))
        parts.append(Text("\nleft out: " + "; ".join(self.left_out)))
        return Group(*parts)


def _model_temperature(run: Run, maps, temperature, log_hold, temperature_policy=None):
    """The temperature the maps are evaluated at (as :func:`cmmpose.evaluate`)."""
    if maps is None or isinstance(maps.error_maps, ErrorMap):
        return None
    if maps.reads_run:  # the model's own reading of the log (its inputs), or the one given
        return float(temperature) if temperature is not None else maps.inputs(run).temperature
    if maps is None or isinstance(maps, ErrorMap):
        return None
    if temperature is not None:
        return float(temperature)
    if run.temperatures is None:
        raise InputError("temperature: the run has no temperature log; give the machine temperature (C)")
    return machine_temperature(run, run.points["t"], log_hold, temperature_policy=temperature_policy)


def _lengths_from(xyz: np.ndarray, run: Run, result: BallbarResult, reject) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lengths (mm), bar vectors (P, 3) mm and the fits' variance along the bar (mm^2)."""
    sid = run.points["scan_id"]
    keep = np.isin(sid, [s.scan_id for s in result.spheres])  # the evaluated balls only (skipped scans may not fit)
    fits = fit_spheres(xyz[keep], sid[keep], reject=reject)
    index = {int(s): k for k, s in enumerate(fits.labels.tolist())}
    scan = {(s.position, s.ball): index[int(s.scan_id)] for s in result.spheres}
    k1 = np.array([scan[(int(p), 1)] for p in result.positions])
    k2 = np.array([scan[(int(p), 2)] for p in result.positions])
    bar = fits.centre[k2] - fits.centre[k1]
    lengths = np.linalg.norm(bar, axis=1)
    n = bar / lengths[:, None]
    cov = fits.covariance[k1, :3, :3] + fits.covariance[k2, :3, :3]
    var = np.einsum("pi,pij,pj->p", n, cov, n)
    return lengths, bar, var


def evaluation_uncertainty(
    run: Run,
    evaluation: Evaluation,
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: float | None = None,
    *,
    u_temperature_K: float = DEFAULT_U_TEMPERATURE_K,
    u_map_ppm: float | None = None,
    u_model_ppm: float = 0.0,
    u_expansion_ppm_per_K: float = DEFAULT_U_EXPANSION_PPM_PER_K,
    reject: float | None = None,
    out_of_range: str = "raise",
    temperature_tolerance: float = TEMPERATURE_TOLERANCE,
    log_hold: float | None = None,
    temperature_policy=None,
) -> EvaluationUncertainty:
    """Uncertainties (k = 2) and budgets of every figure of ``evaluation``
    (module docstring; docs/uncertainty.md).

    Parameters
    ----------
    run : Run
        The run evaluated.
    evaluation : Evaluation
        ``cmmpose.evaluate(run, maps, temperature, ...)``.
    maps : ErrorMap, ErrorMapSet or Model, optional
        The maps (or diagnosis model) the evaluation used (None:
        uncompensated only). A model's parameter uncertainties enter the
        compensated figures' budgets (module docstring).
    temperature : float, optional
        The machine temperature the evaluation was given, C (None: the run's log).
    u_temperature_K : float
        Standard uncertainty of the machine (and part) temperature reading, K.
    u_map_ppm : float, optional
        Standard uncertainty of each axis's map scale, ppm; default
        :func:`default_map_ppm`.
    u_model_ppm : float
        Standard uncertainty of the residual model error, ppm of the length
        (from a verification of the compensation); 0: left out.
    u_expansion_ppm_per_K : float
        Standard uncertainty of the artefact's expansion coefficient, ppm/K.
    reject : float, optional
        As given to ``evaluate`` (robust fits).
    out_of_range, temperature_tolerance, log_hold, temperature_policy
        As given to ``evaluate`` (the policy: how the log becomes temperatures,
        cmmpose.temperature).

    Returns
    -------
    EvaluationUncertainty
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    if not isinstance(evaluation, Evaluation):
        raise InputTypeError(f"evaluation: expected a cmmpose.Evaluation, got {type(evaluation).__name__}")
    u_t = nonnegative("u_temperature_K", u_temperature_K)
    u_map = default_map_ppm() if u_map_ppm is None else nonnegative("u_map_ppm", u_map_ppm)
    u_model = nonnegative("u_model_ppm", u_model_ppm)
    u_alpha = nonnegative("u_expansion_ppm_per_K", u_expansion_ppm_per_K)
    log_hold = LOG_HOLD if log_hold is None else log_hold
    out = []
    no_sensitivity = False
    once: set = set()  # the checks of the model on this run: said once, not again for each perturbation
    map_side = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
    for res in evaluation.results:
        compensated = res.label == "compensated"
        model = maps if compensated else None
        model_t = _model_temperature(run, model, temperature, log_hold, temperature_policy) if compensated else None
        xyz = machine_coordinates(run, model, model_t, map_side, once=once)
        lengths, bar, var_fit = _lengths_from(xyz, run, res, reject)
        if not np.allclose(lengths, res.lengths, rtol=0, atol=1e-9):
            raise InputError("evaluation: its lengths are not those of run with these maps and temperature; pass the "
                             "same run, maps, temperature and reject as to evaluate")
        c_t = np.zeros(len(lengths))
        if model_t is not None:
            c_t = _temperature_sensitivity(run, model, model_t, res, reject, out_of_range, lengths, once)
            if c_t is None:
                c_t = np.zeros(len(lengths))
                no_sensitivity = True
        terms = _model_terms(run, maps, model_t, res, reject, map_side, lengths, once) \
            if compensated and maps.effects else ()
        out.append(_result_uncertainty(res, lengths, bar, var_fit, c_t, compensated, u_t, u_map, u_model, u_alpha,
                                       terms))
    left_out = _left_out(maps, u_model, no_sensitivity)
    inputs = {"u_temperature_K": u_t, "u_map_ppm": round(u_map, 4), "u_model_ppm": u_model,
              "u_expansion_ppm_per_K": u_alpha}
    return EvaluationUncertainty(tuple(out), inputs, tuple(left_out))


def _left_out(maps, u_model: float, no_sensitivity: bool) -> list[str]:
    """What the figures' uncertainty leaves out, in words: always the certificate, the part temperature, the
    alignment and gradients; a residual model error not given, a single map's temperature, the model's parameters
    without a number, a temperature sensitivity that could not be taken (logged too)."""
    left_out = [
        "the artefact's certificate (these figures are measured lengths, not errors against a calibrated length; "
        "cmmpose standards acceptance counts it)",
        "a part temperature other than the machine mean the evaluation uses (thesis 6.4.1)",
        "the alignment's pose and mount-offset uncertainty as a common error (cmmpose.evaluation.uncertainty."
        "linear_ballbar_length_uncertainty propagates it; its position-dependent part is in the Type A term)",
        "thermal gradients and drift within a scan beyond the machine-mean temperature",
    ]
    if u_model == 0:
        left_out.append("the residual model error (no u_model_ppm given)")
    if maps is not None and isinstance(maps.error_maps, ErrorMap):
        left_out.append("a single map's temperature mismatch (no temperature sensitivity without a map set)")
    if maps is not None and maps.effects:
        pairs = [(f"{s.name}.{p}", u) for s, _ in maps.effects for p, u in
                 zip(s.params, np.ravel(maps.uncertainty.get(s.name, np.full(s.size, np.nan))))]
        undetermined = [n for n, u in pairs if np.isinf(u)]
        known = [n for n, u in pairs if np.isnan(u)]
        if undetermined:  # the diagnosis could not determine them: no number would be honest
            left_out.append("the model's parameters " + ", ".join(undetermined) + " are undetermined (the run the "
                            "model was found on cannot determine them): their uncertainty is not a number, and the "
                            "figures' u leave it out")
        if known:
            left_out.append("the uncertainty of the model's parameters " + ", ".join(known)
                            + " (the model file gives none)")
        left_out.append("correlations between the model's parameters (the model file keeps none: taken as independent)")
    if no_sensitivity:
        left_out.append("the temperature reading through the maps: neither +-0.5 K about the machine temperature is "
                        "inside them")
        _log.warning("no temperature sensitivity: +-%g K about the machine temperature leaves the maps", _STEP_K)
    return left_out


def _temperature_sensitivity(run, maps, model_t, res, reject, out_of_range, lengths,
                             once: set | None = None) -> np.ndarray | None:
    """d(length)/d(machine temperature), um/K, by a central difference, or a
    one-sided one where a step leaves the maps; None where both do. A step
    is never held or clamped at the maps' edge (that would halve the slope):
    it raises and is not taken, unless the evaluation extrapolates."""
    policy = "extrapolate" if out_of_range == "extrapolate" else "raise"
    got = {}
    for step in (_STEP_K, -_STEP_K):
        try:
            xyz = machine_coordinates(run, maps, np.asarray(model_t) + step,
                                      TemperaturePolicy(out_of_range=policy, temperature_tolerance=0.0), once=once)
        except Error:
            continue
        got[step] = _lengths_from(xyz, run, res, reject)[0]
    if len(got) == 2:
        return (got[_STEP_K] - got[-_STEP_K]) / (2 * _STEP_K) * 1e3
    if len(got) == 1:
        (step, shifted), = got.items()
        return (shifted - lengths) / step * 1e3
    return None


def _model_terms(run, model, model_t, res, reject, policy, lengths, once: set | None = None) -> list[tuple]:
    """One term per parameter of the model whose standard uncertainty it holds:
    (label, unit, u, dL/dp per length um/unit, d rms/dp um/unit, d B89/dp um/unit),
    by a forward difference of the effect's step through the kernel and the fits."""
    from .metrics import b89_value, rms_accuracy_error

    out = []
    for spec, values in model.effects:
        u = np.ravel(model.uncertainty.get(spec.name, np.full(spec.size, np.nan)))
        for j, param in enumerate(spec.params):
            if u[j] < 0:  # a row dropped without a word would understate the budget
                raise InputError(f"model: effect {spec.name!r}: the standard uncertainty of parameter {param!r} is "
                                 f"{u[j]:g} {spec.units[j]}; expected >= 0 (inf: undetermined, NaN: not given)")
            if not (np.isfinite(u[j]) and u[j] > 0):
                continue
            v = np.array(values, dtype=float)
            step = float(spec.steps[j])
            v[j] += step
            xyz = machine_coordinates(run, model.with_values(spec, v), model_t, policy, once=once)
            moved = _lengths_from(xyz, run, res, reject)[0]
            c_len = (moved - lengths) / step * 1e3
            c_rms = (rms_accuracy_error(moved) - rms_accuracy_error(lengths)) / step * 1e3
            c_b89 = (b89_value(moved) - b89_value(lengths)) / step * 1e3
            out.append((f"model {spec.name}: {param}", spec.units[j], float(u[j]), c_len, c_rms, c_b89))
    return out


def _typical(name: str, rows_per_p) -> Budget:
    """Each term's rms over the positions (its contribution), as one budget."""
    first = rows_per_p[0]
    rows = []
    for j, row in enumerate(first):
        contrib = math.sqrt(float(np.mean([r[j].contribution ** 2 for r in rows_per_p])))
        u = row.standard_uncertainty
        if row.unit == "um" or u == 0:
            rows.append(Input(row.name, 0.0, contrib, "um", 1.0, row.note + " (rms over the positions)"))
        else:
            rows.append(Input(row.name, 0.0, u, row.unit, contrib / u, row.note + " (rms over the positions)"))
    return Budget(name, tuple(rows), "um")


def _spread_budgets(s: float, P: int, model_terms, model_note: str):
    """The budgets of the figures of the lengths' spread, each with its Type A term alone: the rms accuracy
    error (s / sqrt(2 (P - 1))) and B89 (a parametric bootstrap of the largest |L - mean| of P lengths);
    ((budget, Type A u) of each)."""
    u_rms = s / math.sqrt(2 * (P - 1))
    b_rms = Budget("rms accuracy error", (Input("Type A: sample standard deviation of P lengths", 0.0, u_rms, "um", 1.0,
                                                f"s / sqrt(2 (P - 1)), P = {P}"),
                                          *[Input(name, 0.0, u, unit, c_rms, model_note)
                                            for name, unit, u, _, c_rms, _ in model_terms]), "um")
    draws = np.random.default_rng(_B89_SEED).normal(0.0, s, (_B89_DRAWS, P))
    b89_draws = np.max(np.abs(draws - draws.mean(axis=1, keepdims=True)), axis=1)
    u_b89 = float(np.std(b89_draws, ddof=1))
    b_b89 = Budget("B89", (Input("Type A: largest |L - mean| of P lengths", 0.0, u_b89, "um", 1.0,
                                 f"parametric bootstrap, {_B89_DRAWS} draws of {P} normal lengths of sd s_L"),
                           *[Input(name, 0.0, u, unit, c_b89, model_note)
                             for name, unit, u, _, _, c_b89 in model_terms]), "um")
    return (b_rms, u_rms), (b_b89, u_b89)


def _result_uncertainty(res: BallbarResult, lengths, bar, var_fit, c_t, compensated, u_t, u_map, u_model,
                        u_alpha, model_terms=()) -> ResultUncertainty:
    P = len(lengths)
    L_um = lengths * 1e3
    s = float(np.std(lengths, ddof=1)) * 1e3
    u_fit = np.sqrt(var_fit) * 1e3
    u_between = math.sqrt(max(s ** 2 - float(np.mean(u_fit ** 2)), 0.0))
    # Map scale of axis j: dL = e_j dL_j^2 / L.
    geo = bar ** 2 / lengths[:, None]  # (P, 3) mm per unit scale error
    u_map_len = u_map * 1e-3 * np.sqrt(np.sum(geo ** 2, axis=1))  # um
    u_map_mean = u_map * 1e-3 * float(np.sqrt(np.sum(np.mean(geo, axis=0) ** 2)))
    alpha = res.expansion
    temps = res.temperatures
    dT = np.where(np.isfinite(temps), temps - 20.0, np.nan)
    c_t20 = c_t - L_um * alpha  # the reading is also the part temperature
    fit_note = "s^2 (J^T J)^-1 of both centres along the bar: noise on u and v alike, from the residuals"
    a_note = f"s_L = {s:.3g} um over {P} lengths ({P - 1} degrees of freedom), less the fits' share"
    map_note = f"{u_map:.3g} ppm per axis map, through dL_j^2 / L"
    sys_inputs = lambda L, u_ml, ct: [  # noqa: E731 - the common terms of one figure
        *([Input("error maps: scale of each axis", 0.0, u_ml, "um", 1.0, map_note)] if compensated else []),
        *([Input("residual model error", 0.0, u_model, "ppm", L * 1e-6, "given (verification of the compensation)")]
          if compensated else []),
        *([Input("machine temperature reading (through the maps)", 0.0, u_t, "K", ct, "difference of +-0.5 K")]
          if compensated else []),
    ]

    model_note = "the diagnosis's standard uncertainty, through one step of the effect (kernel and fits)"

    def length_budget(u_fit_p, L, u_ml, ct, n=1, p=None):
        c = 1.0 / math.sqrt(n)
        return [Input("Type A: scan-to-scan reproducibility", 0.0, u_between, "um", c, a_note),
                Input("scanner noise (u and v) via the sphere fits", 0.0, u_fit_p, "um", c, fit_note),
                *sys_inputs(L, u_ml, ct),
                *[Input(name, 0.0, u, unit, float(c_len[p] if p is not None else np.mean(c_len)), model_note)
                  for name, unit, u, c_len, _, _ in model_terms]]

    def at20(inputs, L, dt, ct20):
        # Replace the temperature row: for the 20 C figure the reading is also the part's.
        rows = [i for i in inputs if not i.name.startswith("machine temperature")]
        rows.append(Input("temperature reading (maps and part expansion)", 0.0, u_t, "K", ct20,
                          f"through the maps and - L alpha, alpha = {alpha * 1e6:g} ppm/K"))
        rows.append(Input("expansion coefficient", 0.0, u_alpha, "ppm/K", L * 1e-6 * abs(dt) if np.isfinite(dt) else 0.0,
                          "L |T - 20|"))
        return rows

    lengths_fig, lengths20_fig, per_len_inputs, per_len20_inputs = [], [], [], []
    l20 = res.lengths_at_20c
    for p in range(P):
        inp = length_budget(u_fit[p], L_um[p], u_map_len[p], c_t[p], p=p)
        inp20 = at20(inp, L_um[p], dT[p], c_t20[p])
        b = Budget(f"length {int(res.positions[p])}", tuple(inp), "um")
        b20 = Budget(f"length {int(res.positions[p])} at 20 C", tuple(inp20), "um")
        per_len_inputs.append(inp)
        per_len20_inputs.append(inp20)
        lengths_fig.append(Figure(f"length {int(res.positions[p])}", float(lengths[p]), "mm",
                                  b.combined_standard_uncertainty, budget=b))
        lengths20_fig.append(Figure(f"length {int(res.positions[p])} at 20 C", float(l20[p]), "mm",
                                    b20.combined_standard_uncertainty, budget=b20))

    Lm = float(np.mean(L_um))
    u_fit_mean = math.sqrt(float(np.mean(u_fit ** 2)))
    mean_inp = length_budget(u_fit_mean, Lm, u_map_mean, float(np.mean(c_t)), n=P)
    b_mean = Budget("mean length", tuple(mean_inp), "um")
    dT_mean = float(np.nanmean(dT)) if np.any(np.isfinite(dT)) else float("nan")
    b_mean20 = Budget("mean length at 20 C", tuple(at20(mean_inp, Lm, dT_mean, float(np.mean(c_t20)))), "um")
    (b_rms, u_rms), (b_b89, u_b89) = _spread_budgets(s, P, model_terms, model_note)
    budgets = {"length": _typical("length (typical)", per_len_inputs),
               "length at 20 C": _typical("length at 20 C (typical)", per_len20_inputs),
               "mean length": b_mean, "mean length at 20 C": b_mean20, "rms accuracy error": b_rms, "B89": b_b89}
    return ResultUncertainty(
        label=res.label, lengths=tuple(lengths_fig), lengths_20c=tuple(lengths20_fig),
        mean=Figure("mean length", res.mean_length, "mm", b_mean.combined_standard_uncertainty, budget=b_mean),
        mean_20c=Figure("mean length at 20 C", res.mean_length_at_20c, "mm", b_mean20.combined_standard_uncertainty,
                        budget=b_mean20),
        rms_accuracy_error=Figure("rms accuracy error", res.rms_accuracy_error * 1e3, "um",
                                  b_rms.combined_standard_uncertainty if model_terms else u_rms, budget=b_rms),
        b89=Figure("B89", res.b89 * 1e3, "um", b_b89.combined_standard_uncertainty if model_terms else u_b89,
                   budget=b_b89),
        budgets=budgets, s_lengths_um=s, temperature_sensitivity_um_per_K=float(np.mean(c_t)))
