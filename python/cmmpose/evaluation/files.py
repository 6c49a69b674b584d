"""The files of a ballbar evaluation: ``evaluation.json``, ``lengths.csv``
and, with matplotlib, its plots; for several runs, each run's files, a
``summary.csv`` across them and a plot of the trend. What ``cmmpose
evaluate --report DIR`` and ``cmmpose demo`` write (docs/formats.md).

Every file is written atomically (:mod:`cmmpose.atomicfile`); a missing
matplotlib leaves the plots out with a log line (logger ``cmmpose``).
"""

from __future__ import annotations

import logging
from pathlib import Path

from ..atomicfile import ensure_folder, write_text
from ..errors import InputError

__all__ = ["write_evaluation_files", "write_fleet_files", "REPORT_FILES", "FLEET_FILES"]

#: The files of one run's report (a ballbar run's; the plots only with matplotlib, error_map.png with maps).
REPORT_FILES = ("evaluation.json", "lengths.csv", "ballbar_lengths.png", "error_map.png")
#: The files of a report across runs, beside each run's folder.
FLEET_FILES = ("summary.csv", "trend.png")

_log = logging.getLogger("cmmpose")


def _csv(rows: list[dict] | list, header: list[str], value) -> str:
    """CSV text: ``header`` then one line per row (``value(row, column)``)."""
    return "\n".join([",".join(header)] + [",".join(str(value(row, k)) for k in header) for row in rows]) + "\n"


def _has_matplotlib() -> bool:
    try:
        import matplotlib  # noqa: F401 - an optional extra
    except ImportError:
        _log.warning("matplotlib is not installed: no plots (pip install 'cmmpose[plot]')")
        return False
    return True


def write_evaluation_files(evaluation, directory, maps=None) -> list[Path]:
    """Write ``evaluation`` (an :class:`~cmmpose.evaluation.ballbar.Evaluation`) into ``directory``.

    Parameters
    ----------
    evaluation : Evaluation
    directory : str or Path
        Made if missing.
    maps : ErrorMap or ErrorMapSet, optional
        The maps compensated with: plotted as ``error_map.png``.

    Returns
    -------
    list of Path
        The files written: evaluation.json, lengths.csv (lengths in mm, errors
        in um as the evaluation's rows say) and, with matplotlib,
        ballbar_lengths.png and error_map.png.
    """
    directory = ensure_folder(directory)
    files = [directory / "evaluation.json", directory / "lengths.csv"]
    write_text(files[0], evaluation.to_json(indent=2))
    rows = [{"result": r.label, **row} for r in evaluation.results for row in r.rows()]
    write_text(files[1], _csv(rows, list(rows[0]), lambda row, k: row[k]))
    if not _has_matplotlib():
        return files
    from .plots import plot_ballbar_lengths, plot_error_map

    plot_ballbar_lengths(evaluation.results, directory / "ballbar_lengths.png")
    files.append(directory / "ballbar_lengths.png")
    if maps is not None:
        plot_error_map(maps, directory / "error_map.png")
        files.append(directory / "error_map.png")
    return files


def write_fleet_files(run_dirs, evaluations, rows, directory, maps=None) -> list[Path]:
    """Write the evaluations of several runs into ``directory``: each run's
    files in a folder named after it (:func:`write_evaluation_files`),
    ``summary.csv`` (the ``rows`` of :func:`cmmpose.scale.fleet_summary`) and,
    with matplotlib and a trend to draw, ``trend.png``.

    Returns
    -------
    list of Path
        The files written.
    """
    directory = ensure_folder(directory)
    files = []
    for r, ev in zip(run_dirs, evaluations):
        files += write_evaluation_files(ev, directory / Path(r).name, maps)
    summary = directory / "summary.csv"
    write_text(summary, _csv(rows, list(rows[0].__dataclass_fields__), getattr))
    files.append(summary)
    if _has_matplotlib():
        from .plots import plot_fleet_trend

        try:
            plot_fleet_trend(rows, directory / "trend.png")
            files.append(directory / "trend.png")
        except InputError as exc:  # nothing to draw a trend of: the table and files stand
            _log.warning("no trend plot: %s", exc)
    return files
