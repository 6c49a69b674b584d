"""``cmmpose.diagnose``: rank the candidate effects, add them one at a time
(forced ones first, then each significant leader), refit, and keep the
history of the error falling; say which effects the run cannot show and what
measurement would."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._json import dumps as strict_json
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..fitting import fit_spheres
from ..run import Run
from .covariance import determined_values, model_covariance
from .identify import ALPHA, Candidate, Problem, value_text, check_effect_names, fit_model, rank_candidates
from ..model.spec import EffectSpec, effect_spec, run_library
from ..model.point_inputs import single_map_warning
from ..model.domain import Domain
from ..model.model import Model, as_model, check_kinematics, run_kinematics
from ..evaluation.observables import ModelFigures, figures
from .unexplained import periodic_errors, unexplained_findings
from .wording import without_held_needs

__all__ = ["diagnose", "Diagnosis", "Step", "POLISH_POINTS_PER_SCAN"]

#: What a step's label says between the effect it added and the one it replaced.
_INSTEAD = " (instead of "

#: Point residuals per scan the final model's effects are refitted on.
POLISH_POINTS_PER_SCAN = 3000


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

    @property
    def effect(self) -> str:
        """The effect this step added ('' for the base): the label reads
        '+ <effect>' or '+ <effect> (instead of <replaced>)'."""
        return "" if self.label == "base" else self.label[2:].split(_INSTEAD)[0]

    @property
    def replaces(self) -> str:
        """The effect this step's took the place of ('' when none): the same
        physics following another sensor, which the data prefer."""
        return self.label.partition(_INSTEAD)[2].rstrip(")")

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
    #: The covariance of the final model's determined parameters (:func:`cmmpose.diagnosis.covariance.model_covariance`).
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
    #: Which revealing measurements the run holds (:func:`run_holds`): advice never asks for them.
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
        return [s.ambiguity for s in self.steps if s.ambiguity is not None]

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


def diagnose(
    run: Run,
    maps: Model | ErrorMap | ErrorMapSet | None = None,
    *,
    add=(),
    auto: bool = True,
    max_effects: int = 4,
    candidates=None,
    user_effects=(),
    patterns: bool = True,
    polish: bool = True,
    out_of_range: str | None = None,
    temperature_tolerance: float | None = None,
    log_hold: float | None = None,
    map_corrections: bool = True,
    reproducibility_um: float | None = None,
    temperature_policy=None,
    reproducibility_source: str = "stated",
    default_reproducibility_um: float | None = None,
    machine=None,
) -> Diagnosis:
    """Find which physical effects the model misses on ``run``, add them, and
    keep the history of the error falling.

    Parameters
    ----------
    run : Run
        A measurement run with sphere scans (ballbar balls, reference sphere).
    maps : Model, ErrorMap or ErrorMapSet, optional
        What compensates at the start (``maps`` as everywhere in the API,
        docs/conventions.md "Names"): a saved Model, or maps alone, which
        make the thesis model. Default: the run's bundled maps
        (``run.maps``, on the configuration it names) or the thesis set.
        Maps stacked for another machine configuration than run.json names
        are refused (an InputError naming both).
    add : sequence of str or EffectSpec
        Effects to add first, in order, whether significant or not.
    auto : bool
        Then keep adding the most significant candidate while one is left.
    max_effects : int
        Most effects added automatically.
    candidates : sequence of str or EffectSpec, optional
        Restrict (or extend, with user effects) the candidate library.
    user_effects : sequence of UserEffect
        Added to the candidates (the library's or ``candidates``): each is
        added to the model when significant, like a library effect.
    patterns : bool
        Also compute the residual patterns of the base and final models.
    polish : bool
        Refit the final model's effects that shape the points within a scan
        (scanner and user effects) on POLISH_POINTS_PER_SCAN points of each
        scan (the selection uses POINTS_PER_SCAN): the residual patterns and
        findings look at every point, and those values and their
        uncertainties then come from as many.
    out_of_range : {'raise', 'clamp', 'extrapolate'}, optional
        Temperatures beyond the tolerance outside the maps (cmmpose.policy);
        default the model's ('raise' for a new one).
    temperature_tolerance : float, optional
        K: temperatures this close outside the maps are held at the edge;
        default the model's (0.5 K for a new one).
    log_hold : float, optional
        s: points this far outside the thermocouple log take its nearest
        reading; default the model's (120 s for a new one).
    map_corrections : bool
        Also offer corrections of the map's 18 per-axis components (the
        translational ones and each axis's three angles) by smooth
        functions of their axis's position (polynomials, local splines,
        sinusoids over the whole period range;
        :mod:`cmmpose.diagnosis.mapfamily`), judged after the library's
        named effects (not when ``candidates`` restricts the list), and
        report which components the run determines, which are aliased
        with which, and which it cannot see (``Diagnosis.components``).
    reproducibility_um : float, optional
        um per axis: the per-scan centre reproducibility, for the noise
        floor of a run that repeats no scan (one that does measures it;
        :mod:`cmmpose.diagnosis.floor`). Without either, the floor is the
        spheres' fit scatter (a lower bound; the verdict says first that
        there is no floor), in the selection as in the noise test.
    temperature_policy : TemperaturePolicy, optional
        The whole temperature policy (cmmpose.temperature: also gaps, broken
        channels, which sensor each role reads); the three keywords above
        override its fields. None: the model's (``TemperaturePolicy()`` for
        one made from maps), the same default as every other function.
    reproducibility_source : str
        Where a stated ``reproducibility_um`` comes from, in the noise
        floor's words (``cmmpose diagnose --machine FILE``: the file).
    default_reproducibility_um : float, optional
        um per axis: the machine's stated per-scan reproducibility
        (:attr:`cmmpose.machine.Machine.reproducibility_um`), the floor when
        ``reproducibility_um`` is not given and the run repeats no scan (a
        run that does measures its own). Checked as ``reproducibility_um``.
    machine : cmmpose.machine.Machine, optional
        Where the "next" advice for an open ambiguity set looks for the
        placement that tells its members apart (its travel and poses;
        default the thesis machine): ``Diagnosis.separating``.

    Returns
    -------
    Diagnosis
    """
    import time

    t0 = time.perf_counter()
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    model = as_model(maps, run_kinematics(run))
    check_kinematics(model, run)  # a model for another machine configuration: refused, naming both
    policy = {k: v for k, v in (("out_of_range", out_of_range), ("temperature_tolerance", temperature_tolerance),
                                ("log_hold", log_hold)) if v is not None}
    if temperature_policy is not None:  # the whole policy, then the keywords given
        model = replace(model, temperature_policy=temperature_policy, out_of_range=temperature_policy.out_of_range,
                        temperature_tolerance=temperature_policy.temperature_tolerance,
                        log_hold=temperature_policy.log_hold)
    if policy:
        model = replace(model, **policy)
    cand = None
    if candidates is not None:
        cand = {}
        known = run_library(model.inputs(run))
        for c in candidates:
            # A name of an effect that follows a sensor stands for all its variants.
            variants = [k for k in known if isinstance(c, str) and k.startswith(f"{c}@") and known[k].sensor]
            for spec in [known[k] for k in variants] or [effect_spec(c, known if isinstance(c, str) else None)]:
                cand[spec.name] = spec
    problem = Problem(model, run, cand,
                      extra=user_specs([a for a in add if not isinstance(a, str)] + list(user_effects)))
    if reproducibility_um is None and default_reproducibility_um is not None:
        reproducibility_um = default_floor(problem, default_reproducibility_um)
    state_floor(problem, reproducibility_um)
    single_map_warning(model, problem.inputs.temperature)  # as evaluating with the map alone warns
    if map_corrections and candidates is None:  # a restricted list of candidates is the whole list
        add_map_candidates(problem, model)
    add_names = [a if isinstance(a, str) else a.name for a in add]
    check_effect_names(add_names, problem)
    steps, model = select_effects(problem, model, add_names, auto, max_effects,
                                  lambda label, m, forced: _step(label, m, problem, forced))
    uncertainty_problem = problem
    # Only the effects that shape the points within a scan (on the scanner,
    # or user-defined) gain from more point residuals; the others are fixed
    # by lengths and centres, which do not grow with the points.
    # A model given to start from is applied as saved: what it holds is never refitted here.
    given = set(steps[0].model.names)
    shaping = {spec.name for spec, _ in model.effects
               if (spec.kind == "python" or getattr(spec.effect, "on_scanner", False)) and spec.name not in given}
    if polish and shaping:
        # The selection fits the effects to POINTS_PER_SCAN points of each scan;
        # the residual patterns and the findings look at every point. Refit the
        # final model's effects on many more points so that its own parameters'
        # imprecision does not show up as structure (a depth scale off by its
        # uncertainty leaves a v pattern that 400 points cannot see but all can).
        fine = Problem(model, run, {s.name: s for s, _ in model.effects}, points_per_scan=POLISH_POINTS_PER_SCAN)
        model = fit_model(model, run, iterations=2, problem=fine, only=shaping)
        last = steps[-1]
        steps[-1] = _step(last.label, model, problem, forced=last.forced)
        from .cv import cv_groups, step_cv

        folds, items, split = cv_groups(problem)
        step_cv(problem, steps[-1], (folds, items), split)
        uncertainty_problem = fine
    unobservable, advice, ambiguous = unobservable_candidates(problem, steps)
    final_unc, final_cov = model_covariance(uncertainty_problem, model)
    diag = Diagnosis(steps, unobservable, ambiguous, n_points=run.n_points, advice=advice,
                     final_uncertainty=final_unc, final_covariance=final_cov,
                     final_values=determined_values(uncertainty_problem, model),
                     domain=Domain.of_runs([run], [problem.inputs], model.maps.kinematics),
                     skipped=dict(problem.skipped), thermal=problem.inputs.thermal, run_has=run_holds(problem))
    from .aliases import find_alternatives

    diag.alternatives = find_alternatives(problem, steps, model)
    attach_floor(diag, problem, steps[-1], reproducibility_um, reproducibility_source)
    if map_corrections and candidates is None:
        from .mapfamily import component_report

        diag.components = component_report(problem, model)
    if steps[0].model.effects:  # a found model on a run: does it hold here?
        from .cv import verify

        diag.verification = verify(steps[0].model, run)
    if patterns:
        try:
            from .patterns import find_patterns
        except ImportError:  # pragma: no cover
            find_patterns = None
        if find_patterns is not None:
            nominal = run.artefact.get("calibrated_radius_mm")
            for which, m in (("base_patterns", steps[0].model), ("patterns", steps[-1].model)):
                xyz = m.compensate(problem.inputs)
                sid = problem.inputs.scan_id
                keep = np.isin(sid, problem.layout.labels)
                fits = fit_spheres(xyz[keep], sid[keep])
                sub = run if keep.all() else _subset(run, keep)
                setattr(diag, which, find_patterns(sub, xyz[keep], fits, temperature=problem.inputs.temperature[keep],
                                                   nominal_radius=nominal))
                if which == "patterns":  # the final model's: what it leaves unexplained
                    diag.unexplained = unexplained_findings(diag.patterns, periodic_errors(sub, xyz[keep], fits),
                                                            m.names)
    if diag.open_ambiguity:
        from .plan import separating_measurement

        separating_measurement(diag, [run], machine)
    diag.elapsed = time.perf_counter() - t0
    return diag


def _two_axis_first(problem, step, candidate) -> bool:
    """Whether an error varying with two axes at once explains the structure
    better than the map correction ``candidate`` (a smaller p-value): then the
    candidate is refused, with the reason on it (``candidate.cv``)."""
    from .floor import explained_beyond, two_axis_findings

    found = getattr(step, "_two_axis", None)
    if found is None:
        found = step._two_axis = two_axis_findings(problem, step)
    if not found:
        return False
    f = found[0]
    beyond = min(1.0, explained_beyond(problem, step, f, problem.columns[candidate.name])
                 * getattr(candidate.spec, "trials", 1))
    if beyond < candidate.threshold:  # it explains more than the two-axis error does
        return False
    candidate.cv = {"passes": False, "why": (f"is refused: {f['description']}, explains the structure "
                                             f"(p = {f['p_value']:.2g}); beyond it this correction has p = "
                                             f"{beyond:.2g}")}
    return True


def default_floor(problem, default_reproducibility_um: float):
    """The stated reproducibility of ``problem`` when only a default (the
    machine's) is given: the default for a run that repeats no scan, None for
    one that does (it measures its own, Type A); one per run of a joint
    problem, a single value (or None) for one run."""
    from .._validate import check_reproducibility
    from .floor import repeats_scans

    um = check_reproducibility("default_reproducibility_um", default_reproducibility_um)
    values = [None if r else um for r in repeats_scans(problem)]
    return values if getattr(problem, "parts", None) else values[0]


def state_floor(problem, reproducibility_um=None) -> None:
    """The headline's noise level never below the floor each run of
    ``problem`` (a Problem, or a JointProblem's parts) has: a stated
    ``reproducibility_um`` (one, or one per run); for a run that repeats no
    scan and states none, its spheres' fit scatter
    (:func:`cmmpose.diagnosis.floor.fit_scatter_um`), so that the selection
    adds only what that conservative floor supports. A run that repeats
    scans estimates its own noise level."""
    from .floor import fit_scatter_um, per_run, repeats_scans

    parts = getattr(problem, "parts", None) or [problem]
    stated = per_run(reproducibility_um, len(parts))
    repeated = repeats_scans(problem)
    scatter = None
    for i, p in enumerate(parts):  # one per run
        if stated[i] is not None:
            p.state_reproducibility(stated[i])
        elif not repeated[i]:
            scatter = fit_scatter_um(problem) if scatter is None else scatter
            if scatter[i] > 0:
                p.state_reproducibility(float(scatter[i]))
    if len(parts) > 1 or parts[0] is not problem:
        problem.class_floor = np.concatenate([p.class_floor for p in parts])


def attach_floor(diag, problem, step, reproducibility_um=None, reproducibility_source: str = "stated") -> None:
    """Set ``diag.noise`` and ``diag.two_axis`` from ``step``'s model; then
    let the steps drop their working arrays (residuals, the cross-validation's
    designs), which a diagnosis sent between processes need not carry."""
    from .floor import noise_floor, two_axis_findings

    diag.noise = noise_floor(problem, step, reproducibility_um, reproducibility_source)
    diag.two_axis = [{k: v for k, v in f.items() if not k.startswith("_")} for f in two_axis_findings(problem, step)]
    for s in diag.steps:
        s.residual = None
        for k in ("_cv_state", "_cv_by_run", "_two_axis"):
            s.__dict__.pop(k, None)


def add_map_candidates(problem, model) -> None:
    """Offer ``problem`` the map corrections (:func:`mapfamily.map_candidates`)
    and the cross-axis corrections (:func:`mapfamily.cross_candidates`) with
    their centre-level sensitivities."""
    from .mapfamily import cross_candidates, map_candidates

    for name, spec in {**map_candidates(problem, model), **cross_candidates(problem)}.items():
        if name in problem.candidates:
            continue
        problem.candidates[name] = spec
        problem.columns[name] = problem._columns(problem.base, spec, np.zeros(spec.size), problem.base_obs)


def _subset(run: Run, keep: np.ndarray) -> Run:
    pts = {k: v[keep] for k, v in run.points.items()}
    return Run(pts, dict(run.scans), dict(run.poses), run.temperatures, run.temperature_channels, run.artefact,
               run.maps, run.metadata, run.created)


def user_specs(user_effects) -> tuple[EffectSpec, ...]:
    """``user_effects`` checked: extra candidates for a :class:`Problem`."""
    named: dict[str, EffectSpec] = {}
    for u in user_effects:
        if not isinstance(u, EffectSpec):
            raise InputTypeError(f"user_effects: expected UserEffect objects, got {type(u).__name__}")
        if u.name in named and named[u.name] is not u:
            # Which of two effects of one name is fitted would depend on their order.
            raise InputError(f"user_effects: two effects are named {u.name!r}: give each effect once, under its "
                             "own name", what=u.name)
        named[u.name] = u
    return tuple(named.values())


def select_effects(problem, model: Model, add_names, auto: bool, max_effects: int, step):
    """Forward selection: the effects ``add_names`` first (fitted whether
    significant or not), then the most significant candidate while one is
    left, refitting after each; ``step(label, model, forced)`` makes each
    step of the history. Returns the steps and the final model."""
    from .cv import INTERPOLATION_ONLY, cv_groups, judge_candidate
    from .cv import step_cv as _step_cv

    across = None  # the folds that judge an ambiguity set (cv_groups(across=True)), made when first needed

    # Cross-validation needs the problem's observables (a scripted problem has none: selection by significance).
    cross_validate = hasattr(problem, "classes")
    folds, items, split = cv_groups(problem) if cross_validate else (None, None, "")
    groups = (folds, items)

    def step_cv(problem, step, groups, split):
        if cross_validate:
            _step_cv(problem, step, groups, split)

    steps = [step("base", model, False)]
    step_cv(problem, steps[-1], groups, split)
    for name in add_names:
        spec = problem.candidates[name]
        model = fit_model(model.with_values(spec, np.zeros(spec.size)), None, problem=problem)
        steps.append(step(f"+ {name}", model, True))
        step_cv(problem, steps[-1], groups, split)
    added = 0
    swapped: set[str] = set()
    while auto:
        # An alternative the data now prefer (the same physics following
        # another sensor) takes its sibling's place, once per effect; one
        # added on request stays (its alternative is labelled 'preferred').
        forced = {s.effect for s in steps if s.forced}
        better = [c for c in steps[-1].ranking if c.decision == "preferred" and c.name not in swapped
                  and c.alternative_to not in forced]
        if better:
            c = max(better, key=lambda c: c.lr)
            swapped.add(c.alternative_to)
            model = fit_model(model.without(c.alternative_to).with_values(c.spec, c.values), None, problem=problem)
            steps.append(step(f"+ {c.name}{_INSTEAD}{c.alternative_to})", model, False))
            step_cv(problem, steps[-1], groups, split)
            continue
        if added >= max_effects:
            break
        # The most significant candidate that also predicts held-out data
        # better (cmmpose.diagnosis.cv): a step that raises the
        # cross-validated error is never added.
        best = None
        for c in steps[-1].ranking:
            if not c.significant or c.alternative_to:
                break
            if cross_validate and getattr(c.spec, "family", None) == "map" and _two_axis_first(problem, steps[-1], c):
                continue  # an error of two axes at once: reported unexplained, not forced into one axis
            if not cross_validate or judge_candidate(problem, steps[-1], c, groups, split):
                best = c
                break
        if best is None:
            break
        if cross_validate:
            # Competing explanations side by side (cmmpose.diagnosis.ambiguity): when others predict held-out
            # data as well and their corrections differ over the travel, none is added.
            from .ambiguity import find_ambiguity

            if across is None:
                across = cv_groups(problem, across=True)
            amb = find_ambiguity(problem, steps[-1], best, (across[0], across[1]), across[2],
                                 INTERPOLATION_ONLY in across[2])
            if amb is not None:
                steps[-1].ambiguity = amb
                if not amb.agree:
                    break
                amb.chosen = best.name
        model = fit_model(model.with_values(best.spec, best.values), None, problem=problem)
        steps.append(step(f"+ {best.name}", model, False))
        step_cv(problem, steps[-1], groups, split)
        added += 1
    return steps, model


def _step(label: str, model: Model, problem: Problem, forced: bool = False, obs=None) -> Step:
    if obs is None:
        obs = problem.base_obs if model is problem.base else problem.observe(model)
    figs = figures(problem.layout, None, model, observed=obs)
    return Step(label, model, figs, rank_candidates(problem, model, obs), forced, residual=obs.residual)


def unobservable_candidates(problem: Problem, steps: list[Step]):
    """Candidates the run cannot show (from the base ranking), and groups
    that it cannot tell apart, each with the measurement that would help."""
    out = dict(problem.skipped)
    advice = {}
    for c in steps[0].ranking:
        advice[c.name] = c.spec.reveal
        if c.name in [s.effect for s in steps[1:]] or getattr(c.spec, "family", None) in ("map", "cross"):
            continue  # map corrections: cmmpose.diagnosis.mapfamily.component_report says what the run determines
        # "Not observable" only where the design cannot determine the effect;
        # a determined but weak one is "not significant" (Candidate.reason says how weak).
        if not c.observable:
            out[c.name] = _agrees_with_run(c.reason().replace("; needs: ", "; "), c.spec.reveal, problem)
    ambiguous = []
    for s in steps:
        for c in s.ranking[:1]:
            if c.indistinguishable_from:
                group = tuple([c.name, *c.indistinguishable_from])
                if group not in ambiguous:
                    ambiguous.append(group)
                    has = run_holds(problem) if hasattr(problem, "layout") else {}
                    advice[group[0]] = "; ".join(
                        f"{n}: {without_held_needs(problem.candidates[n].reveal, problem.candidates[n].reveal, has)}"
                        for n in group)
    return out, advice, ambiguous


def run_holds(problem) -> dict[str, bool]:
    """Which revealing measurements the run (every run of a joint problem) already holds."""
    parts = getattr(problem, "parts", None) or [problem]
    has = {"calibrated bar length": all(getattr(p.layout, "calibrated_length", None) is not None for p in parts),
           "calibrated sphere radius": all(getattr(p.layout, "calibrated_radius", None) is not None for p in parts)}
    try:
        has["both directions"] = all(len(np.unique(np.sign(p.run.scans["sweep_direction"]))) > 1 for p in parts)
        has["two or more poses"] = all(len(p.inputs.pose_ids) > 1 for p in parts)
    except (AttributeError, KeyError):
        pass
    return has


def _agrees_with_run(reason: str, reveal: str, problem) -> str:
    """``reason`` without advice to take a measurement the run already has:
    then the run has it, and it still does not pin the effect (a typical
    size stands too little above the noise, or other effects take it up)."""
    try:
        has = run_holds(problem)
    except AttributeError:  # a scripted problem
        return reason
    held = [k for k, v in has.items() if v and k in reveal]
    if not held:
        return reason
    head = reason.split("; ")[0]
    return (f"{head}; the run has {', '.join(held)}, and still does not pin it at a typical size "
            f"(larger or more varied positions, or a longer run, would)")
