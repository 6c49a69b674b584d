"""Evaluation of an artefact run (docs/artefacts.md): every ball's deviation
from its calibrated centre after the best-fit rigid transform of its
placement, at 20 C, and every ball-pair length error, uncompensated and
compensated, with standard uncertainties.

For each placement the measured centres (sphere fits, ``cmmpose.fit_spheres``;
the mean where a ball was scanned more than once) are brought to 20 C with
the artefact's own coefficient at the placement's mean machine temperature,
the calibrated centres likewise from the certificate's temperature, and the
calibrated centres are moved onto the measured ones by the rigid transform
(rotation and translation) that minimises the sum of squared distances
(Kabsch). A ball's deviation is its measured centre minus the moved
calibrated one, in the machine frame; a pair's length error is the measured
centre distance minus the calibrated one (E in the manner of ISO 10360-2).

Standard uncertainties (k = 1) combine the certificate's per-axis values,
the sphere fit's covariance, Type A (the spread of repeated scans of a ball)
and the temperature reading (``u_temperature`` K through the coefficient of
expansion), propagated through the rigid fit linearised; correlations between
the certificate's values are not known and are left out. The machine's own
errors are what is measured, not an uncertainty.

Units: mm inside, um in tables and JSON (``_um`` keys), degrees C.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .._json import dumps as strict_json
from .. import artefacts
from ..errormap import ErrorMapSet
from ..errors import InputError, InputTypeError
from .ballbar import machine_coordinates, evaluation_provenance, rounded_dict, log_notes, machine_temperature_and_log
from ..temperature import TemperaturePolicy, as_policy
from .ballbar_uncertainty import DEFAULT_U_TEMPERATURE_K
from ..fitting import fit_spheres
from .point_monte_carlo import MapDraw, perturbed_maps
from ..run import Run
from .artefact_balls import (check_labels, ball_scans, check_ball_positions, is_artefact_run,
                             rigid_fit, rigid_projection)

__all__ = ["BallDeviation", "LengthDeviation", "PlacementResult", "ArtefactResult", "ArtefactEvaluation",
           "evaluate_artefact"]


@dataclass(frozen=True)
class BallDeviation:
    """One ball of one placement.

    Attributes
    ----------
    ball : int
        The ball's id.
    scans : tuple of int
        The scans that measured it.
    measured : ndarray (3,)
        Measured centre at 20 C, mm (machine frame; the mean of its scans).
    calibrated : ndarray (3,)
        The calibrated centre at 20 C moved by the placement's best-fit
        rigid transform, mm.
    deviation : ndarray (3,)
        ``measured - calibrated``, mm.
    u : ndarray (3,)
        Standard uncertainty of each component of ``deviation``, mm.
    radius_error, form : float
        Fitted minus calibrated radius (probing size), largest minus
        smallest residual (probing form), mm; means over its scans.
    """

    ball: int
    scans: tuple[int, ...]
    measured: np.ndarray
    calibrated: np.ndarray
    deviation: np.ndarray
    u: np.ndarray
    radius_error: float
    form: float

    @property
    def magnitude(self) -> float:
        return float(np.linalg.norm(self.deviation))


@dataclass(frozen=True)
class LengthDeviation:
    """One ball pair: calibrated ``length`` at 20 C, ``error`` = measured
    minus calibrated and its standard uncertainty ``u``, mm."""

    ball_a: int
    ball_b: int
    length: float
    error: float
    u: float


class _Figures:
    """The summary figures of a set of ball deviations and length errors
    (``balls`` and ``lengths``): one placement or all of them."""

    @property
    def rms(self) -> float:
        """Rms of the balls' deviation magnitudes, mm."""
        return float(np.sqrt(np.mean([b.magnitude ** 2 for b in self.balls])))

    @property
    def largest(self) -> BallDeviation:
        return max(self.balls, key=lambda b: b.magnitude)

    @property
    def largest_length_error(self) -> LengthDeviation | None:
        return max(self.lengths, key=lambda e: abs(e.error)) if self.lengths else None


@dataclass(frozen=True)
class PlacementResult(_Figures):
    """One placement: its balls, pairs, fitted transform and temperature."""

    position: int
    label: str
    temperature: float
    rotation: np.ndarray
    translation: np.ndarray
    balls: tuple[BallDeviation, ...]
    lengths: tuple[LengthDeviation, ...]
    missing: tuple[int, ...] = ()


@dataclass(frozen=True)
class ArtefactResult(_Figures):
    """All placements under one model ('uncompensated' or 'compensated')."""

    label: str
    placements: tuple[PlacementResult, ...]

    @property
    def balls(self) -> list[BallDeviation]:
        return [b for p in self.placements for b in p.balls]

    @property
    def lengths(self) -> list[LengthDeviation]:
        return [e for p in self.placements for e in p.lengths]

    def to_dict(self) -> dict:
        out = {"label": self.label, "rms_deviation_um": self.rms * 1e3, "largest_deviation_um": self.largest.magnitude * 1e3,
               "placements": []}
        worst = self.largest_length_error
        out["largest_length_error_um"] = None if worst is None else worst.error * 1e3
        for p in self.placements:
            big, e = p.largest, p.largest_length_error
            out["placements"].append(rounded_dict({
                "position": p.position, "label": p.label, "temperature_C": p.temperature,
                "rms_deviation_um": p.rms * 1e3, "largest_deviation_um": big.magnitude * 1e3,
                "largest_deviation_ball": big.ball,
                "largest_length_error_um": None if e is None else e.error * 1e3,
                "missing_balls": list(p.missing),
                "rotation": [[round(float(x), 12) for x in r] for r in p.rotation],
                "translation_mm": [round(float(x), 5) for x in p.translation],
                "balls": [rounded_dict({"ball": b.ball, "scans": list(b.scans),
                                    **{f"measured_{a}_mm": float(b.measured[k]) for k, a in enumerate("xyz")},
                                    **{f"deviation_{a}_um": float(b.deviation[k] * 1e3) for k, a in enumerate("xyz")},
                                    **{f"u_{a}_um": float(b.u[k] * 1e3) for k, a in enumerate("xyz")},
                                    "deviation_um": b.magnitude * 1e3, "size_error_um": b.radius_error * 1e3,
                                    "form_um": b.form * 1e3}) for b in p.balls],
                "lengths": [rounded_dict({"ball_a": e.ball_a, "ball_b": e.ball_b, "length_mm": e.length,
                                      "error_um": e.error * 1e3, "u_um": e.u * 1e3}) for e in p.lengths],
            }))
        return rounded_dict(out)


@dataclass(frozen=True)
class ArtefactEvaluation:
    """Uncompensated and (with maps) compensated results of an artefact run."""

    artefact: artefacts.Artefact
    uncompensated: ArtefactResult
    compensated: ArtefactResult | None = None
    provenance: dict = field(default_factory=dict, compare=False)

    @property
    def results(self) -> tuple[ArtefactResult, ...]:
        return tuple(r for r in (self.uncompensated, self.compensated) if r is not None)

    @property
    def skipped(self) -> list[dict]:
        """Ballbar positions skipped (as :attr:`cmmpose.Evaluation.skipped`):
        none; balls not measured are in each placement's ``missing`` and
        the provenance's notes."""
        return []

    def to_dict(self) -> dict:
        a = self.artefact
        return {"artefact": {"kind": a.kind, "name": a.name, "balls": a.n_balls, "certificate": a.certificate,
                             "expansion_ppm_per_K": round(a.expansion * 1e6, 6),
                             "reference_temperature_C": a.reference_temperature},
                "results": [r.to_dict() for r in self.results], "provenance": self.provenance}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def __rich__(self):
        from rich.markup import escape
        from rich.table import Table

        # Names and labels come from files (the artefact file, run.json): shown as text, never as Rich markup.
        t = Table(title=f"Artefact evaluation: {escape(self.artefact.name)} ({escape(self.artefact.kind)})")
        t.add_column("placement")
        t.add_column("T (C)", justify="right")
        t.add_column("balls", justify="right")
        for r in self.results:
            t.add_column(f"{escape(r.label)}\nrms dev (um)", justify="right")
            t.add_column("largest (um)", justify="right")
            t.add_column("largest |E| (um)", justify="right")
        for k, p in enumerate(self.uncompensated.placements):
            cells = [escape(f"{p.position}: {p.label}"), f"{p.temperature:.2f}", str(len(p.balls))]
            for r in self.results:
                q = r.placements[k]
                e = q.largest_length_error
                cells += [f"{q.rms * 1e3:.2f}", f"{q.largest.magnitude * 1e3:.2f} (ball {q.largest.ball})",
                          "-" if e is None else f"{e.error * 1e3:+.2f} ({e.ball_a}-{e.ball_b})"]
            t.add_row(*cells)
        t.add_section()
        cells = ["all placements", "", str(len(self.uncompensated.balls))]
        for r in self.results:
            e = r.largest_length_error
            cells += [f"{r.rms * 1e3:.2f}", f"{r.largest.magnitude * 1e3:.2f}", "-" if e is None else f"{e.error * 1e3:+.2f}"]
        t.add_row(*cells)
        t.caption = "\n".join([f"deviations after the best-fit rigid transform per placement, at 20 C "
                               f"({self.artefact.expansion * 1e6:g} ppm/K); u in the JSON (k = 1)",
                               *map(escape, self.provenance.get("notes", []))])
        return t

    def __str__(self) -> str:
        from rich.console import Console

        console = Console(width=140, record=True, file=open("/dev/null", "w"))  # noqa: SIM115 - render to text only
        console.print(self)
        return console.export_text()


def _model_moves(run, model, model_t, groups, reject, policy, base_xyz, once: set | None = None) -> list[dict]:
    """Per parameter of a diagnosis model that states its standard uncertainty u: each scan's fitted centre
    move for a change of u (mm), by a difference of one step of the effect through the kernel and the fits
    (``once``: the checks the evaluation already made of this run, not made again for each step)."""
    sid = run.points["scan_id"]
    keep = np.isin(sid, [s for balls in groups.values() for scans in balls.values() for s in scans])
    base = fit_spheres(base_xyz[keep], sid[keep], reject=reject)
    out = []
    for spec, values in model.effects:
        u = np.ravel(model.uncertainty.get(spec.name, np.full(spec.size, np.nan)))
        for j in range(spec.size):
            if not (np.isfinite(u[j]) and u[j] > 0):
                continue
            v = np.array(values, dtype=float)
            v[j] += spec.steps[j]
            xyz = machine_coordinates(run, model.with_values(spec, v), model_t, policy, once=once)
            moved = fit_spheres(xyz[keep], sid[keep], reject=reject)
            d = (moved.centre - base.centre) * (u[j] / spec.steps[j])
            out.append({int(k): d[i] for i, k in enumerate(base.labels.tolist())})
    return out


def _map_moves(run, maps, model_t, groups, reject, policy, base_xyz, once: set | None = None) -> list[dict]:
    """Per component the maps state an uncertainty for (:class:`cmmpose.point_uncertainty.MapUncertainty`):
    each scan's fitted centre move for a change of that u (mm), the maps moved by one unit of the component
    (um, arc-second or ppm: the model is linear in each) through the kernel and the fits. Such a move is common
    to every ball, as a parameter of a model is: the rigid fit and the lengths take it with its correlations."""
    stated = maps.error_maps.stated_uncertainty
    if stated is None:
        return []
    sid = run.points["scan_id"]
    keep = np.isin(sid, [s for balls in groups.values() for scans in balls.values() for s in scans])
    base = fit_spheres(base_xyz[keep], sid[keep], reject=reject)
    ref = stated.reference_mm
    out = []
    shapes = {"position_um": (3, 3), "rotation_arcsec": (3, 3), "squareness_arcsec": (3,), "positioning_ppm": (3,)}
    for field_name, shape in shapes.items():
        u_all = np.asarray(getattr(stated, field_name), dtype=float)
        for index in np.ndindex(shape):
            if u_all[index] <= 0:
                continue
            unit = {f: np.zeros(s) for f, s in shapes.items()}  # one unit of this component, none of the others
            unit[field_name][index] = 1.0
            moved_maps = perturbed_maps(maps.error_maps, MapDraw(**unit), ref)
            moved_model = moved_maps if maps.error_maps is maps else dataclasses.replace(maps, maps=moved_maps)
            xyz = machine_coordinates(run, moved_model, model_t, policy, once=once)
            moved = fit_spheres(xyz[keep], sid[keep], reject=reject)
            d = (moved.centre - base.centre) * u_all[index]
            out.append({int(k): d[i] for i, k in enumerate(base.labels.tolist())})
    return out


def _evaluate_state(label, run, xyz, groups, artefact, temps, labels, reject, u_temperature,
                    model_moves=(), check=False) -> ArtefactResult:
    sid = run.points["scan_id"]
    wanted = [s for balls in groups.values() for scans in balls.values() for s in scans]
    keep = np.isin(sid, wanted)
    fits = fit_spheres(xyz[keep], sid[keep], reject=reject)
    row = {int(s): k for k, s in enumerate(fits.labels)}
    check_labels(groups, fits, artefact.nominal_radius)
    alpha = artefact.expansion
    cal20_all = artefact.centres_at_20c()
    placements = []
    for pos in sorted(groups):
        balls = groups[pos]
        ids = sorted(balls)
        scans_of = [balls[b] for b in ids]
        in_pos = np.isin(sid, [s for scans in scans_of for s in scans])
        T = float(np.mean(temps[in_pos]))
        k20 = float(artefact.scale_to(20.0) / artefact.scale_to(T))
        m = np.array([np.mean([fits.centre[row[s]] for s in scans], axis=0) for scans in scans_of])
        m20 = m.mean(axis=0) + (m - m.mean(axis=0)) * k20
        if check:  # the labels, once (uncompensated): a swapped pair would read as pitch-sized deviations
            check_ball_positions(artefact, f"scans: position {pos} ({labels.get(pos, 'unlabelled')}) of "
                                 f"the run of {artefact.name!r}", ids, m20, cal20_all, scans_of)
        c20 = cal20_all[[artefact.index(b) for b in ids]]
        r, t = rigid_fit(c20, m20)
        placed = c20 @ r.T + t
        dev = m20 - placed
        cov = []
        for b, scans in zip(ids, scans_of):
            u_cert = artefact.u_centres[artefact.index(b)]
            s_cert = r @ np.diag(u_cert ** 2) @ r.T
            s_fit = np.mean([fits.covariance[row[s]][:3, :3] for s in scans], axis=0) / len(scans)
            s_a = np.zeros((3, 3))
            if len(scans) > 1:
                spread = np.array([fits.centre[row[s]] for s in scans])
                s_a = np.diag(np.var(spread, axis=0, ddof=1) / len(scans))
            cov.append(s_cert + s_fit + s_a)
        n = len(ids)
        big = np.zeros((3 * n, 3 * n))
        for i, c in enumerate(cov):
            big[3 * i:3 * i + 3, 3 * i:3 * i + 3] = c
        proj = rigid_projection(placed)
        thermal = ((placed - placed.mean(axis=0)) * alpha * u_temperature).ravel()
        cov_dev = proj @ big @ proj.T + np.outer(proj @ thermal, proj @ thermal)
        # A diagnosis model's parameters: common to every ball (its u moves them all at once).
        moves = [np.array([np.mean([mv[s] for s in scans], axis=0) for scans in scans_of]) for mv in model_moves]
        for d in moves:
            cov_dev += np.outer(proj @ d.ravel(), proj @ d.ravel())
        u_dev = np.sqrt(np.clip(np.diag(cov_dev), 0.0, None)).reshape(n, 3)
        radius_err = [float(np.mean([fits.radius[row[s]] for s in scans])) - artefact.calibrated_radius
                      for scans in scans_of]
        form = [float(np.mean([fits.form[row[s]] for s in scans])) for scans in scans_of]
        deviations = tuple(BallDeviation(b, tuple(scans), m20[i], placed[i], dev[i], u_dev[i], radius_err[i], form[i])
                           for i, (b, scans) in enumerate(zip(ids, scans_of)))
        lengths = []
        for i in range(n):
            for j in range(i + 1, n):
                d_meas = m20[j] - m20[i]
                length = float(np.linalg.norm(c20[j] - c20[i]))
                direction = d_meas / np.linalg.norm(d_meas)
                u2 = direction @ (cov[i] + cov[j]) @ direction + (alpha * length * u_temperature) ** 2
                u2 += sum(float(direction @ (d[j] - d[i])) ** 2 for d in moves)
                lengths.append(LengthDeviation(ids[i], ids[j], length, float(np.linalg.norm(d_meas)) - length,
                                           float(np.sqrt(u2))))
        missing = tuple(int(b) for b in artefact.ids if int(b) not in balls)
        placements.append(PlacementResult(pos, labels.get(pos, f"position {pos}"), T, r, t, deviations,
                                          tuple(lengths), missing))
    return ArtefactResult(label, tuple(placements))


def evaluate_artefact(
    run: Run,
    maps=None,
    temperature: float | None = None,
    *,
    reject: float | None = None,
    u_temperature: float = DEFAULT_U_TEMPERATURE_K,
    out_of_range: str | None = None,
    temperature_tolerance: float | None = None,
    log_hold: float | None = None,
    temperature_policy: TemperaturePolicy | None = None,
    map_uncertainty: bool = False,
) -> ArtefactEvaluation:
    """Evaluate an artefact run: deviations and length errors per placement.

    Parameters
    ----------
    run : Run
        A run that embeds its artefact (``run.artefact['definition']``).
    maps : ErrorMap, ErrorMapSet or Model, optional
        The compensation model's maps; None: uncompensated only; or a model a
        diagnosis found (its maps and effects; ``cmmpose.evaluate`` says how).
    temperature : float, optional
        Machine (and part) temperature, C, for all points; default the
        machine mean of the run's thermocouple log at each point's time.
    reject : float, optional
        Robust sphere fits (``fit_spheres``).
    u_temperature : float
        Standard uncertainty of the part temperature, K.
    out_of_range, temperature_tolerance, log_hold
        Override the temperature policy's fields.
    temperature_policy : TemperaturePolicy, optional
        How the log becomes temperatures (cmmpose.temperature); default
        ``TemperaturePolicy()``.
    map_uncertainty : bool
        Also carry the maps' stated uncertainty per component
        (``stated_uncertainty``, docs/uncertainty.md section 5) into the
        compensated deviations' and lengths' u: each component moves every
        ball's centre at once (one kernel pass and fit per stated
        component), so the rigid fit and the lengths take it with its
        correlations, not as independent per ball.

    Returns
    -------
    ArtefactEvaluation

    Raises
    ------
    InputError
        A run without an artefact, a scan labelled with a ball the artefact
        lacks or a placement the run does not record, two labels on one ball,
        a ball (uncompensated) further from where the placement's best fit
        puts it than any machine error could take it (mislabelled, e.g. two
        labels swapped, or mismeasured: :func:`check_ball_positions`), no
        temperature.
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    if not is_artefact_run(run):
        raise InputError("run: records no artefact definition (a ballbar run: use cmmpose.evaluate)")
    policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance,
                       log_hold=log_hold)
    out_of_range, temperature_tolerance, log_hold = policy.out_of_range, policy.temperature_tolerance, policy.log_hold
    if not (isinstance(u_temperature, (int, float)) and np.isfinite(u_temperature) and u_temperature >= 0):
        raise InputError(f"u_temperature: expected a standard uncertainty >= 0 K, got {u_temperature!r}")
    artefact = artefacts.from_dict(run.artefact["definition"], "run.json: artefact.definition")
    recorded = run.artefact.get("placements")
    labels = {k: str(p.get("label", f"position {k}")) for k, p in enumerate(recorded or [], start=1)
              if isinstance(p, dict)}
    groups = ball_scans(run, artefact, len(recorded) if isinstance(recorded, list) else None)
    log = None
    if temperature is not None:
        temps = np.full(run.n_points, float(temperature))
    elif run.temperatures is not None:
        temps, log = machine_temperature_and_log(run, run.points["t"], temperature_policy=policy)
    else:
        raise InputError("temperature: the run has no thermocouple log; give the machine temperature (C)")
    prov = evaluation_provenance(run, maps, temperature, temps, artefact.expansion, out_of_range, temperature_tolerance, log_hold)
    if log is not None:
        prov["temperature"]["log"] = log
        prov["notes"].extend(log_notes(log))
    prov["u_temperature_K"] = u_temperature
    _note_scans(prov, run, groups, artefact)
    raw = _evaluate_state("uncompensated", run, machine_coordinates(run, None, None), groups, artefact, temps,
                          labels, reject, u_temperature, check=True)
    if maps is None:
        return ArtefactEvaluation(artefact, raw, provenance=prov)
    model_t = temperature if temperature is not None else temps
    if maps.reads_run:  # a found model reads the run's log itself, with the caller's policy
        maps, model_t = maps.with_policy(log_hold=log_hold), temperature
    elif not isinstance(maps, ErrorMapSet):
        model_t = None
    reports: list = []
    once: set = set()  # the checks of the model on this run: said once, not again for each parameter's step
    xyz = machine_coordinates(run, maps, model_t, policy, reports, once=once)
    moves = _uncertain_moves(run, maps, model_t, groups, reject, policy, xyz, once, map_uncertainty, prov)
    comp = _evaluate_state("compensated", run, xyz, groups, artefact, temps, labels, reject, u_temperature, moves)
    prov["points_clamped"] = int(sum(r.clamped_points for r in reports))
    prov["points_held_at_maps_edge"] = int(sum(r.held_temperature for r in reports))
    return ArtefactEvaluation(artefact, raw, comp, provenance=prov)


def _note_scans(prov: dict, run: Run, groups: dict, artefact) -> None:
    """Notes of what the evaluation leaves out: balls a position did not measure, scans of other features."""
    for pos, balls in sorted(groups.items()):
        missing = [int(b) for b in artefact.ids if int(b) not in balls]
        if missing:
            prov["notes"].append(f"position {pos}: balls {', '.join(map(str, missing))} were not measured")
    skipped = int(np.sum(run.scans["feature"] != "ball"))
    if skipped:
        prov["notes"].append(f"{skipped} scans of other features (not 'ball') are not part of the evaluation")


def _uncertain_moves(run: Run, maps, model_t, groups, reject, policy, xyz, once: set, map_uncertainty: bool,
                     prov: dict) -> list:
    """How the compensated balls move with each uncertain input: the model's parameters (when it has effects)
    and, with ``map_uncertainty``, the maps' stated uncertainty; a note of each, and of the parameters the
    diagnosis left undetermined (left out: no number would be honest)."""
    moves = _model_moves(run, maps, model_t, groups, reject, policy, xyz, once) \
        if maps.effects else []
    if moves:
        prov["notes"].append(f"the u of the compensated deviations and lengths include the model's {len(moves)} "
                             f"parameter uncertainties (taken as independent: the model file keeps no correlations)")
    if map_uncertainty:
        stated_moves = _map_moves(run, maps, model_t, groups, reject, policy, xyz, once)
        moves = list(moves) + stated_moves
        prov["notes"].append(
            f"the u of the compensated deviations and lengths include the maps' stated uncertainty "
            f"({len(stated_moves)} components, each common to every ball)" if stated_moves else
            "map_uncertainty: the maps state no uncertainty (docs/uncertainty.md, section 5): none is included")
    undetermined = [f"{s.name}.{p}" for s, _ in maps.effects for p, u in
                    zip(s.params, np.ravel(maps.uncertainty.get(s.name, np.full(s.size, np.nan)))) if np.isinf(u)]
    if undetermined:  # the diagnosis could not determine them: no number would be honest
        prov["notes"].append("the model's parameters " + ", ".join(undetermined) + " are undetermined (the run the "
                             "model was found on cannot determine them): the u of the compensated deviations and "
                             "lengths leave them out")
    return moves
