"""Figures of the diagnosis: residual patterns, ballbar length deviations,
point residuals and the error falling as effects are added.

Like :mod:`cmmpose.evaluation.plots`, matplotlib is imported lazily (``pip install
cmmpose[plot]``) and every figure is a plain Figure on an Agg canvas (no
pyplot, headless-safe). Each function returns the Figure and also saves it
when ``path`` is given. Deviations and residuals are in um (written ``µm``).

- :func:`plot_patterns`: the strongest patterns, one panel each.
- :func:`plot_length_deviation`: ballbar length deviation per position.
- :func:`plot_point_residuals`: point fit residual against u, v, incidence.
- :func:`plot_history`: rms accuracy error, B89 and form per model step.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from numbers import Real
from os import PathLike

import numpy as np

from ..errors import InputError, InputTypeError
from ..evaluation.plots import new_figure, save_plot
from .pattern_results import Pattern, Patterns

__all__ = ["plot_patterns", "plot_length_deviation", "plot_point_residuals", "plot_history"]

_UM = "\u00b5m"
_DEG = "\u00b0"


def _patterns(patterns) -> Patterns:
    if not isinstance(patterns, Patterns):
        raise InputTypeError(f"patterns: expected the Patterns of find_patterns, got {type(patterns).__name__}")
    return patterns


def _unit_label(p: Pattern) -> str:
    unit = {"degree": _DEG, "1": ""}.get(p.quantity_unit, p.quantity_unit)
    return f"{p.quantity} ({unit})" if unit else p.quantity


def _draw_pattern(ax, p: Pattern, *, show_title: bool = True) -> None:
    """One pattern in one axes: data (points, bin means or group means) and the model."""
    colour = "C3" if p.significant else "C0"
    if p.categorical or p.model == "mean":
        pos = np.arange(len(p.x))
        ax.bar(pos, p.y, color=colour, alpha=0.55, width=0.6)
        ax.set_xticks(pos, [str(v) for v in p.x], rotation=90 if len(p.x) > 8 else 0, fontsize=7)
        ax.axhline(0.0, color="0.4", lw=0.8)
        ax.set_xlabel(p.quantity)
    else:
        x, y, fitted = (np.asarray(a, dtype=float) for a in (p.x, p.y, p.fitted))
        if p.y_err is not None:
            ax.errorbar(x, y, yerr=2.0 * np.asarray(p.y_err), fmt="o", ms=3.5, color=colour, ecolor="0.6",
                        elinewidth=0.8, capsize=1.5, label="bin mean \u00b1 2 s.e.")
        else:
            ax.plot(x, y, "o", ms=4, color=colour, label="data")
        order = np.argsort(x, kind="stable")
        if p.y_err is None and len(x) > 1:
            # a smooth curve of the fitted polynomial between the observations
            xs = np.linspace(x.min(), x.max(), 60)
            ys = np.interp(xs, x[order], fitted[order]) if p.model == "linear" else _quadratic_through(x, fitted, xs)
            ax.plot(xs, ys, "-", color="k", lw=1.2, label=p.model)
        else:
            ax.plot(x[order], fitted[order], "-", color="k", lw=1.2, label=p.model)
        ax.set_xlabel(_unit_label(p))
    ax.set_ylabel(f"{p.observable.replace('ballbar ', '')} ({_UM})", fontsize=8)
    ax.grid(True, alpha=0.3)
    if show_title:
        head = "\n".join(textwrap.wrap(p.title, 42))
        ax.set_title(f"{head}\nR\u00b2 {p.r2:.2f}, {p.amplitude_um:.1f} {_UM}, p {p.p_value:.1e}",
                     fontsize=8.5, fontweight="bold" if p.significant else "normal")


def _quadratic_through(x: np.ndarray, fitted: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The quadratic model between observations (it is exactly a quadratic in x)."""
    if len(np.unique(x)) < 3:
        order = np.argsort(x)
        return np.interp(xs, x[order], fitted[order])
    c = np.polyfit(x, fitted, 2)
    return np.polyval(c, xs)


def plot_patterns(patterns, top: int = 6, path: str | PathLike | None = None, *, title: str | None = None):
    """The ``top`` strongest residual patterns, one panel each.

    Length- and scan-level patterns show every observation (um) against the
    quantity with the fitted model; point-level patterns show quantile-bin
    means of the residual (um) with +/- 2 standard errors and the model;
    categorical ones (pose, sweep direction, ...) show group means as bars.
    Significant patterns are red with bold titles, others blue.

    Parameters
    ----------
    patterns : Patterns
        From :func:`cmmpose.diagnosis.patterns.find_patterns`.
    top : int
        Number of patterns to draw (>= 1), in rank order.
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    title : str, optional
        First line of the figure title (the second is the summary sentence).

    Returns
    -------
    matplotlib.figure.Figure
        One axes per pattern drawn (min(top, number of patterns)).

    Raises
    ------
    InputError
        Not a Patterns, ``top`` < 1, or matplotlib not installed.
    """
    pats = _patterns(patterns)
    if isinstance(top, bool) or not isinstance(top, (int, np.integer)) or top < 1:
        raise InputError(f"top: expected a positive number of patterns, got {top!r}")
    shown = list(pats.patterns[: int(top)])
    n = max(len(shown), 1)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig = new_figure(figsize=(4.3 * cols, 3.6 * rows + 0.8), layout="constrained")
    if not shown:
        ax = fig.add_subplot()
        ax.text(0.5, 0.5, "no patterns could be tested", ha="center", va="center")
        ax.set_axis_off()
    for k, p in enumerate(shown):
        _draw_pattern(fig.add_subplot(rows, cols, k + 1), p)
    summary = "\n".join(textwrap.wrap(pats.summary(), 110))
    fig.suptitle(summary if title is None else f"{title}\n{summary}", fontsize=10)
    return save_plot(fig, path)


def _direction_label(d: np.ndarray) -> str:
    """'X', 'XY', '-XYZ'-style name of a bar direction from its large cosines."""
    big = np.abs(d) > 0.3
    axes = "".join(a for a, b in zip("XYZ", big) if b)
    signs = np.sign(d[big])
    return axes if signs.size < 2 or np.all(signs == signs[0]) else f"{axes}\u00b1"


def plot_length_deviation(patterns, path: str | PathLike | None = None, *, title: str | None = None):
    """Ballbar length deviation from the mean per position, with the strongest
    length-level pattern's model overlaid.

    Bars give the deviation (um) of each position, labelled with the bar
    direction (axes whose direction cosine exceeds 0.3; '±' when their signs
    differ, e.g. an XY anti-diagonal). Black diamonds give the fitted values of
    the top-ranked length-level pattern (named in the legend).

    Parameters
    ----------
    patterns : Patterns
        From ``find_patterns``; its ``lengths`` table must exist (a run with
        at least 3 complete ballbar positions).
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    title : str, optional
        First line of the figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One axes: one bar container, plus one line of the model when there is
        a length-level pattern.

    Raises
    ------
    InputError
        Not a Patterns, no ballbar lengths, or matplotlib not installed.
    """
    pats = _patterns(patterns)
    table = pats.lengths
    if table is None:
        raise InputError("patterns: the run has no ballbar lengths (needs >= 3 positions with both balls)")
    positions = np.asarray(table["position"])
    dev = np.asarray(table["deviation_um"], dtype=float)
    fig = new_figure(figsize=(max(7.0, 0.42 * len(positions) + 2.5), 4.8), layout="constrained")
    ax = fig.add_subplot()
    idx = np.arange(len(positions))
    ax.bar(idx, dev, color=np.where(dev >= 0, "C3", "C0"), alpha=0.7, width=0.7, label="deviation from mean length")
    labels = [f"{p}\n{_direction_label(d)}" for p, d in zip(positions.tolist(), np.asarray(table["direction"]))]
    ax.set_xticks(idx, labels, fontsize=7)
    ax.axhline(0.0, color="0.3", lw=0.8)
    length_pats = pats.level("length")
    if length_pats:
        best = length_pats[0]
        ax.plot(idx, np.asarray(best.fitted, dtype=float), "D", color="k", ms=4.5,
                label=f"model: {best.title.replace('ballbar length deviation ', '')} "
                      f"(R\u00b2 {best.r2:.2f}{', significant' if best.significant else ''})")
    rms = float(np.std(dev, ddof=1)) if len(dev) > 1 else 0.0
    ax.set_xlabel("position (bar direction)")
    ax.set_ylabel(f"length deviation ({_UM})")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    text = f"Ballbar length deviation per position: rms {rms:.1f} {_UM}, range {np.ptp(dev):.1f} {_UM}"
    fig.suptitle(text if title is None else f"{title}\n{text}")
    return save_plot(fig, path)


def plot_point_residuals(patterns, path: str | PathLike | None = None, *, quantities: Sequence[str] = ("u", "v", "incidence"),
                         title: str | None = None):
    """Point fit residual (um) against u (mm), v (mm) and the incidence angle
    (degrees): quantile-bin means +/- 2 standard errors and the fitted model.

    Parameters
    ----------
    patterns : Patterns
        From ``find_patterns``.
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    quantities : sequence of str
        Point-level quantities to draw, one panel each ('u', 'v', 'incidence',
        'D in scan', 'E in scan', 'F in scan', 't in scan', 'temperature').
    title : str, optional
        First line of the figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One axes per quantity found among the patterns, sharing the y axis.

    Raises
    ------
    InputError
        Not a Patterns, none of the quantities among the point-level patterns,
        or matplotlib not installed.
    """
    pats = _patterns(patterns)
    if isinstance(quantities, str):
        quantities = [quantities]
    by_q = {p.quantity: p for p in pats.level("point")}
    chosen = [by_q[q] for q in quantities if q in by_q]
    if not chosen:
        raise InputError(f"quantities: none of {list(quantities)} among the point-level patterns ({sorted(by_q)})")
    fig = new_figure(figsize=(4.2 * len(chosen), 4.0), layout="constrained")
    axes = fig.subplots(1, len(chosen), sharey=True, squeeze=False)[0]
    for ax, p in zip(axes, chosen):
        _draw_pattern(ax, p)
    axes[0].legend(fontsize=7, loc="best")
    text = f"Sphere fit residuals per point (noise rms {pats.residual_rms_um:.1f} {_UM})"
    fig.suptitle(text if title is None else f"{title}\n{text}")
    return save_plot(fig, path)


_HISTORY_KEYS = (("rms_accuracy_error_um", "rms accuracy error"), ("b89_um", "B89 value"), ("form_um", "form"))
#: Of an artefact run (ball plate, step gauge): deviations in place of lengths.
_ARTEFACT_HISTORY_KEYS = (("rms_deviation_um", "rms deviation"), ("largest_deviation_um", "largest deviation"),
                          ("form_um", "form"))


def _history_keys(steps) -> tuple:
    first = steps[0] if isinstance(steps, Sequence) and steps and isinstance(steps[0], Mapping) else {}
    return _ARTEFACT_HISTORY_KEYS if first.get("rms_deviation_um") is not None else _HISTORY_KEYS


def _history(steps) -> tuple[list[str], dict[str, np.ndarray]]:
    if isinstance(steps, (str, bytes, Mapping)) or not isinstance(steps, Sequence):
        raise InputTypeError(f"steps: expected a list of dicts, got {type(steps).__name__}")
    if not steps:
        raise InputError("steps: expected at least one step (the base model)")
    keys = _history_keys(steps)
    labels, values = [], {k: [] for k, _ in keys}
    for i, s in enumerate(steps):
        if not isinstance(s, Mapping):
            raise InputTypeError(f"steps[{i}]: expected a dict, got {type(s).__name__}")
        if not isinstance(s.get("label"), str):
            raise InputError(f"steps[{i}]: 'label' must be a string, got {s.get('label')!r}")
        labels.append(s["label"])
        for k, _ in keys:
            v = s.get(k)
            if isinstance(v, bool) or not isinstance(v, (Real, np.floating, np.integer)) or not math.isfinite(float(v)) \
                    or float(v) < 0:
                raise InputError(f"steps[{i}]: {k!r} must be a finite value >= 0 in um, got {v!r}")
            values[k].append(float(v))
    return labels, {k: np.array(v) for k, v in values.items()}


def plot_history(steps, path: str | PathLike | None = None, *, title: str | None = None):
    """The error falling as effects are added to the model.

    One line with markers per figure of merit (rms accuracy error, B89 value,
    sphere form, all in um) against the model steps ('base', '+ squareness',
    ...), each point labelled with its value.

    Parameters
    ----------
    steps : list of dict
        One per model, in order: ``label`` (str), ``rms_accuracy_error_um``,
        ``b89_um`` and ``form_um`` (float, um, finite, >= 0).
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    title : str, optional
        First line of the figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Two axes sharing x (tick labels the step labels): rms and B89 on the
        left axis, the sphere form (peak-to-valley, mostly noise) on the right
        one; the legend below them.

    Raises
    ------
    InputError
        No steps, a step without a label or with a missing, negative or
        non-finite value, or matplotlib not installed.
    """
    labels, values = _history(steps)
    keys = _history_keys(steps)
    (main_key, main_name), (second_key, second_name) = keys[0], keys[1]
    fig = new_figure(figsize=(max(6.0, 1.4 * len(labels) + 3.0), 5.0), layout="constrained")
    ax = fig.add_subplot()
    # The sphere form is the peak-to-valley of the fit residuals: mostly the
    # scanner's noise, tens of um while the rms error falls to a fraction of
    # one. It gets its own (right) axis, so it neither hides the fall nor
    # reads as an error of the same kind.
    ax_form = ax.twinx()
    idx = np.arange(len(labels))
    handles = []
    # value labels: rms below its marker, the others above, so close values stay readable
    for (key, name), marker, dy, axis in zip(keys, ("o", "s", "^"), (-11, 4, 4), (ax, ax, ax_form)):
        style = {"ls": "--", "color": "0.45"} if axis is ax_form else {}
        line, = axis.plot(idx, values[key], marker=marker, ms=6, lw=1.5, label=name, **style)
        handles.append(line)
        for i, v in zip(idx, values[key]):
            axis.annotate(f"{v:.1f}", (i, v), textcoords="offset points", xytext=(6, dy), fontsize=7.5,
                          color=line.get_color())
    ax.set_xticks(idx, labels, rotation=20 if len(labels) > 4 else 0, ha="right" if len(labels) > 4 else "center")
    top = max(float(max(values[k].max() for k in (main_key, second_key))), 1e-9)
    ax.set_ylim(-0.08 * top, 1.15 * top)  # room for the value labels under the rms markers near 0
    ax_form.set_ylim(0.0, 1.15 * max(float(values["form_um"].max()), 1e-9))
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlim(-0.4, len(labels) - 0.4)
    ax.set_xlabel("model")
    ax.set_ylabel(f"{main_name}, {second_name} ({_UM})")
    ax_form.set_ylabel(f"sphere form ({_UM}), peak-to-valley", color="0.35")
    ax.grid(True, alpha=0.3)
    # Below the axes: a legend inside would cover the last points.
    fig.legend(handles=handles, labels=[main_name, second_name,
                                        "sphere form (right axis: peak-to-valley of the fit residuals, "
                                        "mostly scanner noise)"],
               loc="outside lower center", ncols=2, fontsize=8, frameon=False)
    first, last = values[main_key][0], values[main_key][-1]
    text = f"Error as effects are added: {main_name} {first:.1f} \u2192 {last:.1f} {_UM}"
    fig.suptitle(text if title is None else f"{title}\n{text}")
    return save_plot(fig, path)
