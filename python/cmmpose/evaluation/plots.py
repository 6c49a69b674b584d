"""Figures of evaluations, sphere fits and error maps (optional, extra ``plot``).

matplotlib is imported lazily inside each function, so ``import cmmpose`` never
needs it; without it the functions raise :class:`cmmpose.InputError` saying
``pip install cmmpose[plot]``. The figures are plain
:class:`matplotlib.figure.Figure` objects on an Agg canvas: no pyplot, no global
state, safe in threads and on headless machines. Every function returns the
Figure and also saves it when ``path`` is given (format from the suffix, e.g.
``.png``, ``.pdf``, ``.svg``).

Units on the figures: lengths and positions in mm, deviations, residuals and
map deltas in um (written ``µm``), map angles and squareness in arc-seconds.

- :func:`plot_ballbar_lengths`: ballbar length per position (thesis Figures 6-4 to 6-8).
- :func:`plot_sphere_residuals`: residual map of one sphere fit over its cap.
- :func:`plot_error_map`: the 18 carriage components against position (thesis
  Figures 3-7 to 3-18), one map or a set at several temperatures.
- :func:`plot_fleet_trend`: rms and B89 over a fleet of runs, with temperature.
- :func:`plot_artefact_deviations`: deviation arrows over an artefact, per placement.
- :func:`plot_length_errors`: ball-pair length errors against length.
"""

from __future__ import annotations

from os import PathLike

import numpy as np

from ..atomicfile import save_figure
from ..errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from .._validate import finite

__all__ = ["plot_ballbar_lengths", "plot_sphere_residuals", "plot_error_map", "plot_fleet_trend",
           "plot_artefact_deviations", "plot_length_errors", "COMPONENTS"]

#: Component names accepted by :func:`plot_error_map` (``components``), in table order.
COMPONENTS = ("dx", "dy", "dz", "ex", "ey", "ez")

_UM = "\u00b5m"  # micro sign + m
_DPI = 150


# -- shared helpers ----------------------------------------------------------------
def new_figure(**kw):
    """A new Figure on an Agg canvas (lazy matplotlib import)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("plots need matplotlib: pip install cmmpose[plot]") from None
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def save_plot(fig, path):
    """``fig`` written to ``path`` (PNG, PDF, SVG by suffix; atomically, a
    special file as a stream) unless ``path`` is None; returns ``fig``."""
    if path is not None:
        if not isinstance(path, (str, PathLike)):
            raise InputTypeError(f"path: expected a file path or None, got {type(path).__name__}")
        save_figure(fig, path, dpi=_DPI)  # atomic; a special file as a stream
    return fig


def _attr(obj, name: str, where: str):
    try:
        return getattr(obj, name)
    except AttributeError:
        raise InputError(f"{where}: has no attribute {name!r}") from None


def _array(name: str, a, shape) -> np.ndarray:
    """``a`` as float64 with ``shape`` (None entries free), all finite."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as float64 numbers ({exc})") from None
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise InputError(f"{name}: expected shape {want}, got {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1)) if arr.size else []
    if len(bad):
        raise InputError(f"{name}: row {int(bad[0])} is not finite ({arr[bad[0]]})")
    return arr


def _title(fig, title, text: str):
    fig.suptitle(text if title is None else f"{title}\n{text}")


# -- 1. ballbar lengths --------------------------------------------------------------
def _ballbar_series(results):
    if isinstance(results, (str, bytes)) or not hasattr(results, "__iter__"):
        raise InputTypeError(f"results: expected a sequence of ballbar results, got {type(results).__name__}")
    results = list(results)
    if not results:
        raise InputError("results: expected at least one ballbar result, got none")
    series = []
    for i, r in enumerate(results):
        where = f"results[{i}]"
        label = str(_attr(r, "label", where))
        lengths = _array(f"{where}.lengths", _attr(r, "lengths", where), (None,))
        raw_pos = np.asarray(_attr(r, "positions", where))
        if raw_pos.shape != lengths.shape:
            raise InputError(f"{where}.positions: expected shape {lengths.shape} like lengths, got {raw_pos.shape}")
        if len(lengths) == 0:
            raise InputError(f"{where}: no positions")
        try:
            pos_f = raw_pos.astype(np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{where}.positions: expected integer position numbers, got {raw_pos.dtype}") from None
        if not (np.isfinite(pos_f).all() and np.array_equal(pos_f, np.round(pos_f))):
            raise InputError(f"{where}.positions: expected integer position numbers, got {raw_pos[:5]}...")
        mean = finite(f"{where}.mean_length", _attr(r, "mean_length", where))
        rms = finite(f"{where}.rms_accuracy_error", _attr(r, "rms_accuracy_error", where))
        if rms < 0:
            raise InputError(f"{where}.rms_accuracy_error: must be >= 0 mm, got {rms}")
        series.append((label, pos_f.astype(np.int64), lengths, mean, rms))
    return series


def plot_ballbar_lengths(results, path: str | PathLike | None = None, *, title: str | None = None):
    """Ballbar length at every position, one series per result (thesis Figures 6-4 to 6-8).

    Each result is drawn as markers joined by a line, its mean length as a
    dashed horizontal line of the same colour and the band mean +/- rms
    accuracy error shaded. The left y axis is the length in mm (4 decimals,
    no offset); the right y axis gives the same scale as the deviation, in um,
    from the mean length of the first result (its label says which length),
    so differences of a few um can be read directly. The x axis has a tick at
    every position plotted.

    Parameters
    ----------
    results : sequence of objects
        E.g. ``Evaluation.results`` (:class:`cmmpose.BallbarResult`), or anything
        with the attributes ``label`` (str, e.g. 'uncompensated'),
        ``positions`` (array (P,) of integer position numbers, dimensionless),
        ``lengths`` (array (P,), mm), ``mean_length`` (float, mm) and
        ``rms_accuracy_error`` (float, mm). P may differ between results.
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    title : str, optional
        First line of the figure title (the second line says what is plotted).

    Returns
    -------
    matplotlib.figure.Figure
        One axes; per result two lines (data, mean) and one shaded band patch;
        legend entries ``"<label>: mean 404.2357 mm, rms 12.8 µm"``.

    Raises
    ------
    InputError
        No results, a missing attribute, positions and lengths of different
        shapes, non-integer positions, non-finite values, a negative rms, or
        matplotlib not installed.
    """
    series = _ballbar_series(results)
    fig = new_figure(figsize=(8.0, 5.0), layout="constrained")
    ax = fig.add_subplot()
    from matplotlib.ticker import FormatStrFormatter

    for k, (label, pos, lengths, mean, rms) in enumerate(series):
        colour = f"C{k % 10}"
        order = np.argsort(pos, kind="stable")
        ax.axhspan(mean - rms, mean + rms, color=colour, alpha=0.12, lw=0, zorder=0)
        ax.plot(pos[order], lengths[order], marker="o", ms=5, lw=1.3, color=colour, zorder=3,
                label=f"{label}: mean {mean:.4f} mm, rms {rms * 1000:.1f} {_UM}")
        ax.axhline(mean, color=colour, ls="--", lw=1.0, zorder=2)

    all_pos = np.unique(np.concatenate([s[1] for s in series]))
    ax.set_xticks(all_pos)
    if len(all_pos) > 25:
        ax.tick_params(axis="x", labelrotation=90, labelsize=7)
    pad = 0.5
    ax.set_xlim(all_pos[0] - pad, all_pos[-1] + pad)
    ax.set_xlabel("position")
    ax.set_ylabel("ballbar length (mm)")
    ax.yaxis.set_major_formatter(FormatStrFormatter("%.4f"))
    ax.grid(True, alpha=0.3)

    ref = series[0][3]
    sec = ax.secondary_yaxis("right", functions=(lambda y: (y - ref) * 1000.0, lambda d: ref + d / 1000.0))
    sec.set_ylabel(f"deviation from {ref:.4f} mm ({_UM})")

    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1, frameon=False,
              title="dashed: mean; shaded: mean \u00b1 rms", title_fontsize="small")
    _title(fig, title, "Ballbar length per position")
    return save_plot(fig, path)


# -- 2. sphere residuals -----------------------------------------------------------------
def _cap_coordinates(points: np.ndarray, centre: np.ndarray):
    """Azimuthal equidistant projection about the cap's mean direction:
    (polar angle deg, azimuth rad, axis (3,))."""
    d = points - centre
    norm = np.linalg.norm(d, axis=1)
    if np.any(norm == 0):
        raise InputError(f"points: row {int(np.flatnonzero(norm == 0)[0])} is at the fitted centre")
    u = d / norm[:, None]
    m = u.sum(axis=0)
    if np.linalg.norm(m) < 1e-9 * len(u):
        m = np.array([0.0, 0.0, 1.0])  # a balanced whole sphere: any axis will do
    axis = m / np.linalg.norm(m)
    # In-plane basis: the global axis least aligned with the cap axis, made orthogonal.
    g = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = g - axis * (g @ axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    polar = np.degrees(np.arccos(np.clip(u @ axis, -1.0, 1.0)))
    azimuth = np.arctan2(u @ e2, u @ e1)
    return polar, azimuth, axis


def plot_sphere_residuals(points, fit, path: str | PathLike | None = None, *, title: str | None = None):
    """Residual map of a sphere fit over the measured cap.

    The points are projected about the cap's mean direction (the normalised
    sum of the unit vectors from the centre to the points) with an azimuthal
    equidistant projection: polar angle from that direction (degrees) as the
    radius, azimuth about it as the angle (0 along the global axis least aligned
    with the cap direction, counter-clockwise seen from outside the sphere).
    Each point is coloured by its residual in um on a diverging colormap
    symmetric about 0. Rejected points (``fit.inlier`` False, if the fit has
    that attribute) are drawn as grey crosses and do not set the colour scale.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The fitted points, mm, in the order of ``fit.residuals``.
    fit : object
        E.g. :class:`cmmpose.SphereFit`, or anything with ``centre`` (3,) mm,
        ``radius`` mm, ``residuals`` (N,) mm (outward positive), ``rms`` mm and
        ``form`` mm; optional ``inlier`` (N,) bool.
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    title : str, optional
        First line of the title (the second gives radius, rms and form in um).

    Returns
    -------
    matplotlib.figure.Figure
        Two axes (polar map, colorbar); the map has one scatter collection, two
        when some points were rejected.

    Raises
    ------
    InputError
        Points not (N, 3) or N == 0, residuals not (N,), centre not (3,),
        non-finite values, a point at the centre, or matplotlib not installed.
    """
    pts = _array("points", points, (None, 3))
    if len(pts) == 0:
        raise InputError("points: expected at least one point, got none")
    centre = _array("fit.centre", _attr(fit, "centre", "fit"), (3,))
    residuals = _array("fit.residuals", _attr(fit, "residuals", "fit"), (len(pts),))
    radius = finite("fit.radius", _attr(fit, "radius", "fit"))
    rms = finite("fit.rms", _attr(fit, "rms", "fit"))
    form = finite("fit.form", _attr(fit, "form", "fit"))
    inlier = getattr(fit, "inlier", None)
    inlier = np.ones(len(pts), bool) if inlier is None else np.asarray(inlier, dtype=bool)
    if inlier.shape != (len(pts),):
        raise InputError(f"fit.inlier: expected shape ({len(pts)},), got {inlier.shape}")

    polar, azimuth, axis = _cap_coordinates(pts, centre)
    res_um = residuals * 1000.0
    scale_from = res_um[inlier] if inlier.any() else res_um
    vmax = float(np.max(np.abs(scale_from))) or 1.0

    fig = new_figure(figsize=(6.6, 6.0), layout="constrained")
    ax = fig.add_subplot(projection="polar")
    order = np.argsort(np.abs(res_um[inlier]), kind="stable")  # largest residuals drawn on top
    size = float(np.clip(4000.0 / np.sqrt(len(pts)) / 10.0, 1.0, 30.0))
    sc = ax.scatter(azimuth[inlier][order], polar[inlier][order], c=res_um[inlier][order], cmap="RdBu_r",
                    vmin=-vmax, vmax=vmax, s=size, linewidths=0)
    if not inlier.all():
        ax.scatter(azimuth[~inlier], polar[~inlier], marker="x", s=max(size, 12.0), c="0.45", linewidths=0.8,
                   label=f"rejected ({int((~inlier).sum())})")
    rmax = float(polar.max())
    ax.set_ylim(0.0, rmax * 1.05 if rmax > 0 else 1.0)
    ax.yaxis.set_major_formatter(lambda v, _pos: f"{v:g}\u00b0")
    ax.tick_params(axis="y", labelsize=8)
    ax.set_rlabel_position(112.5)
    ax.grid(True, alpha=0.4)
    ax.set_xlabel("polar angle from the cap axis (radius, \u00b0), azimuth about it (angle)", fontsize=9)
    extend = "neither" if inlier.all() else "both"
    cb = fig.colorbar(sc, ax=ax, shrink=0.8, pad=0.08, extend=extend)
    cb.set_label(f"residual, outward positive ({_UM})")
    ax_dir = ", ".join(f"{v:+.3f}" for v in axis)
    _title(fig, title, f"Sphere residuals: radius {radius:.4f} mm, rms {rms * 1000:.1f} {_UM}, "
                       f"form {form * 1000:.1f} {_UM}\n"
                       f"{int(inlier.sum())} points" + ("" if inlier.all() else f", {int((~inlier).sum())} rejected (grey x)")
                       + f", cap axis ({ax_dir})")
    return save_plot(fig, path)


# -- 3. error maps -------------------------------------------------------------------------
def _components(components) -> list[str]:
    if components is None:
        return list(COMPONENTS)
    if isinstance(components, str):
        components = [components]
    try:
        names = list(components)
    except TypeError:
        raise InputError(f"components: expected a sequence of names from {COMPONENTS}, got {components!r}") from None
    out = []
    for c in names:
        key = str(c).lower()
        key = key.split("_")[0] if key in TABLE_COLUMNS else key
        if key not in COMPONENTS:
            raise InputError(f"components: unknown component {c!r}, expected names from {COMPONENTS}")
        if key not in out:
            out.append(key)
    if not out:
        raise InputError("components: expected at least one component")
    return [c for c in COMPONENTS if c in out]


def _component_label(carriage: str, comp: str) -> str:
    axis = comp[1].upper()
    if comp[0] == "d":
        kind = "linear" if axis == carriage else "straightness"
        return f"\u03b4{axis.lower()} ({kind})"
    return f"\u03b5{axis.lower()}"


def plot_error_map(error_map, path: str | PathLike | None = None, *, components=None):
    """Component errors of each carriage against position (thesis Figures 3-7 to 3-18).

    A grid of subplots: one row per carriage (X, Y, Z, position in mm on the x
    axis); the left column shows the translational components delta_x,
    delta_y, delta_z in um (the carriage's own axis is its linear error, the
    other two its straightness), the right column the angular components
    eps_x, eps_y, eps_z in arc-seconds. Colour distinguishes the component;
    for an :class:`ErrorMapSet` every map is overlaid with its own line style
    and marker, labelled by its temperature. The squareness S_xy, S_yz, S_zx
    (arc-seconds) of every map is given in the figure title.

    Parameters
    ----------
    error_map : ErrorMap or ErrorMapSet
        The map (tables in mm, um and arc-seconds; see ``cmmpose.TABLE_COLUMNS``)
        or a set of maps at several temperatures (C).
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi for raster).
    components : sequence of str, optional
        Which components to draw, from ``COMPONENTS`` ('dx', 'dy', 'dz' in um;
        'ex', 'ey', 'ez' in arc-seconds; ``TABLE_COLUMNS`` names such as
        'dx_um' are accepted too). Default all six. A column whose components
        are all left out is not drawn.

    Returns
    -------
    matplotlib.figure.Figure
        3 x (1 or 2) axes, row-major (X, Y, Z); each axes has one line per
        drawn component of its column and map, plus a grey zero line, and a
        legend of its components (colours) beside it; a set adds one figure
        legend of the maps (line styles and markers).

    Raises
    ------
    InputError
        ``error_map`` is not an ErrorMap or ErrorMapSet, an unknown or empty
        ``components``, or matplotlib not installed.
    """
    if isinstance(error_map, ErrorMapSet):
        maps = error_map.maps
    elif isinstance(error_map, ErrorMap):
        maps = [error_map]
    else:
        raise InputTypeError(f"error_map: expected an ErrorMap or ErrorMapSet, got {type(error_map).__name__}")
    comps = _components(components)
    columns = [(kind, [c for c in comps if c[0] == kind]) for kind in ("d", "e")]
    columns = [(k, cs) for k, cs in columns if cs]

    fig = new_figure(figsize=(5.2 * len(columns) + 1.6, 9.0), layout="constrained")
    axes = fig.subplots(len(CARRIAGES), len(columns), squeeze=False)
    styles = [("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"), ((0, (5, 1, 1, 1)), "v")]
    colour = {"x": "C0", "y": "C1", "z": "C2"}
    several = len(maps) > 1

    def map_name(m, i):
        return f"{m.temperature:g} \u00b0C" if m.temperature is not None else f"map {i + 1}"

    from matplotlib.lines import Line2D

    for row, carriage in enumerate(CARRIAGES):
        tables = [m.table(carriage) for m in maps]
        for col, (kind, cs) in enumerate(columns):
            ax = axes[row, col]
            for i, (m, t) in enumerate(zip(maps, tables)):
                ls, mk = styles[i % len(styles)]
                for c in cs:
                    j = TABLE_COLUMNS.index(f"{c}_um" if kind == "d" else f"{c}_arcsec")
                    label = _component_label(carriage, c)
                    ax.plot(t[:, 0], t[:, j], color=colour[c[1]], ls=ls, marker=mk, ms=3, lw=1.2,
                            label=f"{label}, {map_name(m, i)}" if several else label)
            ax.axhline(0.0, color="0.5", lw=0.6, zorder=0)
            ax.grid(True, alpha=0.3)
            ax.set_ylabel(f"{carriage} carriage: " + (f"error ({_UM})" if kind == "d" else "error (arc-second)"))
            ax.set_xlabel(f"{carriage} position (mm)")
            if row == 0:
                ax.set_title("linear and straightness" if kind == "d" else "angular", fontsize="medium")
            # Colour = component (legend beside the axes); style = map (one figure legend).
            handles = [Line2D([], [], color=colour[c[1]], lw=1.6) for c in cs]
            ax.legend(handles, [_component_label(carriage, c) for c in cs], fontsize="small",
                      loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False, handlelength=1.6)
    if several:
        handles = [Line2D([], [], color="0.2", ls=styles[i % len(styles)][0], marker=styles[i % len(styles)][1],
                          ms=4, lw=1.2) for i in range(len(maps))]
        fig.legend(handles, [map_name(m, i) for i, m in enumerate(maps)], loc="outside lower center",
                   ncol=len(maps), frameon=False, handlelength=3.0)

    sq = "; ".join((f"{map_name(m, i)}: " if several else "") + ", ".join(f"{v:g}" for v in m.squareness)
                   for i, m in enumerate(maps))
    heading = "Error map" if not several else "Error maps"
    if not several and maps[0].temperature is not None:
        heading += f" at {maps[0].temperature:g} \u00b0C"
    fig.suptitle(f"{heading}\nsquareness S_xy, S_yz, S_zx (arc-second): {sq}")
    return save_plot(fig, path)


def plot_fleet_trend(rows, path: str | PathLike | None = None, *, title: str | None = None):
    """The trend over a fleet of runs: rms accuracy error and B89 value (um)
    per run, uncompensated and compensated, with the runs' mean machine
    temperature (C) on the right axis.

    Parameters
    ----------
    rows : sequence of objects
        E.g. :func:`cmmpose.scale.fleet_summary`'s rows, in the order to plot:
        anything with ``run`` (str), ``temperature`` (C, NaN if unknown) and
        ``rms_uncompensated``, ``b89_uncompensated``, ``rms_compensated``,
        ``b89_compensated`` (mm; NaN for none).
    path : str or path-like, optional
        Save the figure there (format from the suffix).
    title : str, optional
        The figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One axes with a line per figure of merit, a twin axes with the temperature.

    Raises
    ------
    InputError
        No rows, a row missing an attribute, or matplotlib not installed.
    """
    rows = list(rows)
    if not rows:
        raise InputError("rows: no runs to plot")
    names = [str(_attr(r, "run", f"rows[{i}]")) for i, r in enumerate(rows)]
    fig = new_figure(figsize=(max(6.0, 0.6 * len(rows) + 3.0), 4.5), layout="constrained")
    ax = fig.add_subplot()
    x = np.arange(len(rows))
    for attr, label, style in (("rms_uncompensated", "rms, uncompensated", "o--"),
                               ("b89_uncompensated", "B89, uncompensated", "s--"),
                               ("rms_compensated", "rms, compensated", "o-"),
                               ("b89_compensated", "B89, compensated", "s-")):
        y = np.array([float(_attr(r, attr, f"rows[{i}]")) for i, r in enumerate(rows)]) * 1e3
        if np.any(np.isfinite(y)):
            ax.plot(x, y, style, label=label)
    ax.set_ylabel("\u00b5m")
    ax.set_xticks(x, [n.rstrip("/").split("/")[-1] for n in names], rotation=45 if len(rows) > 6 else 0,
                  ha="right" if len(rows) > 6 else "center")
    ax.set_xlabel("run")
    t = np.array([float(_attr(r, "temperature", f"rows[{i}]")) for i, r in enumerate(rows)])
    if np.any(np.isfinite(t)):
        tx = ax.twinx()
        tx.plot(x, t, "^:", color="0.4", label="temperature")
        tx.set_ylabel("mean machine temperature (\u00b0C)")
    handles = [h for a in fig.axes for h in a.get_lines()]
    fig.legend(handles, [h.get_label() for h in handles], loc="outside lower center", ncol=3,
               fontsize="small", frameon=False)
    fig.suptitle(title or f"Ballbar figures over {len(rows)} runs")
    return save_plot(fig, path)


# -- artefacts (cmmpose.evaluation.artefact) ------------------------------------------
def plot_artefact_deviations(artefact, result, path: str | PathLike | None = None, *, title: str | None = None):
    """Deviation arrows over the artefact, one panel per placement.

    Each ball is drawn at its calibrated place in the artefact's own frame
    (x, y, mm); its arrow is the deviation's component in that plane, scaled
    so the largest spans about a third of the pitch (the scale arrow is
    drawn, in um); the colour of the dot is the component along the
    artefact's z (um).

    Parameters
    ----------
    artefact : cmmpose.artefacts.Artefact
    result : cmmpose.evaluation.artefact.ArtefactResult
    path : path-like, optional
        Where to save the figure.
    """
    placements = result.placements
    if not placements:
        raise InputError("result: no placements to plot")
    n = len(placements)
    fig = new_figure(figsize=(4.6 * n, 4.6), layout="constrained")
    xy = artefact.centres[:, :2]
    extent = np.ptp(xy, axis=0)
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    pitch = float(np.min(gaps[gaps > 0])) if artefact.n_balls > 1 else 1.0
    local = [[p.rotation.T @ b.deviation * 1e3 for b in p.balls] for p in placements]
    biggest = max(float(np.max(np.linalg.norm(np.array(d)[:, :2], axis=1))) for d in local) or 1.0
    scale_um = float(10 ** np.floor(np.log10(biggest)))
    scale_um *= 5 if biggest / scale_um >= 5 else (2 if biggest / scale_um >= 2 else 1)
    k = 0.35 * pitch / biggest  # mm of drawing per um
    zs = np.concatenate([np.array(d)[:, 2] for d in local])
    zlim = float(np.max(np.abs(zs))) or 1.0
    for i, (p, dev) in enumerate(zip(placements, local)):
        ax = fig.add_subplot(1, n, i + 1)
        dev = np.array(dev)
        at = np.array([artefact.centres[artefact.index(b.ball)][:2] for b in p.balls])
        dots = ax.scatter(at[:, 0], at[:, 1], c=dev[:, 2], cmap="coolwarm", vmin=-zlim, vmax=zlim, s=40, zorder=3,
                          edgecolors="0.3")
        ax.quiver(at[:, 0], at[:, 1], dev[:, 0] * k, dev[:, 1] * k, angles="xy", scale_units="xy", scale=1.0,
                  width=0.006, zorder=4)
        for (x, y), b in zip(at, p.balls):
            ax.annotate(str(b.ball), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=6, color="0.4")
        x0 = float(xy[:, 0].min())
        y0 = float(xy[:, 1].min()) - 0.12 * max(extent[0], extent[1], pitch)
        ax.quiver([x0], [y0], [scale_um * k], [0.0], angles="xy", scale_units="xy", scale=1.0, width=0.006, color="C3")
        ax.annotate(f"{scale_um:g} {_UM}", (x0 + scale_um * k, y0), textcoords="offset points", xytext=(4, -3),
                    fontsize=8, color="C3")
        ax.set_aspect("equal")
        ax.margins(0.15)
        ax.set_xlabel("artefact x (mm)")
        ax.set_ylabel("artefact y (mm)")
        ax.set_title(f"{p.position}: {p.label}\nrms {p.rms * 1e3:.2f} {_UM}, largest {p.largest.magnitude * 1e3:.2f} "
                     f"{_UM}", fontsize=9)
    fig.colorbar(dots, ax=fig.axes, label=f"deviation along artefact z ({_UM})", shrink=0.8)
    fig.suptitle(title or f"{artefact.name}: deviations, {result.label}")
    return save_plot(fig, path)


def plot_length_errors(results, path: str | PathLike | None = None, *, title: str | None = None):
    """Every ball-pair length error against its length, per placement, with
    error bars of 2 u (um against mm); one panel per result."""
    results = [r for r in results if r is not None]
    if not results:
        raise InputError("results: nothing to plot")
    fig = new_figure(figsize=(6.4 * len(results), 4.4), layout="constrained")
    for i, r in enumerate(results):
        ax = fig.add_subplot(1, len(results), i + 1)
        for j, p in enumerate(r.placements):
            if not p.lengths:
                continue
            L = np.array([e.length for e in p.lengths])
            E = np.array([e.error for e in p.lengths]) * 1e3
            U = np.array([2 * e.u for e in p.lengths]) * 1e3
            ax.errorbar(L, E, yerr=U, fmt="o", ms=3, elinewidth=0.6, alpha=0.7, color=f"C{j % 10}",
                        label=f"{p.position}: {p.label}")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel("calibrated length at 20 \u00b0C (mm)")
        ax.set_ylabel(f"length error E ({_UM})")
        ax.set_title(r.label)
        ax.legend(fontsize="x-small")
    fig.suptitle(title or "Ball-pair length errors (error bars 2u)")
    return save_plot(fig, path)
