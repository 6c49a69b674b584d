"""A self-contained HTML report: one file a metrologist can send to a
colleague, with inline CSS and every figure embedded as a base64 PNG data URI
(no scripts, no external stylesheets, fonts or images).

Every piece of text (title, headings, paragraphs, table cells) is HTML-escaped,
so run names, labels and messages cannot inject markup.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from numbers import Real
from os import PathLike
from pathlib import Path

import numpy as np

from ..atomicfile import ensure_folder, write_text
from ..errors import InputError, InputTypeError

__all__ = ["write_html_report", "render_html_report", "figure_png"]

#: Resolution of embedded figures, dots per inch.
DPI = 110
_SECTION_KEYS = ("heading", "text", "table", "figures")

_CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; color: #1d232a; margin: 0;
       background: #f6f7f9; }
main { max-width: 1100px; margin: 0 auto; padding: 24px 32px 48px; background: #fff; }
h1 { font-size: 1.6em; border-bottom: 2px solid #2b6cb0; padding-bottom: 6px; }
h2 { font-size: 1.25em; margin-top: 2em; color: #2b6cb0; }
p { line-height: 1.45; }
table { border-collapse: collapse; margin: 12px 0; font-size: 0.85em; }
th, td { border: 1px solid #cfd6de; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #edf2f7; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr:nth-child(even) td { background: #fafbfc; }
figure { margin: 16px 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #e2e8f0; }
footer { margin-top: 3em; font-size: 0.8em; color: #718096; }
"""


def figure_png(fig) -> bytes:
    """A matplotlib Figure as PNG bytes at :data:`DPI` dots per inch.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (any backend; drawn with Agg).

    Returns
    -------
    bytes
        The PNG file, starting with the PNG signature.

    Raises
    ------
    InputError
        ``fig`` is not a matplotlib Figure.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("HTML figures need matplotlib: pip install cmmpose[plot]") from None
    if not isinstance(fig, Figure):
        raise InputTypeError(f"figures: expected matplotlib Figures, got {type(fig).__name__}")
    if fig.canvas is None or not hasattr(fig.canvas, "print_png"):
        FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _cell(value) -> tuple[str, bool]:
    """(escaped text, is a number) of one table cell."""
    if value is None:
        return "", False
    if isinstance(value, bool | np.bool_):
        return ("yes" if value else "no"), False
    if isinstance(value, (Real, np.integer, np.floating)):
        if isinstance(value, (int, np.integer)):
            return f"{int(value)}", True
        v = float(value)
        if not math.isfinite(v):
            return html.escape(str(v)), True
        return (f"{v:.4g}" if (v == 0 or 1e-3 <= abs(v) < 1e5) else f"{v:.3e}"), True
    return html.escape(str(value)), False


def _table_html(rows, where: str) -> str:
    if isinstance(rows, (str, bytes, Mapping)) or not isinstance(rows, Sequence):
        raise InputTypeError(f"{where}: expected a list of dicts (one per row), got {type(rows).__name__}")
    columns: list[str] = []
    for i, row in enumerate(rows):
        if not isinstance(row, Mapping):
            raise InputTypeError(f"{where}[{i}]: expected a dict of column -> value, got {type(row).__name__}")
        for k in row:
            if str(k) not in columns:
                columns.append(str(k))
    if not rows:
        return "<p><em>(no rows)</em></p>"
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = []
    for row in rows:
        by_name = {str(k): v for k, v in row.items()}
        cells = []
        for c in columns:
            text, num = _cell(by_name.get(c))
            cells.append(f'<td class="num">{text}</td>' if num else f"<td>{text}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body) + "\n</tbody>\n</table>"


def _text_html(text, where: str) -> str:
    if not isinstance(text, str):
        raise InputTypeError(f"{where}: expected plain text (str), got {type(text).__name__}")
    paragraphs = [p.strip() for p in text.replace("\r\n", "\n").split("\n\n") if p.strip()]
    return "\n".join("<p>" + html.escape(p).replace("\n", "<br>\n") + "</p>" for p in paragraphs)


def _section_html(i: int, section) -> str:
    where = f"sections[{i}]"
    if not isinstance(section, Mapping):
        raise InputError(f"{where}: expected a dict with 'heading' and optional 'text', 'table', 'figures'")
    unknown = [k for k in section if k not in _SECTION_KEYS]
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(_SECTION_KEYS)})")
    heading = section.get("heading")
    if not isinstance(heading, str) or not heading.strip():
        raise InputError(f"{where}: 'heading' must be a non-empty string, got {heading!r}")
    parts = [f"<section>\n<h2>{html.escape(heading)}</h2>"]
    if section.get("text") is not None:
        parts.append(_text_html(section["text"], f"{where}['text']"))
    if section.get("table") is not None:
        parts.append(_table_html(section["table"], f"{where}['table']"))
    figures = section.get("figures")
    if figures is not None:
        if isinstance(figures, (str, bytes)) or not isinstance(figures, Sequence):
            raise InputTypeError(f"{where}['figures']: expected a list of matplotlib Figures, got {type(figures).__name__}")
        for j, fig in enumerate(figures):
            try:
                png = figure_png(fig)
            except InputError as exc:
                raise InputError(f"{where}['figures'][{j}]: {exc}") from None
            data = base64.b64encode(png).decode("ascii")
            alt = html.escape(f"{heading}, figure {j + 1}", quote=True)
            parts.append(f'<figure><img alt="{alt}" src="data:image/png;base64,{data}"></figure>')
    parts.append("</section>")
    return "\n".join(parts)


def render_html_report(title: str, sections) -> str:
    """The report as one HTML document (see :func:`write_html_report`).

    Parameters
    ----------
    title : str
        Document title and top heading (plain text, escaped).
    sections : list of dict
        As in :func:`write_html_report`.

    Returns
    -------
    str
        A complete HTML5 document.
    """
    if not isinstance(title, str) or not title.strip():
        raise InputError(f"title: expected a non-empty string, got {title!r}")
    if isinstance(sections, (str, bytes, Mapping)) or not isinstance(sections, Sequence):
        raise InputTypeError(f"sections: expected a list of dicts, got {type(sections).__name__}")
    body = "\n".join(_section_html(i, s) for i, s in enumerate(sections))
    try:
        from .. import __version__ as version
    except ImportError:  # pragma: no cover - the extension always defines it
        version = "?"
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    t = html.escape(title)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{t}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n<main>\n<h1>{t}</h1>\n"
        f"{body}\n<footer>Made by cmmpose {html.escape(str(version))} on {when}.</footer>\n"
        "</main>\n</body>\n</html>\n"
    )


def write_html_report(path: str | PathLike, title: str, sections) -> Path:
    """Write a self-contained HTML report: inline CSS, figures as embedded PNGs.

    Parameters
    ----------
    path : str or path-like
        The file to write (UTF-8; parent directories are created).
    title : str
        Document title and top heading (plain text, escaped).
    sections : list of dict
        In order, each ``{"heading": str, "text": str (optional, plain text;
        blank lines separate paragraphs), "table": list of dict (optional,
        one dict per row, columns in order of first appearance, numbers shown
        to 4 significant digits in their own units), "figures": list of
        matplotlib Figures (optional, embedded as PNG at 110 dpi)}``.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    InputError
        An empty title, a section that is not a dict, without a heading or with
        an unknown key, text that is not a string, a table that is not a list
        of dicts, a figure that is not a matplotlib Figure, or matplotlib
        missing when there are figures.
    """
    if not isinstance(path, (str, PathLike)):
        raise InputTypeError(f"path: expected a file path, got {type(path).__name__}")
    doc = render_html_report(title, sections)
    out = Path(path)
    ensure_folder(out.parent if str(out.parent) else ".")
    write_text(out, doc)  # atomic; OutputError naming the file on a full disk
    return out
