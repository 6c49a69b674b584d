"""What to measure next (``cmmpose plan RUN...``; docs/plan.md): the N
placements of an artefact (ballbar positions, plate placements, step-gauge
lines, in the vocabulary of :mod:`cmmpose.placement`) that best determine
the parameters the runs so far leave aliased or invisible, or, given rival
explanations (``rivals``: a diagnosis's ambiguity set), that best tell them
apart (T-optimal, :func:`plan`).

The information. A ball's measured centre moves, to first order, by the
machine's error at the scale reading where the scan plane passes through
it. :func:`centre_sensitivities` computes that move for every candidate
parameter through the compensation kernel at one virtual point per ball
(a forward difference of each parameter's step: the centre level, never the
point clouds), so the same function serves the runs measured and the
placements proposed. A placement sees the centres' moves less its rigid
motion (the rigid fit of :mod:`cmmpose.evaluation.artefact_layout`; a ballbar run's
lengths less their mean when the bar is not calibrated). With a noise of
sigma per centre coordinate, a measurement adds the Fisher information
``J^T P J / sigma^2`` (P the projector onto what its rigid fit leaves).
sigma comes from the runs themselves: the rms of their centre-level
residuals after a least-squares fit of the candidate parameters (Type A,
their degrees of freedom counted), or ``sigma_um`` when given.

The criterion. D-optimal: each step adds the candidate placement that
maximises ``log det(F + F_prior)``, F the information of the runs and the
placements chosen so far and ``F_prior = diag(1 / prior^2)`` what is known
without data (each effect's typical magnitude). Greedy, from a fixed
candidate set (every plane or line of the artefact's kind, turned and moved
over the machine's travel, those whose every ball the pose library reaches).
A parameter is 'aliased with' another when their correlation exceeds 0.9,
else 'invisible' when the data leave more than half its prior uncertainty,
else 'determined'. The predicted uncertainties are those of the linearised
problem: they hold for the model's parameters and the noise level stated;
an error outside the candidate effects (or map corrections) the data will
show in the next diagnosis, not here.

Units: mm, degrees; parameters in their effects' units. What it proposes
(:class:`~cmmpose.diagnosis.plan_results.Plan`,
:class:`~cmmpose.diagnosis.plan_results.Proposal`) is in
:mod:`cmmpose.diagnosis.plan_results`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from .. import artefacts
from ..evaluation.artefact_balls import is_artefact_run
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import Error, InputError, InputTypeError
from ..layouts import sweep_readings
from ..placement import PLANES, Placement, parse
from ..placement import plan as place
from ..run import Run
from .plan_results import Plan, Proposal, separation_text
from ..evaluation.artefact_layout import rigid_dof
from ..model.names import resolve
from ..model.spec import EffectSpec
from ..model.inputs import RunInputs
from ..model.model import Model
from ..evaluation.observables import ObservationLayout, observe

__all__ = [
    "ALIASED_ABOVE",
    "DEFAULT_EFFECTS",
    "INVISIBLE_ABOVE",
    "candidate_placements",
    "centre_sensitivities",
    "plan",
    "separating_measurement",
]

_log = logging.getLogger(__name__)

#: The effects planned for by default: the machine's geometry that a placement separates.
DEFAULT_EFFECTS = ("squareness", "scale", "roll")
#: |correlation| above which two parameters are reported aliased.
ALIASED_ABOVE = 0.9
#: Share of its prior uncertainty above which a parameter is reported invisible.
INVISIBLE_ABOVE = 0.5
#: Smallest noise credited per centre coordinate, mm (as the diagnosis's SIGMA_FLOOR).
SIGMA_FLOOR = 1e-4
#: Rotations tried in each plane, degrees.
ROTATIONS = (0.0, 45.0, 90.0, 135.0)
#: Where along each axis a candidate's centroid is tried: shares of the travel.
SHARES = (0.25, 0.5, 0.75)

#: A given noise per centre coordinate, um: a nanometre to a centimetre.
SIGMA_RANGE_UM = (1e-3, 1e4)


# -- sensitivities at the centre level -----------------------------------------------


def _specs(effects) -> list[EffectSpec]:
    out = []
    for e in effects:
        spec = e if isinstance(e, EffectSpec) else resolve(str(e))
        if spec.kind not in ("kernel", "pose") or spec.needs or spec.sensor is not None \
                or getattr(spec.effect, "on_scanner", False):
            raise InputError(f"effect {spec.name!r}: a placement cannot separate it (it "
                             + ("acts on the scanner" if getattr(spec.effect, "on_scanner", False) else
                                f"needs {', '.join(spec.needs)}" if spec.needs else f"acts on the {spec.kind}")
                             + f"); what shows it: {spec.reveal}")
        out.append(spec)
    if not out:
        raise InputError("effects: give at least one effect to plan for")
    return out


def _virtual_inputs(uv, scales, pose_index, poses, temperature, pose_ids=None) -> RunInputs:
    n = len(uv)
    return RunInputs(uv=np.ascontiguousarray(uv, float), scales=np.ascontiguousarray(scales, float), t=np.zeros(n),
                     scan_id=np.arange(n), pose_ids=tuple(range(len(poses))) if pose_ids is None else tuple(pose_ids),
                     pose_index=np.ascontiguousarray(pose_index, dtype=np.uint32), poses=np.asarray(poses, float),
                     temperature=np.full(n, float(temperature)) if np.ndim(temperature) == 0
                     else np.ascontiguousarray(temperature, float),
                     axis_temperature=None, gradient=None, velocity=np.zeros((n, 3)))


def centre_sensitivities(model: Model, inputs: RunInputs, specs: Sequence[EffectSpec]) -> np.ndarray:
    """How each virtual point's compensated position moves per unit of each
    parameter (mm per unit), (n, 3, p): a forward difference of the
    parameter's step (backward where the forward one leaves the maps)
    through the kernel. Swap this function for an analytic Jacobian when
    the diagnosis exposes one."""
    base = model.compensate(inputs)
    cols = []
    for spec in specs:
        current = model.values(spec.name) if spec.name in model.names else np.zeros(spec.size)
        for j in range(spec.size):
            for sign in (1.0, -1.0):
                v = np.array(current, float)
                v[j] += sign * spec.steps[j]
                try:
                    moved = model.with_values(spec, v).compensate(inputs)
                except Error:
                    if sign < 0:
                        raise
                    continue
                cols.append((moved - base) / (sign * spec.steps[j]))
                break
    return np.stack(cols, axis=2)


def _rigid_projector(centres: np.ndarray, radius: float) -> np.ndarray:
    """Projector (3n, 3n) onto what a placement's best-fit rigid motion leaves
    of its balls' moves: translations and small rotations about the centroid
    taken out (a line's roll moves nothing, so the rank follows rigid_dof)."""
    n = len(centres)
    c = centres - centres.mean(axis=0)
    cols = []
    for k in range(3):
        t = np.zeros((n, 3))
        t[:, k] = 1.0
        cols.append(t.reshape(-1))
        axis = np.zeros(3)
        axis[k] = 1.0
        cols.append(np.cross(axis, c).reshape(-1))
    basis = np.column_stack(cols)
    u, s, _ = np.linalg.svd(basis, full_matrices=False)
    keep = u[:, s > 1e-9 * max(s.max(), 1.0)][:, :rigid_dof(centres, radius)]
    return np.eye(3 * n) - keep @ keep.T


# -- the runs measured ---------------------------------------------------------------


@dataclass
class _Measured:
    fisher: np.ndarray  # (p, p) per sigma^2 = 1 mm^2
    rss: float  # mm^2, centre-coordinate units
    dof: int
    temperature: float


def _scan_virtual(run: Run, inputs: RunInputs, labels: np.ndarray):
    """One virtual point per scan of ``labels``: its points' mean (u, v),
    readings and temperature, and its pose."""
    sid = inputs.scan_id
    keys, inv = np.unique(sid, return_inverse=True)
    n = np.bincount(inv).astype(float)
    mean = lambda a: np.bincount(inv, a) / n
    at = np.searchsorted(keys, labels)
    uv = np.column_stack([mean(inputs.uv[:, k]) for k in range(2)])[at]
    sc = np.column_stack([mean(inputs.scales[:, k]) for k in range(3)])[at]
    temp = mean(inputs.temperature)[at]
    first = np.zeros(len(keys), int)
    first[inv[::-1]] = np.arange(len(sid))[::-1]
    pose_index = inputs.pose_index[first][at]
    return uv, sc, pose_index, temp


def _measured(run: Run, model: Model, specs, centre_model: Model) -> _Measured:
    """The information a measured run holds on the parameters, and its
    centre-level residual after their least-squares fit (the run's points
    compensated by ``model``, the sensitivities through ``centre_model``)."""
    inputs = model.inputs(run)
    layout = ObservationLayout.from_run(run, inputs, points_per_scan=4)
    obs = observe(layout, model.compensate(inputs), model.expansion_ppm_per_kelvin, inputs.scan_id)
    uv, sc, pose_index, temp = _scan_virtual(run, inputs, layout.labels)
    vin = _virtual_inputs(uv, sc, pose_index, inputs.poses, temp, inputs.pose_ids)
    # The poses the model adjusts: the virtual inputs carry the run's own.
    j_scan = centre_sensitivities(centre_model, vin, specs)  # (S, 3, p)
    n_sph = len(layout.sphere_kind)
    counts = np.bincount(layout.sphere_of_scan, minlength=n_sph)
    j_sph = np.zeros((n_sph, 3, j_scan.shape[2]))
    np.add.at(j_sph, layout.sphere_of_scan, j_scan)
    j_sph /= np.maximum(counts, 1)[:, None, None]
    p = j_scan.shape[2]
    if layout.artefact is not None:
        F = np.zeros((p, p))
        y_all, x_all, dof = [], [], 0
        dev = obs.deviations
        at = 0
        for idx, cal in zip(layout.artefact.spheres, layout.artefact.calibrated):
            P = _rigid_projector(cal, layout.artefact.artefact.nominal_radius)
            J = P @ j_sph[idx].reshape(-1, p)
            F += J.T @ J
            y_all.append(dev[at:at + len(idx)].reshape(-1))
            x_all.append(J)
            at += len(idx)
            dof += 3 * len(idx) - rigid_dof(cal, layout.artefact.artefact.nominal_radius)
        y, X = np.concatenate(y_all), np.vstack(x_all)
        scale = 1.0
    else:  # ballbar lengths: n . (c2 - c1), less their mean when the bar is not calibrated
        ends = layout.ends
        if not len(ends):
            raise InputError("run: no ballbar position with both balls, nor an artefact: nothing to plan from")
        c = np.zeros((n_sph, 3))
        np.add.at(c, layout.sphere_of_scan, obs.centres)
        c /= np.maximum(counts, 1)[:, None]
        bar = c[ends[:, 1]] - c[ends[:, 0]]
        nrm = bar / np.linalg.norm(bar, axis=1, keepdims=True)
        X = np.einsum("pk,pkj->pj", nrm, j_sph[ends[:, 1]] - j_sph[ends[:, 0]])
        y = obs.lengths.copy()
        dof = len(y)
        if layout.calibrated_length is None:
            X, y = X - X.mean(axis=0), y - y.mean()
            dof -= 1
        else:
            y = y - layout.calibrated_length
        scale = 0.5  # a length's variance is two centre coordinates'
        F = X.T @ X * scale
    beta, *_ = np.linalg.lstsq(X, -y, rcond=1e-10)
    rank = np.linalg.matrix_rank(X) if X.size else 0
    rss = float(np.sum((y + X @ beta) ** 2)) * scale
    return _Measured(F, rss, max(dof - rank, 0), float(np.mean(inputs.temperature)))


# -- the candidates ------------------------------------------------------------------


def _plane_candidates(at, machine) -> list[Placement]:
    """A plate: its plane as XY, XZ and YZ, turned by ROTATIONS, at SHARES of the travel across it."""
    out = []
    for plane, normal in (("xy", 2), ("xz", 1), ("yz", 0)):
        for rot in ROTATIONS:
            for share in SHARES:
                key = "xyz"[normal]
                out += parse(f"{plane}@{key}={at(normal, share):g},rot={rot:g}", machine.travel)
    return out


def _line_candidates(at, machine) -> list[Placement]:
    """A bar or a gauge: its line along X, Y, Z and the face diagonals at SHARES of the travel across it, and the
    space diagonals."""
    out = []
    for plane, rots in (("xy", (0.0, 45.0, 90.0, 135.0)), ("xz", (45.0, 90.0, 135.0)),
                        ("yz", (45.0, 135.0))):
        normal = {"xy": 2, "xz": 1, "yz": 0}[plane]
        for rot in rots:
            for share in SHARES:
                out += parse(f"{plane}@{'xyz'[normal]}={at(normal, share):g},rot={rot:g}", machine.travel)
    out += [p for p in parse("iso10360-2", machine.travel) if "diagonal" in p.label]
    return out


#: The candidate placements by what an artefact kind's balls span (``ArtefactKind.spans``); a kind whose balls
#: span a point (one sphere) has none.
CANDIDATES = {"plane": _plane_candidates, "line": _line_candidates}


def candidate_placements(artefact, machine) -> list[Placement]:
    """Every candidate placement of ``artefact`` on ``machine``, by what its
    kind's balls span (``ArtefactKind.spans``, never the kind's name): for a
    plane (a plate), the three planes turned by ROTATIONS; for a line (a bar
    or a step gauge), its line along X, Y, Z, the face diagonals and the
    space diagonals; each at SHARES of the travel across it (a plate's plane
    at three heights or depths, a line's centroid moved off the middle)."""
    travel = np.array(machine.travel, float)
    lo, span = travel[:, 0], travel[:, 1] - travel[:, 0]
    at = lambda axis, share: lo[axis] + share * span[axis]
    candidates = CANDIDATES.get(artefacts.get(artefact.kind).spans)
    if candidates is None:
        raise InputError(f"artefact {artefact.name!r} ({artefact.kind}): one ball cannot separate the machine's "
                         f"geometry; plan with a ball plate, a step gauge or a ballbar (--artefact)")
    return candidates(at, machine)


def _shorthand(pl: Placement) -> str:
    """A placement's shorthand with its centre in full (parseable by cmmpose.placement.parse)."""
    r = pl.rotation
    for plane in ("xy", "xz", "yz"):
        x_axis, y_axis = (np.array(a) for a in PLANES[plane])
        if r[:, 2] @ np.cross(x_axis, y_axis) > 1 - 1e-9:
            rot = round(math.degrees(math.atan2(r[:, 0] @ y_axis, r[:, 0] @ x_axis)), 6) + 0.0
            centre = ",".join(f"{a}={c:.6g}" for a, c in zip("xyz", pl.centre))
            return f"{plane}@{centre},rot={rot:g}"
    return pl.label  # a space diagonal: its layout name (resolved centre: the middle of the travel)


# -- the plan ------------------------------------------------------------------------


def _same_machine(runs: Sequence[Run], machine) -> str | None:
    """Refuse runs of different machines (their recorded machine or map stacking differ, or their readings
    leave ``machine``'s travel); the runs' configuration when they record one."""
    seen = {}
    for k, run in enumerate(runs, start=1):
        m = run.metadata.get("machine")
        kin = run.maps.get("kinematics", "thesis") if run.maps.get("kind") == "bundled" else None
        for key, value in (("machine", m), ("kinematics", kin)):
            if value is None:
                continue
            if key in seen and seen[key][1] != value:
                raise InputError(f"runs {seen[key][0]} and {k} were measured on different machines ({key} "
                                 f"{seen[key][1]!r} and {value!r}): plan from the runs of one machine")
            seen.setdefault(key, (k, value))
        sc = run.scales
        if len(sc):
            lo, hi = sc.min(axis=0), sc.max(axis=0)
            for a, (tlo, thi) in enumerate(machine.travel):
                if lo[a] < tlo - 1.0 or hi[a] > thi + 1.0:
                    raise InputError(f"run {k}: its {'XYZ'[a]} readings {lo[a]:.1f}..{hi[a]:.1f} mm leave the travel "
                                     f"{tlo:g}..{thi:g} mm of {machine.name}: another machine (give --machine)")
    return seen["kinematics"][1] if "kinematics" in seen else None


def _status(cov: np.ndarray, names, priors) -> dict:
    u = np.sqrt(np.clip(np.diag(cov), 0, None))
    corr = cov / np.outer(u, u)
    out = {}
    for j, name in enumerate(names):
        partners = [names[k] for k in np.argsort(-np.abs(corr[j])) if k != j and abs(corr[j, k]) > ALIASED_ABOVE]
        if partners:
            out[name] = f"aliased with {', '.join(partners)}"
        else:
            out[name] = "invisible" if u[j] > INVISIBLE_ABOVE * priors[j] else "determined"
    return out


def _check_runs_and_budget(runs, budget) -> list[Run]:
    """:func:`plan`'s runs as a list (at least one, each a Run) once the budget is a whole number >= 1."""
    if isinstance(runs, Run) or not runs:
        raise InputError("runs: give the runs measured so far (a list of at least one cmmpose.Run)")
    runs = list(runs)
    for k, r in enumerate(runs, start=1):
        if not isinstance(r, Run):
            raise InputError(f"runs: item {k} is a {type(r).__name__}, not a cmmpose.Run")
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
        raise InputError(f"budget: how many placements to propose, a whole number >= 1; got {budget!r}",
                         what="budget", option="budget", cli_option="--budget")
    return runs


def _plan_artefact(artefact, runs: list[Run]):
    """What to place next: ``artefact`` loaded, or the artefact the first artefact run embeds, else the thesis
    ballbar."""
    if artefact is None:
        art_run = next((r for r in runs if is_artefact_run(r)), None)
        return (artefacts.from_dict(art_run.artefact["definition"]) if art_run is not None
                else artefacts.load_artefact("thesis-ballbar"))
    if not isinstance(artefact, artefacts.Artefact):
        return artefacts.load_artefact(artefact)
    return artefact


def _plan_model(model, machine, kinematics) -> Model:
    """The current model: ``model`` (maps make one), default the machine's maps; refused when its maps are
    stacked for another configuration than the runs'."""
    if model is None:
        model = Model(machine.maps())
    elif isinstance(model, (ErrorMap, ErrorMapSet)):
        model = Model(model)
    elif not isinstance(model, Model):
        raise InputTypeError(f"model: expected a Model, ErrorMap or ErrorMapSet, got {type(model).__name__}")
    if kinematics is not None and model.maps.kinematics != kinematics:
        raise InputError(f"the runs were measured on a {kinematics!r} machine, the model's maps are stacked as "
                         f"{model.maps.kinematics!r}: give the runs' machine (--machine)")
    return model


def _planned_specs(effects, model: Model, notes: list[str]) -> list:
    """The specs of ``effects``, then of the model's own effects where a placement can separate them (those it
    cannot are held at their values, said in ``notes``)."""
    specs = _specs(list(dict.fromkeys(e.name if isinstance(e, EffectSpec) else str(e) for e in effects)))
    for spec, _ in model.effects:  # the model's own effects are planned for too, where a placement can
        if spec.name in {s.name for s in specs}:
            continue
        try:
            specs += _specs([spec])
        except InputError:
            notes.append(f"the model's effect {spec.name} is held at its value (a placement cannot separate it)")
    return specs


def _noise(measured: list, sigma_um) -> tuple[float, str]:
    """The noise per centre coordinate, mm, and where it comes from: ``sigma_um`` given, or the runs'
    centre-level residuals (floored at SIGMA_FLOOR)."""
    dof = sum(m.dof for m in measured)
    if sigma_um is not None:
        if not (isinstance(sigma_um, (int, float)) and math.isfinite(sigma_um) and sigma_um > 0):
            raise InputError(f"sigma_um: a noise level > 0 um, got {sigma_um!r}", what="sigma_um", option="sigma_um",
                             cli_option="--sigma")
        lo, hi = SIGMA_RANGE_UM
        if not lo <= sigma_um <= hi:  # 1e-320 um: a typo that would promise uncertainties of nothing
            raise InputError(f"sigma_um: {sigma_um:.6g} um is outside {lo:g}..{hi:g} um, the noise of a ball centre "
                             "a CMM can have (check the unit: um)", what="sigma_um", value=f"{sigma_um:.6g}",
                             allowed=SIGMA_RANGE_UM, unit="um", option="sigma_um", cli_option="--sigma")
        return float(sigma_um) * 1e-3, "given"
    if dof > 0:
        sigma = max(math.sqrt(sum(m.rss for m in measured) / dof), SIGMA_FLOOR)
        return sigma, f"the runs' centre-level residuals after fitting these parameters, {dof} degrees of freedom"
    raise InputError("the runs leave no degrees of freedom to estimate their noise from", what="sigma_um",
                     option="sigma_um", cli_option="--sigma", remedy="sigma")


def _placement_options(cand, artefact, machine, centre_model: Model, specs, n_params: int, temperature: float,
                       sigma: float) -> tuple[list, int]:
    """Each candidate placement the machine reaches as (placement, scans, its information, its projected
    sensitivities): the centre-level sensitivities of virtual scans at it, the rigid placement projected out;
    and how many it does not reach."""
    options, unreachable = [], 0
    offset = tuple(machine.offset)
    for pl in cand:
        try:
            (resolved,), scans = place([pl], artefact, machine)
        except InputError:
            unreachable += 1
            continue
        poses = sorted({s.pose for s in scans})
        pose_rows = np.array([[*p, *offset] for p in poses], float)
        centres = np.array([s.centre for s in scans])
        sc = np.array([sweep_readings(c, s.pose, offset, radius=artefact.nominal_radius).mean(axis=0)
                       for c, s in zip(centres, scans)])
        uv = np.array([[0.0, -artefact.nominal_radius]] * len(scans))
        idx = np.array([poses.index(s.pose) for s in scans])
        J = centre_sensitivities(centre_model, _virtual_inputs(uv, sc, idx, pose_rows, temperature), specs)
        P = _rigid_projector(centres, artefact.nominal_radius)
        Jp = P @ J.reshape(-1, n_params)
        options.append((resolved, len(scans), Jp.T @ Jp / sigma ** 2, Jp))
    return options, unreachable


def _d_optimal(options: list, info: np.ndarray, cov: np.ndarray, pnames: list[str], priors: np.ndarray,
               budget: int) -> list[Proposal]:
    """Up to ``budget`` placements chosen greedily, each the one that raises the log determinant of the
    parameters' information ``info`` most, with the parameters' uncertainties after it and those it
    determines."""
    proposals, used = [], set()
    _, logdet = np.linalg.slogdet(info)
    for _ in range(min(int(budget), len(options))):
        best = None
        for i, (label, n, Fi, _) in enumerate(options):
            if i in used:
                continue
            sign, ld = np.linalg.slogdet(info + Fi)
            if sign > 0 and (best is None or ld > best[1] + 1e-9):
                best = (i, ld)
        if best is None:
            break
        i, ld = best
        used.add(i)
        label, n, Fi, _ = options[i]
        prev_cov, prev_status = cov, _status(cov, pnames, priors)
        info = info + Fi
        cov = np.linalg.inv(info)
        u_prev, u_now = np.sqrt(np.diag(prev_cov)), np.sqrt(np.diag(cov))
        now = _status(cov, pnames, priors)
        de = [n_ for j, n_ in enumerate(pnames)
              if (prev_status[n_] != "determined" and now[n_] == "determined") or u_now[j] < 0.5 * u_prev[j]]
        proposals.append(Proposal(_shorthand(label), label, n, float(ld - logdet), dict(zip(pnames, u_now)), de, now))
        logdet = ld
    return proposals


def plan(
    runs: Sequence[Run],
    artefact=None,
    budget: int = 3,
    *,
    machine=None,
    model: Model | ErrorMap | ErrorMapSet | None = None,
    effects: Sequence = DEFAULT_EFFECTS,
    sigma_um: float | None = None,
    candidates: Sequence | None = None,
    rivals=None,
) -> Plan:
    """The ``budget`` next placements that best determine the parameters of
    ``effects`` given ``runs`` (module docstring: D-optimal, greedy).

    Parameters
    ----------
    runs : sequence of Run
        The runs measured so far on one machine (ballbar, plate, step gauge).
    artefact : Artefact, str or path, optional
        What to place next (a file or bundled example name); default the
        artefact the first artefact run embeds, else the thesis ballbar.
    budget : int
        How many placements to propose (>= 1).
    machine : cmmpose.machine.Machine, optional
        Its travel, pose and mount (default the thesis machine).
    model : Model, ErrorMap or ErrorMapSet, optional
        The current model (default the machine's maps); its effects are planned for too.
    effects : sequence of str or EffectSpec
        The candidate effects whose parameters the placements should determine.
    sigma_um : float, optional
        Noise per centre coordinate, um; default from the runs' residuals.
    candidates : sequence of str or Placement, optional
        The candidate placements (default :func:`candidate_placements`).
    rivals : AmbiguitySet or sequence of (EffectSpec or str, values), optional
        Rival explanations of the runs (a diagnosis's open ambiguity set,
        :attr:`cmmpose.diagnosis.result.Diagnosis.open_ambiguity`, or each
        effect with its fitted values in its units; a list of such pairs is
        one rival made of several effects fitted together). Then the placements
        are chosen to tell them apart, not to sharpen parameters: the
        T-optimal criterion (Atkinson and Fedorov 1975). For a pair (A, B),
        A taken true at its values theta_A, B refitted (with its weak
        prior) to everything A predicts (the runs, the placements chosen
        so far and the candidate), the separation is the sum of the squared
        predicted differences of the observables over the noise variance at
        that refit (the data's information only: without the priors, this
        is ``theta_A' (M_AA - M_AB M_BB^-1 M_BA) theta_A``), the smaller of
        the two directions; with several rivals the smallest pairwise
        separation is maximised (greedy). ``effects`` is then not used.

    Returns
    -------
    Plan

    Raises
    ------
    InputError
        No runs, a budget below 1, an unknown artefact, runs of different
        machines, an effect no placement can separate.
    """
    from ..machine import Machine

    runs = _check_runs_and_budget(runs, budget)
    machine = Machine.thesis() if machine is None else machine
    kinematics = _same_machine(runs, machine)
    artefact = _plan_artefact(artefact, runs)
    model = _plan_model(model, machine, kinematics)
    notes = []
    theta = None
    if rivals is not None:
        specs, theta = _rival_specs(rivals)  # theta: each rival's (name, its specs, its values)
    else:
        specs = _planned_specs(effects, model, notes)
    params = [(f"{s.name}.{p}", u, float(pr)) for s in specs for p, u, pr in zip(s.params, s.units, s.prior)]
    pnames = [n for n, _, _ in params]
    priors = np.array([pr for _, _, pr in params])
    # The sensitivities at the centre level: through the effects a ball's centre feels alone (the others, held at
    # their values, act on the points or need inputs no virtual point has).
    names = {s.name for s in specs}
    centre_model = replace(model, effects=tuple((s, v) for s, v in model.effects if s.name in names))
    measured = [_measured(r, model, specs, centre_model) for r in runs]
    sigma, source = _noise(measured, sigma_um)
    prior_info = np.diag(1.0 / priors ** 2)
    F = sum(m.fisher for m in measured) / sigma ** 2
    temperature = float(np.mean([m.temperature for m in measured]))
    if candidates is None:
        cand = candidate_placements(artefact, machine)
    else:
        cand = []
        for c in candidates:
            cand += parse(c, machine.travel) if isinstance(c, str) else [c]
    options, unreachable = _placement_options(cand, artefact, machine, centre_model, specs, len(pnames),
                                              temperature, sigma)
    if not options:
        raise InputError(f"no candidate placement of {artefact.name} fits the travel of {machine.name}")
    info = F + prior_info
    cov = np.linalg.inv(info)
    before = dict(zip(pnames, np.sqrt(np.diag(cov))))
    status = _status(cov, pnames, priors)
    if theta is not None:
        return _t_optimal(f"{artefact.name} ({artefact.kind})", params, specs, theta, sigma, source, info,
                          prior_info, before, status, options, unreachable, notes, budget)
    proposals = _d_optimal(options, info, cov, pnames, priors, budget)
    if len(proposals) < budget:
        notes.append(f"only {len(proposals)} candidate placements reachable: fewer than the budget {budget}")
    return Plan(f"{artefact.name} ({artefact.kind})", "D-optimal (largest log det of the parameters' information), "
                "greedy over the candidate placements", params, sigma * 1e3, source, before, status, proposals,
                len(options), unreachable, notes)


# -- telling rival explanations apart (T-optimal) ------------------------------------


def _rival_specs(rivals):
    """The effects of ``rivals`` (an AmbiguitySet, its ``rivals``, or rivals each (spec or name, values) or a
    list of such for a set of effects fitted together): (specs, each effect once; rivals, each as (name, the
    indices of its specs, its values side by side))."""
    items = list(getattr(rivals, "rivals", rivals))
    specs, out, seen = [], [], set()
    for item in items:
        parts = item if isinstance(item, list) else [item]
        at, values_all, names = [], [], []
        for part in parts:
            try:
                spec, values = part
            except (TypeError, ValueError):
                raise InputError(f"rivals: each rival is (effect, values) or a list of them, got {part!r}") from None
            spec = spec if isinstance(spec, EffectSpec) else resolve(str(spec))
            if spec.needs or spec.sensor is not None or getattr(spec.effect, "on_scanner", False):
                raise InputError(f"rival {spec.name!r}: a placement cannot show it (what shows it: {spec.reveal})")
            values = np.asarray(values, float).reshape(-1)
            if len(values) != spec.size or not np.all(np.isfinite(values)):
                raise InputError(f"rival {spec.name!r}: give its {spec.size} fitted values (finite), got {values!r}")
            if spec.name in names:
                raise InputError(f"rivals: {spec.name!r} is given twice in one set")
            known = [i for i, s in enumerate(specs) if s.name == spec.name]
            if not known:
                specs.append(spec)
            at.append(known[0] if known else len(specs) - 1)
            values_all.append(values)
            names.append(spec.name)
        label = " + ".join(names)
        if label in seen:
            raise InputError(f"rivals: {label!r} is given twice")
        seen.add(label)
        out.append((label, at, np.concatenate(values_all) if values_all else np.zeros(0)))
    if len(out) < 2:
        raise InputError("rivals: give two or more rival explanations to tell apart")
    return specs, out


def _pair_separation(info, prior_info, blocks, theta, a, b):
    """Separation of rival ``a`` (true at ``theta[a]``) from ``b`` refitted: (non-centrality, theta_b refitted).

    ``b`` is refitted to what ``a`` predicts by least squares with its weak prior (``info`` holds the data's
    information and the prior's, ``prior_info`` the prior's alone); the separation is the data's part only:
    the sum of the squared differences of the observables over the noise variance at that refit, the
    priors' penalties left out (a rival's typical magnitude is no measurement)."""
    ia, ib = blocks[a], blocks[b]
    data = info - prior_info
    Mab, Mbb = info[np.ix_(ia, ib)], info[np.ix_(ib, ib)]
    fitted = np.linalg.solve(Mbb, Mab.T @ theta[a])
    Daa, Dab, Dbb = data[np.ix_(ia, ia)], data[np.ix_(ia, ib)], data[np.ix_(ib, ib)]
    delta = theta[a] @ Daa @ theta[a] - 2 * theta[a] @ Dab @ fitted + fitted @ Dbb @ fitted
    return float(max(delta, 0.0)), fitted


def _separations(info, prior_info, blocks, theta, Jp=None) -> list[dict]:
    """Every pair's separation (the smaller direction) under ``info`` and, with ``Jp`` (a placement's
    projected sensitivities, mm per unit), the largest predicted difference of its observables, um."""
    out = []
    for a in range(len(blocks)):
        for b in range(a + 1, len(blocks)):
            best = None
            for x, y in ((a, b), (b, a)):
                delta, fitted = _pair_separation(info, prior_info, blocks, theta, x, y)
                if best is None or delta < best[0]:
                    diff = 0.0
                    if Jp is not None:
                        d = Jp[:, blocks[x]] @ theta[x] - Jp[:, blocks[y]] @ fitted
                        diff = float(np.max(np.abs(d))) * 1e3 if len(d) else 0.0
                    best = (delta, diff)
            out.append({"pair": (a, b), "separation": best[0], "difference_um": best[1]})
    return out


def _t_optimal(artefact_name, params, specs, theta, sigma, source, info, prior_info, before, status, options,
               unreachable, notes, budget) -> Plan:
    """The greedy T-optimal plan (:func:`plan`'s ``rivals``; ``theta``: each rival's (name, its specs' indices,
    its values), :func:`_rival_specs`). A rival's block is its effects' parameters: a set of effects is refitted
    together, and an effect two rivals share is one parameter block."""
    ranges, at = [], 0
    for spec in specs:
        ranges.append(np.arange(at, at + spec.size))
        at += spec.size
    names = [name for name, _, _ in theta]
    blocks = [np.concatenate([ranges[i] for i in idx]) for _, idx, _ in theta]
    theta = [values for _, _, values in theta]

    def named(seps):
        return [{"pair": [names[x["pair"][0]], names[x["pair"][1]]], "separation": round(x["separation"], 4),
                 "difference_um": round(x["difference_um"], 4)} for x in seps]

    now = _separations(info, prior_info, blocks, theta)
    notes.append("from the runs alone: " + "; ".join(
        f"{a} and {b} {x['separation']:.3g} apart in noise units" for x in named(now) for a, b in [x["pair"]]))
    proposals, used = [], set()
    for _ in range(min(int(budget), len(options))):
        best = None
        for i, (label, n, Fi, Jp) in enumerate(options):
            if i in used:
                continue
            worst = min(x["separation"] for x in _separations(info + Fi, prior_info, blocks, theta))
            if best is None or worst > best[1] + 1e-12:
                best = (i, worst)
        if best is None:
            break
        i, worst = best
        used.add(i)
        label, n, Fi, Jp = options[i]
        info = info + Fi
        seps = named(_separations(info, prior_info, blocks, theta, Jp))
        cov = np.linalg.inv(info)
        pn = [p for p, _, _ in params]
        proposals.append(Proposal(_shorthand(label), label, n, float(worst), dict(zip(pn, np.sqrt(np.diag(cov)))),
                                  [], _status(cov, pn, np.array([pr for _, _, pr in params])), seps))
        _log.info("plan: %s separates %s", proposals[-1].placement, separation_text(seps))
    if len(proposals) < budget:
        notes.append(f"only {len(proposals)} candidate placements reachable: fewer than the budget {budget}")
    return Plan(artefact_name, "T-optimal (Atkinson and Fedorov 1975): the smallest separation between two rival "
                "explanations (squared predicted differences over the noise variance, the rival refitted) "
                "maximised, greedy over the candidate placements", params, sigma * 1e3, source, before, status,
                proposals, len(options), unreachable, notes)


def separating_measurement(diagnosis, runs: Sequence[Run], machine=None) -> dict | None:
    """The diagnosis's "next" advice for its first open ambiguity set: the
    one placement, reachable on ``machine`` (default the thesis machine), of
    the runs' artefact that best tells its members apart (:func:`plan` with
    ``rivals``, budget 1). Sets and returns ``diagnosis.separating``
    (``placement``, ``artefact``, ``separates``: the pairs with their
    difference in um and separation in noise units), None when there is no
    open set or no placement can be planned (e.g. runs off the machine's
    travel: said in the log)."""
    sets = getattr(diagnosis, "open_ambiguity", [])
    if not sets:
        return None
    try:
        p = plan(list(runs), rivals=sets[0], budget=1, machine=machine, model=diagnosis.steps[-1].model)
    except (Error, ValueError, np.linalg.LinAlgError) as exc:
        _log.info("no placement planned to tell %s apart: %s", ", ".join(sets[0].names), exc)
        return None
    if not p.proposals:
        return None
    first = p.proposals[0]
    diagnosis.separating = {"placement": first.placement, "artefact": p.artefact,
                            "separates": [dict(x) for x in first.separates], "noise_um": round(p.sigma_um, 4)}
    return diagnosis.separating
