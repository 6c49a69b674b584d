"""Ballbar evaluation of a measurement run (thesis chapter 6): fit every ball,
take the centre distance per position, and report the length statistics,
uncompensated and compensated."""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from .._json import dumps as strict_json
from ..compensation import uncompensated
from ..errormap import ErrorMap, ErrorMapSet, warn_single_map
from ..errors import InputError, InputTypeError, MapTemperatureWarning, RunError
from ..fitting import fit_spheres
from .metrics import STEEL_EXPANSION, STEEL_EXPANSION_PPM_PER_K, b89_value, improvement, length_at_20c, rms_accuracy_error
from ..run import Run
from .observables import figures_difference
from ..temperature import (LOG_HOLD, TEMPERATURE_TOLERANCE, TemperaturePolicy, as_policy, log_notes,  # noqa: F401
                          log_provenance, run_temperatures)

_log = logging.getLogger("cmmpose.evaluation.ballbar")


@dataclass(frozen=True)
class SphereResult:
    """One fitted ball: ``centre`` (3,) and ``radius`` in mm, fit ``rms`` and
    ``form`` (max - min residual) in mm, ``n_points`` used, ``rejected`` points,
    and the ISO 10360-8 style probing errors: form ``pf`` = form, size ``ps`` =
    radius - nominal radius (mm; NaN without a nominal)."""

    position: int
    ball: int
    scan_id: int
    centre: np.ndarray
    radius: float
    rms: float
    form: float
    n_points: int
    rejected: int
    pf: float
    ps: float


@dataclass(frozen=True)
class BallbarResult:
    """The ballbar lengths of one evaluation (one model).

    Attributes
    ----------
    label : str
        'uncompensated' or 'compensated'.
    positions : ndarray (P,)
        Position numbers.
    lengths : ndarray (P,)
        Centre distances, mm.
    temperatures : ndarray (P,)
        Mean machine temperature while each position was scanned, C (NaN if unknown).
    spheres : tuple of SphereResult
        Both balls of every position.
    expansion : float
        Part expansion coefficient used for lengths at 20 C, 1/K.
    """

    label: str
    positions: np.ndarray
    lengths: np.ndarray
    temperatures: np.ndarray
    spheres: tuple[SphereResult, ...] = field(repr=False)
    expansion: float = STEEL_EXPANSION

    @property
    def mean_length(self) -> float:
        """Mean length, mm."""
        return float(np.mean(self.lengths))

    @property
    def rms_accuracy_error(self) -> float:
        """Sample standard deviation (n - 1) of the lengths, mm (eq. 36)."""
        return rms_accuracy_error(self.lengths)

    @property
    def b89(self) -> float:
        """Largest |L - mean|, mm."""
        return b89_value(self.lengths)

    @property
    def lengths_at_20c(self) -> np.ndarray:
        """Lengths at 20 C, mm (NaN where the temperature is unknown)."""
        return length_at_20c(self.lengths, self.temperatures, self.expansion)

    @property
    def mean_length_at_20c(self) -> float:
        return float(np.mean(self.lengths_at_20c))

    def rows(self) -> list[dict]:
        """One dict per position: lengths and both balls' fit figures (mm)."""
        balls = {(s.position, s.ball): s for s in self.spheres}
        out = []
        for p, length, l20 in zip(self.positions.tolist(), self.lengths, self.lengths_at_20c):
            row = {"position": p, "length_mm": float(length), "length_20C_mm": float(l20),
                   "deviation_um": float((length - self.mean_length) * 1e3)}
            for b in (1, 2):
                s = balls[(p, b)]
                row |= {f"ball{b}_{k}": v for k, v in (("x_mm", s.centre[0]), ("y_mm", s.centre[1]), ("z_mm", s.centre[2]),
                                                        ("radius_mm", s.radius), ("fit_mm", s.rms), ("form_mm", s.form),
                                                        ("points", s.n_points))}
            out.append(row)
        return out

    def summary(self) -> dict:
        return {"label": self.label, "positions": len(self.positions), "mean_length_mm": self.mean_length,
                "rms_accuracy_error_mm": self.rms_accuracy_error, "b89_mm": self.b89,
                "mean_length_20C_mm": self.mean_length_at_20c}


@dataclass(frozen=True)
class Evaluation:
    """Uncompensated and (optionally) compensated ballbar results of one run,
    with ``provenance``: what produced them (maps, temperatures and how they
    were chosen, poses, expansion coefficient, policy, version, date)."""

    uncompensated: BallbarResult
    compensated: BallbarResult | None = None
    provenance: dict = field(default_factory=dict, compare=False)

    @property
    def results(self) -> tuple[BallbarResult, ...]:
        return tuple(r for r in (self.uncompensated, self.compensated) if r is not None)

    @property
    def skipped(self) -> list[dict]:
        """Positions and scans left out as incomplete or ambiguous (``evaluate(..., skip_incomplete=True)``)."""
        return list(self.provenance.get("skipped", []))

    @property
    def improvement_rms(self) -> float | None:
        """1 - compensated / uncompensated rms accuracy error."""
        c = self.compensated
        return None if c is None else improvement(self.uncompensated.rms_accuracy_error, c.rms_accuracy_error)

    @property
    def improvement_b89(self) -> float | None:
        c = self.compensated
        return None if c is None else improvement(self.uncompensated.b89, c.b89)

    def to_dict(self) -> dict:
        """Results rounded to what they mean (docs/formats.md): lengths and
        centres to 0.01 um, deviations and figures to 0.001 um, temperatures
        to 0.001 C, ratios to 1e-4; plus the provenance."""
        return {
            "results": [rounded_dict({**r.summary(), "rows": r.rows()}) for r in self.results],
            "improvement_rms": _round(self.improvement_rms, 4),
            "improvement_b89": _round(self.improvement_b89, 4),
            "provenance": self.provenance,
        }

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def to_pandas(self):
        """One row per (result, position); pandas is needed only here."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("to_pandas needs pandas: pip install pandas") from None

        return pd.DataFrame([{"result": r.label, **row} for r in self.results for row in r.rows()])

    def __rich__(self):
        from rich.markup import escape
        from rich.table import Table

        t = Table(title="Ballbar evaluation")
        t.add_column("position", justify="right")
        for r in self.results:
            t.add_column(f"{r.label}\nlength (mm)", justify="right")
            t.add_column("dev (um)", justify="right")
        rows = [r.rows() for r in self.results]
        for i, p in enumerate(self.uncompensated.positions.tolist()):
            cells = [str(p)]
            for rr in rows:
                cells += [f"{rr[i]['length_mm']:.4f}", f"{rr[i]['deviation_um']:+.1f}"]
            t.add_row(*cells)
        t.add_section()
        for name, get, fmt in (("mean (mm)", lambda r: r.mean_length, "{:.4f}"),
                               ("rms accuracy error (um)", lambda r: r.rms_accuracy_error * 1e3, "{:.1f}"),
                               ("B89 (um)", lambda r: r.b89 * 1e3, "{:.1f}"),
                               ("mean at 20 C (mm)", lambda r: r.mean_length_at_20c, "{:.4f}")):
            cells = [name]
            for r in self.results:
                cells += [fmt.format(get(r)), ""]
            t.add_row(*cells)
        caption = [f"lengths at 20 C with expansion {self.uncompensated.expansion * 1e6:g} ppm/K"]
        if self.compensated is not None:
            caption.insert(0, f"improvement: rms {self.improvement_rms:.1%}, B89 {self.improvement_b89:.1%}")
        for note in self.provenance.get("notes", []):
            caption.append(escape(str(note)))  # notes name runs and files: text, not Rich markup
        t.caption = "\n".join(caption)
        return t

    def __str__(self) -> str:
        from rich.console import Console

        console = Console(width=110, record=True, file=open("/dev/null", "w"))  # noqa: SIM115 - render to text only
        console.print(self)
        return console.export_text()


def machine_temperature(run: Run, t, log_hold: float | None = None, *,
                        temperature_policy: TemperaturePolicy | None = None) -> np.ndarray:
    """Machine mean temperature (C) at times ``t`` (s): the mean of the clean
    axis-scale thermocouples (thesis section 6.4), interpolated in time; stuck,
    open-circuit and implausible channels are left out
    (:func:`cmmpose.temperature.run_temperatures`). Points up to ``log_hold``
    s (default the policy's, 120 s) outside the log take its nearest reading."""
    return run_temperatures(run, t, temperature_policy, log_hold=log_hold)[0]


def machine_temperature_and_log(run: Run, t, log_hold: float | None = None, *,
                                temperature_policy: TemperaturePolicy | None = None) -> tuple[np.ndarray, dict]:
    """:func:`machine_temperature` and what was done to the log to get it,
    for the provenance (:func:`cmmpose.temperature.log_provenance`): channels
    used, each channel dropped (role, why, samples, action), the points held
    past the log's ends (how many, how many seconds), the channels each
    axis role read, and the log side of the policy."""
    return run_temperatures(run, t, temperature_policy, log_hold=log_hold)


def machine_coordinates(run: Run, maps, temperature, policy: TemperaturePolicy | None = None,
                        reports: list | None = None, once: set | None = None) -> np.ndarray:
    """All points in machine coordinates, compensated with ``maps`` (any
    :class:`cmmpose.model.MachineModel`: maps, or a found model, which reads
    the run's inputs itself) or not (None), under ``policy`` (the
    :class:`cmmpose.TemperaturePolicy`, handed to the kernel whole; None: the
    model's own); the kernel reports are appended to ``reports``.
    ``temperature``: C, one or per point (None: a single map's own, or a
    model's reading of the run's log)."""
    if maps is None:
        return uncompensated_coordinates(run)
    return maps.compensate_run(run, temperature, policy=policy, reports=reports, compare=figures_difference(run),
                               once=once)


def uncompensated_coordinates(run: Run) -> np.ndarray:
    """All points as the digitizer software reports them (no map), mm."""
    out = np.empty((run.n_points, 3))
    for rows, pose, offset in run.points_by_pose():
        out[rows] = uncompensated(run.uv[rows], run.scales[rows], pose, offset)
    return out


def ballbar_scans(run: Run, skip_incomplete: bool = False) -> tuple[dict[int, dict[int, int]], list[dict]]:
    """The scans of each complete ballbar position of ``run``, and what was skipped.

    A scan with ``position`` -1 and ``ball`` -1 is not a ballbar scan (a
    reference sphere, an unknown feature) and is left out silently. Every
    other scan must be ball 1 or 2 of a position >= 0, with points, and each
    position needs exactly one scan of each ball. A position with a ball
    missing, duplicated or mislabelled (``ball`` 3, or its scan moved to
    ``position`` -1), or a scan without points, is incomplete or ambiguous.
    A run that declares repeated scans (``metadata['repeat_scans']``: scans
    of a ball again, the bar not moved, for the noise floor) may have up to
    that many second scans of a ball: the first scan of each ball gives the
    length, the repeats measure reproducibility (the diagnosis's floor).

    Parameters
    ----------
    run : Run
        The run.
    skip_incomplete : bool
        False (default): an incomplete or ambiguous position raises
        ``RunError`` naming the position, ball and scan. True: it is
        skipped and listed.

    Returns
    -------
    positions : dict
        ``{position: {1: scan_id, 2: scan_id}}`` of the complete positions.
    skipped : list of dict
        One per skipped position or stray scan: ``position`` (None for a
        scan that names none), ``scan_ids`` and ``reason``.

    Raises
    ------
    RunError
        Without ``skip_incomplete``: every incomplete or ambiguous position
        (up to 10 listed) and how to skip them.
    """
    scans = run.scans
    with_points = set(np.unique(run.points["scan_id"]).tolist())
    by_pos: dict[int, dict[int, list[int]]] = {}
    problems: dict = {}  # position (or ('scan', id)) -> reasons
    for scan_id, pos, ball in zip(scans["scan_id"].tolist(), scans["position"].tolist(), scans["ball"].tolist()):
        if pos == -1 and ball == -1:
            continue
        if pos < 0:
            problems.setdefault(("scan", scan_id), []).append(
                f"scan {scan_id} (position {pos}, ball {ball}) names no position (expected a position >= 0 with "
                f"ball 1 or 2, or position -1 and ball -1 for a scan that is no ballbar ball)")
            continue
        if ball not in (1, 2):
            problems.setdefault(pos, []).append(f"position {pos}: scan {scan_id} has ball {ball} (expected 1 or 2)")
            continue
        if scan_id not in with_points:
            problems.setdefault(pos, []).append(f"position {pos} ball {ball}: scan {scan_id} has no points")
            continue
        by_pos.setdefault(pos, {}).setdefault(ball, []).append(scan_id)
    repeats = int((run.metadata or {}).get("repeat_scans", 0) or 0)
    if repeats and sum(len(ids) - 1 for balls in by_pos.values() for ids in balls.values()) <= repeats:
        # The declared repeats are the run's last scans: each ball's first scan gives the length. A ball
        # scanned twice before them is not a repeat but a mislabelled or duplicated scan (ambiguous).
        tail = set(sorted(i for balls in by_pos.values() for ids in balls.values() for i in ids)[-repeats:])

        def first(ids):
            main = [i for i in sorted(ids) if i not in tail]
            return main if len(main) > 1 else (main or sorted(ids))[:1]

        by_pos = {p: {b: first(ids) for b, ids in balls.items()} for p, balls in by_pos.items()}
    for pos in sorted(set(by_pos) | {p for p in problems if not isinstance(p, tuple)}):
        balls = by_pos.get(pos, {})
        for b in (1, 2):
            ids = balls.get(b, [])
            if len(ids) > 1:
                problems.setdefault(pos, []).append(f"position {pos} ball {b}: scans {', '.join(map(str, ids))} "
                                                    f"(duplicated: which one is the ball is ambiguous)")
            elif not ids:
                other = balls.get(3 - b, [])
                has = f" (ball {3 - b} is scan {', '.join(map(str, other))})" if other else ""
                problems.setdefault(pos, []).append(f"position {pos} ball {b}: no scan{has}")
    complete = {p: {b: ids[0] for b, ids in balls.items()} for p, balls in by_pos.items() if p not in problems}
    skipped = []
    for key, reasons in sorted(problems.items(), key=lambda kv: (isinstance(kv[0], tuple), str(kv[0]))):
        if isinstance(key, tuple):
            skipped.append({"position": None, "scan_ids": [key[1]], "reason": "; ".join(reasons)})
        else:
            ids = sorted({int(s) for s in scans["scan_id"][scans["position"] == key].tolist()})
            skipped.append({"position": int(key), "scan_ids": ids, "reason": "; ".join(reasons)})
    if skipped and not skip_incomplete:
        lines = [s["reason"] for s in skipped]
        more = f"; and {len(lines) - 10} more" if len(lines) > 10 else ""
        raise RunError(f"run: {len(lines)} incomplete or ambiguous ballbar position(s) or scan(s): "
                       + "; ".join(lines[:10]) + more, option="skip_incomplete", remedy="skip_incomplete")
    for s in skipped:
        _log.info("skipped %s: %s", "scan" if s["position"] is None else f"position {s['position']}", s["reason"])
    return dict(sorted(complete.items())), skipped


def skipped_note(skipped: list[dict]) -> str | None:
    """One line naming the skipped positions and scans (None when nothing was skipped)."""
    if not skipped:
        return None
    return "skipped (incomplete or ambiguous): " + "; ".join(s["reason"] for s in skipped)


def _ballbar(run: Run, xyz: np.ndarray, label: str, temps: np.ndarray, nominal_radius, reject, expansion,
             positions: dict[int, dict[int, int]]) -> BallbarResult:
    """The lengths of the complete ``positions`` (:func:`ballbar_scans`) from the points ``xyz`` (mm)."""
    complete = sorted(positions)
    if len(complete) < 2:
        raise InputError(f"run: needs at least 2 positions with both balls scanned, found {len(complete)}")
    sid = run.points["scan_id"]
    keep = np.isin(sid, [s for p in complete for s in positions[p].values()])
    fits = fit_spheres(xyz[keep], sid[keep], reject=reject)  # only the positions' balls
    by_pos: dict[int, dict[int, SphereResult]] = {}
    point_t: dict[int, list[int]] = {}
    for pos in complete:
        for ball in (1, 2):
            scan_id = positions[pos][ball]
            f = fits[scan_id]
            ps = f.radius - nominal_radius if nominal_radius is not None else float("nan")
            by_pos.setdefault(pos, {})[ball] = SphereResult(pos, ball, scan_id, f.centre, f.radius, f.rms, f.form,
                                                            f.n_points, f.rejected, f.form, ps)
            point_t.setdefault(pos, []).append(scan_id)
    lengths = np.array([np.linalg.norm(by_pos[p][2].centre - by_pos[p][1].centre) for p in complete])
    pos_temps = np.array([float(np.mean(temps[np.isin(sid, point_t[p])])) if temps is not None else np.nan for p in complete])
    spheres = tuple(by_pos[p][b] for p in complete for b in (1, 2))
    return BallbarResult(label, np.array(complete), lengths, pos_temps, spheres, expansion)


def evaluate(
    run: Run,
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: float | None = None,
    *,
    nominal_radius: float | None = None,
    reject: float | None = None,
    expansion_ppm_per_K: float = STEEL_EXPANSION_PPM_PER_K,
    out_of_range: str | None = None,
    temperature_tolerance: float | None = None,
    log_hold: float | None = None,
    skip_incomplete: bool = False,
    temperature_policy: TemperaturePolicy | None = None,
) -> Evaluation:
    """Ballbar evaluation of ``run``: uncompensated, and compensated with ``maps``.

    Parameters
    ----------
    run : Run
        A ballbar run: scans with ``position`` and ``ball`` (1, 2).
    maps : ErrorMap, ErrorMapSet or Model, optional
        The compensation model's maps. None: uncompensated only. Or a model
        a diagnosis found (``cmmpose.Model.load('m.json')``): its maps and
        effects, each reading its inputs from the run (thermocouple roles,
        time stamps; one the run lacks is an ``InputError`` naming it).
    temperature : float, optional
        Machine temperature, C, for all points. Default: the machine mean from
        the run's thermocouple log at each point's time stamp (thesis policy).
    nominal_radius : float, optional
        Ball radius for the probing size error, mm; default the run's
        ``artefact['ball_radius_mm']`` if present.
    reject : float, optional
        Robust sphere fits (see ``fit_sphere``), e.g. 3.5 to drop bar points.
    expansion_ppm_per_K : float
        Part expansion coefficient for lengths at 20 C, ppm/K (steel 12);
        printed with the results and kept in the provenance.
    out_of_range : {'raise', 'clamp', 'extrapolate'}, optional
        Temperatures farther than ``temperature_tolerance`` outside the maps
        (and readings outside them) raise, are clamped with a warning, or
        (temperatures) are extrapolated linearly; overrides the policy's.
    temperature_tolerance : float, optional
        K: temperatures this close outside the maps are held at the edge
        (a log at 19.99 C against maps from 20 C) and counted; overrides
        the policy's.
    log_hold : float, optional
        s: points this far outside the thermocouple log (a recovered run)
        take its nearest reading; farther raise; overrides the policy's.
    skip_incomplete : bool
        A position with a ball scan missing, duplicated or mislabelled
        (:func:`ballbar_scans`) raises ``RunError`` naming it; True skips
        such positions instead and lists them in ``provenance['skipped']``
        and its notes.
    temperature_policy : TemperaturePolicy, optional
        How the log becomes temperatures and what happens at the edges
        (cmmpose.temperature); default ``TemperaturePolicy()``. Channels
        dropped, points held and the channels each role read go into
        ``provenance['temperature']['log']`` and the notes.

    Returns
    -------
    Evaluation

    Raises
    ------
    RunError
        An incomplete or ambiguous position, without ``skip_incomplete``.
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    if run.artefact.get("kind", "ballbar") != "ballbar":  # its balls are not bars' ends (docs/artefacts.md)
        raise InputError(f"run: measured a {run.artefact.get('kind')!r}, not a ballbar: evaluate it with "
                         f"cmmpose.evaluation.artefact.evaluate_artefact (cmmpose evaluate does)")
    policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance,
                       log_hold=log_hold)
    out_of_range, temperature_tolerance, log_hold = policy.out_of_range, policy.temperature_tolerance, policy.log_hold
    if not (isinstance(expansion_ppm_per_K, (int, float)) and np.isfinite(expansion_ppm_per_K)):
        raise InputError(f"expansion_ppm_per_K: expected a finite coefficient in ppm/K, got {expansion_ppm_per_K!r}",
                         option="expansion_ppm_per_K", cli_option="--expansion")
    expansion = expansion_ppm_per_K * 1e-6  # 1/K from here on (BallbarResult.expansion)
    if nominal_radius is None:
        nominal_radius = run.artefact.get("ball_radius_mm")
    if maps is not None:  # a model's own log policy gives way to the caller's
        maps = maps.with_policy(log_hold=log_hold)
    temps, log = None, None
    if temperature is not None:
        temps = np.full(run.n_points, float(temperature))
    elif run.temperatures is not None:
        temps, log = run_temperatures(run, run.points["t"], policy)
    if not isinstance(skip_incomplete, bool):
        raise InputError(f"skip_incomplete: expected True or False, got {skip_incomplete!r}")
    positions, skipped = ballbar_scans(run, skip_incomplete)
    prov = evaluation_provenance(run, maps, temperature, temps, expansion, out_of_range, temperature_tolerance, log_hold)
    _note_inputs(prov, maps, log, skipped)
    raw = _ballbar(run, machine_coordinates(run, None, None), "uncompensated", temps, nominal_radius, reject, expansion,
                   positions)
    if maps is None:
        return Evaluation(raw, provenance=prov)
    if temps is None and isinstance(maps.error_maps, ErrorMapSet):
        raise InputError("temperature: the run has no temperature log; give the machine temperature (C)")
    model_t = _model_temperature(maps, temperature, temps, temperature_tolerance, prov)
    reports: list = []
    xyz = machine_coordinates(run, maps, model_t, policy, reports)
    comp = _ballbar(run, xyz, "compensated", temps, nominal_radius, reject, expansion, positions)
    _count_kernel_reports(prov, reports, temperature_tolerance)
    return Evaluation(raw, comp, provenance=prov)


def _note_inputs(prov: dict, maps, log, skipped) -> None:
    """What the provenance says of the evaluation's inputs: the thermocouple log's use, the positions skipped,
    a model's own artefact expansion (not the one the lengths use)."""
    if log is not None:
        prov["temperature"]["log"] = log
        prov["notes"].extend(log_notes(log))
    prov["skipped"] = skipped
    if maps is not None and maps.expansion_ppm_per_kelvin:
        prov["notes"].append(f"the model's artefact-expansion ({maps.expansion_ppm_per_kelvin:+.3g} ppm/K) describes "
                             f"the artefact it was found on: the lengths at 20 C use the expansion given here")
    if skipped:
        prov["notes"].append(skipped_note(skipped))


def _model_temperature(maps, temperature, temps, tolerance: float, prov: dict):
    """The temperature the model is applied at: a found model reads the run's log itself (the caller's value
    only); one map holds at its own temperature (None: a warning, noted, when the run's differs); a set takes
    the given temperature or the run's."""
    if maps.reads_run:  # a found model reads the run's log itself, with the caller's policy
        return temperature
    if isinstance(maps, ErrorMap):
        if temps is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", MapTemperatureWarning)
                note = warn_single_map(maps, temps, tolerance)
            if note:
                warnings.warn(note, MapTemperatureWarning, stacklevel=3)  # the caller of evaluate
                prov["notes"].append(note)
        return None
    return temperature if temperature is not None else temps


def _count_kernel_reports(prov: dict, reports: list, tolerance: float) -> None:
    """The compensation's counts into the provenance, with a note for each that is not zero: points held at
    the maps' edge, clamped into them, temperatures extrapolated beyond them."""
    held = sum(r.held_temperature for r in reports)
    clamped = sum(r.clamped_points for r in reports)
    extrapolated = sum(r.extrapolated_temperature for r in reports)
    prov["points_held_at_maps_edge"] = int(held)
    prov["points_clamped"] = int(clamped)
    prov["points_extrapolated"] = int(extrapolated)
    if extrapolated:
        prov["max_extrapolation_K"] = round(max(r.max_extrapolation for r in reports), 3)
    if held:
        prov["notes"].append(f"{held} points within {tolerance:g} K outside the maps' temperatures "
                             f"were held at the edge")
    if clamped:
        prov["notes"].append(f"{clamped} points were clamped into the maps")
    if extrapolated:
        prov["notes"].append(f"{extrapolated} temperatures extrapolated beyond the maps, up to "
                             f"{prov['max_extrapolation_K']:g} K")


def evaluation_provenance(run: Run, maps, temperature, temps, expansion, out_of_range, tolerance, log_hold) -> dict:
    """What produced an evaluation, for its JSON."""
    from .. import __version__

    m = {"kind": "none"} if maps is None else maps.provenance()
    if run.maps:
        m["run_says"] = run.maps
    if temperature is not None:
        source = "given for every point"
    elif temps is not None:
        source = "run thermocouple log: machine mean of the axis-scale channels at each point's time (thesis 6.4)"
    else:
        source = "none (no log)"
    t = {"source": source}
    if temps is not None and len(temps):
        t |= {"min_C": round(float(np.min(temps)), 3), "max_C": round(float(np.max(temps)), 3),
              "mean_C": round(float(np.mean(temps)), 3)}
    poses = []
    for p in run.poses["pose_id"].tolist():
        pose, offset = run.pose(int(p))
        poses.append({"pose_id": int(p), "alpha_beta_gamma_deg": [round(float(x), 6) for x in pose],
                      "offset_mm": [round(float(x), 6) for x in offset]})
    return {
        "cmmpose_version": __version__,
        "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "run": {"points": int(run.n_points), "scans": int(len(run.scans["scan_id"])),
                "metadata": {k: v for k, v in run.metadata.items() if isinstance(v, (str, int, float, bool))}},
        "maps": m,
        "temperature": t,
        "policy": {"out_of_range": out_of_range, "temperature_tolerance_K": tolerance, "log_hold_s": log_hold},
        "expansion_ppm_per_K": round(expansion * 1e6, 6),
        "poses": poses,
        "notes": [],
    }


def _round(x, digits: int):
    if x is None or not isinstance(x, float) or not np.isfinite(x):
        return x
    return round(x, digits)


#: Decimals by key suffix: mm to 0.01 um; um to 0.001 um; C to 0.001 C.
_DIGITS = (("_um", 3), ("_mm", 5), ("_C", 3))


def rounded_dict(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, list):
            out[k] = [rounded_dict(x) if isinstance(x, dict) else x for x in v]
        elif isinstance(v, float):
            digits = next((n for suffix, n in _DIGITS if k.endswith(suffix)), 6)
            out[k] = _round(v, digits)
        else:
            out[k] = v
    return out
