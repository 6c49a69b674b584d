"""Aliased choices kept as aliased (issue 25, section 5): which effects the
data a model was found on could not tell from the ones it holds
(:func:`find_alternatives`), each fitted in the chosen one's place. The
alternatives are saved with the model and checked where it is applied
(:mod:`cmmpose.model.alternatives`, whose docstring gives the thresholds)."""

from __future__ import annotations

import logging

import numpy as np

from ..errors import Error
from ..model.alternatives import Alternative, observables_difference_um
from ..model.spec import EffectSpec
from .identify import PRIOR_WEIGHT

__all__ = ["find_alternatives", "linear_swap"]

log = logging.getLogger(__name__)


def _first_rows(problem) -> list[np.ndarray]:
    """Row indices of the first observable class (lengths or deviations) of each run of ``problem``."""
    k = 4  # observables.CLASSES
    cls = np.asarray(problem.classes)
    return [np.flatnonzero(cls == c) for c in np.unique(cls[cls % k == 0])]


def find_alternatives(problem, steps, model) -> tuple[Alternative, ...]:
    """The alternatives of the effects in the final ``model`` of a selection.

    An alternative is a candidate the data could not tell from the effect
    added (``Candidate.indistinguishable_from`` of the step's leader), or
    the same physics following another sensor whose swap changes -2 log L
    by less than ``INDISTINGUISHABLE_LR`` against the final model. Each is
    refitted in place of its chosen effect, with the model's other effects
    and the nuisances, and its in-sample difference measured: linearised
    about the final model through the problem's sensitivity columns (the
    ones the ranking used), so no alternative costs a compensation of the
    run (:func:`linear_swap`).
    """
    pairs: dict[tuple[str, str], str] = {}
    names = set(model.names)
    for prev, s in zip(steps, steps[1:]):
        chosen = s.effect
        if chosen not in names:
            continue
        lead = next((c for c in prev.ranking if c.name == chosen), None)
        if lead is None:
            continue
        for other in lead.indistinguishable_from:
            c = next((x for x in prev.ranking if x.name == other), None)
            if c is not None and other not in names:
                pairs.setdefault((chosen, other), f"the run could not tell {other} from {chosen}: "
                                                  f"-2 log L within the margin, contributions alike")
    for c in steps[-1].ranking:
        if c.alternative_to in names and c.alternative_to in c.aliases and c.name not in names:
            pairs.setdefault((c.alternative_to, c.name),
                             f"the run could not choose between {c.name} and {c.alternative_to} "
                             f"(-2 log L {abs(c.lr):.1f} apart)")
    if not pairs:
        return ()
    groups = _first_rows(problem)
    last = steps[-1] if steps else None
    if last is not None and last.model is model and getattr(last, "residual", None) is not None:
        here = last.residual  # the final step observed the model already
    else:
        try:
            here = problem.observe(model).residual
        except Error:
            return ()
    out = []
    for (chosen, other), reason in pairs.items():
        spec = problem.candidates.get(other)
        if spec is None or other not in problem.columns or chosen not in problem.columns:
            continue
        try:
            values, predicted = linear_swap(problem, model, here, chosen, spec)
            diff = observables_difference_um(predicted, here, groups)
        except (Error, ValueError, np.linalg.LinAlgError) as exc:  # it cannot be put in the model's place
            log.debug("alternative %s to %s left out: %s", other, chosen, exc)
            continue
        out.append(Alternative(chosen, spec, np.asarray(values, float), diff, reason))
    return tuple(out)


def linear_swap(problem, model, residual: np.ndarray, chosen: str, spec: EffectSpec):
    """``spec`` fitted in place of the model's ``chosen`` effect, linearised
    about ``model`` (whose residual observables are ``residual``, mm).

    The chosen effect is taken out of the residual through its own columns
    (its values over its prior magnitudes), then ``spec``, the model's other
    effects (as changes of their values) and the nuisances are fitted by the
    diagnosis's weighted least squares with its weak prior (each effect's
    total value near zero within a few typical magnitudes), as
    :func:`cmmpose.diagnosis.identify.fit_model` does with the
    sensitivities of the current model.

    Returns
    -------
    (values, predicted) : ``spec``'s fitted values (its units), and the
    residual observables the model holding it instead predicts (mm; the
    nuisances' fitted change not applied: what observing that model gives).
    """
    X0, index = problem.model_design(model)
    k0 = problem.nuisance.shape[1]
    keep, ridge, target, at = list(range(k0)), [0.0] * k0, [0.0] * k0, k0
    for name, k in index:
        if name != chosen:
            keep.extend(range(at, at + k))
            ridge.extend([PRIOR_WEIGHT] * k)
            target.extend(-np.asarray(model.values(name), float) / np.asarray(problem.candidates[name].prior))
        at += k
    held = problem.candidates[chosen]
    r = residual - problem.columns[chosen] @ (np.asarray(model.values(chosen), float) / np.asarray(held.prior))
    J = problem.columns[spec.name]
    X = np.concatenate([X0[:, keep], J], axis=1)
    fit = problem.wls(r, X, ridge=np.r_[ridge, np.full(J.shape[1], PRIOR_WEIGHT)],
                      target=np.r_[target, np.zeros(J.shape[1])])
    predicted = r + X[:, k0:] @ fit.beta[k0:]
    return fit.beta[-J.shape[1]:] * np.asarray(spec.prior, float), predicted


