"""The covariance of a found model's parameters, and what the data determine of them.

The weighted least-squares covariance of the linearised diagnosis problem
(:class:`~cmmpose.diagnosis.identify.Problem`) at a model, without the weak
prior (:func:`model_uncertainties`, :func:`model_covariance`: what a saved
model keeps to predict the uncertainty of its correction elsewhere); the values
a saved model applies, with every combination the data do not determine taken
out (:func:`determined_values`); and the covariance of a whitened design by
its column-normalised SVD, with the parameters it leaves free
(:func:`design_covariance`, :func:`design_variances`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ._blas import one_blas_thread

if TYPE_CHECKING:
    from .identify import Problem

__all__ = ["model_uncertainties", "model_covariance", "determined_values", "design_covariance", "design_variances",
           "UNDETERMINED_RCOND", "UNDETERMINED_SHARE", "UNDETERMINED_PRIORS"]


@one_blas_thread
def model_uncertainties(problem: Problem, model) -> dict[str, np.ndarray]:
    """Standard uncertainty of every parameter of the effects in ``model``
    (each effect's units), jointly with the nuisances and each other: the
    weighted least-squares covariance of the linearised problem at ``model``,
    without the weak prior (the data's own uncertainty). inf where the run
    does not determine a parameter."""
    return model_covariance(problem, model)[0]


def model_covariance(problem: Problem, model) -> tuple[dict[str, np.ndarray], dict]:
    """:func:`model_uncertainties`, and the covariance of the values a saved
    model applies (``{"parameters": ["effect.param", ...], "matrix": (k, k)}``
    in their units; empty without effects): what a saved model keeps to
    predict the uncertainty of its correction elsewhere
    (:mod:`cmmpose.model.domain`).

    A parameter the data do not determine on its own (a spline knot of which
    only a combination is seen, inf in the uncertainties) is still in the
    matrix: the model applies its value projected onto what the data
    determine (:func:`determined_values`), and the matrix is the
    pseudo-inverse covariance of exactly that projection, so the correction's
    predicted uncertainty ``J C J^T`` holds for what is applied. A parameter
    the data do not see at all (its column is zero: it keeps no value) is left
    out."""
    design = _effects_design(problem, model)
    if design is None:
        return {}, {}
    cov, free = design_covariance(design.whitened_r)
    var = np.diag(cov)
    out, pos = {}, design.k0
    for name, k in design.index:
        prior = np.asarray(problem.candidates[name].prior, float)
        sd = np.sqrt(np.clip(var[pos:pos + k], 0.0, None)) * prior
        # A parameter the data alone cannot tell from zero at UNDETERMINED_PRIORS typical magnitudes is not
        # determined by them: its fitted value is the prior's (an XY-plane run's squareness yz and zx).
        out[name] = np.where(free[pos:pos + k] | (sd > UNDETERMINED_PRIORS * np.abs(prior)), np.inf, sd)
        pos += k
    live = ~design.zero
    if not live.any():
        return out, {}
    # Normalised coordinates c = value / prior * norm: A = Re / norm = U S V^T; what is applied is the part of c
    # on the kept right singular vectors, whose covariance is V_k S_k^-2 V_k^T (the pseudo-inverse's).
    _, s, vt = np.linalg.svd(design.normalised(), full_matrices=False)
    keep = s > UNDETERMINED_RCOND * (s[0] if len(s) and s[0] > 0 else 1.0)
    w = vt[keep].T / s[keep]
    scale = design.prior[live] / design.norm[live]
    matrix = (w @ w.T) * np.outer(scale, scale)
    names = [f"{name}.{param}" for name, k in design.index for param in problem.candidates[name].params]
    names = [n for n, ok in zip(names, live) if ok]
    return out, {"parameters": names, "matrix": (matrix + matrix.T) / 2}


@dataclass(frozen=True)
class _EffectsDesign:
    """The whitened design of a model's effects at the model, with the
    nuisances projected out (:func:`_effects_design`)."""

    whitened_r: np.ndarray  # nuisances then effects, as the fit's
    k0: int  # nuisance columns
    projected: np.ndarray  # the effects' columns less their nuisance part
    norm: np.ndarray  # each projected column's norm
    zero: np.ndarray  # columns the data do not see at all
    prior: np.ndarray  # each parameter's typical magnitude (its units)
    index: list  # (effect, parameters) in column order

    def normalised(self) -> np.ndarray:
        """The seen columns, each of unit norm."""
        live = ~self.zero
        return self.projected[:, live] / self.norm[live]


def _effects_design(problem: Problem, model) -> _EffectsDesign | None:
    """The design of ``model``'s effects (None without effects)."""
    X0, index = problem.model_design(model)
    if not index:
        return None
    k0 = problem.nuisance.shape[1]
    R = problem.wls(problem.observe(model).residual, X0).whitened_r
    Rn, Re = R[:, :k0], R[:, k0:]
    if k0:
        q, _ = np.linalg.qr(Rn)
        Re = Re - q @ (q.T @ Re)
    norm = np.linalg.norm(Re, axis=0)
    top = norm.max() if len(norm) else 0.0
    zero = norm <= UNDETERMINED_RCOND * max(top, 1e-300)
    prior = np.concatenate([np.asarray(problem.candidates[n].prior, float) for n, _ in index])
    return _EffectsDesign(R, k0, Re, norm, zero, prior, index)


def determined_values(problem: Problem, model) -> dict[str, np.ndarray]:
    """The effects' values of ``model`` with every combination the data do
    not determine taken out: what a saved model applies.

    The whitened design of the effects, with the nuisances (each placement's
    rigid fit, a run's offsets) projected out, has singular directions the
    data cannot see (below ``UNDETERMINED_RCOND`` of the largest: an
    alignment change on a single-pose plate, which each placement's rigid
    fit absorbs; a knot no ball came near). The fit's values along them are
    the prior's, not the data's, and act elsewhere in the volume: they are
    removed (the values projected onto the determined subspace, in
    column-normalised coordinates). The training observables do not change
    (to first order); the values elsewhere do only by what the data never
    tested. Effects with no determined direction keep no value. Returns
    effect -> values in its units (every effect of ``model``)."""
    design = _effects_design(problem, model)
    if design is None:
        return {}
    zero, norm, prior, index = design.zero, design.norm, design.prior, design.index
    b = np.concatenate([np.asarray(model.values(n), float) for n, _ in index]) / prior
    c = np.where(zero, 0.0, b * norm)
    live = ~zero
    if live.any():
        _, s, vt = np.linalg.svd(design.normalised(), full_matrices=True)
        s = np.r_[s, np.zeros(int(live.sum()) - len(s))]
        null = vt.T[:, s <= UNDETERMINED_RCOND * (s[0] if len(s) and s[0] > 0 else 1.0)]
        c[live] -= null @ (null.T @ c[live])
    values = np.where(zero, 0.0, c / np.where(zero, 1.0, norm)) * prior
    out, pos = {}, 0
    for name, k in index:
        out[name] = values[pos:pos + k]
        pos += k
    return out


#: Relative singular value below which a direction of the (column-normalised,
#: whitened) design counts as undetermined, and the share of a parameter on
#: such directions that makes it undetermined.
UNDETERMINED_RCOND, UNDETERMINED_SHARE = 1e-10, 1e-6
#: Data-only standard uncertainty, in typical magnitudes (priors), above which
#: a model parameter counts as undetermined (inf).
UNDETERMINED_PRIORS = 5.0


def design_variances(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The diagonal of :func:`design_covariance`, and which parameters the design leaves free."""
    cov, free = design_covariance(R)
    return np.diag(cov).copy(), free


def design_covariance(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The covariance of the least-squares parameters of the whitened design
    ``R`` (columns in their own units), and which parameters the design leaves
    free (a share of ``UNDETERMINED_SHARE`` or more on a direction whose
    singular value is below ``UNDETERMINED_RCOND`` of the largest): their
    variance is infinite. The SVD acts on ``R`` with its columns normalised,
    not on ``R^T R``: the normal matrix squares the condition number, and a
    pseudo-inverse of it drops directions the data do determine weakly
    (then their variance reads near zero: an XY-plane run's squareness yz
    and zx at 1e-5 arc-seconds instead of tens)."""
    k = R.shape[1]
    if k == 0:
        return np.zeros((0, 0)), np.zeros(0, bool)
    norm = np.linalg.norm(R, axis=0)
    zero = norm <= 0
    A = R / np.where(zero, 1.0, norm)
    _, s, vt = np.linalg.svd(A, full_matrices=True)
    s = np.r_[s, np.zeros(k - len(s))]
    keep = s > UNDETERMINED_RCOND * (s[0] if len(s) and s[0] > 0 else 1.0)
    v = vt.T
    w = v[:, keep] / s[keep]
    n = np.where(zero, 1.0, norm)
    cov = (w @ w.T) / np.outer(n, n)
    np.fill_diagonal(cov, np.sum(w ** 2, axis=1) / n ** 2)  # the variances summed as such, not through a product
    free = zero | (np.sum(v[:, ~keep] ** 2, axis=1) > UNDETERMINED_SHARE)
    return cov, free
