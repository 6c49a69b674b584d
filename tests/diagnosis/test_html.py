"""The diagnosis figures and the self-contained HTML report: structure only
(no browser needed): embedded PNGs decode, nothing is fetched from outside,
text is escaped."""

import base64
import re
import functools
from html.parser import HTMLParser

import numpy as np
import pytest

pytest.importorskip("matplotlib")

import cmmpose  # noqa: E402
from cmmpose.diagnosis.html import render_html_report, write_html_report  # noqa: E402
from cmmpose.diagnosis.patterns import find_patterns  # noqa: E402
from cmmpose.diagnosis.plots import plot_history, plot_length_deviation, plot_patterns, plot_point_residuals  # noqa: E402
from cmmpose.evaluation.ballbar import machine_coordinates  # noqa: E402
from cmmpose.fitting import fit_spheres  # noqa: E402
from cmmpose.sim.effects import ScannerScale, Squareness  # noqa: E402
from cmmpose.sim.runs import simulate_ballbar_run  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
STEPS = [
    {"label": "base", "rms_accuracy_error_um": 9.1, "b89_um": 15.2, "form_um": 80.0},
    {"label": "+ squareness", "rms_accuracy_error_um": 2.3, "b89_um": 4.1, "form_um": 79.0},
    {"label": "+ scanner-scale", "rms_accuracy_error_um": 0.4, "b89_um": 0.8, "form_um": 58.0},
]


@functools.lru_cache(maxsize=None)
def _patterns():
    maps = cmmpose.ErrorMapSet.thesis()
    run, _ = simulate_ballbar_run(maps, 22.5, [Squareness(xy=15.0), ScannerScale(depth=1e-3)], seed=4)
    xyz = machine_coordinates(run, maps, 22.5)
    return find_patterns(run, xyz, fit_spheres(xyz, run.points["scan_id"]), nominal_radius=run.artefact["ball_radius_mm"])


class _Tags(HTMLParser):
    """Every start tag with its attributes, and the text."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)


def _parse(doc: str) -> _Tags:
    p = _Tags()
    p.feed(doc)
    p.close()
    return p


# -- figures ------------------------------------------------------------------------------------
def test_plot_patterns_draws_the_top_patterns_in_rank_order():
    pats = _patterns()
    fig = plot_patterns(pats, top=4)
    assert len(fig.axes) == 4
    assert "dx*dy" in fig.axes[0].get_title()  # the strongest first
    assert "strongest pattern" in fig._suptitle.get_text()
    assert len(plot_patterns(pats, top=100).axes) == len(pats)
    with pytest.raises(cmmpose.InputError, match="top"):
        plot_patterns(pats, top=0)
    with pytest.raises(cmmpose.InputError, match="Patterns"):
        plot_patterns([1, 2, 3])


def test_plot_length_deviation_has_one_bar_per_position_and_the_model():
    pats = _patterns()
    fig = plot_length_deviation(pats)
    ax = fig.axes[0]
    bars = ax.containers[0]
    assert len(bars) == 20
    np.testing.assert_allclose([b.get_height() for b in bars], pats.lengths["deviation_um"])
    model = ax.get_lines()[-1]
    np.testing.assert_allclose(model.get_ydata(), pats.level("length")[0].fitted)
    assert "dx*dy" in model.get_label()


def test_plot_point_residuals_shows_u_v_and_incidence():
    pats = _patterns()
    fig = plot_point_residuals(pats)
    titles = [ax.get_title() for ax in fig.axes]
    assert len(titles) == 3
    for q, t in zip(("u", "v", "incidence"), titles):
        assert t.startswith(f"point fit residual vs {q}")
    with pytest.raises(cmmpose.InputError, match="none of"):
        plot_point_residuals(pats, quantities=["nonsense"])


def test_plot_history_draws_the_three_figures_of_merit_per_step(tmp_path):
    fig = plot_history(STEPS, tmp_path / "history.png")
    ax = fig.axes[0]
    # rms and B89 on the left axis; the form (mostly noise) on its own right axis
    lines = {ln.get_label(): ln for a in fig.axes for ln in a.get_lines()}
    assert {ln.get_label() for ln in ax.get_lines()} >= {"rms accuracy error", "B89 value"}
    assert [ln.get_label() for ln in fig.axes[1].get_lines()] == ["form"]
    assert fig.legends and not ax.get_legend()  # below the axes, covering no point
    np.testing.assert_allclose(lines["rms accuracy error"].get_ydata(), [9.1, 2.3, 0.4])
    np.testing.assert_allclose(lines["B89 value"].get_ydata(), [15.2, 4.1, 0.8])
    np.testing.assert_allclose(lines["form"].get_ydata(), [80.0, 79.0, 58.0])
    assert [t.get_text() for t in ax.get_xticklabels()] == ["base", "+ squareness", "+ scanner-scale"]
    assert (tmp_path / "history.png").read_bytes().startswith(PNG_SIGNATURE)
    with pytest.raises(cmmpose.InputError, match="at least one step"):
        plot_history([])
    with pytest.raises(cmmpose.InputError, match=r"steps\[1\]: 'b89_um'"):
        plot_history([STEPS[0], {**STEPS[1], "b89_um": float("nan")}])
    with pytest.raises(cmmpose.InputError, match=r"steps\[0\]: 'label'"):
        plot_history([{**STEPS[0], "label": None}])


# -- the HTML report ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """One report for all structure tests (figures take a second to draw)."""
    tmp_path = tmp_path_factory.mktemp("report")
    pats = _patterns()
    rows = [{"observable": p.observable, "quantity": p.quantity, "R2": p.r2, "n": p.n, "significant": p.significant}
            for p in pats][:5]
    rows.append({"observable": "<b>bold</b> & co", "extra column": "x"})
    sections = [
        {"heading": "Summary <1>", "text": pats.summary() + "\n\nline one\nline <two> & 'three'"},
        {"heading": "Patterns", "table": rows},
        {"heading": "Figures", "figures": [plot_patterns(pats), plot_length_deviation(pats)]},
        {"heading": "History", "text": "falling", "figures": [plot_history(STEPS)]},
    ]
    path = write_html_report(tmp_path / "sub" / "report.html", "Diagnosis <script>alert(1)</script>", sections)
    return path, path.read_text(encoding="utf-8")


def test_report_embeds_every_figure_as_a_png_data_uri(report):
    path, doc = report
    assert path.name == "report.html" and path.is_file()
    imgs = [attrs for tag, attrs in _parse(doc).tags if tag == "img"]
    assert len(imgs) == 3
    for attrs in imgs:
        prefix = "data:image/png;base64,"
        assert attrs["src"].startswith(prefix)
        png = base64.b64decode(attrs["src"][len(prefix):], validate=True)
        assert png.startswith(PNG_SIGNATURE) and len(png) > 10_000
        assert attrs["alt"]


def test_report_fetches_nothing_from_outside(report):
    _, doc = report
    tags = _parse(doc).tags
    names = {t for t, _ in tags}
    assert not names & {"script", "link", "iframe", "object", "embed"}
    for tag, attrs in tags:
        for key in ("src", "href", "srcset", "action", "data"):
            if key in attrs:
                assert attrs[key].startswith("data:"), (tag, key, attrs[key][:60])
    assert "url(" not in doc and "@import" not in doc and "http://" not in doc and "https://" not in doc
    assert any(t == "style" for t, _ in tags)  # the CSS is inline


def test_report_escapes_text_headings_and_cells(report):
    _, doc = report
    parsed = _parse(doc)
    assert "<script>" not in doc and "<b>bold" not in doc
    text = "".join(parsed.text)
    assert "Diagnosis <script>alert(1)</script>" in text  # shown literally, as text
    assert "Summary <1>" in text and "line <two> & 'three'" in text and "<b>bold</b> & co" in text
    assert [t for t, _ in parsed.tags].count("h2") == 4
    # the text's blank line makes two paragraphs, its newline a line break
    assert "line one<br>" in doc


def test_report_table_has_the_union_of_columns_in_first_seen_order(report):
    _, doc = report
    start = doc.index("<table>")
    table = _parse(doc[start:doc.index("</table>", start)])
    heads = re.findall(r"<th>(.*?)</th>", doc[start:])
    assert heads == ["observable", "quantity", "R2", "n", "significant", "extra column"]
    assert sum(1 for t, _ in table.tags if t == "tr") == 1 + 6


def test_report_rejects_bad_sections(tmp_path):
    out = tmp_path / "r.html"
    with pytest.raises(cmmpose.InputError, match="title"):
        write_html_report(out, "", [])
    with pytest.raises(cmmpose.InputError, match=r"sections\[0\]: 'heading'"):
        write_html_report(out, "t", [{"text": "no heading"}])
    with pytest.raises(cmmpose.InputError, match=r"sections\[0\]: unknown key 'image'"):
        write_html_report(out, "t", [{"heading": "h", "image": 1}])
    with pytest.raises(cmmpose.InputError, match=r"sections\[0\]\['figures'\]\[0\]"):
        write_html_report(out, "t", [{"heading": "h", "figures": ["not a figure"]}])
    with pytest.raises(cmmpose.InputError, match=r"sections\[0\]\['table'\]\[1\]"):
        write_html_report(out, "t", [{"heading": "h", "table": [{"a": 1}, "row"]}])
    with pytest.raises(cmmpose.InputError, match=r"sections\[0\]\['text'\]"):
        write_html_report(out, "t", [{"heading": "h", "text": 3}])
    with pytest.raises(cmmpose.InputError, match="sections"):
        write_html_report(out, "t", {"heading": "h"})
    assert not out.exists()


def test_render_html_report_is_a_complete_document():
    doc = render_html_report("t", [{"heading": "h", "table": [{"x": 1.23456789, "y": None, "z": float("nan")}]}])
    assert doc.startswith("<!DOCTYPE html>") and doc.rstrip().endswith("</html>")
    assert '<meta charset="utf-8">' in doc
    assert '<td class="num">1.235</td>' in doc and "<td></td>" in doc and ">nan<" in doc
