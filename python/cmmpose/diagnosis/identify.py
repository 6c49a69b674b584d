"""Which physical effect is missing: sensitivities of the observables to
every candidate's parameters (finite differences through the Rust kernel
and the sphere fits), a joint weighted least-squares fit with one noise
level per observable class, and forward selection by likelihood ratio and
BIC.

Statistics. Each class c of observables (lengths, centre disagreements,
radii, point residuals) has its own unknown noise sigma_c, estimated from
its residuals (iteratively reweighted least squares). The profile
log-likelihood is -2 log L = sum_c n_c log(RSS_c / n_c); adding an effect
with k identifiable parameters gains LR = -2 log L(before) + 2 log L(after),
asymptotically chi-square with k degrees of freedom under "no effect". A
class of few observables (a crossed layout's 8 lengths) estimates its own
noise level poorly: residuals that happen to fall below the scatter its
centres allow make any fit to them look like a large gain. When the run's
per-scan reproducibility is stated, that class's noise level is never
taken below the floor it implies (:meth:`Problem.state_reproducibility`).
An effect is proposed only if its p-value beats 1e-3 divided by the number of
candidates (Bonferroni); the BIC change is reported alongside. (BIC alone
would charge every parameter ln n with n counted over all classes, tens of
thousands of point residuals, and so miss effects seen only in the 20
ballbar lengths.) Parameters are
scaled by their prior magnitude so the design is well conditioned;
condition numbers are of the whitened, column-normalised design.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._validate import MAX_REPRODUCIBILITY_MM, check_reproducibility
from ..errors import Error, InputError, InputTypeError, UserEffectError
from ..run import Run
from ._blas import one_blas_thread
from .statistics import (RSS_FLOOR, ALPHA, INDISTINGUISHABLE, INDISTINGUISHABLE_LR, NOT_OBSERVABLE_BELOW,
                         OBSERVABLE_AT, PRIOR_WEIGHT, SIGMA_FLOOR, chi2_sf)
from .artefact import artefact_columns, linearised_columns
from .floor import headline_floors
from .mapfamily import centre_columns, compressed_view
from ..model.names import resolve
from ..model.spec import EffectSpec, run_library
from ..model.inputs import RunInputs
from ..evaluation.observables import CLASSES, POINTS_PER_SCAN, ObservationLayout, Observed, check_first_observation, observe

__all__ = ["Problem", "Candidate", "rank_candidates", "fit_effect", "fit_model", "ALPHA", "OBSERVABLE_AT"]



@dataclass
class Fit:
    """A weighted least-squares fit of the residual r0 + X beta."""

    beta: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    sigma: np.ndarray
    neg2loglik: float
    rank: int
    rss: np.ndarray
    #: The whitened design (X over each row's final sigma) reduced to the R
    #: factors of its classes: the same inner products of columns.
    whitened_r: np.ndarray | None = None
    #: (class, R_c) of each class present: the unweighted R factor of X's
    #: rows of that class (R_c^T R_c = X_c^T X_c), in ``whitened_r``'s order.
    blocks: list | None = None


class Problem:
    """The linearised diagnosis problem of one run at one model.

    Parameters
    ----------
    model : Model
        The current model.
    run : Run
        The run.
    candidates : dict of str -> EffectSpec, optional
        Default: the whole library for the run (plus per-pose alignments and
        one candidate per thermocouple role for effects that follow a sensor).
    extra : sequence of EffectSpec
        Added to the candidates (user-defined effects).
    """

    def __init__(self, model, run: Run, candidates: dict[str, EffectSpec] | None = None, *,
                 points_per_scan: int = POINTS_PER_SCAN, extra=()):
        self.run = run
        self.inputs: RunInputs = model.inputs(run)
        self.layout = ObservationLayout.from_run(run, self.inputs, points_per_scan)
        self.classes = self.layout.classes
        self.n_class = np.bincount(self.classes, minlength=len(CLASSES)).astype(float)
        self._class_rows = [np.flatnonzero(self.classes == c) for c in range(len(CLASSES))]
        # Deviations from a group mean have (k - 1) dof per k scans.
        n_groups = len(np.unique(self.layout.sphere_of_scan[self.layout.repeated]))
        self.n_eff = self.n_class.copy()
        self.n_eff[1] = 3 * (len(self.layout.repeated) - n_groups)
        if self.layout.artefact is not None:  # each placement's rigid fit takes its degrees of freedom
            self.n_eff[0] = max(self.n_class[0] - self.layout.artefact.fitted_dof, 0)
        self.nuisance, self.nuisance_names = self.layout.nuisance()
        #: Smallest noise level credited to each class, mm (state_reproducibility raises the headline's).
        self.class_floor = np.full(len(CLASSES), SIGMA_FLOOR)
        self.candidates = dict(run_library(self.inputs) if candidates is None else candidates)
        self.candidates |= {spec.name: spec for spec in extra}
        for spec, _ in model.effects:
            self.candidates.setdefault(spec.name, spec)
        self.skipped: dict[str, str] = {}
        for name, spec in list(self.candidates.items()):
            missing = [n for n in spec.needs if not self.inputs.available(n)]
            if spec.sensor and spec.sensor not in self.inputs.sensors:
                missing.append(f"thermocouples of role {spec.sensor!r}")
            if missing:
                self.skipped[name] = f"the run lacks {', '.join(missing)}: {spec.reveal}"
                del self.candidates[name]
        self.base = model
        self.base_obs = self.observe(model)
        check_first_observation(self.layout, self.base_obs, getattr(run, "source", None) or "run")
        self.columns = self._sensitivities(model, self.base_obs)

    def state_reproducibility(self, reproducibility_um: float) -> None:
        """Never take the headline class's noise level (ballbar lengths, an
        artefact's ball deviations) below what a stated per-scan centre
        reproducibility (um per axis) implies: the rms of its observables'
        floors (:func:`cmmpose.diagnosis.floor.headline_floors`). A class of
        few observables whose residuals happen to fall below that floor
        would otherwise credit any fit to them with a large likelihood gain
        (a crossed layout's 8 lengths at 1.9 um rms against a 4.24 um
        floor: a 3-parameter map correction at p = 2e-6 on noise alone)."""
        sc = check_reproducibility("reproducibility_um", reproducibility_um, what="reproducibility_um",
                                   option="reproducibility_um", cli_option="--reproducibility",
                                   remedy="reproducibility_um") * 1e-3
        f = headline_floors(self.layout, sc)
        if len(f):
            self.class_floor[0] = max(SIGMA_FLOOR, float(np.sqrt(np.mean(f ** 2))))

    def observe(self, model) -> Observed:
        return observe(self.layout, model.compensate(self.inputs), model.expansion_ppm_per_kelvin,
                       self.inputs.scan_id)

    def _sensitivities(self, model, obs: Observed) -> dict[str, np.ndarray]:
        """Residual change per prior magnitude of each parameter (mm). A
        candidate whose change cannot be evaluated on this run either way
        (a step that takes a temperature outside the maps, say) is moved to
        ``skipped`` with the reason; one already in the model raises."""
        out = {}
        for name, spec in list(self.candidates.items()):
            current = model.values(name) if name in model.names else np.zeros(spec.size)
            try:
                out[name] = self._columns(model, spec, current, obs)
            except UserEffectError:  # an error in the user's code, not a verdict on the data
                raise
            except Error as e:
                if name in model.names:
                    raise
                self.skipped[name] = f"its effect on this run cannot be evaluated ({e}): {spec.reveal}"
                del self.candidates[name]
        return out

    def _columns(self, model, spec: EffectSpec, current: np.ndarray, obs: Observed) -> np.ndarray:
        """Residual change per prior magnitude of each parameter of ``spec``:
        analytic for the artefact expansion of a ballbar run (it acts on the
        predicted length only), else finite differences of size ``spec.steps`` through the
        kernel and the sphere fits: forward, or backward where the forward
        step cannot be evaluated (it leaves the maps' range)."""
        if getattr(spec, "family", None) in ("map", "cross"):  # map and cross-axis corrections: at the centre level
            return centre_columns(self, obs, spec)
        if spec.kind == "length" and self.layout.artefact is None:
            ref = self.layout.calibrated_length or (float(np.mean(obs.lengths)) if len(obs.lengths) else 0.0)
            return self.layout.expansion_column(ref)[:, None] * np.asarray(spec.prior)
        if self.layout.artefact is not None and linearised_columns(spec):  # a plate: linearised fits of a sample
            return artefact_columns(self, model, spec, current, obs)
        return spec.difference_columns(current, lambda v: self.observe(model.with_values(spec, v)).residual
                                       - obs.residual)

    # -- fitting ------------------------------------------------------------

    def wls(self, r0: np.ndarray, X: np.ndarray, iterations: int = 6, ridge: np.ndarray | None = None,
            target: np.ndarray | None = None) -> Fit:
        """Fit r0 + X beta with one noise level per class (IRLS).

        ``ridge`` (one per column, 0 for none) adds the pseudo-observation
        ridge_j (beta_j - target_j) = 0: a weak prior that keeps directions the
        data barely sees from wandering (not part of the likelihood).

        The rows of one class share their weight in every iteration, so each
        class enters the least squares as the R factor of the QR of
        [X_c | r0_c] (at most one row per column) instead of its rows: the
        block-diagonal Q has orthonormal columns, so the reduced design has the
        singular values of the whitened one (the same rank at the same
        ``rcond``) and the same minimiser; what of r0_c lies outside the span
        of X_c only adds a constant to the objective."""
        cls, n_eff = self.classes, self.n_eff
        present = self.n_class > 0
        floor = getattr(self, "class_floor", None)  # mm per class (state_reproducibility), else SIGMA_FLOOR
        rss_floor = (RSS_FLOOR if floor is None else np.maximum(floor, SIGMA_FLOOR) ** 2) * np.maximum(n_eff, 1)
        k = X.shape[1]
        blocks = []  # (class, R_c, Q_c^T r0_c)
        if k:
            for c in np.flatnonzero(present):
                rows = self._class_rows[c]
                Xc = X[rows]
                m = min(len(rows), k)
                used = np.flatnonzero(np.any(Xc != 0, axis=0))
                if len(used) < k:
                    # Columns zero on this class (a map correction's on the point residuals) are zero
                    # columns of its R factor: the QR of the others gives the same normal equations.
                    r = np.linalg.qr(np.column_stack([Xc[:, used], r0[rows]]), mode="r")
                    mu = min(r.shape[0], m, len(used))
                    R = np.zeros((m, k))
                    R[:mu, used] = r[:mu, :len(used)]
                    q = np.zeros(m)
                    q[:mu] = r[:mu, len(used)]
                    blocks.append((c, R, q))
                    continue
                r = np.linalg.qr(np.column_stack([Xc, r0[rows]]), mode="r")
                blocks.append((c, r[:m, :k], r[:m, k]))
        w = np.ones(len(self.n_class))
        beta = np.zeros(k)
        rank = 0
        for _ in range(iterations):
            if k:
                A = [w[c] * R for c, R, _ in blocks]
                rhs = [-w[c] * qr0 for c, _, qr0 in blocks]
                if ridge is not None:
                    A.append(np.diag(ridge))
                    rhs.append(ridge * (np.zeros(len(ridge)) if target is None else target))
                beta, _, rank, _ = np.linalg.lstsq(np.vstack(A), np.concatenate(rhs), rcond=1e-10)
            res = r0 + X @ beta
            rss = np.bincount(cls, res ** 2, minlength=len(self.n_class))
            sigma = np.sqrt(np.maximum(rss, rss_floor) / np.maximum(n_eff, 1))
            w = 1.0 / sigma
        Rw = np.vstack([w[c] * R for c, R, _ in blocks]) if blocks else np.zeros((0, k))
        cov = np.linalg.pinv(Rw.T @ Rw, rcond=1e-10) if k else np.zeros((0, 0))
        use = present & (n_eff > 0)
        rss_f = np.maximum(rss, rss_floor)
        n2ll = float(np.sum(n_eff[use] * np.log(rss_f[use] / n_eff[use])))
        return Fit(beta, cov, res, sigma, n2ll, int(rank), rss, Rw, [(c, R) for c, R, _ in blocks])

    def model_design(self, model) -> tuple[np.ndarray, list[tuple[str, int]]]:
        """Nuisance columns and the columns of the effects already in ``model``."""
        blocks, index = [self.nuisance], []
        for name in model.names:
            if name in self.columns:
                blocks.append(self.columns[name])
                index.append((name, self.columns[name].shape[1]))
        return np.column_stack(blocks) if blocks else np.zeros((len(self.classes), 0)), index

    def prior_design(self, model, extra: np.ndarray | None = None):
        """Nuisance and effect columns of ``model`` (plus ``extra`` columns)
        with the diagnosis's weak prior: ``(X, ridge, target, index)``, the
        first three as :meth:`wls` takes them, ``index`` as :meth:`model_design`."""
        X, index = self.model_design(model)
        k0 = self.nuisance.shape[1]
        now = np.concatenate([model.values(n) / np.asarray(self.candidates[n].prior) for n, _ in index]) \
            if index else np.zeros(0)
        ridge = np.r_[np.zeros(k0), np.full(len(now), PRIOR_WEIGHT)]
        target = np.r_[np.zeros(k0), -now]
        if extra is not None and extra.shape[1]:
            X = np.column_stack([X, extra])
            ridge = np.r_[ridge, np.full(extra.shape[1], PRIOR_WEIGHT)]
            target = np.r_[target, np.zeros(extra.shape[1])]
        return X, ridge, target, index

    def whitened(self, X: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        return X / sigma[self.classes][:, None]


@dataclass
class Candidate:
    """One candidate effect evaluated against the current model.

    Attributes
    ----------
    name : str
        Effect name.
    values : ndarray
        Fitted parameter values (current value + fitted change), in the
        effect's units.
    uncertainty : ndarray
        Standard uncertainty of each value, same units (inf where the run
        does not determine it).
    lr : float
        Likelihood-ratio statistic against the current model.
    dof : int
        Parameters the run determines (rank gain).
    p_value : float
        chi-square upper tail of lr with dof degrees of freedom.
    delta_bic : float
        BIC change if added (negative: better).
    explained : float
        Share of the remaining whitened residual sum of squares it explains.
    explained_length : float
        Share of the remaining ballbar-length residual it explains.
    correlation : float
        Largest |correlation| of its columns with the model's columns and
        nuisances; ``correlated_with`` names that column's effect.
    condition : float
        Condition number of the whitened, normalised design with it added.
    observability : float
        Squared signal-to-noise of its largest parameter at the prior
        magnitude, after what the model already explains (< OBSERVABLE_AT:
        the run cannot show it at a typical size).
    significant : bool
        Passes the Bonferroni chi-square test.
    """

    name: str
    spec: EffectSpec
    values: np.ndarray
    uncertainty: np.ndarray
    lr: float
    dof: int
    p_value: float
    delta_bic: float
    explained: float
    explained_length: float
    correlation: float
    correlated_with: str
    condition: float
    observability: float
    significant: bool = False
    indistinguishable_from: list = field(default_factory=list)
    #: Leaders whose fitted contribution this one repeats, though the data
    #: prefer the leader (it "stands for" the leader's physics).
    stands_for: list = field(default_factory=list)
    threshold: float = ALPHA
    model_effects: tuple = ()
    #: The effect in the model of which this one is an alternative (the same
    #: physics following another sensor): then ``lr`` is the likelihood
    #: ratio of the model holding this one instead (negative: worse).
    alternative_to: str = ""
    #: Cross-validation against the current model (:mod:`cmmpose.diagnosis.cv`),
    #: for the candidates the selection judged: ``cv_rms_um``, ``cv_rms_u_um``
    #: and ``in_sample_rms_um`` with it added, the change (``gain_um``,
    #: ``gain_u_um``, ``gain_whitened``, ``gain_whitened_u``), ``passes`` and ``why``.
    cv: dict | None = None

    @property
    def rejected_out_of_sample(self) -> bool:
        """Significant in sample, but it does not improve the prediction of
        held-out data (the cross-validation rule): never added."""
        return bool(self.cv is not None and not self.cv.get("passes", True))

    @property
    def aliases(self) -> list[str]:
        """Effects this one cannot be told apart from: those the data cannot
        separate from the leader (``indistinguishable_from``), the leader whose
        contribution it repeats less well (``stands_for``), and an effect
        already in the model whose fitted columns its own repeat (|correlation|
        above INDISTINGUISHABLE). An alternative of an effect in the model is
        aliased with it when the swap changes -2 log L by less than
        INDISTINGUISHABLE_LR."""
        if self.alternative_to:  # judged by the likelihood of the swap alone
            return [self.alternative_to] if abs(self.lr) < INDISTINGUISHABLE_LR else []
        out = list(self.indistinguishable_from) + [n for n in self.stands_for if n not in self.indistinguishable_from]
        if self.correlation > INDISTINGUISHABLE and self.correlated_with in self.model_effects \
                and self.correlated_with not in out:
            out.append(self.correlated_with)
        return out

    @property
    def observable(self) -> bool:
        """Whether the run's design determines the effect: every parameter's
        uncertainty finite, and a typical magnitude (the prior) at least 2
        sigma above the noise after what the model explains."""
        return (self.dof > 0 and bool(np.all(np.isfinite(self.uncertainty)))
                and self.observability >= NOT_OBSERVABLE_BELOW)

    @property
    def decision(self) -> str:
        """One label, one meaning: 'significant', 'significant, aliased'
        (significant, but the run cannot tell it from ``aliases``), 'aliased'
        (not significant on its own and repeating an effect already in the
        model), 'not significant' (determined, but p above the threshold),
        'not observable' (the run's design cannot determine it), or, for an
        alternative of an effect in the model, 'not chosen' (the data prefer
        the model's) or 'preferred' (the data prefer this one)."""
        if self.alternative_to:
            if self.aliases:
                return "aliased"
            return "preferred" if self.lr > 0 else "not chosen"
        if self.significant:
            if self.rejected_out_of_sample:
                return "not significant out of sample"
            return "significant, aliased" if self.aliases else "significant"
        if not self.observable:
            return "not observable"
        if self.aliases:
            return "aliased"
        return "not significant"

    def reason(self) -> str:
        """Why the decision, in words with the numbers behind it."""
        vals = ", ".join(value_text(p, v, u, unit) for p, v, u, unit in
                         zip(self.spec.params, self.values, self.uncertainty, self.spec.units))
        test = f"p = {self.p_value:.2g} against the threshold {self.threshold:.2g}"
        d = self.decision
        if self.alternative_to:
            odds = f"-2 log L {abs(self.lr):.1f} {'lower' if self.lr > 0 else 'higher'} than with {self.alternative_to}"
            if d == "aliased":
                return (f"the run cannot choose between it and {self.alternative_to} ({odds}); {vals}; needs: "
                        f"{self.spec.reveal}")
            if d == "preferred":
                return f"the data prefer it to {self.alternative_to}: {odds}; {vals}"
            return f"the data prefer {self.alternative_to}: {odds}; {vals}"
        if d == "not observable":
            if self.dof > 0 and np.all(np.isfinite(self.uncertainty)):
                return (f"a typical {self.spec.describe(self.spec.prior)} would stand only "
                        f"{math.sqrt(max(self.observability, 0.0)):.1f} sigma above the noise here; "
                        f"needs: {self.spec.reveal}")
            return f"the run does not determine it; needs: {self.spec.reveal}"
        if d == "not significant out of sample":
            return f"{vals}, {test} in sample, but it {self.cv['why']}"
        if d == "aliased":
            return f"same as {', '.join(self.aliases)} (already in the model); {vals}, {test}"
        if d.startswith("significant"):
            same = f"; same as {', '.join(self.aliases)}: {self.spec.reveal}" if self.aliases else ""
            return f"{vals}, {test}{same}"
        weak = ""
        if self.observability < OBSERVABLE_AT:
            weak = (f"; weakly determined: a typical {self.spec.describe(self.spec.prior)} would stand "
                    f"{math.sqrt(max(self.observability, 0.0)):.1f} sigma above the noise (needs: {self.spec.reveal})")
        return f"{vals}, {test}{weak}"

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"name": self.name, "params": dict(zip(self.spec.params, map(num, self.values))),
                "uncertainty": dict(zip(self.spec.params, map(num, self.uncertainty))),
                "units": dict(zip(self.spec.params, self.spec.units)), "lr": num(self.lr), "dof": self.dof,
                "p_value": num(self.p_value), "delta_bic": num(self.delta_bic), "explained": num(self.explained),
                "explained_length": num(self.explained_length), "correlation": num(self.correlation),
                "correlated_with": self.correlated_with, "condition": num(self.condition),
                "observability": num(self.observability), "significant": self.significant,
                "indistinguishable_from": list(self.indistinguishable_from), "reveal": self.spec.reveal,
                "aliases": self.aliases, "decision": self.decision, "reason": self.reason(),
                "threshold": num(self.threshold), "alternative_to": self.alternative_to or None,
                "cross_validation": self.cv}


def value_text(p, v, u, unit) -> str:
    """'xy = +8.1 ± 1.7 arc-second' (dimensionless values without a unit)."""
    unit = "" if unit in ("1", "") else f" {unit}"
    if not math.isfinite(u):
        return f"{p} = {v:+.3g}{unit} (undetermined)"
    return f"{p} = {v:+.3g} ± {u:.2g}{unit}"


@one_blas_thread
def rank_candidates(problem: Problem, model, obs: Observed | None = None) -> list[Candidate]:
    """Every candidate not in ``model``, evaluated against it, best first
    (significant before not, then by p-value)."""
    obs = problem.observe(model) if obs is None else obs
    r0 = obs.residual
    X0, ridge0, target0, index = problem.prior_design(model)
    base = problem.wls(r0, X0, ridge=ridge0, target=target0)
    n_total = float(np.sum(problem.n_eff))
    todo = [n for n in problem.candidates if n not in model.names]
    out = []
    W0 = problem.whitened(X0, base.sigma)
    q0 = np.linalg.qr(W0)[0] if X0.shape[1] else np.zeros((len(r0), 0))
    labels = [n for n in problem.nuisance_names] + [name for name, k in index for _ in range(k)]
    held = {s.key: s.name for s, _ in model.effects if s.kind == "kernel"}
    alternatives = []
    betas: dict[str, np.ndarray] = {}  # each candidate's fitted change, for _flag_indistinguishable
    every_row, map_rows = (problem, r0, X0, base, W0, q0), None
    for name in todo:
        spec = problem.candidates[name]
        if spec.kind == "kernel" and spec.key in held:
            alternatives.append(_alternative(problem, model, spec, held[spec.key], r0, X0, index, ridge0, target0,
                                             base))
            continue
        P, r0_, X0_, base_, _, q0_ = every_row
        if getattr(spec, "family", None) in ("map", "cross"):
            # A map (or cross-axis) correction moves centres and radii only: it is ranked on a view of the problem whose
            # point residuals are compressed to their R factor (the same fits, at a fraction of the cost).
            if map_rows is None:
                map_rows = _compressed_rows(problem, r0, X0, ridge0, target0)
            P, r0_, X0_, base_, _, q0_ = map_rows
        J = P.columns[name]
        fit = P.wls(r0_, np.column_stack([X0_, J]), ridge=np.r_[ridge0, np.full(J.shape[1], PRIOR_WEIGHT)],
                          target=np.r_[target0, np.zeros(J.shape[1])])
        dof = max(fit.rank - base_.rank, 0)
        lr = max(base_.neg2loglik - fit.neg2loglik, 0.0)
        p = chi2_sf(lr, dof) if dof else 1.0
        # A candidate chosen by a search (a map correction's period or knot
        # spacing) pays for its alternatives: Bonferroni over the search.
        p = min(1.0, p * getattr(spec, "trials", 1))
        dbic = -lr + dof * math.log(max(n_total, 2.0))
        wb = 1.0 / base_.sigma[P.classes] ** 2
        before = float(np.sum(base_.residual ** 2 * wb))
        after = float(np.sum(fit.residual ** 2 * wb))
        L = P.classes % len(CLASSES) == 0  # lengths (of every run, in a joint problem)
        lb = float(np.sum(base_.residual[L] ** 2))
        la = float(np.sum(fit.residual[L] ** 2))
        k = J.shape[1]
        beta = fit.beta[-k:]
        betas[name] = beta
        sd = np.sqrt(np.clip(np.diag(fit.cov)[-k:], 0, None))
        current = model.values(name) if name in model.names else np.zeros(spec.size)
        values = current + beta * np.asarray(spec.prior)
        unc = sd * np.asarray(spec.prior)
        # Marginal uncertainty of each parameter: 1 / |whitened column after
        # projecting out every other column| (exact for weighted LS); inf
        # where the run does not determine it.
        # Projections depend only on the columns' inner products, so they are
        # taken on the fit's reduced whitened design [X0 | J] (a few rows per
        # column), which has the inner products of its thousands of rows.
        k0_ = X0_.shape[1]
        unc = _marginal_uncertainty(fit.whitened_r, k0_, spec.prior)
        # Observability at the prior magnitude, against the current model only.
        Wb = P.whitened(J, base_.sigma)
        perp = Wb - q0_ @ (q0_.T @ Wb)
        s2 = np.sum(perp ** 2, axis=0)
        corr, with_, cond = _correlation_and_condition(fit, base_, k0_, labels)
        out.append(Candidate(name, spec, values, unc, lr, dof, p, dbic,
                             1 - after / before if before > 0 else 0.0,
                             1 - la / lb if lb > 0 else 0.0, corr, with_, cond, float(np.max(s2)) if k else 0.0))
    threshold = _judge(out, len(todo) - len(alternatives), model)
    # Significant first, then by p-value (the likelihood gain against the parameters spent). A cross-axis term
    # ranks with the named effects, or before the map shapes, only where it explains clearly more than the best
    # of them (-2 log L beyond INDISTINGUISHABLE_LR): the simpler physics is preferred where the two say the
    # same (a sag took a periodic Y error's signal before the map shapes were judged beside it).
    named_lr = max((c.lr for c in out if c.significant and getattr(c.spec, "family", None) is None), default=0.0)
    map_lr = max((c.lr for c in out if c.significant and getattr(c.spec, "family", None) == "map"), default=0.0)

    def tier(c) -> int:
        family = getattr(c.spec, "family", None)
        if family == "cross":
            if c.lr <= map_lr + INDISTINGUISHABLE_LR:
                return 3
            return 0 if c.lr > named_lr + INDISTINGUISHABLE_LR else 1
        return 2 if family == "map" else 0

    out.sort(key=lambda c: (not c.significant, tier(c), c.p_value, -c.lr))
    _flag_indistinguishable(problem, out, r0, X0, base, ridge0, target0, betas)
    for c in alternatives:
        c.threshold = threshold
        c.model_effects = tuple(model.names)
    # Alternatives after the candidates, the data's favourite first.
    return out + sorted(alternatives, key=lambda c: -c.lr)


def _compressed_rows(problem: Problem, r0, X0, ridge0, target0) -> tuple:
    """:func:`rank_candidates`'s rows for a map (or cross-axis) correction: the problem's view with its point
    residuals compressed to their R factor (:func:`~cmmpose.diagnosis.mapfamily.compressed_view`), the base
    fit on it, its whitened design and that design's Q factor."""
    view, r0v, X0v = compressed_view(problem, r0, X0)
    bv = view.wls(r0v, X0v, ridge=ridge0, target=target0)
    W0v = view.whitened(X0v, bv.sigma)
    return (view, r0v, X0v, bv, W0v, np.linalg.qr(W0v)[0] if X0v.shape[1] else np.zeros((len(r0v), 0)))


def _marginal_uncertainty(Rf: np.ndarray, k0: int, prior) -> np.ndarray:
    """The marginal standard uncertainty of each of a candidate's parameters (the last columns of the fit's
    reduced whitened design ``Rf`` after the ``k0`` model columns), in the parameters' units: the prior over
    the norm of its column after projecting out every other column (exact for weighted least squares); inf
    where the run does not determine it."""
    Rm, Rk = Rf[:, :k0], Rf[:, k0:]
    unc = np.empty(Rk.shape[1])
    for j in range(Rk.shape[1]):
        others = np.column_stack([Rm, np.delete(Rk, j, axis=1)])
        q = np.linalg.qr(others)[0] if others.shape[1] else np.zeros((len(Rf), 0))
        rest = Rk[:, j] - q @ (q.T @ Rk[:, j])
        s = float(np.sum(rest * rest))
        unc[j] = np.inf if s <= 1e-10 * float(np.sum(Rk[:, j] ** 2)) or s == 0 else prior[j] / math.sqrt(s)
    return unc


def _correlation_and_condition(fit: Fit, base: Fit, k0: int, labels) -> tuple[float, str, float]:
    """A candidate's largest correlation with a model column (and that column's label) and the condition
    number of the design: the model's ``k0`` columns whitened by the base fit's noise levels beside the
    candidate's by its own fit's, their inner products from each class's R factor of [X0 | J] (which has the
    inner products of the class's rows)."""
    wf, wb0 = 1.0 / fit.sigma, 1.0 / base.sigma
    mixed = np.vstack([np.concatenate([wb0[c] * R[:, :k0], wf[c] * R[:, k0:]], axis=1) for c, R in fit.blocks])
    norms = np.maximum(np.linalg.norm(mixed, axis=0), 1e-300)
    mixed = mixed / norms
    corr, with_ = 0.0, ""
    if k0:
        c = np.abs(mixed[:, k0:].T @ mixed[:, :k0])
        i, j = np.unravel_index(np.argmax(c), c.shape)
        corr, with_ = float(c[i, j]), labels[j]
    sv = np.linalg.svd(mixed, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if len(sv) == mixed.shape[1] and sv[-1] > 0 else float("inf")
    return corr, with_, cond


def _judge(out: list[Candidate], n_ranked: int, model) -> float:
    """Each ranked candidate's threshold and significance against ``model``; the named effects' threshold.

    The map corrections (cmmpose.diagnosis.mapfamily) are a family of their own, with their own Bonferroni
    threshold; the library's named effects rank before them (the better physics where they explain it). The
    cross-axis corrections (cmmpose.model.crossaxis) likewise; they rank with the named effects (a twisted
    table is physics in words), each family paying Bonferroni over its own members. ``n_ranked``: the
    candidates evaluated, alternatives to a held effect not counted."""
    n_map = sum(1 for c in out if getattr(c.spec, "family", None) == "map")
    n_cross = sum(1 for c in out if getattr(c.spec, "family", None) == "cross")
    threshold = ALPHA / max(n_ranked - n_map - n_cross, 1)
    map_threshold = ALPHA / max(n_map, 1)
    cross_threshold = ALPHA / max(n_cross, 1)
    for c in out:
        family = getattr(c.spec, "family", None)
        c.threshold = map_threshold if family == "map" else cross_threshold if family == "cross" else threshold
        c.significant = c.dof > 0 and c.p_value < c.threshold
        c.model_effects = tuple(model.names)
    return threshold


def _alternative(problem: Problem, model, spec: EffectSpec, held: str, r0, X0, index, ridge0, target0,
                 base: Fit) -> Candidate:
    """``spec`` evaluated in place of ``held``, the model's effect of the
    same term (the same physics following another sensor): the likelihood
    ratio of the model holding ``spec`` instead, and its values there."""
    k0 = problem.nuisance.shape[1]
    at = k0
    for name, k in index:
        if name == held:
            break
        at += k
    k_held = problem.columns[held].shape[1]
    keep = np.r_[np.arange(at), np.arange(at + k_held, X0.shape[1])]
    # The residual holds the held effect at its values: take it out (to
    # first order, through its own columns) before fitting the other.
    r_without = r0 - problem.columns[held] @ (model.values(held) / np.asarray(problem.candidates[held].prior))
    J = problem.columns[spec.name]
    k = J.shape[1]
    X = np.column_stack([X0[:, keep], J])
    fit = problem.wls(r_without, X, ridge=np.r_[ridge0[keep], np.full(k, PRIOR_WEIGHT)],
                      target=np.r_[target0[keep], np.zeros(k)])
    lr = base.neg2loglik - fit.neg2loglik
    values = fit.beta[-k:] * np.asarray(spec.prior)
    unc = np.sqrt(np.clip(np.diag(fit.cov)[-k:], 0, None)) * np.asarray(spec.prior)
    Wk = problem.whitened(J, fit.sigma)
    Wh = problem.whitened(problem.columns[held], fit.sigma)
    a = Wk / np.maximum(np.linalg.norm(Wk, axis=0), 1e-300)
    b = Wh / np.maximum(np.linalg.norm(Wh, axis=0), 1e-300)
    corr = float(np.max(np.abs(a.T @ b))) if k and k_held else 0.0
    full = problem.whitened(X, fit.sigma)
    full = full / np.maximum(np.linalg.norm(full, axis=0), 1e-300)
    sv = np.linalg.svd(full, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if len(sv) and sv[-1] > 0 else float("inf")
    s2 = np.sum(problem.whitened(J, base.sigma) ** 2, axis=0)
    return Candidate(spec.name, spec, values, unc, float(lr), max(fit.rank - base.rank + k_held, 0), 1.0, float("nan"),
                     0.0, 0.0, corr, held, cond, float(np.max(s2)) if k else 0.0, alternative_to=held)


def _flag_indistinguishable(problem: Problem, ranked: list[Candidate], r0, X0, base: Fit, ridge0, target0,
                            betas: dict | None = None) -> None:
    """Mark candidates whose fitted contributions the data cannot tell apart
    from the leader's: a likelihood gain within INDISTINGUISHABLE_LR of the
    leader's and fitted contributions that correlate above INDISTINGUISHABLE."""
    if not ranked or not ranked[0].significant:
        return
    lead = ranked[0]

    # Each class weighs the same in the comparison: 20 ballbar lengths must
    # agree as well as 16,000 point residuals for two effects to count as
    # the same (one that fits the spheres but ruins the lengths is not).
    balance = 1.0 / np.sqrt(np.maximum(problem.n_class, 1.0))[problem.classes]

    def contribution(c: Candidate) -> np.ndarray:
        J = problem.columns[c.name]
        beta = (betas or {}).get(c.name)
        if beta is None:  # not fitted by the ranking: fit it against the model here
            fit = problem.wls(r0, np.column_stack([X0, J]), ridge=np.r_[ridge0, np.full(J.shape[1], PRIOR_WEIGHT)],
                              target=np.r_[target0, np.zeros(J.shape[1])])
            beta = fit.beta[-J.shape[1]:]
        return (J @ beta) / base.sigma[problem.classes] * balance

    a = contribution(lead)
    for c in ranked[1:]:
        close = lead.lr - c.lr <= INDISTINGUISHABLE_LR
        if not (close or c.significant):
            continue
        b = contribution(c)
        denom = np.linalg.norm(a) * np.linalg.norm(b)
        if denom > 0 and abs(float(a @ b)) / denom > INDISTINGUISHABLE:
            if close:  # the data cannot choose between them
                lead.indistinguishable_from.append(c.name)
                c.indistinguishable_from.append(lead.name)
            else:  # the same physics, which the leader explains better
                c.stands_for.append(lead.name)


@one_blas_thread
def fit_effect(model, effect, run: Run):
    """A new model with ``effect`` added to ``model`` and fitted to ``run``,
    jointly with the effects already in it (:func:`fit_model`).

    Parameters
    ----------
    model : Model
        The model to add to.
    effect : str or EffectSpec
        A library name (``cmmpose.model.LIBRARY``, variants such as
        'alignment@2' included) or a spec (e.g. a :class:`UserEffect`).
    run : Run
        The run to fit it to.
    """
    if not isinstance(run, Run):
        raise InputTypeError(f"run: expected a cmmpose.Run to fit {effect!r} to, got {type(run).__name__}")
    spec = resolve(effect) if isinstance(effect, str) else effect
    return fit_model(model.add(spec, np.zeros(spec.size)), run)


def fit_model(model, run: Run, iterations: int = 3, problem: Problem | None = None, only=None):
    """Fit the parameters of every effect in ``model`` to ``run`` (Gauss-Newton
    through the kernel, nuisances and class noise levels estimated alongside).

    Parameters
    ----------
    model : Model
        Its effects' current values are the starting point.
    run : Run
        The measurement run.
    iterations : int
        Gauss-Newton iterations at most (each recomputes the sensitivities).
    problem : Problem, optional
        Reuse its inputs and layout.
    only : collection of str, optional
        Fit only these effects; the others keep their values.

    Returns
    -------
    Model
        The same effects with fitted values.
    """
    if not model.effects:
        return model
    prob = problem if problem is not None else Problem(model, run, candidates={s.name: s for s, _ in model.effects})

    def cost(m):
        """Profile -2 log L of model m, or None if it cannot be evaluated."""
        try:
            o = prob.observe(m)
        except UserEffectError:  # an error in the user's code, not a model the data rule out
            raise
        except Error:
            return None, None
        return prob.wls(o.residual, prob.nuisance).neg2loglik, o

    if model is prob.base:  # the problem observed it already: reuse that, and its sensitivities below
        obs = prob.base_obs
        current = prob.wls(obs.residual, prob.nuisance).neg2loglik
    else:
        current, obs = cost(model)
    if current is None:
        # The starting values do not even give fittable spheres: start at zero.
        model = model.__class__(model.maps, tuple((s, np.zeros(s.size)) for s, _ in model.effects),
                                model.temperature, model.out_of_range)
        current, obs = cost(model)
        if current is None:
            raise InputError("fit_model: the model cannot be evaluated on this run even with its effects at zero")
    free = [(spec, v) for spec, v in model.effects if only is None or spec.name in only]
    if not free:
        return model
    for _ in range(iterations):
        cols, specs = [], []
        for spec, _v in free:
            at_base = model is prob.base and spec.name in prob.columns
            cols.append(prob.columns[spec.name] if at_base else prob._columns(model, spec, model.values(spec.name), obs))
            specs.append(spec)
        X = np.column_stack([prob.nuisance] + cols)
        # Prior: each parameter within a few typical magnitudes of zero.
        k0 = prob.nuisance.shape[1]
        ridge = np.r_[np.zeros(k0), np.full(X.shape[1] - k0, PRIOR_WEIGHT)]
        now = np.concatenate([np.asarray(model.values(sp.name), float) / np.asarray(sp.prior) for sp in specs])
        fit = prob.wls(obs.residual, X, ridge=ridge, target=np.r_[np.zeros(k0), -now])
        beta = fit.beta[k0:]
        # Step halving: accept the first step that does not raise the cost.
        for _halving in range(6):
            trial, at = model, 0
            for spec in specs:
                b = beta[at:at + spec.size]
                at += spec.size
                trial = trial.with_values(spec, trial.values(spec.name) + b * np.asarray(spec.prior))
            new, new_obs = cost(trial)
            if new is not None and new <= current + 1e-9:
                break
            beta = beta / 2
        else:
            break
        model, current, obs = trial, new, new_obs
        if float(np.max(np.abs(beta))) < 1e-3:  # a thousandth of the prior: converged
            break
    return model


def check_effect_names(names, problem: Problem) -> None:
    for n in names:
        if n not in problem.candidates:
            why = problem.skipped.get(n)
            raise InputError(f"effect {n!r}: " + (why if why else
                             f"unknown; available: {', '.join(sorted(problem.candidates))}"),
                             what=n, option="add", cli_option=None if why else "--add")
