"""Where a model holds: the domain it was fitted on, and the checks of data
it is applied to.

A found model is a fit: its effects' values are what the training runs
could determine, over the travel, the poses, the temperatures and the
artefact placements those runs covered. Applied elsewhere it extrapolates,
and a term the training data barely pinned down (a roll seen only in one
plane, a spline knot no ball came near) can move points by more than it
corrects. So a model records its :class:`Domain` (saved with it) and,
applied to a run or to points, says where the data leave it and how far
(:func:`domain_notes`), and how uncertain its correction is there
(:func:`correction_uncertainty`): the standard uncertainty of the
correction at each point, propagated from the parameters' covariance
through the model's own Jacobian (one step of each parameter through the
kernel, on a sample of the points).

Each note is a sentence naming what is outside and by how much. Applying
the model warns with them (:class:`cmmpose.ModelDomainWarning`); ``cmmpose
evaluate --model`` and ``cmmpose compensate --model`` print them, and their
``--strict-model`` turns them into exit status 1.

Tolerances (why these numbers): a sphere scan reaches a ball's radius and
the sweep's run-out beyond the ball's centre, so travel within
:data:`TRAVEL_MARGIN_MM` of the trained range counts as inside, and only a
share above :data:`OUTSIDE_SHARE` of the points outside it is said (a few
stray points are no new domain); temperatures within
:data:`TEMPERATURE_MARGIN_K` (the maps' own tolerance) are inside; a pose
whose Euler angles differ from every trained one by more than
:data:`POSE_MARGIN_DEG` is a new pose (the alignment library's repeatability
is ~0.01 degrees). A correction is called undetermined where its predicted
standard uncertainty is more than :data:`COMPARABLE` of its own rms and above
:data:`NEGLIGIBLE_UM` (a correction of a tenth of a micrometre with a large
relative uncertainty harms nothing).

Units: mm, degrees, degrees C, um.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .inputs import RunInputs

__all__ = ["COMPARABLE", "Domain", "NEGLIGIBLE_UM", "OUTSIDE_SHARE", "POSE_MARGIN_DEG", "TEMPERATURE_MARGIN_K",
           "TRAVEL_MARGIN_MM", "correction_uncertainty", "domain_notes", "parameter_jacobian",
           "uncertainty_notes"]

#: mm beyond the trained travel still inside (a ball's radius and the sweep's run-out).
TRAVEL_MARGIN_MM = 25.0
#: Share of the points outside the domain below which nothing is said.
OUTSIDE_SHARE = 0.01
#: K beyond the trained temperatures still inside (the maps' own tolerance).
TEMPERATURE_MARGIN_K = 0.5
#: Degrees: Euler angles this close to a trained pose's are that pose.
POSE_MARGIN_DEG = 0.5
#: A correction's predicted standard uncertainty above this share of its own rms: not determined.
COMPARABLE = 0.5
#: um: corrections and uncertainties below this are not worth a word.
NEGLIGIBLE_UM = 0.5
#: Points of the data the correction's uncertainty is propagated through (a sample, the same each time).
UNCERTAINTY_SAMPLE = 4000


@dataclass(frozen=True)
class Domain:
    """Where a model was fitted.

    Attributes
    ----------
    kinematics : str
        The machine configuration.
    poses : tuple of (alpha, beta, gamma)
        Euler 3-1-3 angles of the poses the training runs used, degrees
        (by angle, not by index: pose 1 of one run is not pose 1 of another).
    travel : tuple of 3 (lo, hi)
        The scale readings D, E, F the training points covered, mm.
    temperature : (lo, hi)
        Machine temperatures of the training points, C.
    layouts : tuple of str
        What the training runs measured: a ballbar layout, or an artefact
        with its placements (e.g. 'ball_plate xy@x=300,y=250,z=-400').
    runs : int
        Training runs.
    """

    kinematics: str
    poses: tuple[tuple[float, float, float], ...]
    travel: tuple[tuple[float, float], ...]
    temperature: tuple[float, float]
    layouts: tuple[str, ...] = ()
    runs: int = 1

    @classmethod
    def of_runs(cls, runs, inputs, kinematics: str) -> Domain:
        """The domain of training ``runs`` (Run objects) whose model inputs
        are ``inputs`` (one :class:`RunInputs` each)."""
        scales = np.concatenate([i.scales for i in inputs])
        temps = np.concatenate([i.temperature for i in inputs])
        poses = sorted({tuple(round(float(x), 6) for x in p[:3]) for i in inputs for p in i.poses})
        layouts = []
        for run in runs:
            a = run.artefact or {}
            if isinstance(a.get("definition"), dict):
                kind = a["definition"].get("kind", "artefact")
                layouts += [f"{kind} {p}" for p in (a.get("placements") or [])] or [str(kind)]
            else:
                layouts.append(f"{a.get('kind', 'ballbar')} {a.get('layout', '')}".strip())
        return cls(str(kinematics), tuple(poses),
                   tuple((float(lo), float(hi)) for lo, hi in zip(scales.min(axis=0), scales.max(axis=0))),
                   (float(temps.min()), float(temps.max())), tuple(dict.fromkeys(layouts)), len(runs))

    def to_dict(self) -> dict:
        return {"kinematics": self.kinematics, "poses_deg": [list(p) for p in self.poses],
                "travel_mm": {a: list(r) for a, r in zip("XYZ", self.travel)},
                "temperature_C": list(self.temperature), "layouts": list(self.layouts), "runs": self.runs}

    @classmethod
    def from_dict(cls, doc, where: str) -> Domain:
        """A saved domain, every number checked (``where`` names the file in errors)."""
        def numbers(value, n, key, lo=-1e5, hi=1e5):
            ok = (isinstance(value, list) and len(value) == n
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          and lo <= v <= hi for v in value))
            if not ok:
                raise InputError(f"{where}: domain.{key}: expected {n} finite numbers within [{lo:g}, {hi:g}], got "
                                 f"{value!r}", file=where, what=f"domain.{key}")
            return tuple(float(v) for v in value)

        if not isinstance(doc, dict):
            raise InputError(f"{where}: domain: expected a table, got {doc!r}", file=where, what="domain")
        try:
            travel = tuple(numbers(doc["travel_mm"][a], 2, f"travel_mm.{a}") for a in "XYZ")
            temperature = numbers(doc["temperature_C"], 2, "temperature_C", -273.15, 1000.0)
            poses = tuple(numbers(p, 3, "poses_deg", -720.0, 720.0) for p in doc["poses_deg"])
            kin, layouts, runs = doc["kinematics"], doc.get("layouts", []), doc.get("runs", 1)
        except (KeyError, TypeError) as exc:
            raise InputError(f"{where}: domain: missing or malformed {exc}", file=where, what="domain") from None
        if any(lo > hi for lo, hi in (*travel, temperature)):
            raise InputError(f"{where}: domain: a range's lower end is above its upper end", file=where,
                             what="domain")
        if not isinstance(kin, str) or not isinstance(layouts, list) or not all(isinstance(s, str) for s in layouts):
            raise InputError(f"{where}: domain: kinematics and layouts must be text", file=where, what="domain")
        if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
            raise InputError(f"{where}: domain.runs: expected a count >= 1, got {runs!r}", file=where,
                             what="domain.runs")
        return cls(kin, poses, travel, temperature, tuple(layouts), runs)

    def describe(self) -> str:
        """The domain in one line."""
        trav = ", ".join(f"{a} {lo:.0f}..{hi:.0f} mm" for a, (lo, hi) in zip("XYZ", self.travel))
        poses = "; ".join("(" + ", ".join(f"{x:g}" for x in p) + ")" for p in self.poses)
        return (f"{self.runs} run(s): {', '.join(self.layouts) or 'no artefact named'}; travel {trav}; "
                f"{self.temperature[0]:.2f}..{self.temperature[1]:.2f} C; poses {poses} deg")


def domain_notes(domain: Domain | None, inputs: RunInputs) -> list[str]:
    """Where data whose model inputs are ``inputs`` leave ``domain``, one
    sentence each (empty: inside, or no domain recorded)."""
    if domain is None or not len(inputs.scales):
        return []
    out = []
    n = len(inputs.scales)
    for a, (lo, hi) in enumerate(domain.travel):
        q = inputs.scales[:, a]
        below, above = lo - TRAVEL_MARGIN_MM - q, q - hi - TRAVEL_MARGIN_MM
        outside = (below > 0) | (above > 0)
        if np.count_nonzero(outside) > OUTSIDE_SHARE * n:
            far = float(max(below.max(), above.max()) + TRAVEL_MARGIN_MM)
            out.append(f"{'XYZ'[a]} travel {q.min():.0f} to {q.max():.0f} mm leaves the {lo:.0f} to {hi:.0f} mm the "
                       f"model was fitted on by up to {far:.0f} mm ({100 * np.count_nonzero(outside) / n:.0f} % of "
                       f"the points): its effects are extrapolated there")
    t = inputs.temperature
    t_lo, t_hi = domain.temperature
    off = np.maximum(t_lo - TEMPERATURE_MARGIN_K - t, t - t_hi - TEMPERATURE_MARGIN_K)
    if np.count_nonzero(off > 0) > OUTSIDE_SHARE * n:
        out.append(f"machine temperature {t.min():.2f} to {t.max():.2f} C leaves the {t_lo:.2f} to {t_hi:.2f} C the "
                   f"model was fitted on by up to {float(off.max()) + TEMPERATURE_MARGIN_K:.2f} K")
    trained = np.array(domain.poses, float).reshape(-1, 3)
    used = np.bincount(inputs.pose_index, minlength=len(inputs.pose_ids))
    for k, pose in enumerate(inputs.poses):
        if not used[k] or not len(trained):
            continue
        diff = np.abs((trained - pose[:3] + 180.0) % 360.0 - 180.0).max(axis=1)
        if diff.min() > POSE_MARGIN_DEG:
            near = trained[int(np.argmin(diff))]
            out.append(f"pose {inputs.pose_ids[k]} at ({', '.join(f'{x:g}' for x in pose[:3])}) deg is not a pose the "
                       f"model was fitted on (nearest: ({', '.join(f'{x:g}' for x in near)}) deg, {diff.min():.1f} deg "
                       f"away)")
    return out


def correction_uncertainty(model, inputs: RunInputs, xyz: np.ndarray | None = None) -> dict:
    """The model's correction beyond its plain maps at (a sample of) the
    points of ``inputs``, and its predicted standard uncertainty.

    The Jacobian of the compensated points in each effect parameter is one
    forward step (the effect's ``steps``) through the kernel; the
    uncertainty of each point's correction is ``sqrt(diag(J C J^T))`` with C
    the parameters' covariance (:attr:`cmmpose.Model.covariance`, else their
    standard uncertainties as independent). A parameter the training data
    did not determine on its own (infinite uncertainty) enters through the
    covariance where it covers it (the diagnosis keeps the covariance of the
    projected values it applies: a combination of spline knots); one the
    covariance does not cover is reported by how far it moves the points.

    Returns
    -------
    dict
        ``correction_um`` (rms over the sample of |model - plain maps|),
        ``uncertainty_um`` (rms of the points' standard uncertainty, k = 1,
        the 3-D magnitude), ``largest_uncertainty_um``, ``undetermined``
        (list of (parameter, largest move um)), ``points`` (sample size).
    """
    n = len(inputs.uv)
    rows = np.arange(n) if n <= UNCERTAINTY_SAMPLE else \
        np.sort(np.random.default_rng(0).choice(n, UNCERTAINTY_SAMPLE, replace=False))
    sub = inputs.take(rows)
    base = model.compensate(sub) if xyz is None else np.asarray(xyz)[rows]
    plain = model.without_effects().compensate(sub)
    corr = np.linalg.norm(base - plain, axis=1) * 1e3
    names, J, undetermined = parameter_jacobian(model, sub, base)
    var = np.zeros(len(rows))
    if names:
        C = model.parameter_covariance(names)
        var = np.einsum("mik,kl,mil->m", J, C, J) * 1e6
    sd = np.sqrt(np.clip(var, 0.0, None))
    return {"correction_um": float(np.sqrt(np.mean(corr ** 2))) if len(corr) else 0.0,
            "uncertainty_um": float(np.sqrt(np.mean(var))) if len(var) else 0.0,
            "largest_uncertainty_um": float(sd.max()) if len(sd) else 0.0,
            "undetermined": undetermined, "points": int(len(rows))}


def parameter_jacobian(model, inputs: RunInputs, base: np.ndarray):
    """The compensated points' Jacobian in each effect parameter the model's
    covariance covers, or that has a finite uncertainty (one forward step,
    the effect's ``steps``, through the kernel).

    Returns
    -------
    names : list of str
        ``'effect.param'`` of each column.
    J : ndarray (N, 3, k)
        mm per parameter unit.
    undetermined : list of (str, float)
        Parameters the training data did not determine (infinite
        uncertainty) and that no covariance covers, and how far they move
        the points at most, um.
    """
    names, columns, undetermined = [], [], []
    # A parameter not determined on its own whose applied value is in the covariance (a knot of which the data
    # determine a combination: the value is projected onto it) enters through the covariance.
    covered = set(model.covariance.get("parameters", ()))
    for spec, values in model.effects:
        u = np.ravel(model.uncertainty.get(spec.name, np.full(spec.size, np.nan)))
        for j, param in enumerate(spec.params):
            name = f"{spec.name}.{param}"
            if np.isnan(u[j]) or (u[j] == 0 and name not in covered):
                continue
            v = np.array(values, dtype=float)
            step = float(spec.steps[j])
            v[j] += step
            jac = (model.with_values(spec, v).compensate(inputs) - base) / step  # mm per unit
            if np.isinf(u[j]) and name not in covered:
                move = float(np.max(np.linalg.norm(jac, axis=1)) * abs(float(values[j]))) * 1e3
                undetermined.append((name, move))
                continue
            names.append(name)
            columns.append(jac)
    J = np.stack(columns, axis=2) if columns else np.zeros((len(base), 3, 0))
    return names, J, undetermined


def uncertainty_notes(found: dict) -> list[str]:
    """Sentences for a :func:`correction_uncertainty` result: a correction
    as uncertain as itself, and undetermined parameters that move points."""
    out = []
    c, u = found["correction_um"], found["uncertainty_um"]
    if u > NEGLIGIBLE_UM and u > COMPARABLE * c:
        out.append(f"the model's correction here ({c:.2f} um rms beyond the plain maps) has a predicted standard "
                   f"uncertainty of {u:.2f} um rms (up to {found['largest_uncertainty_um']:.2f} um) from its "
                   f"parameters' covariance: the data it was fitted on do not determine it here")
    for name, move in found["undetermined"]:
        if move > NEGLIGIBLE_UM:
            out.append(f"the model's parameter {name} was not determined by the data it was fitted on, and moves "
                       f"these points by up to {move:.2f} um")
    return out
