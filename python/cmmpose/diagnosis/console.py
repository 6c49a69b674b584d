"""A diagnosis on the console: a verdict first, then the final model's values
and how the error went as effects were added; the full candidate tables only
when asked (``verbose``).

The short view fits a 100-column terminal in about 40 lines (issue 33,
section 8): the verdict says what was found and how sure, what is ambiguous
or unexplained, and the measurement to make next. Every table takes the
console's width and folds its cells rather than cutting a column; below
:data:`WIDE` columns the candidate table drops to a narrower layout (the
dropped figures are in ``--json`` and the report).

The library renders and never prints: :class:`DiagnosisView` is a Rich
renderable the command line prints.
"""

from __future__ import annotations

import math

from rich.markup import escape
from rich.table import Table
from rich.text import Text

from .identify import value_text
from .wording import change_text, change_u_um, rms_u_um, without_held_needs

__all__ = ["DiagnosisView", "verdict", "final_model_table", "history_table", "candidate_table", "WIDE",
           "MOST_LISTED", "as_text", "sphere_table"]

#: Console width (columns) from which the candidate table shows every column.
WIDE = 140
#: Most items of a list (unexplained findings, aliased groups, needs) the verdict names; the rest: --verbose.
MOST_LISTED = 2
#: Longest run name a joint table's headers use (longer: 'run i', named below the table).
SHORT_NAME = 16
#: Parameters of an effect from which the final model's table lists values without their names.
COMPACT_FROM = 5


def _um(x) -> str:
    """A figure in um for a table, '-' when there is none."""
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.2f}"


def _cv_text(cv: dict | None) -> str:
    cv = cv or {}
    if cv.get("cv_rms_um") is None:
        return "-"
    if cv.get("cv_rms_u_um") is None:
        return f"{cv['cv_rms_um']:.2f}"
    return f"{cv['cv_rms_um']:.2f} ± {cv['cv_rms_u_um']:.2f}"


def _names(names, most: int = 3) -> str:
    names = list(names)
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def _headline(figures) -> tuple[str, float | None, int | None]:
    """A step's headline figure: (its name, um, how many values it is an rms of)."""
    what, value = figures.headline
    lengths = getattr(figures, "lengths", None)
    n = len(lengths) if lengths is not None and figures.deviation_rms is None else None
    value = None if value is None or not math.isfinite(value) else value * 1e3
    return what, value, n


def _change_words(first, last) -> str:
    """The headline going from ``first`` to ``last`` (ModelFigures), its verb following the sign."""
    what, before, n = _headline(first)
    _, after, _ = _headline(last)
    if before is None or after is None:
        return f"the {what} cannot be said"
    if first is last:  # one model: its figure, no change to speak of
        return f"the {what} is {before:.2f} um"
    return change_text(f"the {what}", before, after, change_u_um(rms_u_um(before, n), rms_u_um(after, n)))


def _p_text(p: float, digits: int = 1) -> str:
    """'p = 3e-30', or 'p < 1e-300' where it underflows to 0."""
    return "p < 1e-300" if p <= 0 else f"p = {p:.{digits}g}"


def _finding_head(description: str) -> str:
    """A finding's description up to its explanation (what it is, where and how large; the rest: --verbose)."""
    for cut in (": outside", "; ", " (a "):
        description = description.split(cut)[0]
    return description


def _run_labels(d) -> list[str]:
    return [f"run {i + 1}" for i in range(len(getattr(d, "run_names", ()) or ()))]


def _short_names(d) -> list[str]:
    """Each run of a joint diagnosis by its name when short, else as 'run i'."""
    return [str(name) if len(str(name)) <= SHORT_NAME else label for name, label in zip(d.run_names, _run_labels(d))]


def verdict(d) -> list[tuple[str, str]]:
    """The verdict of a diagnosis in words: (heading, text) pairs, plain text.

    Headings: 'found' (what was added, how sure, the figure's change in
    sample and out of sample), 'model check' (a given model on this run),
    'ambiguous', 'unexplained', 'noise floor', 'next' (the measurement to
    make next).

    Parameters
    ----------
    d : Diagnosis or JointDiagnosis

    Returns
    -------
    list of tuple of str
    """
    out = []
    decisions = d.decisions()
    added = [x for x in decisions if x["decision"].startswith("added")]
    if added:
        parts = []
        for x in added:
            how = "added on request" if x["decision"] == "added on request" else \
                _p_text(x["p_value"]) if x.get("p_value") is not None else "in place of its alternative"
            parts.append(f"{x['name']} ({how})")
        found = "the model was missing " + "; ".join(parts)
    elif d.proposals:  # significant, but not added (--no-auto, --max-effects 0, or refused out of sample)
        found = (f"none added; significant against the model: {_names(c.name for c in d.proposals)} "
                 f"(diagnose --add NAME fits one)")
    else:
        found = "no candidate effect is significant against the model: none added"
    steps = d.steps
    per_run = getattr(d, "run_figures", None)
    if per_run:
        changes = [f"{label}: {_change_words(a, b)}" for label, a, b in zip(_short_names(d), per_run[0], per_run[-1])]
        found += "; " + "; ".join(changes)
    else:  # one step: the figure as it stays (the history table is then not shown)
        found += "; " + _change_words(steps[0].figures, steps[-1].figures)
    cv0, cv1 = steps[0].cv or {}, steps[-1].cv or {}
    if len(steps) > 1 and cv0.get("cv_rms_um") is not None and cv1.get("cv_rms_um") is not None:
        u = change_u_um(cv0.get("cv_rms_u_um"), cv1.get("cv_rms_u_um"))
        found += "; out of sample, " + change_text("the cross-validated rms", cv0["cv_rms_um"], cv1["cv_rms_um"], u)
    out.append(("found", found))
    if getattr(d, "verification", None):
        out.append(("model check", d.verification["verdict"]))
    sets = getattr(d, "ambiguity", [])
    # The first set in full (its members' values, where they differ, the equivalences); a further one by its
    # members and their largest difference: the verdict stays within a screen (--verbose, --json: all).
    ambiguous = [_ambiguity_words(a) if i == 0 else _ambiguity_brief(a) for i, a in enumerate(sets[:MOST_LISTED])]
    for group in d.ambiguous[:MOST_LISTED]:
        if any(set(group) <= set(a.effects) for a in sets):
            continue  # said with the set above
        ambiguous.append(f"the run cannot tell apart {_names(group)}")
    said = [set(group) for group in d.ambiguous[:MOST_LISTED]]
    for chosen in list(dict.fromkeys(a.chosen for a in d.alternatives))[:MOST_LISTED]:
        names = [a.name for a in d.alternatives if a.chosen == chosen]
        if any({chosen, *names} <= group for group in said):
            ambiguous[-1] += " (the saved model keeps the others as alternatives)"
            continue
        ambiguous.append(f"{chosen} is an aliased choice: the run cannot tell it from {_names(names)} (kept as "
                         f"alternatives in the saved model)")
    still = [x["name"] for x in decisions if x["decision"].startswith("significant")]
    if still and added:
        ambiguous.append(f"still significant against the final model: {_names(still)}")
    preferred = [x["name"] for x in decisions if x["decision"] == "preferred"]
    if preferred:
        ambiguous.append(f"the data prefer {_names(preferred)} (diagnose --add NAME)")
    rest = max(0, len(d.ambiguous) - MOST_LISTED)
    if ambiguous:
        out.append(("ambiguous", "; ".join(ambiguous) + (f"; {rest} more groups: --verbose" if rest else "")))
    unexplained = [f"{_finding_head(f.description)} (p {f.p_value:.1e})" for f in d.unexplained] + \
        [f"{_finding_head(f['description'])} (p {f['p_value']:.1e})" for f in d.two_axis]
    if unexplained:
        more = len(unexplained) - MOST_LISTED
        out.append(("unexplained", "; ".join(unexplained[:MOST_LISTED]) + (f"; {more} more: --verbose" if more > 0
                                                                             else "")))
    else:
        out.append(("unexplained", "nothing found by the residual-pattern, periodic and two-axis checks"))
    if getattr(d, "noise", None):
        out.append(("noise floor", d.noise["verdict"]))
    out.append(("next", _next(d, decisions, added)))
    return out


def _next(d, decisions, added) -> str:
    """The measurement to make next: what tells an ambiguous group apart, else a user effect on what is
    unexplained, else what reveals an effect the run cannot show, else a check of the model on a new run."""
    has = getattr(d, "run_has", None)
    for a in getattr(d, "open_ambiguity", [])[:1]:
        sep = getattr(d, "separating", None)
        if sep:
            pairs = "; ".join(f"{x['pair'][0]} from {x['pair'][1]} by {x['difference_um']:.2g} um "
                              f"({x['separation']:.3g} in noise units)" for x in sep["separates"][:MOST_LISTED])
            return (f"to tell {_names(a.names)} apart, measure {sep['placement']} ({sep['artefact']}): it separates "
                    f"{pairs}; then diagnose --joint with the new run (cmmpose plan RUN... --separate for more); or "
                    f"choose one: diagnose --add NAME")
        return (f"to tell {_names(a.names)} apart: cmmpose plan RUN... --separate proposes the placements that "
                f"separate them most (T-optimal), then diagnose --joint with the new run; or choose one: "
                f"diagnose --add NAME")
    if d.ambiguous:
        group = d.ambiguous[0]
        return f"to tell {_names(group)} apart: " + _group_advice(d.advice.get(group[0], ""), group, has)
    for a in d.alternatives[:1]:
        reveal = getattr(a.spec, "reveal", "")
        if reveal:
            return f"to tell {a.chosen} from {a.name}: {without_held_needs(reveal, reveal, has)}"
    if d.unexplained:
        return ("model what is unexplained: diagnose RUN --user-effect-skeleton FILE.py drafts a user effect on the "
                "first finding (docs/user-effects.md), then diagnose RUN --user-effect FILE.py")
    if d.two_axis:
        return (f"write a user effect for {_finding_head(d.two_axis[0]['description'])} (docs/user-effects.md), "
                "then diagnose RUN --user-effect FILE.py")
    needs = [x for x in decisions if x["decision"] == "not observable" and not x["name"].startswith("map:")
             and "needs: " in x["reason"]]
    if needs:
        x = needs[0]
        return f"to see {x['name']}, which this run cannot: {x['reason'].split('needs: ')[-1]}"
    if added:
        return ("check the model on a run it has not seen: cmmpose evaluate NEW_RUN --model MODEL.json "
                "(save it with --save-model)")
    return "nothing this run asks for; --verbose lists what each candidate would need"


def _group_advice(advice: str, group, has, most: int = 2) -> str:
    """A group's advice ('name: reveal; name: reveal', :func:`unobservable_candidates`) shortened: each
    distinct measurement once, with the members it reveals, at most ``most`` of them."""
    by_reveal: dict[str, list[str]] = {}
    rest = advice
    names = sorted(group, key=len, reverse=True)
    for piece in advice.split("; "):
        name = next((n for n in names if piece.startswith(f"{n}: ")), None)
        if name is None:  # not of the 'name: reveal' form: as it is
            by_reveal.setdefault(piece, [])
            continue
        by_reveal.setdefault(piece[len(name) + 2:], []).append(name)
    if not by_reveal:
        return rest
    items = [f"{reveal}" + (f" ({_names(members, 2)})" if members else "")
             for reveal, members in list(by_reveal.items())[:most]]
    more = len(by_reveal) - most
    return without_held_needs("; ".join(items), "", has) + (f"; {more} more: --verbose" if more > 0 else "")


def final_model_table(d) -> Table | Text:
    """The final model's effects (those it started with and those added): each with its parameters' values
    ± u in their units, and how sure (p when added, added on request, or from the starting model)."""
    model = d.steps[-1].model
    if not model.effects:
        return Text("Final model: the maps alone (no effect).")
    how = {x["name"]: x for x in d.decisions() if x["decision"].startswith("added")}
    t = Table(title="Final model", title_justify="left", expand=False)
    t.add_column("effect", overflow="fold")
    t.add_column("values ± u", overflow="fold")
    t.add_column("how sure", overflow="fold")
    for spec, values in model.effects:
        params = list(spec.params)
        u = [float(x) for x in d.final_uncertainty.get(spec.name, [math.inf] * len(params))]
        v = [float(x) for x in values]
        if len(params) >= COMPACT_FROM:
            units = set(spec.units)
            unit = units.pop() if len(units) == 1 else ""
            unit = "" if unit in ("1", "") else f" ({unit})"
            vals = f"{params[0]}..{params[-1]}{unit}: " + ", ".join(
                f"{a:+.3g}" + (f"±{b:.2g}" if math.isfinite(b) else " (undetermined)") for a, b in zip(v, u))
        else:
            vals = ", ".join(value_text(p, a, b, unit) for p, a, b, unit in zip(params, v, u, spec.units))
        x = how.get(spec.name)
        if x is None:
            sure = "from the starting model"
        elif x["decision"] == "added on request":
            sure = "added on request"
        else:
            sure = f"{_p_text(x['p_value'], 2)} when added" if x.get("p_value") is not None else \
                "replaced an alternative"
        t.add_row(escape(spec.name), escape(vals), sure)
    return t


def history_table(d, compact: bool = True, width: int = WIDE) -> Table:
    """How the error went as effects were added. ``compact``: the headline
    figure, its cross-validated value and the B89 value (or largest ball
    deviation); otherwise, from ``WIDE`` columns of ``width``, also the
    sphere figures and each step's values (narrower: :func:`sphere_table`).
    A joint diagnosis: each run's headline figure (runs named 'run i')."""
    per_run = getattr(d, "run_figures", None)
    if per_run:
        labels = _run_labels(d)
        names = _short_names(d)
        heads = [f"{name}: {f.headline[0]} (um)" for name, f in zip(names, per_run[0])]
        title = "The error falling as effects are added (one model for every run)"
        if sum(len(h) + 3 for h in heads) + 40 > width:  # the headers whole where they fit; else the figure above
            what = " / ".join(dict.fromkeys(f.headline[0] for f in per_run[0]))
            heads, title = names, f"The error falling: {what} (um) of each run"
        t = Table(title=title, title_justify="left")
        t.add_column("model", overflow="fold")
        for head in heads:
            t.add_column(head, justify="right", overflow="fold", min_width=len(head))
        t.add_column("CV rms (um)", justify="right")
        for s, figs in zip(d.steps, per_run):
            t.add_row(escape(s.label) + (" (forced)" if s.forced else ""),
                      *(_um(None if f.headline[1] is None else f.headline[1] * 1e3) for f in figs), _cv_text(s.cv))
        long = [(label, name) for label, name, short in zip(labels, d.run_names, names) if short == label
                and name != label]
        if long:  # the runs' own names (their folders) below
            t.caption = "; ".join(f"{label}: {escape(str(name))}" for label, name in long)
            t.caption_justify = "left"
        return t
    t = Table(title="The error falling as effects are added", title_justify="left")
    plate = d.steps[0].figures.deviation_rms is not None
    first = (("rms deviation (um)", "rms_deviation_um"), ("largest deviation (um)", "largest_deviation_um")) \
        if plate else (("rms accuracy error (um)", "rms_accuracy_error_um"), ("B89 (um)", "b89_um"))
    cols = ["model", first[0][0], "CV rms (um)", first[1][0]]
    if not compact and width < WIDE:  # the sphere figures in a table of their own (sphere_table)
        compact = True
    if not compact:
        cols += ["sphere form (um)", "fit rms (um)", "centre spread (um)"] + (["effect values"] if width >= WIDE
                                                                              else [])
    for col in cols:
        # The headline's name whole (tests and readers look for it); the others may wrap.
        t.add_column(col, justify="left" if col in ("model", "effect values") else "right", overflow="fold",
                     min_width=len(col) if col == first[0][0] else None)
    for s in d.steps:
        f = s.figures.to_dict()
        row = [escape(s.label) + (" (forced)" if s.forced else ""), _um(f[first[0][1]]), _cv_text(s.cv),
               _um(f[first[1][1]])]
        if not compact:
            eff = "; ".join(f"{sp.name}: {sp.describe(v)}" for sp, v in s.model.effects[-1:]) \
                if s.model.effects and s.label != "base" else ""
            row += [f"{f['form_um']:.1f}", f"{f['fit_rms_um']:.2f}", _um(f["centre_spread_um"])] + \
                ([escape(eff)] if width >= WIDE else [])
        t.add_row(*row)
    return t


def sphere_table(d) -> Table:
    """The sphere figures of each step (form, fit rms, centre spread, um): beside the history on a console
    narrower than ``WIDE``."""
    t = Table(title="Sphere figures as effects are added", title_justify="left")
    for col in ("model", "sphere form (um)", "fit rms (um)", "centre spread (um)"):
        t.add_column(col, justify="left" if col == "model" else "right", overflow="fold")
    for s in d.steps:
        f = s.figures.to_dict()
        t.add_row(escape(s.label) + (" (forced)" if s.forced else ""), f"{f['form_um']:.1f}", f"{f['fit_rms_um']:.2f}",
                  _um(f["centre_spread_um"]))
    return t


def candidate_table(d, step: int = 0, width: int = WIDE) -> Table:
    """The candidates ranked at ``step``, best first, with their decisions.
    Below ``WIDE`` columns: effect, fitted value ± u, p and decision only.
    Every cell folds; no column is cut."""
    s = d.steps[step]
    wide = width >= WIDE
    t = Table(title=f"Candidate effects against the model '{escape(s.label)}'", title_justify="left")
    of = "of lengths" if s.figures.deviation_rms is None else "of deviations"  # an artefact run's balls
    cols = ("effect", "fitted value ± u", "explains", of, "LR (dof)", "p", "corr", "cond", "decision") if wide \
        else ("effect", "fitted value ± u", "p", "decision")
    for col in cols:
        words = col in ("effect", "fitted value ± u", "decision")
        # The figures' headers whole (short; tests and readers look for them); the words' columns fold.
        t.add_column(col, justify="left" if words else "right", overflow="fold", ratio=2 if words else None,
                     min_width=None if words else len(col))
    for c in s.ranking:
        vals = ", ".join(value_text(p, v, u, unit) for p, v, u, unit in zip(c.spec.params, c.values, c.uncertainty,
                                                                          c.spec.units))
        decision = c.decision
        if c.significant and c is s.ranking[0]:
            decision = "[bold green]proposed[/]" + (", aliased" if c.aliases else "")
        elif decision == "not observable":
            decision = "[dim]not observable[/]"
        if c.aliases:
            decision += f" [yellow](same as {escape(', '.join(c.aliases))})[/]"
        name = f"{escape(c.name)}\n[dim]{escape(c.spec.physics)}[/]" if wide else escape(c.name)
        row = {"effect": name, "fitted value ± u": escape(vals), "explains": f"{c.explained:.1%}",
               of: f"{c.explained_length:.1%}", "LR (dof)": f"{c.lr:.1f} ({c.dof})", "p": f"{c.p_value:.1e}",
               "corr": f"{c.correlation:.2f}", "cond": f"{c.condition:.2g}", "decision": decision}
        t.add_row(*(row[col] for col in cols))
    return t


def _verdict_grid(d) -> Table:
    g = Table.grid(padding=(0, 1))
    g.add_column(style="bold", no_wrap=True)
    g.add_column(overflow="fold")
    for head, text in verdict(d):
        g.add_row(f"{head}:", escape(text))
    return g


class DiagnosisView:
    """A diagnosis as the console shows it.

    Parameters
    ----------
    diagnosis : Diagnosis or JointDiagnosis
    verbose : bool
        Also the full history, the candidate tables at the base and final
        models, every finding, what each candidate would need, and the
        residual patterns.
    """

    def __init__(self, diagnosis, verbose: bool = False):
        self.d = diagnosis
        self.verbose = verbose

    def __rich_console__(self, console, options):
        d = self.d
        title = "Verdict" + (f" ({len(d.run_names)} runs, one model)" if getattr(d, "run_names", None) else "")
        yield Text(title, style="bold underline")
        yield _verdict_grid(d)
        yield final_model_table(d)
        if self.verbose or len(d.steps) > 1:  # one step: nothing fell, and "found" says each run's figure
            yield history_table(d, not self.verbose or bool(getattr(d, "run_figures", None)), options.max_width)
        if not self.verbose:
            yield Text(f"{d.n_points} points, {d.elapsed:.1f} s; the candidate tables: --verbose (or --json, "
                       f"--report)", style="dim")
            return
        yield from self._details(options.max_width)

    def _details(self, width):
        d = self.d
        if width < WIDE and not getattr(d, "run_figures", None):
            yield sphere_table(d)
        if d.verification is not None:
            yield f"[bold]Verification of the given model:[/] {escape(d.verification['verdict'])}"
        yield candidate_table(d, 0, width)
        if len(d.steps) > 1:
            yield candidate_table(d, len(d.steps) - 1, width)
        for group in d.ambiguous:
            advice = without_held_needs(d.advice.get(group[0], ""), "", getattr(d, "run_has", None))
            yield f"[yellow]cannot tell apart:[/] {escape(', '.join(group))}: {escape(advice)}"
        if d.unexplained:
            yield ("[bold]Structure the final model does not explain[/] (diagnose --user-effect-skeleton FILE "
                   "drafts an effect):")
            for f in d.unexplained:
                yield f"  {escape(f.input)}: {escape(f.description)} (p {f.p_value:.1e})"
        if d.noise is not None:
            yield f"[bold]Noise floor:[/] {escape(d.noise['verdict'])}"
        for f in d.two_axis:
            yield f"[bold]Unexplained:[/] {escape(f['description'])} (p {f['p_value']:.1e})"
        if d.unobservable:
            yield "[bold]Not observable in this run[/] (what would reveal each):"
            for name, why in d.unobservable.items():
                yield f"  {escape(name)}: {escape(why)}"
        if d.patterns is not None and hasattr(d.patterns, "__rich__"):
            yield d.patterns.__rich__()
        yield f"{d.n_points} points, {d.elapsed:.1f} s"


def as_text(d, verbose: bool = True, width: int = WIDE) -> str:
    """The console view as plain text at ``width`` columns."""
    import io

    from rich.console import Console

    console = Console(width=width, record=True, file=io.StringIO())
    console.print(DiagnosisView(d, verbose))
    return console.export_text()



def _ambiguity_brief(a) -> str:
    """A further ambiguity set in a sentence: its members and how far their corrections differ."""
    if a.agree:
        return f"{_names(a.names)} explain the data alike and agree over the travel ({a.chosen or 'none'} added)"
    return (f"the data cannot choose between {_names(a.names)} either (their corrections differ by up to "
            f"{a.largest_difference_um:.1f} um over the travel; none added; each member's values: --verbose)")


def _ambiguity_words(a) -> str:
    """An ambiguity set in the verdict's words: the members with their parameters and cross-validated rms, where
    they disagree most, the known equivalences among them."""
    members = []
    for m in a.members:
        vals = ", ".join(f"{k} = {v:.3g} ± {m['uncertainty'][k]:.2g} {m['units'][k]}" for k, v in m["values"].items())
        members.append(f"{m['name']} ({m['physics']}; {vals}; cross-validated rms {m['cv_rms_um']:.2f} ± "
                       f"{m['cv_rms_u_um']:.2f} um)")
    return "; ".join([a.verdict() + ": " + "; ".join(members), *a.equivalences])
