"""The observables of an artefact run (ball plate, step gauge, ...; docs/artefacts.md)
for a diagnosis: each ball's centre per placement relative to its
calibrated centre after the placement's best-fit rigid transform, as
:mod:`cmmpose.evaluation.artefact` defines the deviation.

For each placement the calibrated centres (the certificate's, in the
artefact's frame) are expanded to the placement's mean machine temperature
with the artefact's own coefficient, times the model's
``artefact-expansion`` (an error in that coefficient), and moved onto the
measured centres (the mean of each ball's scans) by the rigid transform that
minimises the sum of squared distances (Kabsch). What is left, three
components per ball in the machine frame, is what the diagnosis explains:
the rigid fit takes away the six (five for balls in a row) degrees of
freedom of each placement, which the statistics count
(:attr:`ArtefactLayout.fitted_dof`).

Units: mm, degrees C.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import artefacts
from ..evaluation.artefact import ball_scans, check_ball_positions, rigid_fit
from ..artefacts._base import line_distance
from .model import inputs_with_incidence

__all__ = ["ArtefactLayout", "artefact_columns", "artefact_deviations", "linearised_columns", "rigid_dof"]


@dataclass(frozen=True)
class ArtefactLayout:
    """Which physical spheres of a run are which balls of which placement.

    Attributes
    ----------
    artefact : cmmpose.artefacts.Artefact
        The artefact the run embeds.
    positions : tuple of int
        The placements measured (1-based), ascending.
    spheres : tuple of ndarray
        Per placement, the physical-sphere indices (of the observation
        layout) of its balls, in ascending ball id.
    balls : tuple of ndarray
        Per placement, the ball ids.
    calibrated : tuple of ndarray (n, 3)
        Per placement, the certificate's centres of its balls (artefact
        frame, at the certificate's temperature), mm.
    temperature : ndarray (P,)
        Mean machine temperature while each placement was scanned, C.
    """

    artefact: artefacts.Artefact
    positions: tuple[int, ...]
    spheres: tuple[np.ndarray, ...]
    balls: tuple[np.ndarray, ...]
    calibrated: tuple[np.ndarray, ...]
    temperature: np.ndarray

    @classmethod
    def from_run(cls, run, uniq: list, sphere_temperature) -> ArtefactLayout:
        """The layout of an artefact run.

        Parameters
        ----------
        run : cmmpose.Run
            A run that embeds its artefact (``run.artefact['definition']``).
        uniq : list of (feature, position, ball)
            The observation layout's physical spheres.
        sphere_temperature : callable
            ``sphere_temperature(indices)``: mean machine temperature (C)
            over the points of those spheres' scans.

        Raises
        ------
        InputError
            A scan labelled with a ball the artefact lacks or a placement the
            run does not record (as the evaluation does).
        """
        artefact = artefacts.from_dict(run.artefact["definition"], "run.json: artefact.definition")
        recorded = run.artefact.get("placements")
        ball_scans(run, artefact, len(recorded) if isinstance(recorded, list) else None)  # checks the labels
        positions = sorted({p for f, p, _ in uniq if f == "ball"})
        spheres, balls, calibrated, temps = [], [], [], []
        for pos in positions:
            ids = sorted(b for f, p, b in uniq if f == "ball" and p == pos)
            idx = np.array([uniq.index(("ball", pos, b)) for b in ids], dtype=int)
            spheres.append(idx)
            balls.append(np.array(ids, dtype=int))
            calibrated.append(artefact.centres[[artefact.index(b) for b in ids]])
            temps.append(float(sphere_temperature(idx)))
        return cls(artefact, tuple(positions), tuple(spheres), tuple(balls), tuple(calibrated), np.array(temps))

    @property
    def n_balls(self) -> int:
        """Balls measured over all placements."""
        return int(sum(len(s) for s in self.spheres))

    @property
    def size(self) -> int:
        """Observables: three deviation components per ball and placement."""
        return 3 * self.n_balls

    @property
    def fitted_dof(self) -> int:
        """Degrees of freedom the placements' rigid fits take: 6 per placement
        (5 for balls in a row, within a ball radius of one line, whose roll
        about that line moves them by nanometres; 3 for one ball), never more
        than the placement's observables."""
        return sum(rigid_dof(c, self.artefact.nominal_radius) for c in self.calibrated)


def rigid_dof(centres: np.ndarray, radius: float) -> int:
    """Degrees of freedom a rigid fit of ``centres`` (n, 3, mm) takes: 6; 5
    for balls within ``radius`` (mm) of one line (a step gauge, whose roll
    about its line moves them by nanometres); 3 for one ball; never more
    than the 3n coordinates."""
    n = len(centres)
    if n == 1:
        return 3
    dof = 5 if n == 2 or line_distance(centres).max() <= radius else 6
    return min(dof, 3 * n)


def check_placements(layout: ArtefactLayout, mean_centres: np.ndarray) -> None:
    """``InputError`` when a ball of a placement lies further from its
    calibrated place than any machine error could take it (mislabelled or
    mismeasured), as the evaluation checks it
    (:func:`cmmpose.evaluation.artefact.check_ball_positions`).

    Parameters
    ----------
    layout : ArtefactLayout
    mean_centres : ndarray (S, 3)
        Mean centre of each physical sphere of a run's first observation, mm.
    """
    a = layout.artefact
    for pos, balls, idx, temp in zip(layout.positions, layout.balls, layout.spheres, layout.temperature):
        check_ball_positions(a, f"scans: position {pos} of the run of {a.name!r}", balls, mean_centres[idx],
                             a.centres * float(a.scale_to(temp)))


def artefact_deviations(layout: ArtefactLayout, mean_centres: np.ndarray,
                        expansion_ppm_per_kelvin: float = 0.0) -> np.ndarray:
    """Each ball's deviation per placement, (n_balls, 3) mm, placements in order.

    Parameters
    ----------
    layout : ArtefactLayout
    mean_centres : ndarray (K, 3)
        Mean measured centre of each physical sphere, mm.
    expansion_ppm_per_kelvin : float
        The model's artefact expansion on top of the certificate's
        coefficient, ppm/K.

    """
    a = layout.artefact
    out = []
    for idx, cal, temp in zip(layout.spheres, layout.calibrated, layout.temperature):
        m = mean_centres[idx]
        c = cal * (float(a.scale_to(temp)) * (1.0 + expansion_ppm_per_kelvin * 1e-6 * (temp - 20.0)))
        r, t = rigid_fit(c, m)
        out.append(m - (c @ r.T + t))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _sample_inputs(inputs, rows: np.ndarray):
    """The run inputs of the points ``rows`` only (every per-point array taken)."""
    def take(a):
        return None if a is None else np.ascontiguousarray(a[rows])

    return replace(inputs, uv=take(inputs.uv), scales=take(inputs.scales), t=take(inputs.t),
                   scan_id=take(inputs.scan_id), pose_index=take(inputs.pose_index),
                   temperature=take(inputs.temperature), axis_temperature=take(inputs.axis_temperature),
                   gradient=take(inputs.gradient), velocity=take(inputs.velocity), incidence=take(inputs.incidence),
                   role_temperatures={k: take(v) for k, v in inputs.role_temperatures.items()},
                   sensors={k: take(v) for k, v in inputs.sensors.items()})


#: Points per scan whose linearised sphere fit gives a scan's change of centre
#: and radius in :func:`artefact_columns` (drawn at random, the same each time).
FIT_SAMPLE = 1000


def linearised_columns(spec) -> bool:
    """Whether :func:`artefact_columns` takes ``spec``'s columns: the artefact's
    expansion, and the kernel effects of the machine (not the scanner's),
    whose displacement over one ball is nearly a translation that a sample
    of its points carries; the scanner's and the pose's effects reshape each
    ball, and only a fit of all its points sees their small centre shifts."""
    if spec.kind == "length":
        return True
    return spec.kind == "kernel" and not getattr(spec.effect, "on_scanner", False) and spec.key != "incidence"


def artefact_columns(problem, model, spec, current: np.ndarray, obs) -> np.ndarray:
    """Residual change per prior magnitude of each parameter of ``spec`` on an
    artefact run (as :meth:`cmmpose.diagnosis.identify.Problem._columns`,
    for the effects :func:`linearised_columns` takes), from centre-level
    quantities: the kernel compensates only a fixed random sample of each
    scan's points (FIT_SAMPLE, and the layout's observed point residuals),
    and the change of each scan's sphere fit is the Gauss-Newton step of the
    fit linearised at ``obs`` (each point's shift along its sphere normal,
    projected on the centre and radius), not a refit of every point.

    The balls' deviations then follow from the changed mean centres through
    each placement's rigid fit (:func:`artefact_deviations`, exactly), the
    repeated-scan, radius and point-residual blocks to first order. A
    forward step that cannot be evaluated (it leaves the maps' range) is
    taken backward, as the finite differences do.

    Parameters
    ----------
    problem : cmmpose.diagnosis.identify.Problem
        Its layout (``layout.artefact`` set) and inputs.
    model : Model
        The model the columns are taken at.
    spec : EffectSpec
        The effect; its ``steps`` and ``prior`` as for finite differences.
    current : ndarray
        The effect's current values in ``model``.
    obs : Observed
        ``problem.observe(model)``.

    Returns
    -------
    ndarray (n_observables, spec.size)
    """
    layout = problem.layout
    cache = problem.__dict__.setdefault("_artefact_sample", {})
    if cache.get("of") is not problem.inputs or cache.get("maps") is not model.maps:
        inputs = problem.inputs
        if inputs.incidence is None and any(s.key == "incidence" for s in problem.candidates.values()):
            # The incidence effect reads angles from sphere fits of every point under the maps
            # alone (whatever the effects): the model would take them on each call; take them once.
            inputs = inputs_with_incidence(model, inputs)
        sid = inputs.scan_id
        order = np.argsort(sid, kind="stable")
        starts = np.searchsorted(sid[order], layout.labels)
        stops = np.searchsorted(sid[order], layout.labels, side="right")
        rng = np.random.default_rng(0)
        drawn = [order[a + np.sort(rng.choice(b - a, min(FIT_SAMPLE, b - a), replace=False))]
                 for a, b in zip(starts, stops)]
        rows, inverse = np.unique(np.concatenate([*drawn, layout.sample]), return_inverse=True)
        scan = np.searchsorted(layout.labels, sid[rows])
        by_scan = np.argsort(scan, kind="stable")  # the sample in scan order: sums per scan are reduceat
        where = np.empty(len(rows), int)
        where[by_scan] = np.arange(len(rows))
        rows, scan = rows[by_scan], scan[by_scan]
        cache.update(of=problem.inputs, maps=model.maps, inputs=_sample_inputs(inputs, rows), scan=scan,
                     edges=np.searchsorted(scan, np.arange(len(layout.labels))),
                     observed=where[inverse[-len(layout.sample):]], at=None)
    sample, scan, edges, observed = (cache[k] for k in ("inputs", "scan", "edges", "observed"))

    def per_scan(values):  # sums over each scan's sample points, (S, ...)
        return np.add.reduceat(values, edges, axis=0)

    if cache["at"] is None or cache["at"][0] is not model or cache["at"][1] is not obs:
        # the linearised fits at this model, for all its columns
        base = model.compensate(sample)
        normal = base - obs.centres[scan]
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        # Per scan, the normal equations of (centre, radius) from d(residual) = n . (dx - dc) - dr
        nn = per_scan(np.einsum("ij,ik->ijk", normal, normal).reshape(-1, 9)).reshape(-1, 3, 3)
        ns = per_scan(normal)
        cnt = np.diff(np.r_[edges, len(scan)]).astype(float)
        eq = np.zeros((len(edges), 4, 4))
        eq[:, :3, :3], eq[:, :3, 3], eq[:, 3, :3], eq[:, 3, 3] = nn, ns, ns, cnt
        cache.update(at=(model, obs), base=base, normal=normal, solve=np.linalg.inv(eq))
    base, normal, solve = cache["base"], cache["normal"], cache["solve"]
    counts = np.bincount(layout.sphere_of_scan, minlength=len(layout.sphere_kind))
    mean_c = np.zeros((len(layout.sphere_kind), 3))
    np.add.at(mean_c, layout.sphere_of_scan, obs.centres)
    mean_c /= np.maximum(counts, 1)[:, None]
    at = layout.sample_scan

    def change(values) -> np.ndarray:
        moved = model.with_values(spec, values)
        shift = np.zeros_like(base) if spec.kind == "length" else moved.compensate(sample) - base
        along = np.einsum("ij,ij->i", normal, shift)
        rhs = np.column_stack([per_scan(normal * along[:, None]), per_scan(along)])
        step = np.einsum("sij,sj->si", solve, rhs)  # each scan's (centre, radius)
        d_centre, d_radius = step[:, :3], step[:, 3]
        d_mean = np.zeros_like(mean_c)
        np.add.at(d_mean, layout.sphere_of_scan, d_centre)
        d_mean /= np.maximum(counts, 1)[:, None]
        deviations = artefact_deviations(layout.artefact, mean_c + d_mean, moved.expansion_ppm_per_kelvin)
        d_first = deviations.reshape(-1) - obs.deviations.reshape(-1)
        d_repeat = (d_centre - d_mean[layout.sphere_of_scan])[layout.repeated].reshape(-1)
        d_point = along[observed] - np.einsum("ij,ij->i", normal[observed], d_centre[at]) - d_radius[at]
        return np.concatenate([d_first, d_repeat, d_radius, d_point])

    return spec.difference_columns(current, change)
