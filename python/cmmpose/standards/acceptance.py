"""Optical probing and length tests in the manner of ISO 10360-8, decided
against the user's maximum permissible errors (MPEs) by an ISO 14253-1 style
rule (docs/standards.md, "Acceptance").

From one measurement run (a ballbar run, optionally with scans of the
reference sphere), evaluated compensated with the maps (or uncompensated
without):

- probing form error, single view: the range (max - min) of the radial
  residuals of a least-squares sphere fitted to all points of one scan of a
  calibrated sphere (every ball of every position and every reference scan is
  one test);
- probing form error, all points: the same for one sphere fitted to the points
  of every scan of the reference sphere together (its views from several poses);
- probing size error: fitted diameter minus calibrated diameter, single view
  and all points alike;
- length measurement error: the distance between the two sphere centres of a
  position (the B89 length), brought to 20 C with the artefact's expansion
  coefficient and the run's temperature, minus the calibrated length.

Each error is compared with its MPE (um; the length MPE may grow with the
length, ``A + L/K`` with L in mm). The decision rule (ISO 14253-1 style, the
test uncertainty counted against whoever states conformance, here the user):

- ``pass`` (conformance proven): |error| + U <= MPE;
- ``fail`` (nonconformance proven): |error| - U > MPE;
- ``not proven``: otherwise;
- ``no decision``: the error itself is not determined (a probing size from a
  free-radius fit over so small a cap that the radius moves with the centre,
  ``cmmpose.errors.IllConditionedFit``): the error is shown, but the points
  do not determine it, whatever U the certificates give;

with U the expanded (k = 2) uncertainty of the test: the uncertainty of the
test itself (the artefact's certificate, its expansion coefficient and
temperature), not the tested machine's own scatter, which the error shows.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from .._json import dumps as strict_json
from ..errormap import ErrorMap, ErrorMapSet
from .._validate import finite, nonnegative
from ..errors import InputError, InputTypeError
from ..evaluation.ballbar import machine_coordinates, evaluate, machine_temperature, skipped_note
from ..fitting import ILL_CONDITIONED_CORRELATION, fit_sphere
from ..evaluation.metrics import STEEL_EXPANSION_PPM_PER_K
from ..evaluation.plots import new_figure, save_plot
from ..run import Run
from ..temperature import TemperaturePolicy, as_policy, log_notes

__all__ = [
    "DECISION_RULE",
    "ACCEPTANCE_CLAUSE",
    "MPE",
    "parse_mpe",
    "decide",
    "NO_DECISION",
    "Check",
    "AcceptanceResult",
    "acceptance_test",
    "probing_test",
]

_log = logging.getLogger("cmmpose.standards")

DECISION_RULE = ("ISO 14253-1 style, the test uncertainty U (k = 2) counted against the user who states conformance: "
                 "pass when |error| + U <= MPE, fail when |error| - U > MPE, otherwise not proven; no decision when the "
                 "error itself is not determined (an ill-conditioned fit)")
ACCEPTANCE_CLAUSE = ("in the manner of ISO 10360-8:2013 (optical distance sensors): probing form and size errors on a "
                     "calibrated sphere (single view and all points), length measurement error between sphere "
                     "centres of a calibrated artefact; decision per ISO 14253-1")

_MPE_TEXT = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*(?:\+\s*L\s*/\s*([0-9]*\.?[0-9]+)\s*)?$", re.IGNORECASE)


@dataclass(frozen=True)
class MPE:
    """A maximum permissible error ``A + L/K`` um (L in mm), or a constant ``A``.

    Attributes
    ----------
    constant_um : float
        A, um.
    length_divisor_mm : float or None
        K, mm per um (the MPE grows by 1 um every K mm); None for a constant MPE.
    """

    constant_um: float
    length_divisor_mm: float | None = None

    def at(self, length_mm: float = 0.0) -> float:
        """The MPE at a length, um.

        Parameters
        ----------
        length_mm : float
            Measured length L, mm (ignored by a constant MPE).
        """
        if self.length_divisor_mm is None:
            return self.constant_um
        return self.constant_um + abs(float(length_mm)) / self.length_divisor_mm

    def __str__(self) -> str:
        if self.length_divisor_mm is None:
            return f"{self.constant_um:g} um"
        return f"{self.constant_um:g} + L/{self.length_divisor_mm:g} um (L in mm)"


def parse_mpe(text, name: str = "mpe") -> MPE:
    """An MPE from text: ``'12'`` (um) or ``'8+L/300'`` (um, L in mm).

    Parameters
    ----------
    text : str or float
        The MPE as written on a specification.
    name : str
        The argument's name, for messages.
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        text = repr(float(text))
    m = _MPE_TEXT.match(str(text))
    if not m:
        raise InputError(f"{name}: expected an MPE in um like '12' or '8+L/300' (L in mm), got {text!r}")
    a = float(m.group(1))
    k = None if m.group(2) is None else float(m.group(2))
    if k is not None and k <= 0:
        raise InputError(f"{name}: the length divisor K of 'A+L/K' must be positive, got {text!r}")
    return MPE(a, k)


def decide(error_um: float, mpe_um: float, expanded_uncertainty_um: float) -> str:
    """``'pass'``, ``'fail'`` or ``'not proven'`` by :data:`DECISION_RULE`.

    Parameters
    ----------
    error_um : float
        The error of indication, um (its magnitude is compared).
    mpe_um : float
        The maximum permissible error, um.
    expanded_uncertainty_um : float
        U (k = 2) of the test, um.
    """
    e, u = abs(float(error_um)), float(expanded_uncertainty_um)
    if e + u <= mpe_um:
        return "pass"
    if e - u > mpe_um:
        return "fail"
    return "not proven"


#: What the command line and reports say of an error that cannot be decided (``Check.decision``).
NO_DECISION = "no decision"

_ORDER = {"pass": 0, "not proven": 1, NO_DECISION: 2, "fail": 3}


def _worst(decisions) -> str:
    return max(decisions, key=_ORDER.__getitem__)


def _undetermined_size(fit, what: str) -> str | None:
    """Why a free-radius ``fit`` (cmmpose.fitting.SphereFit) does not determine a probing size error, or None:
    over so small a cap that the radius moves with the centre (the ``IllConditionedFit`` condition), the size
    error is not determined, whatever U the certificates give."""
    rho = fit.centre_radius_correlation
    if not rho > ILL_CONDITIONED_CORRELATION:
        return None
    return (f"{what}: no decision: the free-radius fit is ill-conditioned over a {fit.polar_coverage:.1f} deg cap "
            f"(centre-radius correlation {rho:.4f} > {ILL_CONDITIONED_CORRELATION:g}: the radius moves with the "
            f"centre, u(radius) {fit.radius_uncertainty * 1e3:.2g} um from the points' scatter alone), so the size "
            "error is not determined; scan more of the sphere")


def _size_check(test: str, item: str, fit, calibrated_radius: float, mpe_um: float, U_um: float, notes: list) -> Check:
    """The probing size check of ``fit`` against ``calibrated_radius`` (mm): decided, or ``no decision`` with
    the reason appended to ``notes`` when the fit does not determine the radius (:func:`_undetermined_size`)."""
    check = Check.judged(test, item, 2 * (fit.radius - calibrated_radius) * 1e3, mpe_um, U_um)
    reason = _undetermined_size(fit, f"{test} of {item}")
    if reason:
        notes.append(reason)
        return replace(check, decision=NO_DECISION)
    return check


@dataclass(frozen=True)
class Check:
    """One tested value.

    Attributes
    ----------
    test : str
        ``'probing form, single view'``, ``'probing form, all points'``,
        ``'probing size, single view'``, ``'probing size, all points'`` or ``'length'``.
    item : str
        What was measured (scan, position, length).
    error_um : float
        The error of indication, um (form >= 0; size and length signed).
    mpe_um : float
        The MPE it is held against, um.
    U_um : float
        Expanded uncertainty (k = 2) of the test, um.
    decision : str
        ``'pass'``, ``'fail'``, ``'not proven'`` or ``'no decision'`` (the
        error not determined; the result's notes say why).
    length_mm : float
        Length tests: the measured length at 20 C, mm (NaN otherwise).
    """

    test: str
    item: str
    error_um: float
    mpe_um: float
    U_um: float
    decision: str
    length_mm: float = float("nan")

    @classmethod
    def judged(cls, test: str, item: str, error_um: float, mpe_um: float, U_um: float,
               length_mm: float = float("nan")) -> Check:
        """The check with its decision by :data:`DECISION_RULE`."""
        return cls(test, item, error_um, mpe_um, U_um, decide(error_um, mpe_um, U_um), length_mm)

    def to_dict(self) -> dict:
        d = {"test": self.test, "item": self.item, "error_um": round(self.error_um, 3), "mpe_um": round(self.mpe_um, 3),
             "U_um": round(self.U_um, 3), "k": 2, "decision": self.decision}
        if np.isfinite(self.length_mm):
            d["length_mm"] = round(self.length_mm, 5)
        return d


@dataclass(frozen=True)
class AcceptanceResult:
    """The acceptance tests of one run (:func:`acceptance_test`).

    Attributes
    ----------
    checks : tuple of Check
        Every tested value.
    label : str
        ``'compensated'`` or ``'uncompensated'``: the points tested.
    mpe_form, mpe_size : MPE
        The user's MPEs.
    mpe_length : MPE or None
        The length MPE (None: no length test asked, :func:`probing_test`).
    uncertainty_notes : tuple of str
        What each test uncertainty is made of, and what it leaves out.
    notes : tuple of str
        Tests that could not be made (no reference scans, no calibrated length...),
        and the positions skipped.
    skipped : tuple of dict
        Ballbar positions and scans left out as incomplete or ambiguous
        (``skip_incomplete=True``; :func:`cmmpose.evaluation.ballbar.ballbar_scans`).
    temperature_log : dict or None
        How the run's temperatures were read from its thermocouple log
        (channels dropped and why, points held and how long, the channels
        each role read: :func:`cmmpose.temperature.log_provenance`); None
        when a temperature was given.
    """

    checks: tuple[Check, ...]
    label: str
    mpe_form: MPE
    mpe_size: MPE
    mpe_length: MPE | None
    uncertainty_notes: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    skipped: tuple[dict, ...] = field(default=())
    temperature_log: dict | None = None

    def tests(self) -> list[str]:
        """The tests made, in order."""
        return list(dict.fromkeys(c.test for c in self.checks))

    def summary(self) -> dict[str, dict]:
        """Per test: the value with the largest |error| (its check) and the
        worst decision of all its values."""
        out = {}
        for test in self.tests():
            cs = [c for c in self.checks if c.test == test]
            worst = max(cs, key=lambda c: abs(c.error_um) - c.mpe_um)
            out[test] = {"largest": worst, "decision": _worst(c.decision for c in cs), "n": len(cs)}
        return out

    @property
    def decision(self) -> str:
        """The overall decision: fail if any value fails, pass if all pass, no decision if a value could not be
        decided, otherwise not proven."""
        return _worst(c.decision for c in self.checks)

    def to_dict(self) -> dict:
        return {
            "decision": self.decision, "decision_rule": DECISION_RULE, "standard": ACCEPTANCE_CLAUSE, "points": self.label,
            "mpe": {"form": str(self.mpe_form), "size": str(self.mpe_size),
                    "length": "not tested" if self.mpe_length is None else str(self.mpe_length)},
            "tests": {t: {"decision": s["decision"], "values": s["n"], **{k: v for k, v in s["largest"].to_dict().items()
                                                                       if k != "test"}}
                      for t, s in self.summary().items()},
            "checks": [c.to_dict() for c in self.checks],
            "uncertainty_notes": list(self.uncertainty_notes), "notes": list(self.notes),
            "skipped": list(self.skipped), "temperature_log": self.temperature_log,
        }

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def to_markdown(self) -> str:
        """A report section: one row per test (its largest error), the decision rule, U's makeup, notes."""
        lines = [f"## Acceptance ({self.label} points): {self.decision}", "", ACCEPTANCE_CLAUSE + ".", "",
                 f"Decision rule: {DECISION_RULE}.", "",
                 "| test | values | largest error (um) | at | MPE (um) | U, k = 2 (um) | decision |", "|" + "---|" * 7]
        for test, s in self.summary().items():
            c = s["largest"]
            lines.append(f"| {test} | {s['n']} | {c.error_um:+.2f} | {c.item} | {c.mpe_um:.2f} | {c.U_um:.2f} | "
                         f"{s['decision']} |")
        lines += [""] + [f"- {n}" for n in (*self.uncertainty_notes, *self.notes)]
        return "\n".join(lines) + "\n"

    def __rich__(self):
        from rich.table import Table

        colour = {"pass": "green", "fail": "red", "not proven": "yellow", NO_DECISION: "magenta"}
        t = Table(title=f"Acceptance ({self.label} points): {self.decision.upper()}")
        for name in ("test", "values", "largest error (um)", "at", "MPE (um)", "U, k=2 (um)", "decision"):
            t.add_column(name, justify="left" if name in ("test", "at", "decision") else "right")
        for test, s in self.summary().items():
            c = s["largest"]
            t.add_row(test, str(s["n"]), f"{c.error_um:+.2f}", c.item, f"{c.mpe_um:.2f}", f"{c.U_um:.2f}",
                      f"[{colour[s['decision']]}]{s['decision']}[/]")
        t.caption = "\n".join([f"decision rule: {DECISION_RULE}", ACCEPTANCE_CLAUSE, *self.uncertainty_notes,
                               *self.notes])
        return t

    def plot(self, path=None):
        """Length errors against length with the MPE and U bars, and the probing
        errors against their MPEs; saved to ``path`` if given.

        Parameters
        ----------
        path : str or PathLike, optional
            Image file to write.

        Returns
        -------
        matplotlib.figure.Figure
        """
        fig = new_figure(figsize=(11, 4.2))
        a1, a2 = fig.subplots(1, 2)
        lengths = [c for c in self.checks if c.test == "length"]
        if lengths:
            L = np.array([c.length_mm for c in lengths])
            a1.errorbar(L, [c.error_um for c in lengths], yerr=[c.U_um for c in lengths], fmt="o", ms=4, capsize=3,
                        label="E (error bar: U, k = 2)")
            grid = np.linspace(0, max(L.max() * 1.1, 1.0), 50)
            mpe = np.array([self.mpe_length.at(x) for x in grid])
            a1.plot(grid, mpe, "r-", label=f"MPE {self.mpe_length}")
            a1.plot(grid, -mpe, "r-")
            a1.legend(fontsize=8)
        a1.set_xlabel("length (mm)")
        a1.set_ylabel("length measurement error (um)")
        a1.grid(alpha=0.3)
        probing = [c for c in self.checks if c.test != "length"]
        tests = list(dict.fromkeys(c.test for c in probing))
        for i, test in enumerate(tests):
            cs = [c for c in probing if c.test == test]
            a2.errorbar(np.full(len(cs), i) + np.linspace(-0.2, 0.2, len(cs)), [c.error_um for c in cs],
                        yerr=[c.U_um for c in cs], fmt="o", ms=3, capsize=2)
            a2.hlines([cs[0].mpe_um, -cs[0].mpe_um] if "size" in test else [cs[0].mpe_um], i - 0.35, i + 0.35, colors="r")
        a2.set_xticks(range(len(tests)), [t.replace("probing ", "").replace(", ", "\n") for t in tests], fontsize=8)
        a2.set_ylabel("probing error (um)")
        a2.grid(alpha=0.3)
        fig.suptitle(f"Acceptance ({self.label}): {self.decision}")
        fig.tight_layout()
        return save_plot(fig, path)


def acceptance_test(
    run: Run,
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: float | None = None,
    *,
    mpe_form,
    mpe_size,
    mpe_length,
    calibrated_length: float | None = None,
    calibrated_radius: float | None = None,
    reference_radius: float | None = None,
    u_length_certificate_um: float = 0.0,
    u_diameter_certificate_um: float = 0.0,
    u_form_certificate_um: float = 0.0,
    expansion_ppm_per_K: float = STEEL_EXPANSION_PPM_PER_K,
    u_expansion_ppm_per_K: float = 1.0,
    u_part_temperature_K: float = 0.2,
    out_of_range: str | None = None,
    skip_incomplete: bool = False,
    temperature_policy: TemperaturePolicy | None = None,
) -> AcceptanceResult:
    """Probing form and size errors and length measurement errors of a run,
    each decided against its MPE (module docstring; docs/standards.md).

    Parameters
    ----------
    run : Run
        A ballbar run; scans of the reference sphere (feature 'reference')
        give the all-points tests.
    maps : ErrorMap or ErrorMapSet, optional
        Compensation maps: the tests are of the compensated points. None:
        of the uncompensated points.
    temperature : float, optional
        Machine (and part) temperature, C; default the run's thermocouple log.
    mpe_form, mpe_size : str, float or MPE
        MPEs of the probing form and size errors, um.
    mpe_length : str, float or MPE
        MPE of the length measurement error, um, e.g. ``'8+L/300'`` (L in mm).
    calibrated_length : float, optional
        Certified centre distance of the artefact at 20 C, mm; default the
        run's ``artefact['calibrated_length_mm']``. Without one, no length test.
    calibrated_radius : float, optional
        Certified radius of the ballbar's balls, mm; default the run's
        ``artefact['calibrated_radius_mm']``. Without one, no probing test on the balls.
    reference_radius : float, optional
        Certified radius of the reference sphere, mm; default the run's
        ``artefact['reference_sphere']['radius_mm']``.
    u_length_certificate_um : float
        Standard uncertainty of the certified length, um.
    u_diameter_certificate_um : float
        Standard uncertainty of a certified diameter, um.
    u_form_certificate_um : float
        Standard uncertainty of the spheres' form (certified form deviation), um.
    expansion_ppm_per_K : float
        Expansion coefficient of the artefact, ppm/K.
    u_expansion_ppm_per_K : float
        Standard uncertainty of the expansion coefficient, ppm/K.
    u_part_temperature_K : float
        Standard uncertainty of the artefact's temperature, K.
    out_of_range : {'raise', 'clamp', 'extrapolate'}, optional
        As :func:`cmmpose.evaluate`; overrides the policy's.
    skip_incomplete : bool
        As :func:`cmmpose.evaluate`: False (default) raises ``RunError`` on a
        position with a ball scan missing, duplicated or mislabelled; True
        leaves such positions out of every test and lists them in ``skipped``
        and the notes.
    temperature_policy : TemperaturePolicy, optional
        As :func:`cmmpose.evaluate` (cmmpose.temperature): how the log becomes
        temperatures; the thermocouples dropped, the points held and the
        channels each role read are in ``temperature_log`` and the notes.

    Returns
    -------
    AcceptanceResult
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    mpes = {n: (v if isinstance(v, MPE) else parse_mpe(v, n)) for n, v in
            (("mpe_form", mpe_form), ("mpe_size", mpe_size), ("mpe_length", mpe_length))}
    u_len = nonnegative("u_length_certificate_um", u_length_certificate_um)
    u_dia = nonnegative("u_diameter_certificate_um", u_diameter_certificate_um)
    u_frm = nonnegative("u_form_certificate_um", u_form_certificate_um)
    u_alpha = nonnegative("u_expansion_ppm_per_K", u_expansion_ppm_per_K)
    expansion = finite("expansion_ppm_per_K", expansion_ppm_per_K) * 1e-6  # 1/K
    u_t = nonnegative("u_part_temperature_K", u_part_temperature_K)
    art = run.artefact
    if calibrated_length is None:
        calibrated_length = art.get("calibrated_length_mm")
    if calibrated_radius is None:
        calibrated_radius = art.get("calibrated_radius_mm")
    if reference_radius is None and isinstance(art.get("reference_sphere"), dict):
        reference_radius = art["reference_sphere"].get("radius_mm")

    policy = as_policy(temperature_policy, out_of_range=out_of_range)
    ev = evaluate(run, maps, temperature, expansion_ppm_per_K=expansion_ppm_per_K, skip_incomplete=skip_incomplete,
                  temperature_policy=policy)
    res = ev.compensated if ev.compensated is not None else ev.uncompensated
    checks: list[Check] = []
    tlog = ev.provenance["temperature"].get("log")
    notes: list[str] = [n for n in (skipped_note(ev.skipped),) if n] + (log_notes(tlog) if tlog else [])
    unotes: list[str] = []
    U_form = 2 * u_frm
    U_size = 2 * u_dia
    if calibrated_radius is not None:
        checks += _ball_probing_checks(res.spheres, float(calibrated_radius), mpes, U_form, U_size)
    else:
        notes.append("no calibrated ball radius (artefact calibrated_radius_mm): no probing tests on the ballbar's balls")

    ref_ids = run.scans["scan_id"][run.scans["feature"] == "reference"] if len(run.scans["scan_id"]) else []
    if len(ref_ids) and reference_radius is not None:
        checks += _reference_checks(run, maps, temperature, policy, np.asarray(ref_ids), float(reference_radius),
                                    mpes, U_form, U_size, notes)
    elif len(ref_ids):
        notes.append("reference scans without a calibrated radius (artefact reference_sphere.radius_mm): "
                     "no all-points tests")
    else:
        notes.append("no scans of the reference sphere: no all-points probing tests")

    if calibrated_length is not None:
        checks += _length_checks(res, float(calibrated_length), mpes["mpe_length"], u_len, u_alpha, expansion, u_t)
        unotes.append(f"length U = 2 sqrt(u_cert^2 + (L u_alpha |T - 20|)^2 + (L alpha u_T)^2): u_cert {u_len:g} um, "
                      f"u_alpha {u_alpha:g} ppm/K, alpha {expansion * 1e6:g} ppm/K, u_T {u_t:g} K")
    else:
        notes.append("no calibrated length (artefact calibrated_length_mm): no length test")
    unotes.append(f"probing U: form 2 x {u_frm:g} um (sphere form certificate), size 2 x {u_dia:g} um (diameter "
                  "certificate)")
    unotes.append("U leaves out the tested machine's own scatter (the errors show it) and the fixture; a zero "
                  "certificate uncertainty means none was given")
    if not checks:
        raise InputError("run: nothing to test: give a calibrated length and/or calibrated radii")
    _log.info("acceptance: %d values tested", len(checks))
    return AcceptanceResult(tuple(checks), res.label, mpes["mpe_form"], mpes["mpe_size"], mpes["mpe_length"],
                            tuple(unotes), tuple(notes), tuple(ev.skipped), tlog)


def _ball_probing_checks(spheres, r_cal: float, mpes: dict, U_form: float, U_size: float) -> list[Check]:
    """The single-view probing tests on the ballbar's balls: each ball's form, then each ball's size error
    (twice the radius error against the calibrated radius), um."""
    checks = []
    for s in spheres:
        item = f"position {s.position} ball {s.ball} (scan {s.scan_id})"
        checks.append(Check.judged("probing form, single view", item, s.form * 1e3, mpes["mpe_form"].at(),
                                   U_form))
    for s in spheres:
        item = f"position {s.position} ball {s.ball} (scan {s.scan_id})"
        e = 2 * (s.radius - r_cal) * 1e3
        checks.append(Check.judged("probing size, single view", item, e, mpes["mpe_size"].at(), U_size))
    return checks


def _length_checks(res, l_cal: float, mpe_length: MPE, u_len: float, u_alpha: float, expansion: float,
                   u_t: float) -> list[Check]:
    """The length test at each position: the error of the length at 20 C against the calibrated length, um, with
    U = 2 sqrt(u_cert^2 + (L u_alpha |T - 20|)^2 + (L alpha u_T)^2)."""
    l20 = res.lengths_at_20c
    if not np.all(np.isfinite(l20)):
        raise InputError("temperature: the run has no temperature log; give the part temperature (C) for the "
                         "lengths at 20 C")
    checks = []
    for p, length, t in zip(res.positions.tolist(), l20, res.temperatures):
        e = (length - l_cal) * 1e3
        u = math.sqrt(u_len ** 2 + (length * u_alpha * (t - 20.0) * 1e-3) ** 2
                      + (length * expansion * 1e6 * u_t * 1e-3) ** 2)
        mpe = mpe_length.at(length)
        checks.append(Check.judged("length", f"position {p}", e, mpe, 2 * u, float(length)))
    return checks


def _reference_checks(run: Run, maps, temperature, policy, ref_ids: np.ndarray, radius: float, mpes,
                      U_form: float, U_size: float, notes: list) -> list[Check]:
    """Probing tests on the reference sphere: every scan alone and all together (a size the fit does not
    determine: no decision, the reason appended to ``notes``)."""
    if maps is None or isinstance(maps, ErrorMap):
        xyz = machine_coordinates(run, maps, None, policy)
    else:
        if temperature is not None:
            model_t = float(temperature)
        elif run.temperatures is not None:
            model_t = machine_temperature(run, run.points["t"], temperature_policy=policy)
        else:
            raise InputError("temperature: the run has no temperature log; give the machine temperature (C)")
        xyz = machine_coordinates(run, maps, model_t, policy)
    sid = run.points["scan_id"]
    out = []
    views = []
    for i in ref_ids.tolist():
        pts = xyz[sid == i]
        f = fit_sphere(pts)
        views.append(f)
        out.append(Check.judged("probing form, single view", f"reference scan {i}", f.form * 1e3,
                                mpes["mpe_form"].at(), U_form))
        out.append(_size_check("probing size, single view", f"reference scan {i}", f, radius, mpes["mpe_size"].at(),
                               U_size, notes))
    f = fit_sphere(xyz[np.isin(sid, ref_ids)])
    item = f"reference sphere, {len(ref_ids)} views together"
    out.append(Check.judged("probing form, all points", item, f.form * 1e3, mpes["mpe_form"].at(), U_form))
    out.append(_size_check("probing size, all points", item, f, radius, mpes["mpe_size"].at(), U_size, notes))
    return out


def probing_test(points, calibrated_radius: float, *, mpe_form, mpe_size, u_form_certificate_um: float = 0.0,
                 u_diameter_certificate_um: float = 0.0, item: str = "sphere scan") -> AcceptanceResult:
    """Probing form and size errors of one scan of a calibrated sphere (a
    single view; all points given are used, as the test asks), decided
    against the MPEs by :data:`DECISION_RULE`.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The sphere's points, mm (segmented from a raw scan first, e.g. with
        ``cmmpose.fitting.e3125``; the caller's array is not modified).
    calibrated_radius : float
        Certified radius, mm.
    mpe_form, mpe_size : str, float or MPE
        MPEs of the probing form and size errors, um.
    u_form_certificate_um : float
        Standard uncertainty of the sphere's form, um.
    u_diameter_certificate_um : float
        Standard uncertainty of the certified diameter, um.
    item : str
        What the points are (a file name), for the result.

    Returns
    -------
    AcceptanceResult
        Two checks: probing form and probing size, single view. When the
        free-radius fit is ill-conditioned (centre-radius correlation above
        ``cmmpose.fitting.ILL_CONDITIONED_CORRELATION``: a small cap, where
        the radius moves with the centre) the size is not determined: its
        decision is ``'no decision'`` and the notes say why (the form, the
        residuals' range over the points given, is still decided).
    """
    mpes = {n: (v if isinstance(v, MPE) else parse_mpe(v, n)) for n, v in (("mpe_form", mpe_form), ("mpe_size", mpe_size))}
    r_cal = float(calibrated_radius)
    if not (math.isfinite(r_cal) and r_cal > 0):
        raise InputError(f"calibrated_radius: expected a positive radius in mm, got {calibrated_radius!r}")
    U_form = 2 * nonnegative("u_form_certificate_um", u_form_certificate_um)
    U_size = 2 * nonnegative("u_diameter_certificate_um", u_diameter_certificate_um)
    f = fit_sphere(points)
    notes = [f"{f.n_points} points, least-squares sphere with a free radius over a {f.polar_coverage:.0f} deg cap"]
    checks = (Check.judged("probing form, single view", item, f.form * 1e3, mpes["mpe_form"].at(), U_form),
              _size_check("probing size, single view", item, f, r_cal, mpes["mpe_size"].at(), U_size, notes))
    unotes = (f"probing U: form 2 x {U_form / 2:g} um (sphere form certificate), size 2 x {U_size / 2:g} um "
              "(diameter certificate); U leaves out the tested instrument's own scatter",)
    return AcceptanceResult(checks, "given", mpes["mpe_form"], mpes["mpe_size"], None, unotes, tuple(notes))
