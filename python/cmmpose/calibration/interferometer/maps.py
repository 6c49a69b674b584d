"""Error maps assembled from processed interferometer runs, and maps compared (thesis section 3.3).

:func:`build_map` (:class:`MapBuild`) and :func:`map_from_runs` assemble the
18 carriage components and 3 squareness values into an
:class:`~cmmpose.ErrorMap` (roll not measured is stored as 0, thesis line 793);
:func:`compare_maps` (:class:`MapComparison`) and :func:`plot_map_difference`
compare two maps.

Units: positions mm, map deltas um, angles arc-second, temperatures degrees C.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from os import PathLike

import numpy as np

from ..._validate import finite, triple
from ...atomicfile import save_figure
from ...errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap
from ...errors import InputError, InputTypeError, InterferometerRunError, InterferometerWarning, MapError
from ...evaluation.plots import new_figure
from .air import THESIS_AIR_UNCERTAINTY
from .processing import ProcessedRun, process_run
from .runfile import InterferometerRun

_COMPONENTS = ("dx", "dy", "dz", "ex", "ey", "ez")


@dataclass(frozen=True, eq=False)
class MapBuild:
    """The result of :func:`build_map`.

    Attributes
    ----------
    map : ErrorMap
        The assembled map (zero components where nothing was measured).
    runs : tuple of ProcessedRun
        The processed runs, by carriage and component.
    missing : tuple of str
        Components filled with zeros, e.g. ('ex(X)', 'ey(Y)', 'ez(Z)') when the
        rolls were not measured (thesis line 793).
    temperature : float or None
        The map's temperature, C.
    notes : tuple of str
        Everything that was warned about (missing components, truncated
        ranges, temperature spread).
    """

    map: ErrorMap
    runs: tuple[ProcessedRun, ...]
    missing: tuple[str, ...]
    temperature: float | None
    notes: tuple[str, ...] = field(default=())


def _by_component(processed: list[ProcessedRun]) -> dict[tuple[str, str], ProcessedRun]:
    """(carriage, component) -> its run; two runs for one component, or runs processed with different
    material modes, refused."""
    by_key: dict[tuple[str, str], ProcessedRun] = {}
    for p in processed:
        key = (p.axis, p.component)
        if key in by_key:
            raise InterferometerRunError(
                f"two runs for {p.component}({p.axis}): {by_key[key].source or by_key[key].name} and "
                f"{p.source or p.name}; average them into one run or leave one out")
        by_key[key] = p
    modes = {p.material for p in processed}
    if len(modes) > 1:
        raise InterferometerRunError("runs mix material='keep' and material='normalise'; a map has one temperature")
    return by_key


def _carriage_table(c: str, by_key: dict, notes: list[str], missing: list[str]) -> np.ndarray:
    """Carriage ``c``'s map table (position, dx ... ez): the union of its runs' targets over their common
    range, each component interpolated linearly (zero without a run, named in ``missing``); a truncation
    is noted in ``notes``."""
    mine = [by_key[(c, comp)] for comp in _COMPONENTS if (c, comp) in by_key]
    if not mine:
        raise InterferometerRunError(f"no run for the {c} carriage: its grid is unknown (give at least one run)")
    lo = max(float(p.positions_mm[0]) for p in mine)
    hi = min(float(p.positions_mm[-1]) for p in mine)
    if not lo < hi:
        raise InterferometerRunError(
            f"the {c} carriage runs have no common range: " +
            ", ".join(f"{p.name} {p.positions_mm[0]:g}..{p.positions_mm[-1]:g} mm" for p in mine))
    longer = [p.name for p in mine if p.positions_mm[0] < lo or p.positions_mm[-1] > hi]
    if longer:
        notes.append(f"{c} carriage: map truncated to the common range {lo:g}..{hi:g} mm of its runs "
                     f"(longer: {', '.join(longer)})")
    grid = np.unique(np.concatenate([p.positions_mm for p in mine]))
    grid = grid[(grid >= lo) & (grid <= hi)]
    table = np.zeros((len(grid), 7))
    table[:, 0] = grid
    for j, comp in enumerate(_COMPONENTS, start=1):
        p = by_key.get((c, comp))
        if p is None:
            missing.append(f"{comp}({c})")
            continue
        table[:, j] = np.interp(grid, p.positions_mm, p.values)
    return table


def build_map(
    runs: Iterable[InterferometerRun | ProcessedRun],
    squareness: Sequence[float],
    temperature: float | None = None,
    *,
    air_correction: bool = True,
    material: str = "keep",
    expansion_ppm_per_C: float | None = None,
    air_uncertainty: Sequence[float] = THESIS_AIR_UNCERTAINTY,
    temperature_spread_C: float = 1.0,
    source: str | None = None,
) -> MapBuild:
    """Assemble runs into an ErrorMap: 18 carriage components + 3 squareness values.

    Parameters
    ----------
    runs : iterable of InterferometerRun or ProcessedRun
        At most one run per carriage and component; raw runs are processed
        with the options below (:func:`process_run`), processed ones are used
        as they are. Every carriage needs at least one run (its grid).
    squareness : (S_xy, S_yz, S_zx)
        Arc-seconds, thesis sign convention (Table 7; measured with a ballbar,
        line 703, not with the interferometer).
    temperature : float, optional
        Map temperature, C. Default: the mean of the runs' temperatures (their
        mean material temperatures, or 20 when normalised), rounded to 0.001 C.
    air_correction, material, expansion_ppm_per_C, air_uncertainty
        Passed to :func:`process_run` for raw runs.
    temperature_spread_C : float
        Warn when the runs' temperatures spread more than this, C.
    source : str, optional
        Source text of the map (default: a summary of the runs).

    Returns
    -------
    MapBuild
        ``.map`` is the ErrorMap. Each carriage's grid is the union of its
        runs' targets over their common range (components interpolated
        linearly, exact on shared targets); components without a run are zero
        and listed in ``.missing`` and in an :class:`InterferometerWarning`.

    Raises
    ------
    InterferometerRunError
        Two runs for one component, a carriage without runs, runs of one
        carriage without a common range, or runs processed with different
        material modes.
    """
    processed: list[ProcessedRun] = []
    for i, r in enumerate(list(runs)):
        if isinstance(r, InterferometerRun):
            processed.append(process_run(r, air_correction=air_correction, material=material,
                                         expansion_ppm_per_C=expansion_ppm_per_C, air_uncertainty=air_uncertainty))
        elif isinstance(r, ProcessedRun):
            processed.append(r)
        else:
            raise InputTypeError(f"runs[{i}]: expected an InterferometerRun or ProcessedRun, got {type(r).__name__}")
    sq = triple("squareness", squareness, unit="arc-seconds")
    by_key = _by_component(processed)
    notes: list[str] = []
    missing: list[str] = []
    tables = [_carriage_table(c, by_key, notes, missing) for c in CARRIAGES]
    if missing:
        rolls = [m for m in missing if m in ("ex(X)", "ey(Y)", "ez(Z)")]
        extra = " (roll is usually measured with levels, if at all: the thesis stores it as 0, line 793)" if rolls else ""
        notes.append(f"not measured, stored as zero: {', '.join(missing)}{extra}")
    temps = [p.temperature for p in processed]
    if temperature is None:
        temperature = round(float(np.mean(temps)), 3)  # 1 mK: no float noise in the map file
    else:
        temperature = finite("temperature", temperature)
    spread = max(temps) - min(temps)
    if spread > temperature_spread_C:
        notes.append(f"the runs' temperatures spread {spread:.2f} C ({min(temps):.2f}..{max(temps):.2f} C); "
                     f"the map is labelled {temperature:g} C")
    for n in notes:
        warnings.warn(n, InterferometerWarning, stacklevel=3)
    if source is None:
        source = f"{len(processed)} interferometer runs at {temperature:.2f} C"
        if missing:
            source += f"; zero (not measured): {', '.join(missing)}"
    try:
        m = ErrorMap(*tables, sq, temperature, source=source)
    except MapError as exc:
        raise InterferometerRunError(f"the assembled map is invalid: {exc}") from None
    return MapBuild(map=m, runs=tuple(by_key[k] for c in CARRIAGES for k in [(c, comp) for comp in _COMPONENTS]
                                      if k in by_key),
                    missing=tuple(missing), temperature=temperature, notes=tuple(notes))


def map_from_runs(runs, squareness, temperature: float | None = None, **options) -> ErrorMap:
    """The ErrorMap of :func:`build_map` (same parameters; ``options`` are its
    keyword options). Missing components are zeros, named in an
    :class:`InterferometerWarning` and in the map's ``source``."""
    return build_map(runs, squareness, temperature, **options).map


@dataclass(frozen=True, eq=False)
class MapComparison:
    """Differences a - b of two maps (:func:`compare_maps`).

    Attributes
    ----------
    positions : dict carriage -> ndarray (m,)
        Common grid per carriage, mm: the union of both grids over the common range.
    differences : dict carriage -> ndarray (m, 6)
        a - b per component, columns dx, dy, dz (um), ex, ey, ez (arc-second)
        (``TABLE_COLUMNS[1:]``).
    max_difference : dict carriage -> dict column -> float
        Largest |a - b| per carriage and component (um or arc-second).
    squareness_difference : (float, float, float)
        a - b of S_xy, S_yz, S_zx, arc-seconds.
    temperature_difference : float or None
        a - b of the map temperatures, C (None if either has none).
    """

    positions: dict[str, np.ndarray]
    differences: dict[str, np.ndarray]
    max_difference: dict[str, dict[str, float]]
    squareness_difference: tuple[float, float, float]
    temperature_difference: float | None

    @property
    def max_um(self) -> float:
        """Largest |difference| of any delta, um."""
        return max(v for d in self.max_difference.values() for k, v in d.items() if k.endswith("_um"))

    @property
    def max_arcsec(self) -> float:
        """Largest |difference| of any angle or squareness, arc-seconds."""
        return max([v for d in self.max_difference.values() for k, v in d.items() if k.endswith("_arcsec")]
                   + [abs(s) for s in self.squareness_difference])

    def table(self) -> str:
        """Plain-text table of the max |difference| per carriage and component."""
        head = "carriage " + " ".join(f"{c:>10}" for c in TABLE_COLUMNS[1:])
        rows = [f"{c:<8} " + " ".join(f"{self.max_difference[c][k]:10.3f}" for k in TABLE_COLUMNS[1:])
                for c in CARRIAGES]
        sq = ", ".join(f"{v:g}" for v in self.squareness_difference)
        t = "n/a" if self.temperature_difference is None else f"{self.temperature_difference:+.3f} C"
        return "\n".join(["max |a - b|", head, *rows, f"squareness a - b (arc-second): {sq}; temperature a - b: {t}"])

    def __str__(self) -> str:
        return self.table()


def compare_maps(a: ErrorMap, b: ErrorMap) -> MapComparison:
    """Per-component differences a - b on a common grid.

    Per carriage the grid is the union of both maps' grids over their common
    range; both tables are interpolated linearly there (exact: the maps are
    piecewise linear in position). Deltas in um, angles in arc-seconds.

    Raises
    ------
    InputError
        Not ErrorMaps, or a carriage whose two ranges do not overlap.
    """
    for name, m in (("a", a), ("b", b)):
        if not isinstance(m, ErrorMap):
            raise InputTypeError(f"{name}: expected an ErrorMap, got {type(m).__name__}")
    positions, diffs, maxima = {}, {}, {}
    for c in CARRIAGES:
        ta, tb = a.table(c), b.table(c)
        lo, hi = max(ta[0, 0], tb[0, 0]), min(ta[-1, 0], tb[-1, 0])
        if not lo < hi:
            raise InputError(f"compare_maps: the {c} ranges {ta[0, 0]:g}..{ta[-1, 0]:g} and {tb[0, 0]:g}..{tb[-1, 0]:g}"
                             " mm do not overlap")
        grid = np.union1d(ta[:, 0], tb[:, 0])
        grid = grid[(grid >= lo) & (grid <= hi)]
        d = np.column_stack([np.interp(grid, ta[:, 0], ta[:, j]) - np.interp(grid, tb[:, 0], tb[:, j])
                             for j in range(1, 7)])
        positions[c], diffs[c] = grid, d
        maxima[c] = {k: float(np.max(np.abs(d[:, j]))) for j, k in enumerate(TABLE_COLUMNS[1:])}
    sq = tuple(float(x - y) for x, y in zip(a.squareness, b.squareness))
    dt = None if a.temperature is None or b.temperature is None else float(a.temperature - b.temperature)
    return MapComparison(positions, diffs, maxima, sq, dt)  # type: ignore[arg-type]


def plot_map_difference(a: ErrorMap, b: ErrorMap, path: str | PathLike | None = None, *,
                        labels: tuple[str, str] = ("a", "b"), title: str | None = None):
    """Difference plot a - b of two maps (e.g. interferometer-built minus truth).

    Three rows (X, Y, Z carriage, position in mm) by two columns (deltas in
    um, angles in arc-seconds); one line per component, its legend entry giving
    the max |difference|. The title gives the squareness and temperature
    differences. matplotlib is imported lazily (Agg canvas, no pyplot).

    Parameters
    ----------
    a, b : ErrorMap
    path : str or path-like, optional
        Save the figure there (format from the suffix, 150 dpi).
    labels : (str, str)
        Names of a and b in the title.
    title : str, optional
        First line of the title.

    Returns
    -------
    matplotlib.figure.Figure
        3 x 2 axes.
    """
    cmp = compare_maps(a, b)
    fig = new_figure(figsize=(12.0, 9.0), layout="constrained")
    axes = fig.subplots(3, 2, squeeze=False)
    colour = {"x": "C0", "y": "C1", "z": "C2"}
    um = "\u00b5m"
    for row, c in enumerate(CARRIAGES):
        x = cmp.positions[c]
        for col, kind in enumerate(("d", "e")):
            ax = axes[row, col]
            for j, name in enumerate(TABLE_COLUMNS[1:]):
                if name[0] != kind:
                    continue
                comp = name.split("_")[0]
                sym = ("\u03b4" if kind == "d" else "\u03b5") + comp[1]
                ax.plot(x, cmp.differences[c][:, j], color=colour[comp[1]], marker="o", ms=2.5, lw=1.2,
                        label=f"{sym}({c}): max {cmp.max_difference[c][name]:.3g}")
            ax.axhline(0.0, color="0.5", lw=0.6, zorder=0)
            ax.grid(True, alpha=0.3)
            ax.set_xlabel(f"{c} position (mm)")
            ax.set_ylabel(f"{c} carriage: difference " + (f"({um})" if kind == "d" else "(arc-second)"))
            if row == 0:
                ax.set_title("linear and straightness" if kind == "d" else "angular", fontsize="medium")
            ax.legend(fontsize="small", loc="best")
    sq = ", ".join(f"{v:.3g}" for v in cmp.squareness_difference)
    t = "" if cmp.temperature_difference is None else f"; temperature {cmp.temperature_difference:+.2f} \u00b0C"
    text = (f"Map difference {labels[0]} - {labels[1]}: max {cmp.max_um:.3g} {um}, {cmp.max_arcsec:.3g} arc-second\n"
            f"squareness S_xy, S_yz, S_zx difference (arc-second): {sq}{t}")
    fig.suptitle(text if title is None else f"{title}\n{text}")
    if path is not None:
        if not isinstance(path, (str, PathLike)):
            raise InputTypeError(f"path: expected a file path or None, got {type(path).__name__}")
        save_figure(fig, path, dpi=150)
    return fig
