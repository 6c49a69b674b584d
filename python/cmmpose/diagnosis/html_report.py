"""The diagnosis as a self-contained HTML report: the error falling, the
ranked candidates, what the run cannot show, and the residual patterns,
plots embedded."""

from __future__ import annotations

import math
from pathlib import Path

from .html import write_html_report
from .identify import value_text

__all__ = ["write_report"]


def _num(x, digits=3):
    x = float(x)
    return "undetermined" if not math.isfinite(x) else float(f"{x:.{digits}g}")


_PARAM_UNITS = {"1": "", "arc-second": "arcsec"}


def _unit(u: str) -> str:
    return _PARAM_UNITS.get(u, u)


def _values_text(params, values, uncertainty, units) -> str:
    out = []
    for p, v, u, unit in zip(params, values, uncertainty, units):
        unit = _unit(unit)  # the effect's declared unit, as declared (a gain is not a ppm)
        out.append(value_text(p, float(v), float(u), unit))
    return ", ".join(out)


def _ranking_rows(ranking) -> list[dict]:
    rows = []
    for c in ranking:
        rows.append({
            "effect": c.name,
            "what it is": c.spec.physics,
            "fitted value ± u (alone, against this model)": _values_text(c.spec.params, c.values, c.uncertainty,
                                                                        c.spec.units),
            "residual explained (%)": round(100 * c.explained, 1),
            "ballbar-length residual explained (%)": round(100 * c.explained_length, 1),
            "p": f"{c.p_value:.1e}",
            "decision": c.decision,
            "same as": ", ".join(c.aliases) or "-",
        })
    return rows


_READING = {
    "history": "Each point is one model: the base model (the maps), then each effect added. The left axis holds "
               "the rms accuracy error over the ballbar lengths and the B89 value (range of the length errors); "
               "the right axis the sphere form, the peak-to-valley of the fit residuals, which stays at several "
               "times the scanner noise whatever the model.",
    "candidates": "One row per candidate effect, fitted alone against the model of the heading. 'Residual "
                  "explained' is the share of the remaining weighted residual the effect takes away (over all "
                  "observables: lengths, sphere centres, radii, point residuals); 'ballbar-length residual "
                  "explained' the share of the length residual alone, negative when fitting the effect to all "
                  "observables makes the lengths worse. p is the likelihood-ratio test against the model; an "
                  "effect is significant below the threshold stated at the top.",
    "patterns": "Each panel plots one residual against a quantity that could explain it (direction cosines of "
                "the bar, scan-plane position u and v, incidence, time, temperature). A significant pattern "
                "(p below the Bonferroni threshold) is structure the model leaves; 'consistent with' names the "
                "effects that would make it.",
    "lengths": "Ballbar length deviation from the mean length per position, against the bar's direction and "
               "position: a squareness shows as a sign change with the product of two direction cosines, a scale "
               "as a trend with one of them squared.",
    "points": "Point fit residuals binned by scan-plane u and v and by incidence angle, with the standard error of "
              "each bin mean: flat at zero when the scanner model holds.",
}


def _cv_text(cv) -> str:
    """'2.31 ± 0.40 (in sample 2.20)' from a step's cross-validation, '-' without one."""
    if not cv or cv.get("cv_rms_um") is None:
        return "-"
    return f"{cv['cv_rms_um']:.2f} ± {cv.get('cv_rms_u_um') or 0:.2f} (in sample {cv['in_sample_rms_um']:.2f})"


def _nothing_added(d) -> str:
    """What a diagnosis that added nothing may say: "missing nothing the run
    can show" only when the residuals were tested against a stated or
    measured floor and look like noise; else what is left is not explained."""
    noise = getattr(d, "noise", None) or {}
    if noise.get("noise") and noise.get("floor_stated_or_measured"):
        return "The model was missing nothing the run can show: no candidate effect is significant and the " \
               "residuals look like noise at the floor."
    if noise.get("noise"):
        return "No candidate effect is significant, and the residuals look like noise even at the spheres' fit " \
               "scatter; without a stated or measured floor that is all the run can say."
    if noise.get("unexplained_um") is not None:
        return (f"No candidate effect is significant, but {noise['unexplained_um']:.2f} um is left above the floor "
                "and not explained (see the noise floor).")
    return "No candidate effect is significant; without a noise floor whether the model misses anything cannot be " \
           "said."


def _changes(first, last) -> str:
    """The headline figures going from ``first`` to ``last`` (ModelFigures), each verb following its sign
    (:func:`cmmpose.diagnosis.wording.change_text`): the rms with its uncertainty, the largest or B89 value."""
    from .wording import change_text, change_u_um, rms_u_um

    if first.deviation_rms is not None:  # an artefact run: ball deviations, no ballbar lengths
        return (change_text("the rms deviation", first.deviation_rms * 1e3, last.deviation_rms * 1e3) + ", "
                + change_text("the largest", first.deviation_largest * 1e3, last.deviation_largest * 1e3))
    n = len(first.lengths)
    a, b = first.rms_accuracy_error * 1e3, last.rms_accuracy_error * 1e3
    return (change_text("the rms accuracy error", a, b, change_u_um(rms_u_um(a, n), rms_u_um(b, n))) + ", "
            + change_text("the B89 value", first.b89 * 1e3, last.b89 * 1e3))


def _verdict(d, model_file, run_dir) -> str:
    """The top of the report: what was missing, the final values, how far the error fell, what next."""
    steps = d.steps
    first, last = steps[0].figures, steps[-1].figures
    decisions = d.decisions()
    added = [x for x in decisions if x["decision"].startswith("added")]
    lines = []
    if added:
        parts = [f"{x['name']} ({_values_text(list(x['values']), list(x['values'].values()), list(x['uncertainty'].values()), list(x['units'].values()))})"
                 for x in added]
        lines.append("The model was missing: " + "; ".join(parts) + ".")
        lines.append("With them " + _changes(first, last) + ".")
    else:
        figure = (f"The rms deviation is {first.deviation_rms * 1e3:.2f} um, the largest "
                  f"{first.deviation_largest * 1e3:.2f} um." if first.deviation_rms is not None else
                  f"The rms accuracy error is {first.rms_accuracy_error * 1e3:.2f} um, the B89 value "
                  f"{first.b89 * 1e3:.2f} um.")
        lines.append(f"{_nothing_added(d)} {figure}")
    cv0, cv1 = steps[0].cv, steps[-1].cv
    if cv0 and cv1 and cv0.get("cv_rms_um") is not None and cv1.get("cv_rms_um") is not None:
        lines.append(f"Out of sample ({cv1.get('split', 'cross-validation')}): {cv0['cv_rms_um']:.2f} ± "
                     f"{cv0.get('cv_rms_u_um') or 0:.2f} um with the base model, {cv1['cv_rms_um']:.2f} ± "
                     f"{cv1.get('cv_rms_u_um') or 0:.2f} um with the final one (in sample "
                     f"{cv0['in_sample_rms_um']:.2f} and {cv1['in_sample_rms_um']:.2f} um).")
    if getattr(d, "verification", None):
        lines.append("The given model on this run: " + d.verification["verdict"] + ".")
    noise = getattr(d, "noise", None)
    if noise and noise.get("floor_stated_or_measured") is False:  # said first: every word below stands on it
        lines.insert(0, "Noise floor: " + noise["verdict"] + ".")
    elif noise:
        lines.append("Noise floor: " + noise["verdict"] + ".")
    for f in getattr(d, "two_axis", [])[:2]:
        lines.append(f"Unexplained: {f['description']} (p {f['p_value']:.1e}).")
    for x in decisions:
        if x["decision"] == "preferred":
            lines.append(f"The data prefer {x['name']}: {x['reason']} (diagnose --add {x['name']} instead).")
    alternatives = getattr(d, "alternatives", ())
    for chosen in dict.fromkeys(a.chosen for a in alternatives):
        names = ", ".join(a.name for a in alternatives if a.chosen == chosen)
        lines.append(f"{chosen} is an aliased choice: the run cannot tell it from {names}. The saved model keeps "
                     f"them as alternatives (fitted in its place), and applying it where they predict differently "
                     f"warns.")
    still = [x for x in decisions if x["decision"].startswith("significant")]
    if still:
        lines.append("Still significant against the final model: " + ", ".join(x["name"] for x in still)
                     + " (more effects than --max-effects, or aliases the run cannot tell apart).")
    for f in d.unexplained[:3]:
        lines.append(f"Structure the final model does not explain: {f.description} (p {f.p_value:.1e}); "
                     "cmmpose diagnose RUN --user-effect-skeleton FILE.py drafts a user effect on it "
                     "(docs/user-effects.md).")
    nxt = []
    if added:
        target = model_file or "MODEL.json (save it with diagnose --save-model)"
        nxt.append(f"check the model on a new run: cmmpose diagnose NEW_RUN --model {target} --no-auto; "
                   f"compensate with it in Python: cmmpose.Model.load('{target}').compensate(...)")
    needs = [x for x in decisions if x["decision"] == "not observable" and not x["name"].startswith("map:")]
    for a in getattr(d, "ambiguity", []):
        nxt.append(f"competing explanations: {a.verdict()}. Members: " + "; ".join(
            f"{m['name']} ({m['physics']}): " + ", ".join(f"{k} = {v:.3g} ± {m['uncertainty'][k]:.2g} {m['units'][k]}"
                                                           for k, v in m["values"].items())
            + f", cross-validated rms {m['cv_rms_um']:.2f} ± {m['cv_rms_u_um']:.2f} um" for m in a.members)
            + "".join(f". {w}" for w in a.equivalences)
            + (". cmmpose plan RUN... --separate proposes the placements that tell them apart" if not a.resolved
               else ""))
    sep = getattr(d, "separating", None)
    if sep:
        nxt.append(f"measure {sep['placement']} ({sep['artefact']}): it separates " + "; ".join(
            f"{x['pair'][0]} from {x['pair'][1]} by {x['difference_um']:.2g} um ({x['separation']:.3g} in noise "
            f"units)" for x in sep["separates"]) + "; then diagnose the runs jointly with it")
    if d.ambiguous:
        for group in d.ambiguous:
            nxt.append(f"to tell {', '.join(group)} apart: {d.advice.get(group[0], '')}")
    if needs:
        nxt.append("to see what this run cannot: " + "; ".join(f"{x['name']}: {x['reason'].split('needs: ')[-1]}"
                                                              for x in needs[:3] if "needs: " in x["reason"]))
    if nxt:
        lines.append("Next: " + "\n".join(nxt))
    return "\n\n".join(lines)


def _headline_columns(f) -> dict:
    """A step's main figures for the history table: an artefact run's rms and largest deviation, a
    ballbar run's rms accuracy error and B89 value (um)."""
    if f.deviation_rms is not None:
        return {"rms deviation (um)": round(f.deviation_rms * 1e3, 3),
                "largest deviation (um)": round(f.deviation_largest * 1e3, 3)}
    return {"rms accuracy error (um)": round(f.rms_accuracy_error * 1e3, 3), "B89 value (um)": round(f.b89 * 1e3, 3)}


def _provenance_rows(d, run, run_dir, model_file) -> list[dict]:
    prov = d.provenance()
    rows = [{"item": "run", "value": str(run_dir) if run_dir else "(in memory)"}]
    if run is not None:
        rows.append({"item": "run points / scans", "value": f"{run.n_points} / {len(run.scans['scan_id'])}"})
        if run.metadata:
            rows.append({"item": "run metadata", "value": ", ".join(f"{k}: {v}" for k, v in run.metadata.items()
                                                                    if isinstance(v, (str, int, float)))})
    maps = prov["maps"]
    rows.append({"item": "maps", "value": (f"set at {', '.join(f'{t:g}' for t in maps['temperatures_C'])} C"
                                           if maps["kind"] == "set" else f"one map at {maps['temperature_C']} C")})
    rows.append({"item": "temperature", "value": prov["temperature"]})
    pol = prov["policy"]
    rows.append({"item": "temperature policy", "value": f"out of range: {pol['out_of_range']}, tolerance "
                                                          f"{pol['temperature_tolerance_K']} K, log hold {pol['log_hold_s']} s"})
    rows.append({"item": "base model effects", "value": ", ".join(prov["base_effects"]) or "none"})
    rows.append({"item": "saved model", "value": str(model_file) if model_file else "not saved (--save-model)"})
    rows.append({"item": "significance", "value": "family-wise 0.001, Bonferroni over the candidates"})
    rows.append({"item": "cmmpose", "value": f"{prov['cmmpose_version']}, {prov['date_utc']}"})
    return rows


def _truth_rows(d, run_dir) -> list[dict] | None:
    """Effects the simulator put in the run against what the diagnosis found (None without a truth)."""
    if run_dir is None:
        return None
    from ..errors import Error
    from ..run import load_truth

    try:
        _, info = load_truth(run_dir)
    except Error:
        return None
    found = {x["name"]: x for x in d.decisions()}
    # An effect that follows a thermocouple group is a candidate per group.
    truth = {f"{e.get('name')}@{e['sensor']}" if isinstance(e.get("sensor"), str) else e.get("name"): e
             for e in info.get("effects", [])}
    rows = []
    for name, e in truth.items():
        x = found.get(name)
        if x is None:
            rows.append({"effect in the truth": name, "true value": "", "found": "not a candidate"})
            continue
        true = ", ".join(f"{p} = {_num(e[p])} {_unit(x['units'].get(p, ''))}".rstrip() for p in x["units"] if p in e)
        got = _values_text(list(x["values"]), list(x["values"].values()), list(x["uncertainty"].values()),
                           list(x["units"].values()))
        rows.append({"effect in the truth": name, "true value": true, "decision": x["decision"], "found": got})
    for x in d.decisions():
        if x["decision"].startswith("added") and x["name"] not in truth:
            rows.append({"effect in the truth": f"(none) - {x['name']} was added", "true value": "-",
                         "decision": x["decision"], "found": ""})
    return rows


def write_report(diagnosis, path, *, run=None, run_dir=None, model_file=None,
                 title: str = "cmmpose diagnosis") -> Path:
    """Write ``diagnosis`` as one HTML file with its plots.

    Parameters
    ----------
    diagnosis : Diagnosis
        From :func:`cmmpose.diagnose`.
    path : path-like
        The .html file to write.
    run : Run, optional
        The run diagnosed (its size and metadata are stated).
    run_dir : path-like, optional
        Where the run was read from: named in the provenance; a simulated run's
        truth beside it is compared with what was found.
    model_file : path-like, optional
        Where the final model was saved (named in the verdict and provenance).
    title : str
        Report title.
    """
    from .plots import plot_history, plot_length_deviation, plot_patterns, plot_point_residuals

    d = diagnosis
    final = d.steps[-1]
    sections = [{"heading": "Verdict", "text": _verdict(d, model_file, run_dir)}]
    sections.append({"heading": "Decision on every candidate effect", "text":
                     "added: fitted in the final model (values with their standard uncertainties); significant: "
                     "p below the threshold against the final model; aliased: the run cannot tell it from the "
                     "effect named; not significant: determined by the run, but p above the threshold; not "
                     "observable: the run cannot determine it at a typical size (what would is said). An effect that "
                     "follows a thermocouple group is a candidate per group (name@role); beside the one added, the "
                     "others are not chosen (the data reject them), aliased (the run cannot choose), preferred (the "
                     "data favour it over one added on request) or replaced (added, then given up for a better one).",
                     "table": [{"effect": x["name"], "decision": x["decision"], "why": x["reason"]}
                               for x in d.decisions()]})
    if d.unexplained:
        sections.append({"heading": "Structure the final model does not explain", "text":
                         "Each row is structure the final model's residuals still hold, with the input it follows: "
                         "a periodic error along an axis (searched from 2 to 40 mm on each scale reading), or a "
                         "significant residual pattern with the library effects that could make it and those the "
                         "model already holds. 'cmmpose diagnose RUN --user-effect-skeleton FILE.py' drafts a user "
                         "effect on the first; docs/user-effects.md goes through one.",
                         "table": [{"input": f.input, "what": f.description, "size (um)": round(f.size_um, 3),
                                    "p": f"{f.p_value:.1e}", "threshold": f"{f.threshold:.1e}"}
                                   for f in d.unexplained]})
    truth = _truth_rows(d, run_dir)
    if truth is not None:
        sections.append({"heading": "Found against the simulator's truth", "table": truth})
    # Each step's figures (a joint diagnosis: its first run's), as Diagnosis.history gives them; called on the
    # steps here, since .result imports this module to write its report (no circle back).
    fig = plot_history([{"label": s.label, **s.figures.to_dict()} for s in d.steps])
    history = [{"model": s.label, **_headline_columns(s.figures),
                "cross-validated rms (um)": _cv_text(s.cv),
                "sphere form, peak-to-valley (um)": round(s.figures.to_dict()["form_um"], 2),
                "fit rms (um)": round(s.figures.to_dict()["fit_rms_um"], 3)} for s in d.steps]
    sections.append({"heading": "The error falling", "text": _READING["history"], "table": history,
                     "figures": [fig]})
    run_names = getattr(d, "run_names", None)
    if run_names:  # a joint diagnosis: one model, every run's error at each step
        sections.append({"heading": "Every run under the one model", "text":
                         f"{len(run_names)} runs diagnosed together; the plots and figures above are the first "
                         f"run's ({run_names[0]}). The rms accuracy error of each run at each step (um; of an "
                         f"artefact run its rms deviation):",
                         "table": [{"model": s.label, **{name: round(f.headline[1] * 1e3, 3)
                                                         for name, f in zip(run_names, per_run)}}
                                   for s, per_run in zip(d.steps, d.run_figures)]})
    sections.append({"heading": "Candidate effects against the base model", "text": _READING["candidates"],
                     "table": _ranking_rows(d.steps[0].ranking)})
    if len(d.steps) > 1:
        sections.append({"heading": f"Candidate effects against the final model ({final.label})",
                         "table": _ranking_rows(final.ranking)})
    for label, pats in (("base model", d.base_patterns), ("final model", d.patterns)):
        if pats is None:
            continue
        pf, notes = [], []
        for make, key in ((plot_patterns, "patterns"), (plot_length_deviation, "lengths"),
                          (plot_point_residuals, "points")):
            try:
                pf.append(make(pats))
                notes.append(_READING[key])
            except Exception as e:  # a plot that has no data for this run is left out, said in the text
                notes.append(f"({make.__name__} left out for the {label}: {e})")
        summary = pats.summary() if hasattr(pats, "summary") else str(pats)
        sections.append({"heading": f"Where the {label} fails: residual patterns",
                         "text": summary + "\n\n" + "\n\n".join(notes), "figures": pf})
    sections.append({"heading": "Provenance", "table": _provenance_rows(d, run, run_dir, model_file)})
    out = write_html_report(path, title, sections)
    return out
