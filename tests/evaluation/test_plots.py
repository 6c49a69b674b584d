"""cmmpose.evaluation.plots: every figure has the expected axes and artists, saves a
non-empty PNG, and bad inputs raise InputError."""

import sys
import types

import numpy as np
import pytest

import cmmpose

pytest.importorskip("matplotlib")
from matplotlib.figure import Figure  # noqa: E402

from cmmpose.evaluation import plots

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 5000


def ballbar(label, lengths, positions=None):
    lengths = np.asarray(lengths, float)
    positions = np.arange(1, len(lengths) + 1) if positions is None else np.asarray(positions)
    return types.SimpleNamespace(label=label, positions=positions, lengths=lengths,
                                 mean_length=float(lengths.mean()),
                                 rms_accuracy_error=float(lengths.std(ddof=1)))


@pytest.fixture
def two_results():
    rng = np.random.default_rng(3)
    return [ballbar("uncompensated", 404.2357 + rng.normal(0, 0.0128, 7)),
            ballbar("compensated", 404.2410 + rng.normal(0, 0.004, 7))]


def cap(n=2000, half_angle=60.0, centre=(10.0, -20.0, 30.0), radius=12.7, noise=0.003, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(5 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 2] >= np.cos(np.radians(half_angle))][:n]
    return np.asarray(centre) + (radius + rng.normal(0, noise, len(d)))[:, None] * d


def sphere_fit(points, centre=(10.0, -20.0, 30.0), radius=12.7, inlier=None):
    res = np.linalg.norm(points - np.asarray(centre), axis=1) - radius
    fit = types.SimpleNamespace(centre=np.asarray(centre, float), radius=radius, residuals=res,
                                rms=float(np.sqrt(np.mean(res**2))), form=float(np.ptp(res)))
    if inlier is not None:
        fit.inlier = inlier
    return fit


# -- ballbar lengths -------------------------------------------------------------------------
def test_ballbar_figure_has_a_series_mean_and_band_per_result(two_results, tmp_path):
    fig = plots.plot_ballbar_lengths(two_results, tmp_path / "bb.png", title="run 3")
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    assert len(ax.lines) == 2 * len(two_results)  # data + dashed mean per result
    assert len(ax.patches) == len(two_results)  # mean +/- rms band
    assert sum(ln.get_linestyle() == "--" for ln in ax.lines) == len(two_results)
    assert list(ax.get_xticks()) == list(range(1, 8))
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    r = two_results[0]
    assert texts[0] == f"uncompensated: mean {r.mean_length:.4f} mm, rms {r.rms_accuracy_error * 1000:.1f} \u00b5m"
    assert texts[1].startswith("compensated: mean ")
    assert "run 3" in fig.get_suptitle()
    assert_png(tmp_path / "bb.png")


def test_ballbar_accepts_different_positions_and_real_results(tmp_path):
    a = ballbar("uncompensated", [404.23, 404.25, 404.24], positions=[1, 2, 4])
    b = ballbar("compensated", [404.24, 404.24], positions=np.array([2.0, 3.0]))
    fig = plots.plot_ballbar_lengths((a, b))
    assert list(fig.axes[0].get_xticks()) == [1, 2, 3, 4]
    res = cmmpose.BallbarResult("compensated", np.array([1, 2, 3]), np.array([404.2, 404.21, 404.205]),
                                np.full(3, 20.0), ())
    fig = plots.plot_ballbar_lengths([res], str(tmp_path / "one.png"))
    assert len(fig.axes[0].lines) == 2
    assert_png(tmp_path / "one.png")


@pytest.mark.parametrize("results, match", [
    ([], "at least one"),
    (None, "sequence"),
    ([ballbar("a", [1.0, 2.0], positions=[1, 2, 3])], "positions"),
    ([types.SimpleNamespace(label="a", positions=np.arange(2), lengths=np.ones(2), mean_length=1.0)],
     "rms_accuracy_error"),
    ([ballbar("a", [[1.0, 2.0]])], "lengths"),
    ([ballbar("a", [1.0, np.nan])], "not finite"),
    ([ballbar("a", [1.0, 2.0], positions=[1.5, 2.0])], "integer"),
])
def test_ballbar_bad_inputs(results, match):
    with pytest.raises(cmmpose.InputError, match=match):
        plots.plot_ballbar_lengths(results)


# -- sphere residuals --------------------------------------------------------------------------
def test_sphere_residual_map(tmp_path):
    pts = cap()
    fit = sphere_fit(pts)
    fig = plots.plot_sphere_residuals(pts, fit, tmp_path / "s.png", title="ball 1")
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2  # polar map + colorbar
    ax, cax = fig.axes
    assert ax.name == "polar"
    assert len(ax.collections) == 1
    sc = ax.collections[0]
    assert len(sc.get_offsets()) == len(pts)
    lo, hi = sc.get_clim()
    assert lo == -hi and hi == pytest.approx(np.abs(fit.residuals).max() * 1000)  # symmetric, in um
    # Azimuthal equidistant about the cap's mean direction: radius = polar angle in degrees.
    u = (pts - fit.centre) / np.linalg.norm(pts - fit.centre, axis=1, keepdims=True)
    axis = u.sum(axis=0) / np.linalg.norm(u.sum(axis=0))
    assert abs(axis[2]) > 0.99  # the cap was generated about +Z
    expected = np.degrees(np.arccos(np.clip(u @ axis, -1, 1)))
    order = np.argsort(np.abs(fit.residuals), kind="stable")  # drawing order of the map
    np.testing.assert_allclose(np.asarray(sc.get_offsets())[:, 1], expected[order], atol=1e-9)
    np.testing.assert_allclose(sc.get_array(), fit.residuals[order] * 1000)
    assert "\u00b5m" in cax.get_ylabel()
    title = fig.get_suptitle()
    assert "ball 1" in title and f"rms {fit.rms * 1000:.1f} \u00b5m" in title and f"form {fit.form * 1000:.1f}" in title
    assert_png(tmp_path / "s.png")


def test_sphere_residual_map_of_a_real_fit_with_rejected_points(tmp_path):
    pts = cap(seed=4)
    pts[:5] += 0.5 * (pts[:5] - [10.0, -20.0, 30.0]) / 12.7  # 0.5 mm outliers
    fit = cmmpose.fit_sphere(pts, reject=3.5)
    assert fit.rejected >= 5
    fig = plots.plot_sphere_residuals(pts, fit, tmp_path / "r.png")
    ax = fig.axes[0]
    assert len(ax.collections) == 2
    assert len(ax.collections[1].get_offsets()) == fit.rejected
    assert ax.collections[0].get_clim()[1] < 100  # outliers do not set the colour scale (um)
    assert_png(tmp_path / "r.png")


def test_sphere_bad_inputs():
    pts = cap(n=50)
    fit = sphere_fit(pts)
    with pytest.raises(cmmpose.InputError, match="points"):
        plots.plot_sphere_residuals(pts[:, :2], fit)
    with pytest.raises(cmmpose.InputError, match="residuals"):
        plots.plot_sphere_residuals(pts[:-1], fit)
    with pytest.raises(cmmpose.InputError, match="centre"):
        plots.plot_sphere_residuals(pts, types.SimpleNamespace(**{**vars(fit), "centre": np.zeros(2)}))
    with pytest.raises(cmmpose.InputError, match="form"):
        plots.plot_sphere_residuals(pts, types.SimpleNamespace(**{k: v for k, v in vars(fit).items() if k != "form"}))
    with pytest.raises(cmmpose.InputError, match="inlier"):
        plots.plot_sphere_residuals(pts, sphere_fit(pts, inlier=np.ones(3, bool)))
    bad = pts.copy()
    bad[7, 1] = np.nan
    with pytest.raises(cmmpose.InputError, match="row 7"):
        plots.plot_sphere_residuals(bad, fit)
    with pytest.raises(cmmpose.InputError, match="at least one"):
        plots.plot_sphere_residuals(np.empty((0, 3)), types.SimpleNamespace(**{**vars(fit), "residuals": np.empty(0)}))


# -- error maps ------------------------------------------------------------------------------
def test_error_map_set_overlays_every_temperature(tmp_path):
    s = cmmpose.ErrorMapSet.thesis()
    fig = plots.plot_error_map(s, tmp_path / "set.png")
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 6  # rows X, Y, Z x columns linear/straightness, angular
    for ax in fig.axes:
        assert len(ax.lines) == 3 * len(s) + 1  # 3 components x 3 maps + zero line
    assert "\u00b5m" in fig.axes[0].get_ylabel() and "arc-second" in fig.axes[1].get_ylabel()
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["20 \u00b0C", "25 \u00b0C", "30 \u00b0C"]
    title = fig.get_suptitle()
    assert "squareness" in title and "-173, -19, 21" in title and "-172, -20, 1" in title
    # The data are the tables: delta_x of the X carriage at 30 C.
    x30 = s.maps[2].table("X")
    line = fig.axes[0].lines[6]
    np.testing.assert_array_equal(line.get_xdata(), x30[:, 0])
    np.testing.assert_array_equal(line.get_ydata(), x30[:, 1])
    assert_png(tmp_path / "set.png")


def test_error_map_single_and_component_subset(tmp_path):
    b = cmmpose.ErrorMap.appendix_b()
    fig = plots.plot_error_map(b, tmp_path / "b.png")
    assert len(fig.axes) == 6 and all(len(ax.lines) == 4 for ax in fig.axes)
    assert not fig.legends and "22 \u00b0C" in fig.get_suptitle()
    assert_png(tmp_path / "b.png")
    fig = plots.plot_error_map(b, components=["ez", "dx_um", "dy"])
    assert len(fig.axes) == 6
    assert [len(ax.lines) for ax in fig.axes] == [3, 2] * 3
    fig = plots.plot_error_map(b, components="ex")
    assert len(fig.axes) == 3 and all(len(ax.lines) == 2 for ax in fig.axes)


@pytest.mark.parametrize("error_map, components, match", [
    (np.zeros((3, 7)), None, "ErrorMap"),
    ("thesis", None, "ErrorMap"),
    (None, ["dw"], "unknown component"),
    (None, [], "at least one"),
    (None, 5, "sequence"),
])
def test_error_map_bad_inputs(error_map, components, match):
    m = cmmpose.ErrorMap.appendix_b() if error_map is None else error_map
    with pytest.raises(cmmpose.InputError, match=match):
        plots.plot_error_map(m, components=components)


# -- without matplotlib ----------------------------------------------------------------------
def test_missing_matplotlib_says_how_to_install(monkeypatch, two_results):
    for name in list(sys.modules):
        if name == "matplotlib" or name.startswith("matplotlib."):
            monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(cmmpose.InputError, match=r"pip install cmmpose\[plot\]"):
        plots.plot_ballbar_lengths(two_results)
    with pytest.raises(cmmpose.InputError, match=r"pip install cmmpose\[plot\]"):
        plots.plot_error_map(cmmpose.ErrorMap.appendix_b())


def test_bad_path_type(two_results):
    with pytest.raises(cmmpose.InputError, match="path"):
        plots.plot_ballbar_lengths(two_results, 42)
