"""Cross-validation of the diagnosis's choices: every candidate effect is
judged by how well the model predicts observables it was not fitted to.

The split follows how the data were taken (:func:`cv_groups`):

- a ballbar run: leave one bar *position* out. A position's two balls are
  scanned in one set-up of the bar, so its length, its balls' centre
  disagreements, radii and point residuals are held out together (holding
  out single points would leave the position's length in the fit, which
  sees the same centres);
- an artefact run (ball plate, step gauge): leave one *ball* out (its
  deviations and scans together). Not a whole placement: the placements of
  one run are usually chosen to see different components (a plate in the
  XY, XZ and YZ planes), so the others cannot predict what only one sees;
- several runs (:class:`cmmpose.diagnosis.joint.JointProblem`): leave one
  *run* out when there are three or more runs (each run is a separate
  set-up, often another day or temperature), else each run's positions (or
  balls, placements) as above: with two runs, holding one out would leave
  nothing to pin what only both together show (an expansion between two
  temperatures). A smoothing choice that must extrapolate between set-ups
  (a map correction's knot spacing) and the decision on a map correction
  hold out whole runs whenever there are two or more: a shape of position
  must carry from one set-up to the next.

Scans of the reference sphere (no figure holds them) are held out one scan at
a time: each pose a separate view.

The fit of each fold is the linearised weighted least-squares fit of the
diagnosis (:meth:`cmmpose.diagnosis.identify.Problem.wls`) with each class's
noise level fixed at its full-data estimate and the same weak prior; folds
are solved from per-group normal-equation blocks, so a candidate costs one
small solve per fold. Two figures are kept:

- ``rms_um``: the headline figure predicted out of sample (the ballbar
  length residuals, or an artefact's ball deviations), in um, beside the
  in-sample one;
- ``whitened``: the mean squared held-out residual of every class, each in
  units of its noise level (the figure that judges effects seen only in the
  sphere fits: scanner effects).

Uncertainties come from the spread over folds (a ratio estimator:
``u(MSE) = sd_g(e_g - MSE n_g) sqrt(G) / sum n_g`` over G groups with squared
held-out error e_g over n_g rows), and a change between two models from the
paired per-fold differences, which removes the folds' common noise.

Decision rule (:func:`judge`): an effect is added only when it lowers the
whitened CV figure by more than that change's own standard uncertainty and
does not raise the headline CV rms materially (by more than
HEADLINE_RISE_SIGMA of the change's uncertainty and HEADLINE_RISE_SHARE of the
rms): never a step that raises the cross-validated error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .observables import CLASSES

#: A candidate whose headline CV rms rises by more than this many standard
#: uncertainties of the (paired) change ...
HEADLINE_RISE_SIGMA = 2.0
#: ... and by more than this share of the CV rms is rejected even when the
#: whitened figure falls (it would trade the figure users read for sphere-fit residuals).
HEADLINE_RISE_SHARE = 0.01

__all__ = ["CVScore", "compare", "cv_groups", "cv_score", "judge", "model_design", "verify"]


def _single_groups(layout) -> tuple[np.ndarray, str]:
    """Group of every observable row of one run (-1: never held out)."""
    sizes = layout.sizes
    n_sph = len(layout.sphere_kind)
    sphere_group = np.full(n_sph, -1)
    first = np.zeros(sizes["length"], int)
    if layout.artefact is None:
        for p, (a, b) in enumerate(layout.ends):
            sphere_group[[a, b]] = p
        first = np.arange(len(layout.positions))
        how = "leave one ballbar position out (its length and its balls' scans held out together)"
    else:
        art = layout.artefact
        rows, g = [], 0
        for sph in art.spheres:
            for s in sph:
                sphere_group[s] = g
                rows += [g] * 3
                g += 1
        first = np.array(rows, int)
        how = "leave one ball out (its deviations and scans held out together)"
    scan_group = sphere_group[layout.sphere_of_scan]
    # Scans of a sphere that no figure holds (the reference sphere, seen
    # from several poses): one scan out at a time (each pose a separate view).
    loose = np.flatnonzero(scan_group < 0)
    scan_group[loose] = max(int(sphere_group.max()), int(first.max(initial=-1))) + 1 + np.arange(len(loose))
    centre = np.repeat(scan_group[layout.repeated], 3)
    radius = scan_group
    point = scan_group[layout.sample_scan]
    return np.concatenate([first, centre, radius, point]).astype(int), how


def cv_groups(problem, by_run: bool | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """The cross-validation fold of every observable row of ``problem``,
    the item each row belongs to (the units whose spread gives the
    uncertainty: ballbar positions, balls, reference scans), and the split
    in words. Rows of fold -1 are always in the training set.

    Parameters
    ----------
    problem : Problem or JointProblem
    by_run : bool, optional
        For several runs: hold out whole runs (True) or positions, balls or
        placements within each run (False). Default: whole runs when there
        are three or more (two runs then still pin what needs both, such as
        an expansion seen between two temperatures), within each run for two.

    Returns
    -------
    folds, items : ndarray (n,) of int
    split : str
    """
    parts = getattr(problem, "parts", None)
    if not parts:
        g, how = _single_groups(problem.layout)
        return g, g, how
    items, off, how = [], 0, ""
    for p in parts:
        g, how = _single_groups(p.layout)
        items.append(np.where(g >= 0, g + off, -1))
        off += max(int(g.max()) + 1, 0)
    items = np.concatenate(items)
    if not (len(parts) >= 3 if by_run is None else by_run):
        return items, items, f"within each run: {how}"
    folds = np.concatenate([np.full(len(p.classes), i) for i, p in enumerate(parts)])
    return folds, items, ("leave one run out (each run a separate set-up: another placement, "
                                          f"day or temperature); uncertainty from the spread over items ({how})")


@dataclass
class CVScore:
    """Held-out residuals of one model under one split.

    Attributes
    ----------
    e_head, n_head : ndarray (G,)
        Per fold: sum of squared held-out headline residuals (mm^2) and how many.
    e_white, n_white : ndarray (G,)
        Per fold: sum of squared whitened held-out residuals (every class) and how many.
    in_sample_um : float
        The headline residual rms of the full-data fit, um.
    """

    e_head: np.ndarray
    n_head: np.ndarray
    e_white: np.ndarray
    n_white: np.ndarray
    in_sample_um: float

    @staticmethod
    def _ratio(e, n) -> tuple[float, float]:
        N = float(np.sum(n))
        if N <= 0:
            return float("nan"), float("nan")
        m = float(np.sum(e)) / N
        G = int(np.sum(n > 0))
        u = float(np.std(e - m * n, ddof=1) * math.sqrt(G) / N) if G > 1 else float("inf")
        return m, u

    @property
    def rms_um(self) -> float:
        """Cross-validated headline rms, um."""
        m, _ = self._ratio(self.e_head, self.n_head)
        return math.sqrt(m) * 1e3 if not math.isnan(m) else float("nan")

    @property
    def u_rms_um(self) -> float:
        """Its standard uncertainty (spread over folds), um."""
        m, u = self._ratio(self.e_head, self.n_head)
        return u / (2 * math.sqrt(m)) * 1e3 if m > 0 else float("nan")

    @property
    def whitened(self) -> float:
        """Cross-validated mean squared whitened residual (1 for a model at its noise)."""
        return self._ratio(self.e_white, self.n_white)[0]

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {"cv_rms_um": num(self.rms_um), "cv_rms_u_um": num(self.u_rms_um),
                "in_sample_rms_um": num(self.in_sample_um), "cv_whitened": num(self.whitened)}


def model_design(problem, model, extra: np.ndarray | None = None):
    """Nuisance and effect columns of ``model`` (plus ``extra`` columns),
    with the diagnosis's weak prior: ``(X, ridge, target)`` as
    :meth:`Problem.wls` takes them."""
    from .identify import PRIOR_WEIGHT

    X0, index = problem.model_design(model)
    k0 = problem.nuisance.shape[1]
    now = np.concatenate([model.values(n) / np.asarray(problem.candidates[n].prior) for n, _ in index]) \
        if index else np.zeros(0)
    ridge = np.r_[np.zeros(k0), np.full(len(now), PRIOR_WEIGHT)]
    target = np.r_[np.zeros(k0), -now]
    if extra is not None and extra.shape[1]:
        X0 = np.column_stack([X0, extra])
        ridge = np.r_[ridge, np.full(extra.shape[1], PRIOR_WEIGHT)]
        target = np.r_[target, np.zeros(extra.shape[1])]
    return X0, ridge, target


def cv_score(problem, r0: np.ndarray, X: np.ndarray, ridge: np.ndarray, target: np.ndarray, sigma: np.ndarray,
             groups, items: np.ndarray | None = None) -> CVScore:
    """Leave-one-group-out prediction of the residual ``r0 + X beta``.

    Parameters
    ----------
    problem : Problem
        For the rows' classes.
    r0 : ndarray (n,)
        Residual of the current model, mm.
    X : ndarray (n, k)
        Columns (nuisances, effects, candidate), mm per prior magnitude.
    ridge, target : ndarray (k,)
        The weak prior (see :meth:`Problem.wls`).
    sigma : ndarray
        Noise level of each class (fixed in every fold), mm.
    groups : ndarray (n,) of int, or the tuple :func:`cv_groups` returns
        The fold of each row (-1: always trained on).
    items : ndarray (n,) of int, optional
        The item of each row, whose spread gives the uncertainty (default the folds).
    """
    if isinstance(groups, tuple):
        groups, items = groups[0], groups[1]
    items = groups if items is None else items
    s = sigma[problem.classes]
    Xw = X / s[:, None]
    rw = r0 / s
    k = X.shape[1]
    head = (problem.classes % len(CLASSES)) == 0
    # An artefact's deviations count per ball (3 rows), as its rms deviation does (of |deviation|).
    parts = getattr(problem, "parts", None) or [problem]
    per_row = np.concatenate([np.where(p.classes == 0, 1.0 / 3.0 if p.layout.artefact is not None else 1.0, 0.0)
                              for p in parts])
    G_all = Xw.T @ Xw
    b_all = Xw.T @ rw
    R2 = np.diag(ridge ** 2)
    prior_rhs = ridge ** 2 * target
    ids = np.unique(groups[groups >= 0])
    pred_w = np.zeros(len(r0))
    held = np.zeros(len(r0), bool)
    order = np.argsort(groups, kind="stable")
    starts = np.searchsorted(groups[order], ids)
    stops = np.searchsorted(groups[order], ids, side="right")
    for a, b in zip(starts, stops):
        rows = order[a:b]
        Xg, rg = Xw[rows], rw[rows]
        A = G_all - Xg.T @ Xg + R2
        rhs = -(b_all - Xg.T @ rg) + prior_rhs
        beta = np.linalg.lstsq(A, rhs, rcond=1e-12)[0] if k else np.zeros(0)
        pred_w[rows] = rg + Xg @ beta
        held[rows] = True
    it = np.where(held & (items >= 0), items, -1)
    uniq, inv = np.unique(it[it >= 0], return_inverse=True)
    m = len(uniq)
    sel = it >= 0
    e_w = np.bincount(inv, pred_w[sel] ** 2, minlength=m)
    n_w = np.bincount(inv, minlength=m).astype(float)
    ph = np.where(head, pred_w * s, 0.0)[sel]
    e_h = np.bincount(inv, ph ** 2, minlength=m)
    n_h = np.bincount(inv, per_row[sel], minlength=m)
    # In sample: the same fit on every row.
    beta = np.linalg.lstsq(G_all + R2, -b_all + prior_rhs, rcond=1e-12)[0] if k else np.zeros(0)
    res = (r0 + X @ beta)[head]
    ins = float(np.sqrt(np.sum(res ** 2) / np.sum(per_row))) * 1e3 if len(res) else float("nan")
    return CVScore(e_h, n_h, e_w, n_w, ins)


def compare(old: CVScore, new: CVScore) -> dict:
    """How ``new`` predicts against ``old`` on the same folds (paired).

    Returns
    -------
    dict
        ``gain_whitened`` and ``gain_whitened_u`` (fall of the whitened CV
        figure and its standard uncertainty), ``gain_um`` and ``gain_u_um``
        (fall of the headline CV rms, um, and its uncertainty).
    """
    def paired(e_old, e_new, n):
        N = float(np.sum(n))
        d = e_old - e_new
        G = int(np.sum(n > 0))
        if N <= 0:
            return float("nan"), float("nan")
        return float(np.sum(d)) / N, (float(np.std(d, ddof=1)) * math.sqrt(G) / N if G > 1 else float("inf"))

    gw, uw = paired(old.e_white, new.e_white, old.n_white)
    gm, um = paired(old.e_head, new.e_head, old.n_head)
    ro, rn = old.rms_um, new.rms_um
    ok = math.isfinite(ro) and math.isfinite(rn) and ro + rn > 0
    denom = (ro + rn) * 1e-3 if ok else float("nan")
    return {"gain_whitened": gw, "gain_whitened_u": uw, "rms_um": ro,
            "gain_um": (ro - rn) if ok else float("nan"),
            "gain_u_um": um / denom * 1e3 if ok else float("nan")}


def judge(change: dict) -> tuple[bool, str]:
    """The decision rule on a :func:`compare` result: (passes, why)."""
    gw, uw, gm, um = (change[k] for k in ("gain_whitened", "gain_whitened_u", "gain_um", "gain_u_um"))
    if math.isnan(gw) or gw <= uw:
        return False, (f"does not lower the cross-validated error by more than its uncertainty "
                       f"(whitened fall {gw:.3g} ± {uw:.2g})")
    if math.isfinite(gm) and math.isfinite(um) and -gm > max(HEADLINE_RISE_SIGMA * um, HEADLINE_RISE_SHARE * change.get("rms_um", 0.0)):
        return False, f"raises the cross-validated rms by {-gm:.2f} ± {um:.2f} um"
    return True, f"lowers the cross-validated error (whitened fall {gw:.3g} ± {uw:.2g}; rms {gm:+.2f} ± {um:.2f} um)"


def _clean(d: dict) -> dict:
    """JSON-safe: non-finite numbers as None."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def _current(problem, step):
    """(r0, X0, ridge0, target0, sigma) of a step's model."""
    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge0, target0 = model_design(problem, step.model)
    sigma = problem.wls(r0, X0, ridge=ridge0, target=target0).sigma
    return r0, X0, ridge0, target0, sigma


def step_cv(problem, step, groups: np.ndarray, split: str) -> CVScore:
    """Set ``step.cv`` (the step's model cross-validated) and return its score."""
    r0, X0, ridge0, target0, sigma = _current(problem, step)
    score = cv_score(problem, r0, X0, ridge0, target0, sigma, groups)
    step.cv = _clean({**score.to_dict(), "split": split, "items": len(score.n_head)})
    step._cv_state = (r0, X0, ridge0, target0, sigma, score)
    return score


def judge_candidate(problem, step, candidate, groups: np.ndarray, split: str) -> bool:
    """Cross-validate ``candidate`` added to ``step``'s model; set
    ``candidate.cv`` and return whether it passes :func:`judge`."""
    state = getattr(step, "_cv_state", None)
    if state is None:
        step_cv(problem, step, groups, split)
        state = step._cv_state
    r0, X0, ridge0, target0, sigma, old = state
    if getattr(candidate.spec, "family", None) == "map" and getattr(problem, "parts", None):
        # A map shape is a function of position: it must carry from one
        # set-up to the next, so with several runs it is judged holding out
        # whole runs (a periodic shape that fits the balls between others
        # can still fail a placement it never saw).
        folds, items, split = cv_groups(problem, by_run=True)
        groups = (folds, items)
        cache = step.__dict__.setdefault("_cv_by_run", {})
        if "old" not in cache:
            cache["old"] = cv_score(problem, r0, X0, ridge0, target0, sigma, groups)
        old = cache["old"]
    J = problem.columns[candidate.name]
    X = np.column_stack([X0, J])
    ridge = np.r_[ridge0, np.full(J.shape[1], _pw())]
    target = np.r_[target0, np.zeros(J.shape[1])]
    new = cv_score(problem, r0, X, ridge, target, sigma, groups)
    change = compare(old, new)
    ok, why = judge(change)
    candidate.cv = _clean({**new.to_dict(), **change, "passes": ok, "why": why, "split": split})
    return ok


def _pw() -> float:
    from .identify import PRIOR_WEIGHT

    return PRIOR_WEIGHT


def verify(model, run, plain=None) -> dict:
    """Does ``model`` hold on ``run``, which it was not fitted to? Its
    headline error (ballbar lengths brought to 20 C about their mean, or the
    artefact's ball deviations) against the plain maps' on the same run,
    with standard uncertainties from the spread over positions (balls), and
    the paired difference.

    Parameters
    ----------
    model : Model
        A found model (effects, map corrections).
    run : Run
        A run the model never saw.
    plain : Model, optional
        What to compare with; default ``model``'s maps without its effects.

    Returns
    -------
    dict
        ``model_rms_um``, ``model_rms_u_um``, ``plain_rms_um``,
        ``plain_rms_u_um``, ``change_um`` and ``change_u_um`` (model minus
        plain), ``holds`` (bool: the model does not raise the error by more
        than its uncertainty) and ``verdict`` (words).
    """
    from dataclasses import replace

    plain = replace(model, effects=(), _inputs_cache={}) if plain is None else plain

    def per_item(m):
        f = m.evaluate(run)
        if f.deviation_rms is not None:
            from .observables import ObservationLayout, observe

            inputs = m.inputs(run)
            layout = ObservationLayout.from_run(run, inputs)
            dev = observe(layout, m.compensate(inputs), m.expansion_ppm_per_kelvin, inputs.scan_id).deviations
            return np.sum(dev ** 2, axis=1), "rms deviation"
        d = f.lengths_20c - np.mean(f.lengths_20c)
        return d ** 2 * len(d) / max(len(d) - 1, 1), "rms accuracy error"

    e_m, what = per_item(model)
    e_p, _ = per_item(plain)
    n = len(e_m)

    def rms_u(e):
        m = float(np.mean(e))
        u = float(np.std(e, ddof=1) / math.sqrt(n)) if n > 1 else float("inf")
        r = math.sqrt(m)
        return r * 1e3, (u / (2 * r) * 1e3 if r > 0 else float("inf"))

    rm, um_ = rms_u(e_m)
    rp, up = rms_u(e_p)
    d = e_m - e_p
    ud = float(np.std(d, ddof=1) / math.sqrt(n)) if n > 1 else float("inf")
    change = rm - rp
    u_change = ud / ((rm + rp) * 1e-3) * 1e3 if rm + rp > 0 else float("inf")
    holds = change <= u_change
    if change < -u_change:
        words = (f"the model holds on this run: {what} {rm:.2f} ± {um_:.2f} um against {rp:.2f} ± {up:.2f} um "
                 f"with the plain maps (a fall of {-change:.2f} ± {u_change:.2f} um)")
    elif holds:
        words = (f"the model neither helps nor harms on this run: {what} {rm:.2f} ± {um_:.2f} um against "
                 f"{rp:.2f} ± {up:.2f} um with the plain maps (change {change:+.2f} ± {u_change:.2f} um)")
    else:
        words = (f"the model does NOT hold on this run: {what} {rm:.2f} ± {um_:.2f} um against {rp:.2f} ± "
                 f"{up:.2f} um with the plain maps (a rise of {change:.2f} ± {u_change:.2f} um)")
    return _clean({"figure": what, "model_rms_um": rm, "model_rms_u_um": um_, "plain_rms_um": rp,
                   "plain_rms_u_um": up, "change_um": change, "change_u_um": u_change, "holds": bool(holds),
                   "items": int(n), "effects": list(model.names), "verdict": words})
