"""Several runs together: one model, its machine and scanner parameters
shared by every run, each run with its own noise levels and nuisances.

A metrologist measures at several temperatures and poses and wants one
model. The joint problem stacks the runs' observables; each candidate
effect's sensitivity columns are stacked too (the same parameters act on
every run); each run keeps its own noise level per observable class; the
nuisances (bar length, ball and reference radii) are shared when the runs
measured the same artefact (``same_artefact=True``: then lengths taken at
different temperatures pin the artefact's expansion, which no single run
can) or kept per run. Selection, decisions and uncertainties are those of
:func:`cmmpose.diagnose` (forward selection by likelihood ratio, Bonferroni).
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..run import Run
from ._blas import one_blas_thread
from .aliases import find_alternatives
from .diagnose import (add_map_candidates, attach_floor, default_floor, residual_findings, run_holds,
                       select_effects, state_floor, unobservable_candidates, user_specs)
from .covariance import determined_values, model_covariance
from .identify import Problem, check_effect_names, rank_candidates
from .result import Diagnosis, Step
from .statistics import ALPHA
from ..model.point_inputs import single_map_warning
from ..model.domain import Domain
from ..model.model import Model, as_model, check_kinematics, run_kinematics
from ..evaluation.observables import CLASSES, ModelFigures, figures

__all__ = ["JointProblem", "JointDiagnosis", "check_distinct", "check_same_kinematics", "diagnose_jointly"]


@dataclass(frozen=True)
class JointObserved:
    """Each run's observables, and their residuals stacked (mm)."""

    parts: tuple
    residual: np.ndarray


class JointProblem(Problem):
    """The linearised diagnosis problem of several runs at one model (the
    interface :func:`rank_candidates` and :func:`fit_model` use).

    Parameters
    ----------
    model : Model
        The current model (its maps and effects act on every run).
    runs : sequence of Run
        Two or more runs.
    candidates : dict of str -> EffectSpec, optional
        Default: each run's library (its poses and thermocouple roles).
    same_artefact : bool
        The runs measured the same artefact: share the bar-length and radius
        nuisances.
    extra : sequence of EffectSpec
        Added to every run's candidates (user-defined effects).
    """

    def __init__(self, model, runs, candidates=None, *, same_artefact: bool = True,
                 extra=()):  # noqa: D107 - documented above
        self.runs = list(runs)
        self.parts = [Problem(model, r, candidates, extra=extra) for r in self.runs]
        # A shared effect must act on every run: a candidate that one run
        # cannot evaluate (it lacks the inputs, or the step fails) is skipped.
        self.candidates = {n: spec for n, spec in self.parts[0].candidates.items()
                           if all(n in p.candidates for p in self.parts)}
        self.skipped = {}
        for i, p in enumerate(self.parts):
            for n, why in p.skipped.items():
                self.skipped.setdefault(n, f"run {i + 1}: {why}")
        for p in self.parts:
            for n in p.candidates:
                if n not in self.candidates and n not in self.skipped:
                    lacking = [str(i + 1) for i, q in enumerate(self.parts) if n not in q.candidates]
                    self.skipped[n] = f"not every run can show it: run {', '.join(lacking)} lacks its inputs"
        k = len(CLASSES)
        self.classes = np.concatenate([p.classes + i * k for i, p in enumerate(self.parts)])
        self.n_class = np.concatenate([p.n_class for p in self.parts])
        self.n_eff = np.concatenate([p.n_eff for p in self.parts])
        self.class_floor = np.concatenate([p.class_floor for p in self.parts])
        sizes = [len(p.classes) for p in self.parts]
        offsets = np.r_[0, np.cumsum(sizes)[:-1]]
        self._class_rows = [rows + off for p, off in zip(self.parts, offsets) for rows in p._class_rows]
        # Nuisances: block-diagonal per run, the same-named ones merged when shared.
        n = int(sum(sizes))
        cols: dict[str, np.ndarray] = {}
        for i, (p, off) in enumerate(zip(self.parts, offsets)):
            for j, name in enumerate(p.nuisance_names):
                key = name if same_artefact else f"{name} (run {i + 1})"
                col = cols.setdefault(key, np.zeros(n))
                col[off:off + sizes[i]] += p.nuisance[:, j]
        self.nuisance_names = list(cols)
        self.nuisance = np.column_stack(list(cols.values())) if cols else np.zeros((n, 0))
        self.columns = {name: np.concatenate([p.columns[name] for p in self.parts]) for name in self.candidates}
        self.base = model
        parts = tuple(p.base_obs for p in self.parts)  # each part observed the model already
        self.base_obs = JointObserved(parts, np.concatenate([o.residual for o in parts]))
        self.layout = self.parts[0].layout  # for figures of the first run; each part keeps its own

    def observe(self, model) -> JointObserved:
        parts = tuple(p.observe(model) for p in self.parts)
        return JointObserved(parts, np.concatenate([o.residual for o in parts]))

    def _columns(self, model, spec, current, obs: JointObserved) -> np.ndarray:
        return np.concatenate([p._columns(model, spec, current, o) for p, o in zip(self.parts, obs.parts)])

    def figures(self, model, obs: JointObserved | None = None) -> list[ModelFigures]:
        """Each run's ballbar and sphere figures under ``model``."""
        obs = self.observe(model) if obs is None else obs
        return [figures(p.layout, None, model, observed=o) for p, o in zip(self.parts, obs.parts)]


@dataclass
class JointDiagnosis(Diagnosis):
    """:class:`Diagnosis` of several runs together. ``steps[i].figures`` are
    the first run's; ``steps[i].run_figures`` and ``run_figures[i]`` hold
    every run's at step i (``to_dict``: each step's ``runs``, named)."""

    run_figures: list = field(default_factory=list)
    run_names: list = field(default_factory=list)

    def history(self) -> list[dict]:
        out = []
        for s, per_run in zip(self.steps, self.run_figures):
            row = {"label": s.label}
            for name, f in zip(self.run_names, per_run):
                what, value = f.headline  # an artefact run's rms deviation, a ballbar run's rms accuracy error
                row[f"{name}: {what.replace(' ', '_')}_um"] = value * 1e3
            out.append(row)
        return out

    def to_dict(self) -> dict:
        d = super().to_dict()
        for step, per_run in zip(d["steps"], self.run_figures):  # every run's figures at each step, named
            step["runs"] = [{"run": name, **f.to_dict()} for name, f in zip(self.run_names, per_run)]
        d["runs"] = list(self.run_names)
        d["run_figures"] = [[f.to_dict() for f in per_run] for per_run in self.run_figures]
        return d

@one_blas_thread
def diagnose_jointly(runs, maps: Model | ErrorMap | ErrorMapSet | None = None, *, add=(), auto: bool = True,
                     max_effects: int = 4, user_effects=(), same_artefact: bool = True,
                     run_names=None, map_corrections: bool = True, reproducibility_um=None,
                     reproducibility_source: str = "stated",
                     default_reproducibility_um: float | None = None, machine=None,
                     patterns: bool = True) -> JointDiagnosis:
    """One model for several runs: the effects' parameters shared, each run
    with its own noise levels (and its own nuisances unless ``same_artefact``).

    Parameters
    ----------
    runs : sequence of Run
        Two or more runs (different temperatures, poses, layouts).
    maps : Model, ErrorMap or ErrorMapSet, optional
        What compensates at the start (a saved Model, or maps alone);
        default the thesis maps.
    add : sequence of str
        Effects to add first, whether significant or not.
    auto : bool
        Then keep adding the most significant candidate.
    max_effects : int
        Most effects added automatically.
    user_effects : sequence of UserEffect
        Extra candidates.
    same_artefact : bool
        The runs measured the same artefact: one bar length and one ball
        radius for all (lengths at different temperatures then pin the
        artefact's expansion).
    run_names : sequence of str, optional
        Names of the runs in tables and messages (default run 1, run 2,
        ...; messages name a loaded run by its directory).
    reproducibility_um : float or sequence of float, optional
        Stated per-scan centre reproducibility, um per axis: one for every
        run, or one per run (None entries: not stated for that run). A run
        that repeats scans measures its own (Type A); a run with neither
        takes its spheres' fit scatter, a lower bound
        (:mod:`cmmpose.diagnosis.floor`).
    reproducibility_source : str
        Where a stated value comes from, in the noise floor's words.
    default_reproducibility_um : float, optional
        The machine's stated reproducibility, um per axis: the floor of each
        run that repeats no scan when ``reproducibility_um`` is not given.
    machine : cmmpose.machine.Machine, optional
        Where the "next" advice for an open ambiguity set looks for the
        placement that tells its members apart (default the thesis machine).
    patterns : bool
        Also look in each run's residuals under the final model for what it
        leaves unexplained (periodic errors, significant residual patterns;
        each family at ALPHA over the runs together, Bonferroni), named by
        run in ``unexplained``.

    Returns
    -------
    JointDiagnosis

    Raises
    ------
    InputError
        A run given twice (:func:`check_distinct`), runs on different
        machine configurations (:func:`check_same_kinematics`), or a
        starting model stacked for another configuration than the runs',
        each naming the runs.
    """
    t0 = time.perf_counter()
    runs = list(runs)
    if len(runs) < 2:
        raise InputError(f"runs: a joint diagnosis needs two or more runs, got {len(runs)}")
    for i, r in enumerate(runs):
        if not isinstance(r, Run):
            raise InputTypeError(f"runs[{i}]: expected a cmmpose.Run, got {type(r).__name__}")
    names = list(run_names) if run_names is not None else [f"run {i + 1}" for i in range(len(runs))]
    labels = [n if run_names is not None else (r.source or n) for r, n in zip(runs, names)]
    check_distinct(runs, labels)
    kinematics = check_same_kinematics(runs, labels)
    model = as_model(maps, kinematics)
    for r, label in zip(runs, labels):
        check_kinematics(model, r, label)
    problem = JointProblem(model, runs, same_artefact=same_artefact, extra=user_specs(list(user_effects)))
    if reproducibility_um is None and default_reproducibility_um is not None:
        reproducibility_um = default_floor(problem, default_reproducibility_um)
    state_floor(problem, reproducibility_um)  # each run's headline noise never below its floor
    for p, label in zip(problem.parts, labels):  # as evaluating each run with the map alone warns
        single_map_warning(model, p.inputs.temperature, label)
    if map_corrections:
        add_map_candidates(problem, model)
    check_effect_names(list(add), problem)

    def step(label, m, forced):
        obs = problem.base_obs if m is problem.base else problem.observe(m)
        per_run = problem.figures(m, obs)  # every run's figures (a look past an open set is a step too, unkept)
        return Step(label, m, per_run[0], rank_candidates(problem, m, obs), forced, residual=obs.residual,
                    run_figures=per_run)

    steps, model = select_effects(problem, model, list(add), auto, max_effects, step)
    unobservable, advice, ambiguous = unobservable_candidates(problem, steps)
    final_unc, final_cov = model_covariance(problem, model)
    diag = JointDiagnosis(steps, unobservable, ambiguous, n_points=sum(r.n_points for r in runs),
                          advice=advice, final_uncertainty=final_unc, final_covariance=final_cov,
                          final_values=determined_values(problem, model),
                          domain=Domain.of_runs(runs, [p.inputs for p in problem.parts], model.maps.kinematics),
                          skipped=dict(problem.skipped),
                          run_figures=[s.run_figures for s in steps], run_names=names, run_has=run_holds(problem))
    diag.alternatives = find_alternatives(problem, steps, model)
    attach_floor(diag, problem, steps[-1], reproducibility_um, reproducibility_source)
    if patterns:
        diag.unexplained = _unexplained(problem, runs, names, model)
    if map_corrections:  # what the runs together determine of each map component (mapfamily)
        from .mapfamily import component_report

        diag.components = component_report(problem, model)
    if diag.open_ambiguity:
        from .plan import separating_measurement

        separating_measurement(diag, runs, machine)
    diag.elapsed = time.perf_counter() - t0
    return diag


def _unexplained(problem, runs, names, model) -> list:
    """What the final model leaves unexplained in each run's residuals (periodic errors, significant
    patterns: :func:`cmmpose.diagnosis.diagnose.residual_findings`), each finding named by its run. Each
    family is tested at ALPHA over the runs together (ALPHA / runs in each), so a joint diagnosis claims no
    more often than one run's."""
    out = []
    for part, run, name in zip(problem.parts, runs, names):
        _, found = residual_findings(part, run, model, alpha=ALPHA / len(runs))
        out += [dataclasses.replace(f, description=f"{name}: {f.description}") for f in found]
    return out


def _fingerprint(run: Run) -> tuple:
    """What tells two runs' data apart cheaply: the point count and a hash of
    run.json's records (artefact, maps, metadata, thermocouples; not the
    time it was written) and of the tables' numeric columns (points, scans,
    poses, thermocouple log). Two measurements never repeat bit for bit; a copied
    run directory does."""
    h = hashlib.blake2b(digest_size=16)
    h.update(repr((run.artefact, run.maps, run.metadata, run.temperature_channels)).encode())
    for table in (run.points, run.scans, run.poses, run.temperatures or {}):
        for name in sorted(table):
            col = np.asarray(table[name])
            if col.dtype.kind in "biuf":
                h.update(name.encode())
                h.update(np.ascontiguousarray(col).tobytes())
    return run.n_points, h.hexdigest()


def check_distinct(runs, labels) -> None:
    """Refuse a run given more than once to a joint diagnosis: the same
    object, the same directory (resolved), or the same data (identical
    run.json records and tables, e.g. a copied folder). Counted twice, its observations
    would divide every uncertainty by sqrt 2 and weigh it double.

    Raises
    ------
    InputError
        Naming both runs.
    """
    seen: dict = {}
    for i, r in enumerate(runs):
        keys = [("object", id(r))]
        if r.source is not None:
            keys.append(("directory", str(Path(r.source).resolve())))
        keys.append(("data", _fingerprint(r)))
        for key in keys:
            j = seen.get(key)
            if j is not None:
                what = {"object": "the same run", "directory": "the same run directory",
                        "data": "the same measurement (identical run.json and tables: a copy of one run)"}[key[0]]
                raise InputError(f"runs: {labels[j]} and {labels[i]} are {what}: a joint diagnosis would count its "
                                 f"observations twice and shrink every uncertainty by sqrt 2; give each run once")
            seen[key] = i


def check_same_kinematics(runs, labels) -> str | None:
    """The machine configuration the runs' run.json files name (None when
    none names one); runs naming different ones are refused: one model's
    maps are stacked one way (:func:`cmmpose.model.model.check_kinematics`).

    Raises
    ------
    InputError
        Naming two runs that differ and their configurations.
    """
    named = [(label, run_kinematics(r)) for r, label in zip(runs, labels)]
    named = [(label, k) for label, k in named if k is not None]
    for label, k in named[1:]:
        if k != named[0][1]:
            raise InputError(f"runs: {named[0][0]} was measured on a machine configured as {named[0][1]!r}, "
                             f"{label} on one configured as {k!r}: one model cannot hold both (its maps are "
                             f"stacked one way); diagnose them separately")
    return named[0][1] if named else None
