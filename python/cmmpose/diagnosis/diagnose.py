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
from ..errors import InputError
from ..fitting import fit_spheres
from ..run import Run
from .identify import (ALPHA, Candidate, Problem, _value_text, check_effect_names, fit_model, model_uncertainties,
                       rank_candidates)
from .effects import EffectSpec, effect_spec, run_library
from .model import Model
from .observables import ModelFigures, figures
from .unexplained import periodic_errors, unexplained_findings

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

    def to_dict(self) -> dict:
        return {"label": self.label, "forced": self.forced, "replaces": self.replaces or None,
                **self.figures.to_dict(),
                "effects": [{"name": s.name, "params": dict(zip(s.params, map(float, v))),
                             "units": dict(zip(s.params, s.units))} for s, v in self.model.effects],
                "ranking": [c.to_dict() for c in self.ranking]}


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
    unexplained: list = field(default_factory=list)

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
            why = ", ".join(_value_text(p, v, u, unit) for p, v, u, unit in zip(spec.params, vals, unc, spec.units))
            if s.replaces and when is not None:
                why += f" (final model); in place of {s.replaces}: {when.reason().split('; ')[0]}"
            elif when is not None and not s.forced:
                why += f" (final model); p = {when.p_value:.2g} when added, against the threshold {when.threshold:.2g}"
            elif s.forced:
                why += " (final model); added on request, whether significant or not"
            if when is not None and when.indistinguishable_from:
                # One of a group the run cannot tell apart stands for the group.
                why += (f"; the run cannot tell it from {', '.join(when.indistinguishable_from)} "
                        f"(needs: {when.spec.reveal})")
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
            out.append({"name": c.name, "decision": c.decision, "reason": c.reason(),
                        "values": dict(zip(c.spec.params, map(float, c.values))),
                        "uncertainty": dict(zip(c.spec.params, map(float, c.uncertainty))),
                        "units": dict(zip(c.spec.params, c.spec.units)), "p_value": float(c.p_value)})
        for name, why in self.skipped.items():
            out.append({"name": name, "decision": "not observable", "reason": why, "values": {}, "uncertainty": {},
                        "units": {}, "p_value": None})
        return out

    @property
    def model(self) -> Model:
        """The final model."""
        return self.steps[-1].model

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
        return {"steps": [s.to_dict() for s in self.steps], "decisions": decisions,
                "significance": {"family_wise_alpha": ALPHA, "per_candidate_threshold": threshold},
                "unexplained": [f.to_dict() for f in self.unexplained],
                "unobservable": self.unobservable,
                "ambiguous": [list(a) for a in self.ambiguous], "advice": self.advice,
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
                "base_effects": list(m.names)}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), default=_json_default, **kw)

    def table(self, step: int = 0):
        """A rich table of the candidates ranked at ``step``."""
        from rich.table import Table

        s = self.steps[step]
        t = Table(title=f"Candidate effects against the model '{s.label}'")
        of = "of lengths" if s.figures.deviation_rms is None else "of deviations"  # an artefact run's balls
        for col in ("effect", "fitted value ± u", "explains", of, "LR (dof)", "p", "corr", "cond",
                    "decision"):
            # Whole names: 'squareness-temperature@granite_top' and '@granite_bottom' differ only at their ends.
            width = max((len(c.name) for c in s.ranking), default=0) if col == "effect" else None
            t.add_column(col, justify="left" if col in ("effect", "fitted value ± u", "decision") else "right",
                         min_width=width, max_width=26 if col == "fitted value ± u" else None)
        for c in s.ranking:
            vals = ", ".join(_value_text(p, v, u, unit) for p, v, u, unit in zip(c.spec.params, c.values, c.uncertainty,
                                                                              c.spec.units))
            decision = c.decision
            if c.significant and c is s.ranking[0]:
                decision = "[bold green]proposed[/]" + (", aliased" if c.aliases else "")
            elif decision == "not observable":
                decision = "[dim]not observable[/]"
            if c.aliases:
                decision += f" [yellow](same as {', '.join(c.aliases)})[/]"
            t.add_row(f"{c.name}\n[dim]{c.spec.physics}[/]", vals, f"{c.explained:.1%}", f"{c.explained_length:.1%}", f"{c.lr:.1f} ({c.dof})",
                      f"{c.p_value:.1e}", f"{c.correlation:.2f}", f"{c.condition:.0f}", decision)
        return t

    def history_table(self):
        from rich.table import Table

        t = Table(title="The error falling as effects are added")
        # An artefact run (ball plate, step gauge) has ball deviations where a ballbar run has lengths.
        plate = self.steps[0].figures.deviation_rms is not None
        first = (("rms deviation (um)", "rms_deviation_um"), ("largest deviation (um)", "largest_deviation_um")) \
            if plate else (("rms accuracy error (um)", "rms_accuracy_error_um"), ("B89 (um)", "b89_um"))
        for col in ("model", first[0][0], first[1][0], "sphere form (um)", "fit rms (um)", "centre spread (um)",
                    "effect values"):
            t.add_column(col, justify="left" if col in ("model", "effect values") else "right")
        for s in self.steps:
            f = s.figures.to_dict()
            eff = "; ".join(f"{sp.name}: {sp.describe(v)}" for sp, v in s.model.effects[-1:]) if s.model.effects \
                and s.label != "base" else ""
            t.add_row(s.label + (" (forced)" if s.forced else ""), *(_um_text(f[k]) for _, k in first),
                      f"{f['form_um']:.1f}", f"{f['fit_rms_um']:.2f}", _um_text(f["centre_spread_um"]), eff)
        return t

    def __rich_console__(self, console, options):
        yield self.history_table()
        yield self.table(0)
        if len(self.steps) > 1:
            yield self.table(len(self.steps) - 1)
        if self.ambiguous:
            for group in self.ambiguous:
                yield f"[yellow]cannot tell apart:[/] {', '.join(group)}: {self.advice.get(group[0], '')}"
        if self.unexplained:
            yield "[bold]Structure the final model does not explain[/] (diagnose --user-effect-skeleton FILE drafts an effect):"
            for f in self.unexplained:
                yield f"  {f.input}: {f.description} (p {f.p_value:.1e})"
        if self.unobservable:
            yield "[bold]Not observable in this run[/] (what would reveal each):"
            for name, why in self.unobservable.items():
                yield f"  {name}: {why}"
        if self.patterns is not None and hasattr(self.patterns, "__rich__"):
            yield self.patterns.__rich__()
        yield f"{self.n_points} points, {self.elapsed:.1f} s"

    def __str__(self) -> str:
        from rich.console import Console

        console = Console(width=140, record=True, file=open("/dev/null", "w"))  # noqa: SIM115 - text only
        console.print(self)
        return console.export_text()

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
        from .report import write_report

        return write_report(self, path, run=run, run_dir=run_dir, model_file=model_file, title=title)


def _um_text(x) -> str:
    """A figure in um for a table, '-' when there is none."""
    return "-" if x is None else f"{x:.2f}"


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def as_model(model) -> Model:
    """The starting model of a diagnosis: a Model as given, maps as the thesis
    model, None as the thesis maps."""
    if model is None:
        return Model(ErrorMapSet.thesis())
    if isinstance(model, (ErrorMap, ErrorMapSet)):
        return Model(model)
    if not isinstance(model, Model):
        raise InputError(f"model: expected a Model, ErrorMap or ErrorMapSet, got {type(model).__name__}")
    return model


def diagnose(
    run: Run,
    model: Model | ErrorMap | ErrorMapSet | None = None,
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
) -> Diagnosis:
    """Find which physical effects the model misses on ``run``, add them, and
    keep the history of the error falling.

    Parameters
    ----------
    run : Run
        A measurement run with sphere scans (ballbar balls, reference sphere).
    model : Model, ErrorMap or ErrorMapSet, optional
        The starting model; maps alone make the thesis model. Default: the
        run's bundled maps (``run.maps``) or the thesis set.
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

    Returns
    -------
    Diagnosis
    """
    import time

    t0 = time.perf_counter()
    if not isinstance(run, Run):
        raise InputError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    model = as_model(model)
    policy = {k: v for k, v in (("out_of_range", out_of_range), ("temperature_tolerance", temperature_tolerance),
                                ("log_hold", log_hold)) if v is not None}
    if policy:
        model = replace(model, **policy, _inputs_cache={})
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
    add_names = [a if isinstance(a, str) else a.name for a in add]
    check_effect_names(add_names, problem)
    steps, model = select_effects(problem, model, add_names, auto, max_effects,
                                  lambda label, m, forced: _step(label, m, problem, forced))
    uncertainty_problem = problem
    # Only the effects that shape the points within a scan (on the scanner,
    # or user-defined) gain from more point residuals; the others are fixed
    # by lengths and centres, which do not grow with the points.
    shaping = {spec.name for spec, _ in model.effects
               if spec.kind == "python" or getattr(spec.effect, "on_scanner", False)}
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
        uncertainty_problem = fine
    unobservable, advice, ambiguous = _unobservable(problem, steps)
    diag = Diagnosis(steps, unobservable, ambiguous, n_points=run.n_points, advice=advice,
                     final_uncertainty=model_uncertainties(uncertainty_problem, model),
                     skipped=dict(problem.skipped))
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
    diag.elapsed = time.perf_counter() - t0
    return diag


def _subset(run: Run, keep: np.ndarray) -> Run:
    pts = {k: v[keep] for k, v in run.points.items()}
    return Run(pts, dict(run.scans), dict(run.poses), run.temperatures, run.temperature_channels, run.artefact,
               run.maps, run.metadata, run.created)


def user_specs(user_effects) -> tuple[EffectSpec, ...]:
    """``user_effects`` checked: extra candidates for a :class:`Problem`."""
    for u in user_effects:
        if not isinstance(u, EffectSpec):
            raise InputError(f"user_effects: expected UserEffect objects, got {type(u).__name__}")
    return tuple(user_effects)


def select_effects(problem, model: Model, add_names, auto: bool, max_effects: int, step):
    """Forward selection: the effects ``add_names`` first (fitted whether
    significant or not), then the most significant candidate while one is
    left, refitting after each; ``step(label, model, forced)`` makes each
    step of the history. Returns the steps and the final model."""
    steps = [step("base", model, False)]
    for name in add_names:
        spec = problem.candidates[name]
        model = fit_model(model.with_values(spec, np.zeros(spec.size)), None, problem=problem)
        steps.append(step(f"+ {name}", model, True))
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
            continue
        best = steps[-1].ranking[0] if steps[-1].ranking else None
        if added >= max_effects or best is None or not best.significant:
            break
        model = fit_model(model.with_values(best.spec, best.values), None, problem=problem)
        steps.append(step(f"+ {best.name}", model, False))
        added += 1
    return steps, model


def _step(label: str, model: Model, problem: Problem, forced: bool = False, obs=None) -> Step:
    if obs is None:
        obs = problem.base_obs if model is problem.base else problem.observe(model)
    figs = figures(problem.layout, None, model, observed=obs)
    return Step(label, model, figs, rank_candidates(problem, model, obs), forced)


def _unobservable(problem: Problem, steps: list[Step]):
    """Candidates the run cannot show (from the base ranking), and groups
    that it cannot tell apart, each with the measurement that would help."""
    out = dict(problem.skipped)
    advice = {}
    for c in steps[0].ranking:
        advice[c.name] = c.spec.reveal
        if c.name in [s.effect for s in steps[1:]]:
            continue
        # "Not observable" only where the design cannot determine the effect;
        # a determined but weak one is "not significant" (Candidate.reason says how weak).
        if not c.observable:
            out[c.name] = c.reason().replace("; needs: ", "; ")
    ambiguous = []
    for s in steps:
        for c in s.ranking[:1]:
            if c.indistinguishable_from:
                group = tuple([c.name, *c.indistinguishable_from])
                if group not in ambiguous:
                    ambiguous.append(group)
                    advice[group[0]] = "; ".join(f"{n}: {problem.candidates[n].reveal}" for n in group)
    return out, advice, ambiguous
