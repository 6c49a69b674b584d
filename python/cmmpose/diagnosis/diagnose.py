"""``cmmpose.diagnose``: rank the candidate effects, add them one at a time
(forced ones first, then each significant leader), refit, and keep the
history of the error falling; say which effects the run cannot show and what
measurement would. What it finds: :mod:`cmmpose.diagnosis.result`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..fitting import fit_spheres
from ..run import Run
from .covariance import determined_values, model_covariance
from .identify import Problem, check_effect_names, fit_model, rank_candidates
from ..model.spec import EffectSpec, effect_spec, run_library
from ..model.point_inputs import single_map_warning
from ..model.domain import Domain
from ..model.model import Model, as_model, check_kinematics, run_kinematics
from ..evaluation.observables import figures
from .result import INSTEAD, Diagnosis, Step
from .statistics import ALPHA
from .unexplained import periodic_errors, unexplained_findings
from .wording import without_held_needs

__all__ = ["diagnose", "POLISH_POINTS_PER_SCAN"]

#: Point residuals per scan the final model's effects are refitted on.
POLISH_POINTS_PER_SCAN = 3000


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
    model = _starting_model(run, maps, out_of_range, temperature_tolerance, log_hold, temperature_policy)
    cand = None if candidates is None else _candidate_specs(model, run, candidates)
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
    model, uncertainty_problem = _polish(problem, run, model, steps) if polish else (model, problem)
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
        _attach_patterns(diag, problem, run, steps)
    if diag.open_ambiguity:
        from .plan import separating_measurement

        separating_measurement(diag, [run], machine)
    diag.elapsed = time.perf_counter() - t0
    return diag


def _starting_model(run: Run, maps, out_of_range, temperature_tolerance, log_hold, temperature_policy) -> Model:
    """:func:`diagnose`'s model to start from: ``maps`` as a model for the run's configuration (another's
    refused, naming both), with the whole ``temperature_policy`` and then the keywords given."""
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
    return model


def _candidate_specs(model: Model, run: Run, candidates) -> dict:
    """:func:`diagnose`'s ``candidates`` as name -> EffectSpec: a name of an effect that follows a sensor
    stands for all its variants."""
    cand = {}
    known = run_library(model.inputs(run))
    for c in candidates:
        # A name of an effect that follows a sensor stands for all its variants.
        variants = [k for k in known if isinstance(c, str) and k.startswith(f"{c}@") and known[k].sensor]
        for spec in [known[k] for k in variants] or [effect_spec(c, known if isinstance(c, str) else None)]:
            cand[spec.name] = spec
    return cand


def _polish(problem: Problem, run: Run, model: Model, steps: list[Step]) -> tuple[Model, Problem]:
    """The final model with the effects that shape the points within a scan refitted on
    POLISH_POINTS_PER_SCAN points of each scan (its step replaced and cross-validated again), and the problem
    its uncertainties come from; the model and ``problem`` unchanged when it has no such effect."""
    # Only the effects that shape the points within a scan (on the scanner,
    # or user-defined) gain from more point residuals; the others are fixed
    # by lengths and centres, which do not grow with the points.
    # A model given to start from is applied as saved: what it holds is never refitted here.
    given = set(steps[0].model.names)
    shaping = {spec.name for spec, _ in model.effects
               if (spec.kind == "python" or getattr(spec.effect, "on_scanner", False)) and spec.name not in given}
    if not shaping:
        return model, problem
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
    return model, fine


def _attach_patterns(diag: Diagnosis, problem: Problem, run: Run, steps: list[Step]) -> None:
    """The residual patterns of the base and the final model on ``diag``, and what the final one leaves
    unexplained."""
    diag.base_patterns, _ = residual_findings(problem, run, steps[0].model, findings=False)
    diag.patterns, diag.unexplained = residual_findings(problem, run, steps[-1].model)


def residual_findings(problem: Problem, run: Run, model, *, alpha: float = ALPHA, findings: bool = True):
    """The residual patterns of ``model`` on ``run`` (``problem`` its problem: the points it holds), and
    with ``findings`` what they leave unexplained (the periodic errors and the significant patterns,
    :func:`cmmpose.diagnosis.unexplained.unexplained_findings`), each family tested at ``alpha``
    family-wise. Returns (Patterns, list of Finding)."""
    from .patterns import find_patterns

    nominal = run.artefact.get("calibrated_radius_mm")
    xyz = model.compensate(problem.inputs)
    sid = problem.inputs.scan_id
    keep = np.isin(sid, problem.layout.labels)
    fits = fit_spheres(xyz[keep], sid[keep])
    sub = run if keep.all() else _subset(run, keep)
    patterns = find_patterns(sub, xyz[keep], fits, temperature=problem.inputs.temperature[keep],
                             nominal_radius=nominal, alpha=alpha)
    if not findings:
        return patterns, []
    return patterns, unexplained_findings(patterns, periodic_errors(sub, xyz[keep], fits, alpha=alpha), model.names)


def _two_axis_first(problem, step, candidate, columns=None) -> bool:
    """Whether an error varying with two axes at once explains the structure
    better than the map correction ``candidate`` (a smaller p-value): then the
    candidate is refused, with the reason on it (``candidate.cv``).
    ``columns``: its columns when they are not the problem's (a sibling shape)."""
    from .floor import explained_beyond, two_axis_findings

    found = getattr(step, "_two_axis", None)
    if found is None:
        found = step._two_axis = two_axis_findings(problem, step)
    if not found:
        return False
    f = found[0]
    J = problem.columns[candidate.name] if columns is None else columns
    beyond = min(1.0, explained_beyond(problem, step, f, J)
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
        for k in ("_cv_state", "_cv_by_run", "_two_axis", "_siblings"):
            s.__dict__.pop(k, None)


def add_map_candidates(problem, model) -> None:
    """Offer ``problem`` the map corrections (:func:`mapfamily.map_candidates`)
    and the cross-axis corrections (:func:`crossfamily.cross_candidates`) with
    their centre-level sensitivities."""
    from .crossfamily import cross_candidates
    from .mapfamily import map_candidates

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
    open_names: set[str] = set()  # members of the ambiguity sets left open: never added, never offered again
    held: list = []  # (spec, values) of each open set's best member, held in while looking past it
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
            steps.append(step(f"+ {c.name}{INSTEAD}{c.alternative_to})", model, False))
            step_cv(problem, steps[-1], groups, split)
            continue
        if added >= max_effects:
            break
        # The candidates are ranked against the model so far and, once an ambiguity set is left open, against
        # it with that set's best member held in (never added): what the open set explains is then not offered
        # again through another of its aliases, and what it does not explain (another physics) still is.
        context = steps[-1] if not held else _look_past(problem, model, held, step)
        best = _next_candidate(problem, context, open_names, cross_validate, groups, split)
        if best is None:
            break
        if cross_validate and getattr(best.spec, "family", None) == "map":
            best = _better_sibling(problem, context, best, open_names, groups, split)
        if cross_validate:
            # Competing explanations side by side (cmmpose.diagnosis.ambiguity): when others predict held-out
            # data as well and their corrections differ over the travel, none is added.
            from .ambiguity import find_ambiguity

            if across is None:
                across = cv_groups(problem, across=True)
            amb = find_ambiguity(problem, context, best, (across[0], across[1]), across[2],
                                 INTERPOLATION_ONLY in across[2])
            if amb is not None:
                if steps[-1].ambiguity is None:
                    steps[-1].ambiguity = amb
                else:
                    steps[-1].further_ambiguity.append(amb)
                if not amb.agree:
                    open_names |= set(amb.effects) | {best.name}
                    held.append((best.spec, best.values))
                    continue
                amb.chosen = best.name
        model = fit_model(model.with_values(best.spec, best.values), None, problem=problem)
        steps.append(step(f"+ {best.name}", model, False))
        step_cv(problem, steps[-1], groups, split)
        added += 1
    return steps, model


def _next_candidate(problem, context: Step, skip: set, cross_validate: bool, groups, split):
    """The most significant candidate of ``context``'s ranking not in ``skip`` that also predicts held-out data
    better (cmmpose.diagnosis.cv: a step that raises the cross-validated error is never added); None if none."""
    from .cv import judge_candidate

    for c in context.ranking:
        if not c.significant or c.alternative_to:
            break
        if c.name in skip:
            continue
        if cross_validate and getattr(c.spec, "family", None) == "map" and _two_axis_first(problem, context, c):
            continue  # an error of two axes at once: reported unexplained, not forced into one axis
        if not cross_validate or judge_candidate(problem, context, c, groups, split):
            return c
    return None


def _better_sibling(problem, context: Step, best, skip: set, groups, split):
    """``best`` (a map correction the selection is about to add), or the
    same shape on a sibling component of its carriage
    (:func:`cmmpose.diagnosis.ambiguity.sibling_candidates`: the same knots
    or period on its axis's other translational components and angles) that
    the data clearly prefer: significant, -2 log L lower by more than
    INDISTINGUISHABLE_LR, and passing the selection's cross-validation. The
    map family searches each component's shape separately, so a shape
    chosen on one component may fit another's physics less well than the
    same shape there. One taken instead joins the problem's candidates (it
    enters the model) and ``context``'s ranking, before ``best``."""
    from .ambiguity import columns_of, sibling_candidates
    from .cv import judge_candidate
    from .statistics import INDISTINGUISHABLE_LR

    fresh = [c for c in sibling_candidates(problem, context, best)
             if c.name not in problem.candidates and c.name not in skip and c.significant
             and c.lr > best.lr + INDISTINGUISHABLE_LR]
    for c in sorted(fresh, key=lambda c: -c.lr):
        J = columns_of(problem, c.name)
        if _two_axis_first(problem, context, c, J):
            continue
        if judge_candidate(problem, context, c, groups, split, columns=J):
            c.cv["why"] += (f"; the same shape as {best.name} on a sibling component, which the data prefer "
                            f"(-2 log L {c.lr - best.lr:.1f} lower)")
            problem.candidates[c.name] = c.spec
            problem.columns[c.name] = J
            context.ranking.insert(context.ranking.index(best), c)
            return c
    return best


def _look_past(problem, model: Model, held: list, step) -> Step:
    """The step that ranks the candidates with each open ambiguity set's best member held in the model (a
    look past what the data cannot tell apart, to what else they show); never part of the history."""
    trial = model
    for spec, values in held:
        trial = trial.with_values(spec, values)
    trial = fit_model(trial, None, problem=problem)
    return step("(looking past the open ambiguity)", trial, False)


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
