"""Per-run work over a fleet of run folders, one task per run (:func:`map_runs`, :func:`evaluate_runs`,
:func:`diagnose_runs`); :func:`fleet_summary` tabulates the evaluations.
"""

from __future__ import annotations

import math
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path

from ..errormap import ErrorMapSet
from ..errors import Error, InputError, quoting
from .scheduler import SCHEDULER_TIMEOUT, gather_results, scheduler_client


def _on_run(func, run_dir: str, args: tuple, kwargs: dict):
    """``func(Run.load(run_dir), *args, **kwargs)`` on a worker; an error names the run."""
    from ..run import Run

    try:
        return func(Run.load(run_dir), *args, **kwargs)
    except Error as exc:
        if run_dir in str(exc):
            raise
        message, fields = quoting(exc, f"{run_dir}: ")
        raise type(exc)(message, **fields) from None


def map_runs(func, run_dirs, *shared, scheduler="threads", progress=None, scheduler_timeout: float = SCHEDULER_TIMEOUT,
             **kwargs) -> list:
    """``func(run, *shared, **kwargs)`` for every run folder, one task per
    run on the scheduler; the run is loaded on the worker.

    Parameters
    ----------
    func : callable
        Takes a :class:`cmmpose.Run` first; must pickle for worker processes
        (a module-level function).
    run_dirs : sequence of path-like
        Run folders (a cluster's workers must see them).
    *shared
        Arguments every call takes (maps, a model): sent to each worker once.
    scheduler : str or distributed.Client
        See :func:`scheduler_client`.
    progress : callable, optional
        ``progress(runs_done, runs_total)`` in this process.
    scheduler_timeout : float
        s: see :func:`scheduler_client`'s ``timeout``.
    **kwargs
        Small keyword arguments, sent with each task.

    Returns
    -------
    list
        ``func``'s results, in the order of ``run_dirs``.

    Raises
    ------
    RunError, Error
        The first run's error, its message naming the run folder.
    """
    run_dirs = [str(Path(r).absolute()) for r in run_dirs]  # a cluster's workers have another working folder
    if not run_dirs:
        raise InputError("run_dirs: no run folders given")
    with scheduler_client(scheduler, timeout=scheduler_timeout) as client:
        args = tuple(client.scatter(a, broadcast=True, hash=False) for a in shared)
        token = uuid.uuid4().hex[:8]
        futures = [client.submit(_on_run, func, r, args, kwargs, key=f"cmmpose-run-{i}-{Path(r).name}-{token}",
                                 pure=False)
                   for i, r in enumerate(run_dirs)]
        return gather_results(client, futures, progress)


def _maps_named_by(run):
    """The maps run.json names (the bundled thesis set), or RunError."""
    from ..errors import RunError

    if run.maps.get("kind") == "bundled" and run.maps.get("name") == "thesis":
        return ErrorMapSet.thesis().with_kinematics(run.maps.get("kinematics", "thesis"))
    raise RunError("run.json names no bundled maps: give the maps")


def _evaluate_run(run, maps, **kwargs):
    from ..evaluation.artefact import evaluate_artefact
    from ..evaluation.artefact_balls import is_artefact_run
    from ..evaluation.ballbar import evaluate

    if isinstance(maps, str) and maps == "run":
        maps = _maps_named_by(run)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if is_artefact_run(run):  # a plate or step gauge: deviations and length errors, not ballbar lengths
            options = {k: v for k, v in kwargs.items() if k in ("temperature", "reject", "out_of_range",
                                                                "temperature_tolerance", "log_hold")}
            ev = evaluate_artefact(run, maps, **options)
        else:
            ev = evaluate(run, maps, **kwargs)
    ev.provenance.setdefault("run", {})["created"] = run.created  # for the fleet's trend
    return ev


def evaluate_runs(run_dirs, maps="run", *, scheduler="threads", progress=None,
                  scheduler_timeout: float = SCHEDULER_TIMEOUT, **kwargs) -> list:
    """:func:`cmmpose.evaluate` of every run, one task per run.

    Parameters
    ----------
    run_dirs : sequence of path-like
        Run folders.
    maps : ErrorMap, ErrorMapSet, None or 'run'
        The compensation maps for every run (sent to each worker once), None
        for uncompensated only, or ``'run'``: the bundled maps each run.json
        names.
    scheduler, progress, scheduler_timeout
        As in :func:`map_runs`.
    **kwargs
        :func:`cmmpose.evaluate`'s options (temperature, reject, expansion,
        out_of_range, temperature_tolerance, log_hold).

    Returns
    -------
    list of Evaluation
        In the order of ``run_dirs``; warnings are in each one's
        ``provenance['notes']``.
    """
    return map_runs(_evaluate_run, run_dirs, maps, scheduler=scheduler, progress=progress,
                    scheduler_timeout=scheduler_timeout, **kwargs)


def _diagnose_run(run, model, temperature=None, **kwargs):
    import dataclasses

    from ..diagnosis import diagnose
    from ..model import Model

    if model is None or (isinstance(model, str) and model == "run"):
        model = Model(_maps_named_by(run), temperature=temperature)
    elif temperature is not None:
        model = dataclasses.replace(Model(model) if not isinstance(model, Model) else model,
                                    temperature=float(temperature))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return diagnose(run, model, **kwargs)


def diagnose_runs(run_dirs, model=None, *, scheduler="threads", progress=None,
                  scheduler_timeout: float = SCHEDULER_TIMEOUT, **kwargs) -> list:
    """:func:`cmmpose.diagnose` of every run, one task per run.

    Parameters
    ----------
    run_dirs : sequence of path-like
        Run folders.
    model : Model, ErrorMap, ErrorMapSet, None or 'run'
        The starting model for every run (sent to each worker once); None or
        ``'run'``: the bundled maps each run.json names (with their
        configuration).
    scheduler, progress, scheduler_timeout
        As in :func:`map_runs`.
    **kwargs
        :func:`cmmpose.diagnose`'s options (add, auto, max_effects,
        out_of_range, temperature_tolerance, log_hold, ...), and
        ``temperature`` (C) for the model instead of the runs' logs.

    Returns
    -------
    list of Diagnosis
        In the order of ``run_dirs``.
    """
    return map_runs(_diagnose_run, run_dirs, model, scheduler=scheduler, progress=progress,
                    scheduler_timeout=scheduler_timeout, **kwargs)


@dataclass(frozen=True)
class FleetRow:
    """One run of a fleet summary.

    Attributes
    ----------
    run : str
        The run folder.
    created : str
        When the run was made (ISO-8601 UTC, from its provenance), or ''.
    temperature : float
        Mean machine temperature over the run, C (NaN if unknown).
    rms_uncompensated, b89_uncompensated : float
        rms accuracy error and B89 value of the uncompensated lengths, mm;
        of an artefact run (``kind`` not 'ballbar'): the rms ball deviation
        and the largest |length error| (E) over all placements.
    rms_compensated, b89_compensated : float
        The same compensated, mm (NaN without maps).
    kind : str
        'ballbar', or the artefact's kind ('ball-plate', 'step-gauge', ...).
    """

    run: str
    created: str
    temperature: float
    rms_uncompensated: float
    b89_uncompensated: float
    rms_compensated: float
    b89_compensated: float
    kind: str = "ballbar"


def fleet_summary(run_dirs, evaluations) -> list[FleetRow]:
    """One :class:`FleetRow` per run from :func:`evaluate_runs`' results."""
    from ..evaluation.artefact import ArtefactEvaluation

    def artefact_figures(result):  # rms deviation and largest |E| of an artefact run, mm
        if result is None:
            return math.nan, math.nan
        worst = result.largest_length_error
        return result.rms, math.nan if worst is None else abs(worst.error)

    rows = []
    for r, ev in zip(run_dirs, evaluations):
        t = ev.provenance.get("temperature", {}).get("mean_C", math.nan)
        created = str(ev.provenance.get("run", {}).get("created", ""))
        if isinstance(ev, ArtefactEvaluation):
            rows.append(FleetRow(str(r), created, float(t), *artefact_figures(ev.uncompensated),
                                 *artefact_figures(ev.compensated), kind=ev.artefact.kind))
            continue
        c = ev.compensated
        rows.append(FleetRow(str(r), created, float(t),
                             ev.uncompensated.rms_accuracy_error, ev.uncompensated.b89,
                             math.nan if c is None else c.rms_accuracy_error, math.nan if c is None else c.b89))
    return rows
