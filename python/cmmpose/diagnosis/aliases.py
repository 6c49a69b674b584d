"""Aliased choices kept as aliased (issue 25, section 5).

When the data a model was found on cannot tell two effects apart (the same
squareness change following one thermocouple role or another when every
role moved in proportion; a roll or a squareness on a plate in one plane),
the diagnosis adds one of them. The model saved keeps the others as
*alternatives*: each the effect it could stand in for, fitted in its place
to the same data, and how far apart the two predicted that data.

Applying the model (``cmmpose.compensate``, ``compensate_file``,
``cmmpose.evaluate`` and their commands) compares the choice with each
alternative on the data at hand and warns (:class:`AliasedChoiceWarning`,
and a warning on this module's logger, ``cmmpose.diagnosis.aliases``) where they differ by more
than the alternative's threshold:

- on a run, the difference is taken in what the evaluation reports: the
  ballbar lengths (an artefact run: its balls' deviations after each
  placement's rigid fit), less their common change (which a run without a
  calibrated length cannot see);
- on points (a point file, ``cmmpose.compensate``), in the compensated
  points, less the best-fitting rigid motion of the whole set (which any
  datum alignment of the part takes up).

The threshold (um) is ``max(ALIAS_FLOOR_UM, ALIAS_FACTOR x in-sample)``,
where in-sample is the largest difference of the two on the data they were
found on (the same measure as on a run): the data could not choose between
them at that difference, so a difference a few times larger is one those
data never tested. ``ALIAS_FLOOR_UM`` (1 um) keeps differences below the
figures' own reporting resolution and the scanner's per-scan floor from
warning on every application.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import AliasedChoiceWarning, Error, InputError
from .effects import EffectSpec

__all__ = ["Alternative", "AliasedChoiceWarning", "ALIAS_FACTOR", "ALIAS_FLOOR_UM", "find_alternatives",
           "check_alternatives", "alternative_difference_um", "points_difference_um"]

log = logging.getLogger(__name__)

#: um: the smallest difference between a choice and an alternative that warns.
ALIAS_FLOOR_UM = 1.0
#: A difference this many times the in-sample one is outside what the data tested.
ALIAS_FACTOR = 2.0


@dataclass(frozen=True)
class Alternative:
    """An effect the data could not tell from one in the model.

    Attributes
    ----------
    chosen : str
        The model's effect it is an alternative to.
    spec : EffectSpec
        The alternative effect.
    values : ndarray
        Its parameters fitted in place of ``chosen`` (its units).
    in_sample_um : float
        Largest difference of the two models' ballbar lengths (or ball
        deviations), less the common change, on the data they were found on, um.
    reason : str
        Why the two are aliased.
    """

    chosen: str
    spec: EffectSpec
    values: np.ndarray
    in_sample_um: float = 0.0
    reason: str = ""

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def threshold_um(self) -> float:
        """um: applying the model warns above this difference (module docstring)."""
        return max(ALIAS_FLOOR_UM, ALIAS_FACTOR * float(self.in_sample_um))

    def to_dict(self) -> dict:
        return {"chosen": self.chosen, "name": self.spec.name, "kind": self.spec.kind,
                "params": dict(zip(self.spec.params, map(float, self.values))),
                "units": dict(zip(self.spec.params, self.spec.units)),
                "in_sample_difference_um": float(self.in_sample_um), "warn_above_um": self.threshold_um,
                "reason": self.reason}

    def swapped(self, model):
        """``model`` holding this alternative in place of ``chosen``."""
        return model.without(self.chosen).with_values(self.spec, self.values)


def _first_rows(problem) -> list[np.ndarray]:
    """Row indices of the first observable class (lengths or deviations) of each run of ``problem``."""
    k = 4  # observables.CLASSES
    cls = np.asarray(problem.classes)
    return [np.flatnonzero(cls == c) for c in np.unique(cls[cls % k == 0])]


def observables_difference_um(a: np.ndarray, b: np.ndarray, groups) -> float:
    """Largest |a - b| (mm arrays) over each group's rows less the group's mean difference, um."""
    out = 0.0
    for rows in groups:
        if len(rows):
            d = np.asarray(a)[rows] - np.asarray(b)[rows]
            out = max(out, float(np.max(np.abs(d - d.mean()))) * 1e3)
    return out


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
    from .identify import PRIOR_WEIGHT

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


def points_difference_um(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| of two compensations of the same points (N, 3, mm)
    less the best-fitting rigid motion of the whole set (a small rotation
    about the points' centroid and a translation), um."""
    d = np.asarray(a, float) - np.asarray(b, float)
    if not len(d):
        return 0.0
    p = np.asarray(b, float)
    q = p - p.mean(axis=0)
    d = d - d.mean(axis=0)
    # Small rotation w: d ~ w x q. Normal equations: (sum |q|^2 I - q q^T) w = sum q x d.
    m = np.eye(3) * float(np.sum(q * q)) - q.T @ q
    w = np.linalg.pinv(m, rcond=1e-12) @ np.cross(q, d).sum(axis=0)
    left = d - np.cross(w, q)
    return float(np.sqrt(np.max(np.sum(left * left, axis=1)))) * 1e3


def alternative_difference_um(model, alt: Alternative, inputs, run=None, xyz=None) -> float:
    """How far ``alt`` and the model's choice differ on these data, um
    (module docstring): on ``run``'s lengths or deviations when the run is
    given, else on the compensated points of ``inputs``."""
    other = alt.swapped(model)
    if run is not None:
        from .observables import ObservationLayout, observe

        layout = ObservationLayout.from_run(run, inputs)
        groups = [np.arange(layout.sizes["length"])]
        a = observe(layout, model.compensate(inputs) if xyz is None else xyz, model.expansion_ppm_per_kelvin,
                    inputs.scan_id)
        b = observe(layout, other.compensate(inputs), other.expansion_ppm_per_kelvin, inputs.scan_id)
        return observables_difference_um(b.residual, a.residual, groups)
    return points_difference_um(other.compensate(inputs), model.compensate(inputs) if xyz is None else xyz)


def check_alternatives(model, inputs, where: str = "run", run=None, xyz=None) -> list[dict]:
    """Warn where an alternative of the model's choices predicts ``inputs``
    differently by more than its threshold (:class:`AliasedChoiceWarning`,
    and the ``cmmpose.diagnosis.aliases`` logger). Returns one dict per alternative
    compared (``chosen``, ``name``, ``difference_um``, ``threshold_um``,
    ``warned``); empty when the model holds none. ``xyz``: the model's
    compensation of ``inputs`` when the caller has it (mm), not computed again."""
    alternatives = getattr(model, "alternatives", ())
    if not alternatives:
        return []
    out = []
    for alt in alternatives:
        if alt.chosen not in model.names:
            continue
        try:
            if xyz is None:
                xyz = model.compensate(inputs)
            diff = alternative_difference_um(model, alt, inputs, run, xyz)
        except InputError as exc:  # the alternative needs an input these data lack: it cannot be compared
            out.append({"chosen": alt.chosen, "name": alt.name, "difference_um": None,
                        "threshold_um": alt.threshold_um, "warned": False, "why": str(exc)})
            continue
        out.append({"chosen": alt.chosen, "name": alt.name, "difference_um": diff, "threshold_um": alt.threshold_um,
                    "warned": bool(diff > alt.threshold_um)})
    what = "lengths" if run is not None else "points"
    for chosen in dict.fromkeys(f["chosen"] for f in out if f["warned"]):  # one message per choice
        differ = "; ".join(f"{f['name']} by up to {f['difference_um']:.2f} um (warns above {f['threshold_um']:.2f})"
                           for f in out if f["warned"] and f["chosen"] == chosen)
        msg = (f"{where}: the model's {chosen} was an aliased choice: effects the data it was found on could not "
               f"tell from it predict these {what} differently: {differ}; the compensation here rests on a choice "
               f"those data did not make (measure what separates them, or diagnose with this run)")
        log.warning(msg)
        warnings.warn(msg, AliasedChoiceWarning, stacklevel=3)
    return out
