"""The sensitivities of an artefact run's observables (:mod:`cmmpose.evaluation.artefact_layout`:
each ball's deviation from its calibrated place after its placement's
rigid fit) to an effect's parameters, by linearised sphere fits of a sample
of each scan's points. Units: mm.
"""

from __future__ import annotations

import numpy as np

from ..evaluation.artefact_layout import artefact_deviations
from ..model.model import inputs_with_incidence

__all__ = ["FIT_SAMPLE", "artefact_columns", "linearised_columns"]


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
    return spec.kind == "kernel" and not getattr(spec.effect, "on_scanner", False)


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
        if inputs.incidence is None and any("incidence" in s.needs for s in problem.candidates.values()):
            # An effect that needs the incidence (what it declares, not its name) reads angles from sphere fits of every point under the maps
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
        cache.update(of=problem.inputs, maps=model.maps, inputs=inputs.take(rows), scan=scan,
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
