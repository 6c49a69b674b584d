"""Is what the final model leaves noise? The noise floor from the data, a
stated test against it, and errors that vary along two axes at once.

Noise floor (:func:`noise_floor`). The headline figure (ballbar lengths, or
an artefact's ball deviations) cannot be noisier than the centres it is
made of. The per-scan centre reproducibility comes from the data where the
run repeats scans of a sphere (Type A: the centre-disagreement class's
standard deviation per axis, with its (k - 1) degrees of freedom per sphere
of k scans); else from a stated ``reproducibility_um`` (per scan, per
axis); else there is no floor and the diagnosis says so. The floor of a
length is ``sqrt(1/n1 + 1/n2) * sigma_c`` (two ball centres, each the mean of
its n scans); of a deviation component ``sigma_c / sqrt(n)``.

The test: the final model's headline residuals r (after its fit: dof = rows
- fitted parameters acting on them) against the floor f; chi2 = sum (r/f)^2
is chi-square with dof degrees of freedom if the residuals are noise at the
floor. "The residuals look like noise" is said only when its upper-tail p
is above FLOOR_ALPHA; otherwise "N um is unexplained above a floor of M um"
with N = sqrt(rms^2 - floor^2), naming the observable.

Two-axis errors (:func:`two_axis_findings`). An error along one direction
varying with the product of two axes' positions (a twisted table: Z error ~
x*y) is outside every rigid-body map: each map component is a function of
one axis. For each of the 9 (direction, axis pair) products the centre-level
sensitivity (as :mod:`cmmpose.diagnosis.mapfamily`) is tested against the
final model (whitened chi-square gain, 1 dof, Bonferroni over the 9 at
ALPHA); a significant one is reported as unexplained, with its axes and its
size over the travel the run used, not forced into a one-axis candidate.
"""

from __future__ import annotations

import math

import numpy as np

from ..evaluation.observables import CLASSES
from .cv import model_design
from .mapfamily import observable_change, reading_subset, travel_range, whitened_gain
from .statistics import ALPHA, chi2_sf

__all__ = ["FLOOR_ALPHA", "headline_floors", "noise_floor", "two_axis_findings"]

#: Upper-tail probability below which the residual scatter is not noise at the floor.
FLOOR_ALPHA = 0.01


def _parts(problem):
    return getattr(problem, "parts", None) or [problem]


def headline_floors(layout, centre_sigma: float) -> np.ndarray:
    """The floor of each headline observable of a run (``layout``: an
    ObservationLayout) when each scan's centre scatters by ``centre_sigma``
    per axis (mm): a length's sqrt(1/n1 + 1/n2) * sigma, a deviation
    component's sigma / sqrt(n) (n: scans of the sphere)."""
    counts = np.bincount(layout.sphere_of_scan, minlength=len(layout.sphere_kind)).astype(float)
    if layout.artefact is None:
        return centre_sigma * np.sqrt(1 / counts[layout.ends[:, 0]] + 1 / counts[layout.ends[:, 1]])
    return np.repeat(centre_sigma / np.sqrt(counts[np.concatenate(layout.artefact.spheres)]), 3)


def noise_floor(problem, step, reproducibility_um: float | None = None) -> dict:
    """The noise floor of the headline figure and whether ``step``'s model
    reaches it (see the module docstring).

    Returns
    -------
    dict
        ``source`` ('repeated scans (Type A)', 'stated', or None),
        ``centre_reproducibility_um``, ``floor_um`` (rms of the headline at
        the floor), ``rms_um`` (the model's in-sample headline rms),
        ``chi2``, ``dof``, ``p_value``, ``noise`` (bool or None),
        ``unexplained_um`` and ``verdict`` (words).
    """
    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge, target = model_design(problem, step.model)
    fit = problem.wls(r0, X0, ridge=ridge, target=target)
    res = fit.residual
    head = problem.classes % len(CLASSES) == 0
    centre_cls = problem.classes % len(CLASSES) == 1
    n_rep = float(np.sum(problem.n_eff[1::len(CLASSES)])) if hasattr(problem, "n_eff") else 0.0
    source, sc = None, None
    if centre_cls.any() and n_rep >= 3:
        sc = math.sqrt(float(np.sum(res[centre_cls] ** 2)) / n_rep)
        source = "repeated scans (Type A)"
    elif reproducibility_um is not None:
        sc = reproducibility_um * 1e-3
        source = "stated"
    what = "ballbar length" if problem.layout.artefact is None else "ball deviation"
    if sc is None or not head.any():
        return {"source": None, "centre_reproducibility_um": None, "floor_um": None,
                "rms_um": float(np.sqrt(np.mean(res[head] ** 2)) * 1e3) if head.any() else None, "chi2": None,
                "dof": None, "p_value": None, "noise": None, "unexplained_um": None,
                "verdict": ("no noise floor: the run repeats no scan of a sphere and no per-scan reproducibility "
                            "was stated (repeat a few scans, or give one), so whether the residuals are noise "
                            "cannot be said")}
    f = np.concatenate([headline_floors(p.layout, sc) for p in _parts(problem)])
    r = res[head]
    k_head = int(np.linalg.matrix_rank(X0[head])) if X0.shape[1] else 0
    if problem.layout.artefact is not None:
        k_head += 6 * sum(len(p.layout.artefact.positions) for p in _parts(problem))  # each placement's rigid fit
    dof = max(len(r) - k_head, 1)
    chi2 = float(np.sum((r / f) ** 2))
    p = chi2_sf(chi2, dof)
    rms = float(np.sqrt(np.sum(r ** 2) / dof)) * 1e3
    floor = float(np.sqrt(np.mean(f ** 2))) * 1e3
    noise = p >= FLOOR_ALPHA
    extra = math.sqrt(max(rms ** 2 - floor ** 2, 0.0))
    if noise:
        words = (f"the residuals look like noise: {what} rms {rms:.2f} um against a floor of {floor:.2f} um "
                 f"({source}; chi2 {chi2:.1f} on {dof} dof, p = {p:.2g} >= {FLOOR_ALPHA:g})")
    else:
        words = (f"{extra:.2f} um is unexplained above a floor of {floor:.2f} um in the {what}s "
                 f"(rms {rms:.2f} um; {source}; chi2 {chi2:.1f} on {dof} dof, p = {p:.2g} < {FLOOR_ALPHA:g})")
    return {"source": source, "centre_reproducibility_um": sc * 1e3, "floor_um": floor, "rms_um": rms,
            "chi2": chi2, "dof": int(dof), "p_value": p, "noise": bool(noise),
            "unexplained_um": extra, "verdict": words}


def two_axis_findings(problem, step, alpha: float = ALPHA) -> list[dict]:
    """Errors along one direction that vary with the product of two axes'
    positions, which ``step``'s model leaves (see the module docstring).

    Returns
    -------
    list of dict
        ``_column`` (its sensitivity, mm per um at the corners; not for
        JSON), ``direction`` ('x', 'y', 'z'), ``axes`` (e.g. 'XY'), ``size_um``
        (the fitted error at the corners of the travel used: the
        coefficient times the half-ranges' product), ``p_value``,
        ``threshold``, ``description``.
    """

    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge, target = model_design(problem, step.model)
    fit = problem.wls(r0, X0, ridge=ridge, target=target)
    s = fit.sigma[problem.classes]
    W0 = X0 / s[:, None]
    W0q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(r0), 0))
    rw = fit.residual / s
    rows = np.flatnonzero(np.isin(problem.classes % len(CLASSES), (0, 1, 2)))
    travel = travel_range(problem)
    mid = [(a + b) / 2 for a, b in travel]
    half = [max((b - a) / 2, 1e-9) for a, b in travel]
    tests = [(d, i, j) for d in range(3) for i, j in ((0, 1), (1, 2), (0, 2))]
    threshold = alpha / len(tests)
    out = []
    for d, i, j in tests:
        if half[i] < 15 or half[j] < 15:  # the run does not move along both
            continue
        cols = []
        for p in _parts(problem):
            q = reading_subset(p)["q"]
            field = np.zeros((len(q), 3, 1))
            field[:, d, 0] = (q[:, i] - mid[i]) / half[i] * (q[:, j] - mid[j]) / half[j]
            cols.append(observable_change(p, p.base_obs, field))
        J = np.concatenate(cols) * 1e-3  # per um at the corners
        gain = whitened_gain(W0q, rw, J / s[:, None], rows)
        pv = chi2_sf(gain, 1)
        if pv < threshold:
            Jw = J / s[:, None]
            P = Jw - W0q @ (W0q.T @ Jw)
            coef = float(-(P[:, 0] @ rw) / max(P[:, 0] @ P[:, 0], 1e-300))
            axes = "XYZ"[i] + "XYZ"[j]
            out.append({"_column": J[:, 0], "direction": "xyz"[d], "axes": axes, "size_um": abs(coef), "p_value": pv,
                        "threshold": threshold,
                        "description": (f"a {'xyz'[d]} error varying with {axes[0]} and {axes[1]} together "
                                        f"({'xyz'[d]} ~ {axes[0].lower()}*{axes[1].lower()}), {abs(coef):.1f} um at "
                                        f"the corners of the travel used: outside every one-axis map "
                                        f"component (a twisted table, a warped guide); unexplained")})
    return sorted(out, key=lambda f: f["p_value"])


def explained_beyond(problem, step, finding: dict, columns: np.ndarray) -> float:
    """p-value of ``columns`` (a candidate's sensitivities) beyond ``step``'s
    model *and* the two-axis ``finding``: small when the candidate explains
    something the two-axis error does not."""

    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge, target = model_design(problem, step.model)
    fit = problem.wls(r0, X0, ridge=ridge, target=target)
    s = fit.sigma[problem.classes]
    W = np.column_stack([X0, finding["_column"]]) / s[:, None]
    Wq = np.linalg.qr(W)[0]
    rw = r0 / s
    rw = rw - Wq @ (Wq.T @ rw)
    gain = whitened_gain(Wq, rw, columns / s[:, None])
    return chi2_sf(gain, columns.shape[1])
