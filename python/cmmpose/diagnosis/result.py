"""What :func:`cmmpose.diagnose` found: the history of the error falling as effects were added
(:class:`Step`) and the diagnosis as a whole (:class:`Diagnosis`): its decision on every candidate, the model it
saves, its JSON and its views (console tables, HTML report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._json import dumps as strict_json
from ..errormap import ErrorMapSet
from ..evaluation.observables import ModelFigures
from ..model.domain import Domain
from ..model.model import Model
from ..run import Run
from .identify import ALPHA, Candidate, value_text
from .wording import without_held_needs

__all__ = ["Diagnosis", "Step", "INSTEAD"]

#: What a step's label says between the effect it added and the one it replaced.
INSTEAD = " (instead of "


@dataclass
class Step:
    """One model of the history and how it does.

    Attributes
    ----------
    label : str
        'base' or '+ <effect>'.
    model : Model
        The model at this step (fitted).
    figures : ModelFigures
        Ballbar and sphere figures under it.
    ranking : list of Candidate
        The candidates evaluated against it, best first.
    forced : bool
        The effect was added on request, not because it was significant.
    """

    label: str
    model: Model
    figures: ModelFigures
    ranking: list[Candidate]
    forced: bool = False
    #: The model's residual observables (mm), for the cross-validation; not saved.
    residual: np.ndarray | None = field(default=None, repr=False)
    #: Cross-validated figures of this model (:class:`cmmpose.diagnosis.cv.CVScore` ``to_dict``):
    #: ``cv_rms_um`` ± ``cv_rms_u_um`` beside ``in_sample_rms_um``, and the split.
    cv: dict | None = None
    #: Of a joint diagnosis: every run's figures under this step's model, in the runs' order
    #: (``figures`` is the first run's); None for one run.
    run_figures: list | None = None
    #: The candidates judged beside the one this step's ranking led to
    #: (:class:`cmmpose.diagnosis.ambiguity.AmbiguitySet`), None when none explained the data as well.
    ambiguity: object = None
    #: Ambiguity sets met after ``ambiguity`` was left open, looking past it to what else the data show.
    further_ambiguity: list = field(default_factory=list)

    @property
    def effect(self) -> str:
        """The effect this step added ('' for the base): the label reads
        '+ <effect>' or '+ <effect> (instead of <replaced>)'."""
        return "" if self.label == "base" else self.label[2:].split(INSTEAD)[0]

    @property
    def replaces(self) -> str:
        """The effect this step's took the place of ('' when none): the same
        physics following another sensor, which the data prefer."""
        return self.label.partition(INSTEAD)[2].rstrip(")")

    def to_dict(self, run_has: dict | None = None) -> dict:
        """The step as plain data; ``run_has`` (what the run holds, :func:`run_holds`): the candidates' reasons
        never ask for it."""
        ranking = []
        for c in self.ranking:
            r = c.to_dict()
            if "reason" in r:
                r["reason"] = without_held_needs(r["reason"], c.spec.reveal, run_has)
            ranking.append(r)
        runs = {} if self.run_figures is None else {"runs": [f.to_dict() for f in self.run_figures]}
        return {"label": self.label, "forced": self.forced, "replaces": self.replaces or None,
                **self.figures.to_dict(), **runs, "cross_validation": self.cv,
                "ambiguity": None if self.ambiguity is None else self.ambiguity.to_dict(),
                **({"further_ambiguity": [a.to_dict() for a in self.further_ambiguity]}
                   if self.further_ambiguity else {}),
                "effects": [{"name": s.name, "params": dict(zip(s.params, map(float, v))),
                             "units": dict(zip(s.params, s.units))} for s, v in self.model.effects],
                "ranking": ranking}


@dataclass
class Diagnosis:
    """What :func:`diagnose` found.

    Attributes
    ----------
    steps : list of Step
        Base model, then one step per effect added.
    unobservable : dict of str -> str
        Candidates the run cannot show at a typical magnitude (or lacks the
        inputs for), with the measurement that would reveal each.
    ambiguous : list of tuple of str
        Groups of effects the run cannot tell apart (with what separates them).
    patterns : object or None
        Residual patterns of the final model (``find_patterns``), if computed.
    unexplained : list of Finding
        Structure the final model's residuals still hold (periodic errors
        along an axis, significant patterns), each naming the input it
        follows, its size and significance (:mod:`cmmpose.diagnosis.unexplained`);
        empty when there is none (or patterns were not computed).
    base_patterns : object or None
        Residual patterns of the base model.
    elapsed : float
        Wall time, s.
    """

    steps: list[Step]
    unobservable: dict[str, str]
    ambiguous: list[tuple[str, ...]]
    patterns: object = None
    base_patterns: object = None
    elapsed: float = 0.0
    n_points: int = 0
    advice: dict[str, str] = field(default_factory=dict)
    final_uncertainty: dict = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    #: The covariance of the final model's determined parameters
    #: (:func:`cmmpose.diagnosis.covariance.model_covariance`).
    final_covariance: dict = field(default_factory=dict)
    #: Where the final model was fitted (:class:`cmmpose.model.domain.Domain`), saved with it.
    domain: Domain | None = None
    #: The final model's values with what the data did not determine taken out
    #: (:func:`cmmpose.diagnosis.covariance.determined_values`): what the saved model applies.
    final_values: dict = field(default_factory=dict)
    unexplained: list = field(default_factory=list)
    #: How the run's temperatures were read (cmmpose.temperature.log_provenance), None if given.
    thermal: dict | None = None
    #: When the starting model holds effects (``diagnose RUN --model m.json``):
    #: whether it holds on this run, which it may never have seen, against
    #: the plain maps (:func:`cmmpose.diagnosis.cv.verify`).
    verification: dict | None = None
    #: The noise floor of the headline figure and whether the final model
    #: reaches it (:func:`cmmpose.diagnosis.floor.noise_floor`).
    noise: dict | None = None
    #: Errors varying with two axes at once that the final model leaves
    #: (:func:`cmmpose.diagnosis.floor.two_axis_findings`): unexplained.
    two_axis: list = field(default_factory=list)
    #: What the run determines of each map component and squareness, against
    #: the final model (:func:`cmmpose.diagnosis.mapfamily.component_report`):
    #: component -> status ('determined', 'aliased', 'invisible'), shapes
    #: determined, the components and named effects it is aliased with.
    #: Empty when the map corrections were not offered.
    components: dict = field(default_factory=dict)
    #: Effects the data could not tell from one in the final model, fitted in
    #: its place (:mod:`cmmpose.diagnosis.aliases`): saved with the model.
    alternatives: tuple = ()
    #: Which revealing measurements the run holds (:func:`cmmpose.diagnosis.diagnose.run_holds`): advice never
    #: asks for them.
    run_has: dict = field(default_factory=dict)
    #: The placement that best tells the first open ambiguity set's members apart
    #: (:func:`cmmpose.diagnosis.plan.separating_measurement`), None when there is none.
    separating: dict | None = None

    def decisions(self) -> list[dict]:
        """The decision on every candidate, with its reason, in one list:
        'added' (or 'added on request') with the final model's values and
        their uncertainties; then each remaining candidate's decision against
        the final model ('significant', 'significant, aliased', 'aliased',
        'not significant', 'not observable'; see ``Candidate.decision``);
        then those the run lacks the inputs for ('not observable').

        Returns
        -------
        list of dict
            ``name``, ``decision``, ``reason``, ``values`` and ``uncertainty``
            (parameter -> value in ``units``), ``units``, ``p_value``.
        """
        out = []
        final = self.steps[-1].model
        for s in self.steps[1:]:
            name = s.effect
            if name not in final.names:
                by = next(t for t in self.steps if t.replaces == name)
                alt = next((c for c in self.steps[self.steps.index(by) - 1].ranking if c.name == by.effect), None)
                why = f"replaced by {by.effect}" + (f": {alt.reason()}" if alt is not None else "")
                # Its values and units are those of the final ranking, where it is an alternative (below).
                out.append({"name": name, "decision": "replaced", "reason": why, "values": {}, "uncertainty": {},
                            "units": {}, "p_value": None})
                continue
            spec = next(sp for sp, _ in final.effects if sp.name == name)
            vals = final.values(name)
            unc = np.asarray(self.final_uncertainty.get(name, np.full(spec.size, np.inf)), dtype=float)
            when = next((c for c in self.steps[self.steps.index(s) - 1].ranking if c.name == name), None)
            why = ", ".join(value_text(p, v, u, unit) for p, v, u, unit in zip(spec.params, vals, unc, spec.units))
            if s.replaces and when is not None:
                why += f" (final model); in place of {s.replaces}: {when.reason().split('; ')[0]}"
            elif when is not None and not s.forced:
                why += f" (final model); p = {when.p_value:.2g} when added, against the threshold {when.threshold:.2g}"
            elif s.forced:
                why += " (final model); added on request, whether significant or not"
            if when is not None and when.indistinguishable_from:
                # One of a group the run cannot tell apart stands for the group.
                why += without_held_needs(f"; the run cannot tell it from {', '.join(when.indistinguishable_from)} "
                                          f"(needs: {when.spec.reveal})", when.spec.reveal, self.run_has)
            out.append({"name": name, "decision": "added on request" if s.forced else "added", "reason": why,
                        "values": dict(zip(spec.params, map(float, vals))),
                        "uncertainty": dict(zip(spec.params, map(float, unc))),
                        "units": dict(zip(spec.params, spec.units)),
                        "p_value": None if when is None or s.replaces else float(when.p_value)})
        replaced = {x["name"]: x for x in out if x["decision"] == "replaced"}
        for c in self.steps[-1].ranking:
            if c.name in replaced:  # one entry per candidate: the history, then how it stands now
                replaced[c.name]["reason"] += f"; against the final model: {c.reason()}"
                replaced[c.name].update(values=dict(zip(c.spec.params, map(float, c.values))),
                                        uncertainty=dict(zip(c.spec.params, map(float, c.uncertainty))),
                                        units=dict(zip(c.spec.params, c.spec.units)))
                continue
            out.append({"name": c.name, "decision": c.decision,
                        "reason": without_held_needs(c.reason(), c.spec.reveal, self.run_has),
                        "values": dict(zip(c.spec.params, map(float, c.values))),
                        "uncertainty": dict(zip(c.spec.params, map(float, c.uncertainty))),
                        "units": dict(zip(c.spec.params, c.spec.units)), "p_value": float(c.p_value)})
        for name, why in self.skipped.items():
            out.append({"name": name, "decision": "not observable", "reason": why, "values": {}, "uncertainty": {},
                        "units": {}, "p_value": None})
        return out

    @property
    def model(self) -> Model:
        """The final model as it is saved: its parameters' uncertainties and
        covariance, how the run's temperatures were read, its aliased
        alternatives and the domain it was fitted on. A combination of its
        parameters the data did not determine is taken out
        (:func:`cmmpose.diagnosis.covariance.determined_values`): it is never
        applied."""
        final = self.steps[-1].model
        unc = {k: np.array(v, float) for k, v in self.final_uncertainty.items()}
        effects = tuple((s, np.asarray(self.final_values.get(s.name, v), float)) for s, v in final.effects)
        return replace(final, effects=effects, uncertainty=unc or final.uncertainty, thermal=self.thermal or final.thermal,
                       alternatives=tuple(self.alternatives) or final.alternatives, domain=self.domain or final.domain,
                       covariance=self.final_covariance or final.covariance)

    @property
    def ambiguity(self) -> list:
        """The ambiguity sets met on the way (:class:`cmmpose.diagnosis.ambiguity.AmbiguitySet`): those
        still open (``not s.resolved``) are why the diagnosis added none of their members."""
        return [a for s in self.steps for a in ([s.ambiguity] if s.ambiguity is not None else [])
                + list(s.further_ambiguity)]

    @property
    def open_ambiguity(self) -> list:
        """The ambiguity sets none of whose members was added: the user chooses, or measures (cmmpose plan)."""
        return [a for a in self.ambiguity if not a.resolved]

    @property
    def added(self) -> list[str]:
        return [s.effect for s in self.steps[1:] if s.effect in self.model.names]

    @property
    def proposals(self) -> list[Candidate]:
        """Significant candidates against the final model (empty when the
        diagnosis stopped because nothing more is significant)."""
        return [c for c in self.steps[-1].ranking if c.significant]

    @property
    def claims(self) -> dict[str, bool]:
        """Which kinds of claim the diagnosis makes about the machine, each True when made: on a machine
        with no error beyond its maps every one is false (benches/diagnosis_false_alarms.py and the null
        machines of benches/unseen_placements.py count them so).

        ``effect`` a library or user effect added; ``map`` a map correction added (``map:...``);
        ``ambiguous`` an open ambiguity set or a group the run cannot tell apart (the data need one of
        them); ``pattern`` a significant residual pattern of the final model; ``unexplained`` an
        unexplained finding; ``floor`` "N um is unexplained above a floor" against a stated or measured
        floor (against the spheres' fit scatter alone, a lower bound, the verdict says first that there
        is no floor and claims nothing); ``two_axis`` an error of two axes at once."""
        added = self.added
        noise = self.noise or {}
        return {"effect": any(not n.startswith("map:") for n in added),
                "map": any(n.startswith("map:") for n in added),
                "ambiguous": bool(self.open_ambiguity or self.ambiguous),
                "pattern": self.patterns is not None and bool(self.patterns.significant),
                "unexplained": bool(self.unexplained),
                "floor": noise.get("noise") is False and bool(noise.get("floor_stated_or_measured")),
                "two_axis": bool(self.two_axis)}

    def history(self) -> list[dict]:
        """One dict per step: label and figures in um (for plots and tables)."""
        return [{"label": s.label, **s.figures.to_dict()} for s in self.steps]

    def to_dict(self) -> dict:
        def finite(x):
            return x if x is None or math.isfinite(x) else None

        decisions = [{**d, "uncertainty": {k: finite(v) for k, v in d["uncertainty"].items()}}
                     for d in self.decisions()]
        threshold = self.steps[-1].ranking[0].threshold if self.steps[-1].ranking else ALPHA
        return {"steps": [s.to_dict(self.run_has) for s in self.steps], "decisions": decisions,
                "significance": {"family_wise_alpha": ALPHA, "per_candidate_threshold": threshold},
                "unexplained": [f.to_dict() for f in self.unexplained],
                "unobservable": self.unobservable, "verification": self.verification,
                "noise_floor": self.noise, "two_axis": self.two_axis,
                "alternatives": [a.to_dict() for a in self.alternatives], "components": self.components,
                "cross_validation": self.steps[-1].cv,
                "ambiguous": [list(a) for a in self.ambiguous], "advice": self.advice,
                "ambiguity_sets": [a.to_dict() for a in self.ambiguity], "separating": self.separating,
                "elapsed_s": self.elapsed, "n_points": self.n_points,
                "patterns": None if self.patterns is None else self.patterns.to_dict(),
                "provenance": self.provenance()}

    def provenance(self) -> dict:
        """What produced the diagnosis: version, date, the base model's maps,
        temperature choice and temperature policy (cmmpose.policy)."""
        from datetime import datetime, timezone

        from .. import __version__

        m = self.steps[0].model
        maps = ({"kind": "set", "temperatures_C": [float(t) for t in m.maps.temperatures]}
                if isinstance(m.maps, ErrorMapSet) else {"kind": "map", "temperature_C": m.maps.temperature})
        return {"cmmpose_version": __version__,
                "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "maps": maps,
                "temperature": "given: %g C" % m.temperature if m.temperature is not None else
                "run thermocouple log: machine mean of the axis-scale channels (thesis 6.4)",
                "policy": {"out_of_range": m.out_of_range, "temperature_tolerance_K": m.temperature_tolerance,
                           "log_hold_s": m.log_hold},
                "temperature_policy": m.policy.to_dict(),
                "temperature_log": self.thermal,
                "base_effects": list(m.names)}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), default=_json_default, **kw)

    def table(self, step: int = 0, width: int = 150):
        """A rich table of the candidates ranked at ``step`` (:func:`cmmpose.diagnosis.console.candidate_table`;
        below 140 columns of ``width`` its narrow layout)."""
        from .console import candidate_table

        return candidate_table(self, step, width)

    def history_table(self, compact: bool = False, width: int = 150):
        """A rich table of the error as effects were added (:func:`cmmpose.diagnosis.console.history_table`)."""
        from .console import history_table

        return history_table(self, compact, width)

    def view(self, verbose: bool = False):
        """The console's view (:class:`cmmpose.diagnosis.console.DiagnosisView`): the verdict, the final
        model's values and the error's history; ``verbose`` adds the candidate tables and every finding."""
        from .console import DiagnosisView

        return DiagnosisView(self, verbose)

    def __rich_console__(self, console, options):
        yield self.view()

    def __str__(self) -> str:
        """The verbose view as text, as wide as its wide layout (:data:`cmmpose.diagnosis.console.WIDE`)."""
        from .console import as_text

        return as_text(self, verbose=True)

    def write_report(self, path, run: Run | None = None, *, run_dir=None, model_file=None,
                     title: str = "cmmpose diagnosis") -> Path:
        """A self-contained HTML report (plots embedded) at ``path``: the
        verdict, the decision on every candidate, the error falling, the
        residual patterns and the provenance (``run_dir``, ``model_file``); a
        simulated run's truth (beside ``run_dir``) against what was found."""
        try:
            import matplotlib  # noqa: F401 - an optional extra
        except ImportError:
            raise ImportError("the HTML report needs matplotlib: pip install 'cmmpose[plot]'") from None
        from .html_report import write_report

        return write_report(self, path, run=run, run_dir=run_dir, model_file=model_file, title=title)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
