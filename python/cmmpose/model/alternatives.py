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
and a warning on this module's logger, ``cmmpose.model.alternatives``) where they differ by more
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

from ..errors import AliasedChoiceWarning, InputError
from .spec import EffectSpec

__all__ = ["Alternative", "ALIAS_FACTOR", "ALIAS_FLOOR_UM", "check_alternatives", "observables_difference_um",
           "points_difference_um"]

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


def observables_difference_um(a: np.ndarray, b: np.ndarray, groups) -> float:
    """Largest |a - b| (mm arrays) over each group's rows less the group's mean difference, um."""
    out = 0.0
    for rows in groups:
        if len(rows):
            d = np.asarray(a)[rows] - np.asarray(b)[rows]
            out = max(out, float(np.max(np.abs(d - d.mean()))) * 1e3)
    return out


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


def alternative_difference_um(model, alt: Alternative, inputs, xyz=None, compare=None) -> float:
    """How far ``alt`` and the model's choice differ on these data, um
    (module docstring): ``compare(model, other, inputs, xyz)`` when the
    caller judges on a run's figures (the evaluation's lengths or
    deviations), else on the compensated points of ``inputs``."""
    other = alt.swapped(model)
    xyz = model.compensate(inputs) if xyz is None else xyz
    if compare is not None:
        return compare(model, other, inputs, xyz)
    return points_difference_um(other.compensate(inputs), xyz)


def check_alternatives(model, inputs, where: str = "run", xyz=None, compare=None) -> list[dict]:
    """Warn where an alternative of the model's choices predicts ``inputs``
    differently by more than its threshold (:class:`AliasedChoiceWarning`,
    and the ``cmmpose.model.alternatives`` logger). Returns one dict per alternative
    compared (``chosen``, ``name``, ``difference_um``, ``threshold_um``,
    ``warned``); empty when the model holds none. ``xyz``: the model's
    compensation of ``inputs`` when the caller has it (mm), not computed again;
    ``compare``: how a run's figures differ (:func:`alternative_difference_um`)."""
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
            diff = alternative_difference_um(model, alt, inputs, xyz, compare)
        except InputError as exc:  # the alternative needs an input these data lack: it cannot be compared
            out.append({"chosen": alt.chosen, "name": alt.name, "difference_um": None,
                        "threshold_um": alt.threshold_um, "warned": False, "why": str(exc)})
            continue
        out.append({"chosen": alt.chosen, "name": alt.name, "difference_um": diff, "threshold_um": alt.threshold_um,
                    "warned": bool(diff > alt.threshold_um)})
    what = "figures" if compare is not None else "points"
    for chosen in dict.fromkeys(f["chosen"] for f in out if f["warned"]):  # one message per choice
        differ = "; ".join(f"{f['name']} by up to {f['difference_um']:.2f} um (warns above {f['threshold_um']:.2f})"
                           for f in out if f["warned"] and f["chosen"] == chosen)
        msg = (f"{where}: the model's {chosen} was an aliased choice: effects the data it was found on could not "
               f"tell from it predict these {what} differently: {differ}; the compensation here rests on a choice "
               f"those data did not make (measure what separates them, or diagnose with this run)")
        log.warning(msg)
        warnings.warn(msg, AliasedChoiceWarning, stacklevel=3)
    return out
