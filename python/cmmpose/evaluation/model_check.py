"""A model checked as saved on a run it was not fitted to.

The check evaluates the run twice through the one evaluation every command
uses (:func:`cmmpose.evaluate` for a ballbar run,
:func:`cmmpose.evaluation.artefact.evaluate_artefact` for an artefact run):
once with the model exactly as saved, once with its plain maps (the same
model without its effects, reading the run's log the same way). Nothing is
fitted to the run: ``cmmpose evaluate RUN --model m.json``, ``cmmpose
diagnose RUN --model m.json`` and :func:`check_model` print the same
figures to the last digit.

The headline figure is the evaluation's own: the ballbar's rms accuracy
error (sample standard deviation of the lengths) or the artefact's rms ball
deviation. Its standard uncertainty comes from the spread over the items it
is made of (lengths, balls): with e_i the item's squared error (a length's
(L_i - mean)^2 n / (n - 1), a ball's |deviation|^2), rms = sqrt(mean e) and
u(mean e) = sd(e) / sqrt(n), so u(rms) = u(mean e) / (2 rms). The change,
model minus plain, takes the paired differences d_i of the e_i:
u(change) = sd(d) / sqrt(n) / (rms_model + rms_plain). The model holds where
the change is not above its uncertainty; it makes the run worse where the
change is above twice its uncertainty (k = 2). Units: um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..run import Run
from .artefact import evaluate_artefact, is_artefact_run
from .ballbar import evaluate

__all__ = ["ModelCheck", "check_model"]


@dataclass(frozen=True)
class ModelCheck:
    """A model applied as saved to a run, beside its plain maps.

    Attributes
    ----------
    figure : str
        'rms accuracy error' (ballbar) or 'rms deviation' (artefact).
    model_um, model_u_um : float
        The figure with the model, and its standard uncertainty, um.
    plain_um, plain_u_um : float
        The same with the model's plain maps, um.
    change_um, change_u_um : float
        Model minus plain, and its standard uncertainty, um.
    items : int
        Lengths or balls the figures are made of.
    effects : tuple of str
        The model's effects.
    notes : tuple of str
        Where the run lies outside the model's domain, or its correction is
        not determined (:meth:`cmmpose.Model.domain_notes`).
    correction_um, correction_u_um : float
        The model's correction beyond its plain maps at the run's points
        (rms over a sample) and its predicted standard uncertainty (k = 1,
        from the parameters' covariance), um.
    evaluation : Evaluation or ArtefactEvaluation
        The run evaluated with the model, as ``cmmpose evaluate`` gives it.
    """

    figure: str
    model_um: float
    model_u_um: float
    plain_um: float
    plain_u_um: float
    change_um: float
    change_u_um: float
    items: int
    effects: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    correction_um: float = 0.0
    correction_u_um: float = 0.0
    evaluation: object = field(default=None, repr=False, compare=False)

    @property
    def holds(self) -> bool:
        """The model does not raise the figure by more than the change's uncertainty."""
        return self.change_um <= self.change_u_um

    @property
    def worse(self) -> bool:
        """The model raises the figure by more than twice the change's
        uncertainty (k = 2: a model that changes nothing is called worse
        about once in 40 runs): what ``--strict-model`` gates on."""
        return self.change_um > 2 * self.change_u_um

    @property
    def verdict(self) -> str:
        """The check in words."""
        figs = (f"{self.figure} {self.model_um:.2f} ± {self.model_u_um:.2f} um against {self.plain_um:.2f} ± "
                f"{self.plain_u_um:.2f} um with the plain maps")
        if self.change_um < -self.change_u_um:
            return f"the model holds on this run: {figs} (a fall of {-self.change_um:.2f} ± {self.change_u_um:.2f} um)"
        if self.holds:
            return (f"the model neither helps nor harms on this run: {figs} (change {self.change_um:+.2f} ± "
                    f"{self.change_u_um:.2f} um)")
        if not self.worse:
            return (f"the model may harm this run: {figs} (a rise of {self.change_um:.2f} ± {self.change_u_um:.2f} um, "
                    f"within twice its uncertainty)")
        return (f"the model made this run WORSE: {figs} (a rise of {self.change_um:.2f} ± {self.change_u_um:.2f} um); "
                f"do not use it here")

    @property
    def warnings(self) -> tuple[str, ...]:
        """What a production line should not pass: a rise beyond the uncertainty, and the domain notes."""
        return ((self.verdict,) if self.worse else ()) + self.notes

    def to_dict(self) -> dict:
        return _finite_or_none({"figure": self.figure, "model_rms_um": self.model_um, "model_rms_u_um": self.model_u_um,
                             "plain_rms_um": self.plain_um, "plain_rms_u_um": self.plain_u_um,
                             "change_um": self.change_um, "change_u_um": self.change_u_um, "holds": self.holds,
                             "worse": self.worse, "items": self.items, "effects": list(self.effects),
                             "notes": list(self.notes), "correction_um": self.correction_um,
                             "correction_u_um": self.correction_u_um, "verdict": self.verdict})


def _finite_or_none(d: dict) -> dict:
    """JSON-safe: a figure that is not finite (one item: no spread) as None."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def _squared_errors(result) -> tuple[float, np.ndarray]:
    """The headline figure of one evaluated state (mm) and its items' squared errors (mm^2)."""
    if hasattr(result, "placements"):  # an artefact: the balls' deviations
        e = np.array([b.magnitude ** 2 for b in result.balls], dtype=float)
        return result.rms, e
    d = np.asarray(result.lengths, dtype=float)
    n = len(d)
    return result.rms_accuracy_error, (d - d.mean()) ** 2 * n / max(n - 1, 1)


def _rms_u(rms_mm: float, e: np.ndarray) -> tuple[float, float]:
    n = len(e)
    u_mean = float(np.std(e, ddof=1) / math.sqrt(n)) if n > 1 else math.inf
    return rms_mm * 1e3, (u_mean / (2 * rms_mm) * 1e3 if rms_mm > 0 else math.inf)


def check_model(run: Run, model, *, evaluation=None, **options) -> ModelCheck:
    """Does ``model`` hold on ``run``, which it was not fitted to? Applied as
    saved (nothing refitted) through the evaluation every command uses,
    beside its plain maps (module docstring).

    Parameters
    ----------
    run : Run
        A ballbar or artefact run the model never saw.
    model : Model
        A found model (:class:`cmmpose.Model`), or maps (then the check
        compares them with themselves).
    evaluation : Evaluation or ArtefactEvaluation, optional
        The run already evaluated with ``model`` and ``options`` (a command
        that printed it): not evaluated again.
    **options
        As :func:`cmmpose.evaluate` (or ``evaluate_artefact``) takes them:
        ``temperature`` C, ``reject``, ``out_of_range``,
        ``temperature_tolerance`` K, ``log_hold`` s, ``temperature_policy``,
        and for a ballbar ``expansion_ppm_per_K`` and ``skip_incomplete``.

    Returns
    -------
    ModelCheck
    """
    apply = evaluate_artefact if is_artefact_run(run) else evaluate
    if evaluation is None:
        evaluation = apply(run, model, **options)
    plain = apply(run, model.without_effects(), **options)
    rm, e_m = _squared_errors(evaluation.compensated)
    rp, e_p = _squared_errors(plain.compensated)
    model_um, model_u = _rms_u(rm, e_m)
    plain_um, plain_u = _rms_u(rp, e_p)
    n = len(e_m)
    ud = float(np.std(e_m - e_p, ddof=1) / math.sqrt(n)) if n > 1 else math.inf
    change = model_um - plain_um
    u_change = ud / ((model_um + plain_um) * 1e-3) * 1e3 if model_um + plain_um > 0 else math.inf
    figure = "rms deviation" if hasattr(evaluation.compensated, "placements") else "rms accuracy error"
    held = model.where_it_holds(run) if model.reads_run else {"notes": [], "correction_um": 0.0,
                                                              "correction_u_um": 0.0}
    return ModelCheck(figure, model_um, model_u, plain_um, plain_u, change, u_change, n,
                      tuple(s.name for s, _ in model.effects), tuple(held["notes"]), held["correction_um"],
                      held["correction_u_um"], evaluation)
