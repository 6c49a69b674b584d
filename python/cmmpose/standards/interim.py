"""An interim check in the manner of the ballbar and gauge products: from one
ballbar run, the three squareness values and the three scale values of the
machine that best explain its lengths, with their uncertainties
(docs/standards.md, "Interim check").

Model (first order, rigid-free): a scale error s_j (ppm of the reading, beyond
what the maps hold: the map's convention, + when the carriage is beyond its
reading) and a squareness error S_ij (arc-seconds, thesis convention, as the
``squareness`` effect: the machine's squareness minus the map's) change a
bar of length L along the unit vector n by

    dL / L = -(s_x n_x^2 + s_y n_y^2 + s_z n_z^2) + c (S_xy n_x n_y + S_yz n_y n_z + S_zx n_z n_x)

with c = 4.8481 ppm per arc-second (measured minus true length). Each
position's length at 20 C gives one equation; the six values are the least-
squares solution. Without a calibrated length the common scale is not
observable (it looks like a bar of another length): the three scale values
are then scale mismatches, each axis against the mean of the three.

Uncertainties (k = 2): the least-squares covariance s^2 (A^T A)^-1 with s^2
the residual variance of the fit (Type A: the run's reproducibility and the
errors the model lacks), plus for absolute scales the common terms of the
reference (the certificate's u / L, the expansion coefficient's |T - 20| u_alpha
and the temperature reading's alpha u_T), which move the three scales together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._json import dumps as strict_json
from .._validate import finite
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..evaluation.ballbar import evaluate, skipped_note
from ..evaluation.metrics import STEEL_EXPANSION_PPM_PER_K
from ..run import Run
from ..temperature import TemperaturePolicy, log_notes

__all__ = ["ARCSEC_PPM", "InterimValue", "InterimCheck", "interim_check"]

#: One arc-second in ppm (um/m): pi / 648000 * 1e6.
ARCSEC_PPM = math.pi / 648000 * 1e6
_PARAMS = ("scale X", "scale Y", "scale Z", "squareness XY", "squareness YZ", "squareness ZX")


@dataclass(frozen=True)
class InterimValue:
    """One value of the check.

    Attributes
    ----------
    name : str
        ``'scale X'`` ... ``'squareness ZX'``.
    words : str
        What the ballbar and gauge products call it (``'scaling error X'``,
        ``'scale mismatch X'``, ``'squareness XY'``).
    value : float
        ppm (scale) or arc-seconds (squareness).
    unit : str
        ``'ppm'`` or ``'arcsec'``.
    u : float
        Standard uncertainty, in ``unit``.
    k : float
        Coverage factor (2).
    """

    name: str
    words: str
    value: float
    unit: str
    u: float
    k: float = 2.0

    @property
    def U(self) -> float:
        """k u, in ``unit``."""
        return self.k * self.u

    @property
    def um_per_m(self) -> float:
        """The value in um/m (ppm), as the ballbar products print squareness."""
        return self.value * (ARCSEC_PPM if self.unit == "arcsec" else 1.0)

    def to_dict(self) -> dict:
        return {"name": self.name, "words": self.words, "value": round(self.value, 3), "unit": self.unit,
                "u": round(self.u, 3), "k": self.k, "U": round(self.U, 3), "um_per_m": round(self.um_per_m, 3)}


@dataclass(frozen=True)
class InterimCheck:
    """The interim check of one run (:func:`interim_check`).

    Attributes
    ----------
    values : tuple of InterimValue
        Scale X, Y, Z then squareness XY, YZ, ZX.
    label : str
        The lengths used: ``'compensated'`` (what the maps leave) or ``'uncompensated'``.
    absolute_scale : bool
        True with a calibrated length (scale errors), False without (scale mismatches).
    residual_um : float
        Rms residual of the lengths after the fit, um.
    positions : int
        Lengths used.
    notes : tuple of str
        How the values were made, and the positions skipped.
    temperature_log : dict or None
        How the temperatures were read from the run's log
        (:func:`cmmpose.temperature.log_provenance`); None when given.
    skipped : tuple of dict
        Ballbar positions and scans left out as incomplete or ambiguous
        (``skip_incomplete=True``; :func:`cmmpose.evaluation.ballbar.ballbar_scans`).
    """

    values: tuple[InterimValue, ...]
    label: str
    absolute_scale: bool
    residual_um: float
    positions: int
    notes: tuple[str, ...] = ()
    skipped: tuple[dict, ...] = ()
    temperature_log: dict | None = None

    def __getitem__(self, name: str) -> InterimValue:
        for v in self.values:
            if v.name == name:
                return v
        raise KeyError(name)

    def to_dict(self) -> dict:
        return {"label": self.label, "absolute_scale": self.absolute_scale, "positions": self.positions,
                "residual_um": round(self.residual_um, 3), "values": [v.to_dict() for v in self.values],
                "notes": list(self.notes), "skipped": list(self.skipped), "temperature_log": self.temperature_log}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def to_markdown(self) -> str:
        """A report section: the six values with u and U (k = 2), and the notes."""
        lines = [f"## Interim check ({self.label} lengths, {self.positions} positions)", "",
                 "| value | as the products say | value | u | U, k = 2 | um/m |", "|" + "---|" * 6]
        lines += [f"| {v.name} | {v.words} | {v.value:+.2f} {v.unit} | {v.u:.2f} | {v.U:.2f} | {v.um_per_m:+.2f} |"
                  for v in self.values]
        lines += ["", f"Rms residual of the lengths after the fit: {self.residual_um:.2f} um.", ""]
        lines += [f"- {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def __rich__(self):
        from rich.table import Table

        t = Table(title=f"Interim check ({self.label} lengths, {self.positions} positions)")
        for name in ("value", "as the products say", "", "u", "U, k=2", "um/m"):
            t.add_column(name, justify="left" if name in ("value", "as the products say", "") else "right")
        for v in self.values:
            t.add_row(v.name, v.words, f"{v.value:+.2f} {v.unit}", f"{v.u:.2f}", f"{v.U:.2f}", f"{v.um_per_m:+.2f}")
        t.caption = "\n".join([f"rms residual of the lengths after the fit: {self.residual_um:.2f} um", *self.notes])
        return t


def interim_check(
    run: Run,
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: float | None = None,
    *,
    calibrated_length: float | None = None,
    u_length_certificate_um: float = 0.0,
    expansion_ppm_per_K: float = STEEL_EXPANSION_PPM_PER_K,
    u_expansion_ppm_per_K: float = 1.0,
    u_temperature_K: float = 0.2,
    out_of_range: str | None = None,
    skip_incomplete: bool = False,
    temperature_policy: TemperaturePolicy | None = None,
) -> InterimCheck:
    """Three squareness and three scale values from one ballbar run (module docstring).

    Parameters
    ----------
    run : Run
        A ballbar run whose positions span the three axes and the three planes'
        diagonals (the B89 layout does).
    maps : ErrorMap or ErrorMapSet, optional
        With maps, the check is of what the compensated machine leaves (the
        values are then beyond the maps'); without, of the raw machine.
    temperature : float, optional
        Machine temperature, C; default the run's log.
    calibrated_length : float, optional
        Certified bar length at 20 C, mm; default the run's
        ``artefact['calibrated_length_mm']``. Without one: scale mismatches.
    u_length_certificate_um : float
        Standard uncertainty of the certified length, um.
    expansion_ppm_per_K : float
        Bar expansion coefficient, ppm/K.
    u_expansion_ppm_per_K : float
        Its standard uncertainty, ppm/K.
    u_temperature_K : float
        Standard uncertainty of the temperature reading, K.
    out_of_range : {'raise', 'clamp', 'extrapolate'}, optional
        As :func:`cmmpose.evaluate`; overrides the policy's.
    skip_incomplete : bool
        As :func:`cmmpose.evaluate`: False (default) raises ``RunError`` on a
        position with a ball scan missing, duplicated or mislabelled; True
        leaves such positions out and lists them in ``skipped`` and the notes.
    temperature_policy : TemperaturePolicy, optional
        As :func:`cmmpose.evaluate` (cmmpose.temperature); the thermocouples
        dropped, points held and channels each role read are in
        ``temperature_log`` and the notes.

    Returns
    -------
    InterimCheck

    Raises
    ------
    InputError
        Positions that do not determine every value (naming the ones missing).
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    for name, v in (("u_length_certificate_um", u_length_certificate_um), ("u_expansion_ppm_per_K", u_expansion_ppm_per_K),
                    ("u_temperature_K", u_temperature_K)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"{name}: expected a finite value >= 0, got {v!r}")
    if calibrated_length is None:
        calibrated_length = run.artefact.get("calibrated_length_mm")
    expansion = finite("expansion_ppm_per_K", expansion_ppm_per_K) * 1e-6  # 1/K
    ev = evaluate(run, maps, temperature, expansion_ppm_per_K=expansion_ppm_per_K, out_of_range=out_of_range, skip_incomplete=skip_incomplete,
                  temperature_policy=temperature_policy)
    tlog = ev.provenance["temperature"].get("log")
    res = ev.compensated if ev.compensated is not None else ev.uncompensated
    a = _sensitivities(res)
    l20 = res.lengths_at_20c
    if not np.all(np.isfinite(l20)):
        raise InputError("temperature: the run has no temperature log; give the machine temperature (C)")
    absolute = calibrated_length is not None
    notes = [n for n in (skipped_note(ev.skipped),) if n] + (log_notes(tlog) if tlog else [])
    if absolute:
        ref = float(calibrated_length)
        y = (l20 - ref) / ref * 1e6  # ppm
        design, basis = a, np.eye(6)
    else:
        ref = float(np.mean(l20))
        y = (l20 - ref) / ref * 1e6
        design, basis = _relative_design(a, len(y))
        notes.append("no calibrated length: the scale values are scale mismatches (each axis against the mean of "
                     "the three); the common scale cannot be told from the bar's length")
    theta, resid, dof, cov_t = _least_squares(design, y, a)
    if absolute:
        params, cov = theta, cov_t
        t_mean = float(np.nanmean(res.temperatures))
        common = (u_length_certificate_um / (ref * 1e3) * 1e6) ** 2 + (abs(t_mean - 20.0) * u_expansion_ppm_per_K) ** 2 \
            + (expansion * 1e6 * u_temperature_K) ** 2  # ppm^2, moves the three scales together
        # Measured minus true = -s, so a reference off by e ppm shifts every s by -e: fully correlated.
        cov = cov.copy()
        cov[:3, :3] += common
    else:
        params = basis @ theta[:5]
        cov = basis @ cov_t[:5, :5] @ basis.T
    u = np.sqrt(np.diag(cov))
    words = [("scaling error " if absolute else "scale mismatch ") + ax for ax in "XYZ"] + \
            [f"squareness {pl}" for pl in ("XY", "YZ", "ZX")]
    values = tuple(InterimValue(_PARAMS[j], words[j], float(params[j]), "ppm" if j < 3 else "arcsec", float(u[j]))
                   for j in range(6))
    notes.append(f"first-order model (scale and squareness only): the {dof} residual degrees of freedom carry the "
                 "run's reproducibility and every other error; u is Type A from them" +
                 (" plus the reference's common scale terms" if absolute else ""))
    residual_um = float(np.sqrt(np.mean(resid ** 2))) * ref * 1e-3
    return InterimCheck(values, res.label, absolute, residual_um, len(y), tuple(notes), tuple(ev.skipped), tlog)


def _sensitivities(res) -> np.ndarray:
    """How each position's length (ppm) moves with the three scales (ppm) and three squarenesses (arcsec),
    from the bar's direction between its two balls: (positions, 6)."""
    balls = {(s.position, s.ball): s.centre for s in res.spheres}
    bar = np.array([balls[(int(p), 2)] - balls[(int(p), 1)] for p in res.positions])
    n = bar / np.linalg.norm(bar, axis=1)[:, None]
    return np.column_stack([-n[:, 0] ** 2, -n[:, 1] ** 2, -n[:, 2] ** 2, ARCSEC_PPM * n[:, 0] * n[:, 1],
                            ARCSEC_PPM * n[:, 1] * n[:, 2], ARCSEC_PPM * n[:, 2] * n[:, 0]])


def _relative_design(a: np.ndarray, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Without a calibrated length: the scales constrained to sum to zero (the common scale is the unknown bar
    length), s = B t, and a constant for the bar length's offset: (design, basis B)."""
    b3 = np.array([[1.0, 0.0], [-0.5, math.sqrt(3) / 2], [-0.5, -math.sqrt(3) / 2]]) * math.sqrt(2 / 3)
    basis = np.zeros((6, 5))
    basis[:3, :2] = b3
    basis[3:, 2:] = np.eye(3)
    return np.column_stack([a @ basis, np.ones(rows)]), basis


def _least_squares(design: np.ndarray, y: np.ndarray, a: np.ndarray):
    """The least-squares values, residuals, degrees of freedom and covariance (Type A, from the residuals); the
    positions must outnumber the values and their directions determine each."""
    n_par = design.shape[1]
    if len(y) <= n_par:
        raise InputError(f"run: {len(y)} positions do not determine {n_par} values; the B89 layout's 20 do")
    sv = np.linalg.svd(design, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        weak = _undetermined(a)
        raise InputError(f"run: the positions' directions do not determine {', '.join(weak) or 'every value'}: add "
                         "positions along each axis and on each plane's diagonals")
    theta, *_ = np.linalg.lstsq(design, y, rcond=None)
    resid = y - design @ theta
    dof = len(y) - n_par
    s2 = float(resid @ resid) / dof
    return theta, resid, dof, s2 * np.linalg.inv(design.T @ design)


def _undetermined(a: np.ndarray) -> list[str]:
    """The values whose columns the others (nearly) explain."""
    out = []
    for j in range(a.shape[1]):
        others = np.delete(a, j, axis=1)
        coef, *_ = np.linalg.lstsq(others, a[:, j], rcond=None)
        if np.linalg.norm(a[:, j] - others @ coef) < 1e-6 * max(np.linalg.norm(a[:, j]), 1e-300):
            out.append(_PARAMS[j])
    return out
