"""The Jacobian of a run's observables with respect to every candidate
parameter, named: the interface a measurement planner
(:mod:`cmmpose.diagnosis.plan`) and other tools use.

:func:`jacobian` returns, for a :class:`~cmmpose.diagnosis.identify.Problem`
(one run) or :class:`~cmmpose.diagnosis.joint.JointProblem` (several):

- ``names``: one per column, ``"<effect>.<parameter>"`` (e.g.
  ``"squareness.xy"``, ``"map:dx(X):sine170.3[169,729].sin_um"``);
- ``J`` (n, p): change of each observable per *prior magnitude* of each
  parameter, mm (rows in the problem's order: ``classes`` gives each row's
  class, index into :data:`cmmpose.evaluation.observables.CLASSES`, plus
  4 x run index in a joint problem);
- ``prior`` and ``units`` of each parameter (multiply a column by
  1 / prior to get mm per unit);
- ``sigma``: each class's noise level of the base fit, mm;
- ``nuisance`` (n, q): the columns every fit takes up first (bar length,
  radii);
- ``singular_values``: of the whitened, nuisance-projected, column-normalised
  J (how many directions the run determines; the planner's criterion acts on
  the same matrix).

Map corrections (:mod:`cmmpose.diagnosis.mapfamily`: each of the 18
per-axis components -- position errors, straightnesses and the three angles
of each axis, e.g. ``"map:ez(X):poly[169,729].p1_as"`` in arc-seconds -- and
the squarenesses when the library's named ``squareness`` is absent) are
included when ``map_corrections`` is true (their analytic centre-level
columns, linear in each shape's coefficients).
"""

from __future__ import annotations

import numpy as np

__all__ = ["jacobian"]


def jacobian(problem, model=None, *, map_corrections: bool = True) -> dict:
    """The named Jacobian of ``problem``'s observables (see the module docstring).

    Parameters
    ----------
    problem : Problem or JointProblem
    model : Model, optional
        The model whose effects count as fitted (projected out with the
        nuisances for the singular values); default the problem's base.
    map_corrections : bool
        Add the map-correction candidates first (if the problem lacks them).
    """
    from .cv import model_design
    from .diagnose import add_map_candidates

    model = problem.base if model is None else model
    if map_corrections and not any(getattr(s, "family", None) == "map" for s in problem.candidates.values()):
        add_map_candidates(problem, model)
    names, cols, prior, units = [], [], [], []
    for name, spec in problem.candidates.items():
        J = problem.columns.get(name)
        if J is None:
            continue
        for j, p in enumerate(spec.params):
            names.append(f"{name}.{p}")
            cols.append(J[:, j])
            prior.append(float(spec.prior[j]))
            units.append(spec.units[j])
    J = np.column_stack(cols) if cols else np.zeros((len(problem.classes), 0))
    X0, ridge, target = model_design(problem, model)
    sigma = problem.wls(problem.base_obs.residual, X0, ridge=ridge, target=target).sigma
    s = sigma[problem.classes]
    W0 = X0 / s[:, None]
    q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(s), 0))
    W = J / s[:, None]
    W = W - q @ (q.T @ W)
    norm = np.linalg.norm(W, axis=0)
    keep = norm > 0
    sv = np.linalg.svd(W[:, keep] / norm[keep], compute_uv=False) if keep.any() else np.zeros(0)
    return {"names": names, "J": J, "prior": np.array(prior), "units": units, "sigma": sigma,
            "classes": problem.classes, "nuisance": problem.nuisance, "singular_values": sv}
