"""The diagnosis as a self-contained HTML report: the error falling, the
ranked candidates, what the run cannot show, and the residual patterns,
plots embedded."""

from __future__ import annotations

import math
from pathlib import Path

from .html import write_html_report

__all__ = ["write_report"]


def _num(x, digits=3):
    x = float(x)
    return "undetermined" if not math.isfinite(x) else float(f"{x:.{digits}g}")


def _ranking_rows(ranking) -> list[dict]:
    rows = []
    for c in ranking:
        rows.append({
            "effect": c.name,
            "what it is": c.spec.physics,
            "fitted value": ", ".join(f"{p}={_num(v)} ± {_num(u, 2)} {unit}" for p, v, u, unit in
                                      zip(c.spec.params, c.values, c.uncertainty, c.spec.units)),
            "explains (all)": f"{c.explained:.1%}", "explains (lengths)": f"{c.explained_length:.1%}",
            "LR": round(c.lr, 1), "dof": c.dof, "p": f"{c.p_value:.1e}", "dBIC": round(c.delta_bic, 1),
            "corr. with model": f"{c.correlation:.2f} {c.correlated_with}", "condition": f"{c.condition:.0f}",
            "significant": "yes" if c.significant else "no",
            "same as": ", ".join(c.indistinguishable_from),
        })
    return rows


def write_report(diagnosis, path, *, run=None, title: str = "cmmpose diagnosis") -> Path:
    """Write ``diagnosis`` as one HTML file with its plots.

    Parameters
    ----------
    diagnosis : Diagnosis
        From :func:`cmmpose.diagnose`.
    path : path-like
        The .html file to write.
    run : Run, optional
        Named in the heading if it has metadata.
    title : str
        Report title.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from .plots import plot_history, plot_length_deviation, plot_patterns, plot_point_residuals

    d = diagnosis
    final = d.steps[-1]
    lines = [f"{d.n_points} points diagnosed in {d.elapsed:.1f} s."]
    if len(d.steps) > 1:
        first, last = d.steps[0].figures, final.figures
        lines.append(f"Adding {', '.join(d.added)} took the rms accuracy error from "
                     f"{first.rms_accuracy_error * 1e3:.2f} um to {last.rms_accuracy_error * 1e3:.2f} um "
                     f"(B89 {first.b89 * 1e3:.2f} -> {last.b89 * 1e3:.2f} um).")
    else:
        lines.append("No candidate effect is significant: the base model explains the run to its noise.")
    if d.proposals:
        lines.append(f"Still significant: {', '.join(c.name for c in d.proposals)}.")
    for group in d.ambiguous:
        lines.append(f"The run cannot tell apart {', '.join(group)}. {d.advice.get(group[0], '')}")
    if d.base_patterns is not None and getattr(d.base_patterns, "strongest", None) is not None:
        s = d.base_patterns.strongest
        lines.append(f"Strongest residual pattern of the base model: {getattr(s, 'description', s)}")
    figs = []
    sections = [{"heading": "Summary", "text": "\n".join(lines)}]
    fig = plot_history(d.history())
    figs.append(fig)
    sections.append({"heading": "The error falling", "table": [
        {"model": s["label"], **{k: (None if v is None else round(v, 3)) for k, v in s.items() if k != "label"}}
        for s in d.history()], "figures": [fig]})
    sections.append({"heading": f"Candidate effects against the base model", "table": _ranking_rows(d.steps[0].ranking)})
    if len(d.steps) > 1:
        sections.append({"heading": f"Candidate effects against the final model ({final.label})",
                         "table": _ranking_rows(final.ranking)})
    if d.unobservable:
        sections.append({"heading": "Not observable in this run, and what would reveal it",
                         "table": [{"effect": k, "why and what to measure": v} for k, v in d.unobservable.items()]})
    for label, pats in (("base model", d.base_patterns), ("final model", d.patterns)):
        if pats is None:
            continue
        pf = []
        for make in (plot_patterns, plot_length_deviation, plot_point_residuals):
            try:
                pf.append(make(pats))
            except Exception as e:  # a plot that has no data for this run is left out, said in the text
                sections.append({"heading": f"({make.__name__} skipped for the {label}: {e})"})
        figs.extend(pf)
        summary = pats.summary() if hasattr(pats, "summary") else str(pats)
        sections.append({"heading": f"Where the {label} fails: residual patterns", "text": summary, "figures": pf})
    out = write_html_report(path, title, sections)
    for f in figs:
        plt.close(f)
    return out
