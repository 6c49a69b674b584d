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
  hold out whole runs when there are three or more
  (:func:`map_runs_out`): a shape of position must carry from one set-up
  to the next. With two, one run alone rarely covers what the other sees (a
  local bump under one placement's balls, near none of the other's): the
  held-out run then tests nothing and a real shape fails; each run's balls
  or positions are held out instead, and a ball held out between the
  others tests the shape between the balls, where an unseen placement's
  balls will lie.

Scans of the reference sphere (no figure holds them) are held out one scan at
a time: each pose a separate view.

The ambiguity set's judge (:mod:`cmmpose.diagnosis.ambiguity`) asks instead
how a model carries to where it will be used (``cv_groups(..., across=True)``):
whole runs out when there are two or more (another placement, plane, pose or
day), else whole placements of a run that holds several (a plate in the XY,
XZ and YZ planes: plane-out), else the digitizer poses of a run whose one
placement was scanned from several (pose-out: each ball or bar position with
the pose, told by its angles, that scanned it), else the split within the
one placement, said to judge interpolation only. Runs of different kinds
hold one pose out of every run at once when each was scanned from several.

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
from scipy.sparse import csr_matrix

from ..evaluation.model_check import check_model
from ..evaluation.observables import CLASSES
from .statistics import PRIOR_WEIGHT

#: A candidate whose headline CV rms rises by more than this many standard
#: uncertainties of the (paired) change ...
HEADLINE_RISE_SIGMA = 2.0
#: ... and by more than this share of the CV rms is rejected even when the
#: whitened figure falls (it would trade the figure users read for sphere-fit residuals).
HEADLINE_RISE_SHARE = 0.01

__all__ = ["CVDesign", "CVScore", "INTERPOLATION_ONLY", "MAP_RUNS_OUT", "POSE_ANGLE_TOL", "compare", "current_state",
           "cv_groups", "cv_score", "judge", "map_runs_out", "model_design", "scan_pose_angles", "verify"]


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


#: Said of a split whose folds lie within one placement.
INTERPOLATION_ONLY = "within one placement: this figure judges interpolation only, not a placement never seen"


def _placement_groups(layout) -> np.ndarray | None:
    """Fold of every observable row of one artefact run by its placement
    (the placement's deviations and scans; -1 elsewhere), or None when the
    run holds one placement (or is not an artefact run)."""
    art = layout.artefact
    if art is None or len(art.spheres) < 2:
        return None
    g, _ = _single_groups(layout)
    n_dev = layout.sizes["length"]
    out = np.full(len(g), -1)
    ball_of = np.concatenate([np.full(3 * len(idx), k) for k, idx in enumerate(art.spheres)])
    # The single split numbers balls in placement order: each ball's group to its placement.
    lut = np.repeat(np.arange(len(art.spheres)), [len(sph) for sph in art.spheres])
    out[:n_dev] = ball_of[:n_dev]
    rest = g[n_dev:]
    inside = (rest >= 0) & (rest < len(lut))
    out[n_dev:] = np.where(inside, lut[np.clip(rest, 0, len(lut) - 1)], -1)
    return out


#: Degrees: two digitizer poses whose Euler angles agree this closely are one pose (poses are identified by
#: their angles, not their ids: two runs may number them differently).
POSE_ANGLE_TOL = 1e-6


def scan_pose_angles(problem) -> np.ndarray:
    """(S, 3): the Euler angles (degrees) of the digitizer pose each sphere
    scan of one run (``problem.layout.labels``) was taken with."""
    layout, inputs = problem.layout, problem.inputs
    sc = problem.run.scans
    sid = np.asarray(sc["scan_id"])
    order = np.argsort(sid, kind="stable")
    pid = np.asarray(sc["pose_id"])[order[np.searchsorted(sid[order], layout.labels)]]
    angles = np.asarray(inputs.poses, float)[:, :3]
    return angles[np.searchsorted(np.asarray(inputs.pose_ids), pid)]


def _pose_groups(problem) -> tuple[np.ndarray, int] | None:
    """Fold of every observable row of one run by the digitizer pose (by its
    angles) that scanned it: each item of :func:`_single_groups` (a ballbar
    position, a ball, a reference scan) goes with the pose of its first
    scan; -1 where the row has no item. None when the scans' items use
    fewer than two poses, or a pose holds no headline row (a pose that
    only viewed the reference sphere). Returns (folds, poses)."""
    return _pose_split([problem])


def _pose_split(parts) -> tuple[np.ndarray, int] | None:
    """:func:`_pose_groups` over the stacked rows of one or more runs, the poses told apart by their angles
    across the runs; None unless every run holds headline rows of two or more poses (each fold then leaves
    every run rows that pin its own nuisances)."""
    try:
        angles = [scan_pose_angles(p) for p in parts]
    except (AttributeError, KeyError, IndexError, TypeError):  # a scripted problem, a run without poses
        return None
    keys = np.round(np.concatenate(angles) / POSE_ANGLE_TOL) * POSE_ANGLE_TOL
    _, pose = np.unique(keys, axis=0, return_inverse=True)
    pose = pose.reshape(-1)
    out, used_all, at_scan = [], set(), 0
    for p, a in zip(parts, angles):
        layout = p.layout
        pose_of_scan = pose[at_scan:at_scan + len(a)]
        at_scan += len(a)
        g, _ = _single_groups(layout)
        S = len(layout.labels)
        at = layout.sizes["length"] + 3 * len(layout.repeated)
        scan_item = g[at:at + S]  # the radius rows: one per scan, its item
        items, first = np.unique(scan_item, return_index=True)
        lut = np.full(int(max(g.max(), items.max())) + 1, -1)
        lut[items] = pose_of_scan[first]
        folds = np.where(g >= 0, lut[np.clip(g, 0, None)], -1)
        head = folds[:layout.sizes["length"]]
        used = set(np.unique(folds[folds >= 0]).tolist())
        if len(used) < 2 or any(not np.any(head == u) for u in used):
            return None
        used_all |= used
        out.append(folds)
    return np.concatenate(out), len(used_all)


#: Runs from which a map (or cross-axis) correction is judged holding whole runs out (fewer: their balls or positions).
MAP_RUNS_OUT = 3


def map_runs_out(problem) -> bool | None:
    """The ``by_run`` of :func:`cv_groups` that judges a map correction and
    chooses its knot spacing: whole runs out with MAP_RUNS_OUT runs or more,
    else within each run (None: a single run's default)."""
    parts = getattr(problem, "parts", None)
    if not parts:
        return None
    return len(parts) >= MAP_RUNS_OUT


def _one_kind(parts) -> bool:
    """Whether the runs of a joint problem are of one kind: all ballbar layouts, or all placements of one
    artefact (by its name), so that one run's figures can be predicted from the others'."""
    kinds = set()
    for p in parts:
        art = p.layout.artefact
        kinds.add("ballbar" if art is None else ("artefact", getattr(art.artefact, "name", "")))
    return len(kinds) == 1


def cv_groups(problem, by_run: bool | None = None, across: bool = False) -> tuple[np.ndarray, np.ndarray, str]:
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
    across : bool
        Folds that mirror how a model is used (the ambiguity set's judge,
        :mod:`cmmpose.diagnosis.ambiguity`): whole runs out when there are
        two or more of one kind (each another placement, plane, pose or
        day; runs of different kinds, a ballbar layout beside a plate,
        cannot predict each other's figures: each run's positions or balls
        then), else whole
        placements of the one run when it holds several, else within the one
        placement, and the split then says that the figure judges
        interpolation only.

    Returns
    -------
    folds, items : ndarray (n,) of int
    split : str
    """
    parts = getattr(problem, "parts", None)
    if across and parts and len(parts) >= 2 and _one_kind(parts):
        by_run = True
    elif across and parts and len(parts) >= 2:
        # Runs of different kinds (a ballbar layout beside an artefact's placements): one cannot predict the
        # other's own figures (its rigid fit, its lengths' offset), so each run's positions or balls are held out;
        # or, when every run was scanned from several digitizer poses, one pose out of every run at once.
        folds, items, split = cv_groups(problem, by_run=False)
        posed = _pose_split(parts)
        if posed is not None:
            return posed[0], items, (f"leave one digitizer pose out of every run ({posed[1]} poses, by their "
                                     f"angles: the positions or balls each scanned, with their scans, held out "
                                     f"together); the runs differ in kind; uncertainty from the spread over "
                                     f"positions or balls")
        return folds, items, f"{split}; the runs differ in kind; {INTERPOLATION_ONLY}"
    elif across:
        # One run: whole placements out when it holds several, else the digitizer poses out when its scans
        # used several (each another view of the same placement), else within the one placement, said so.
        layout = (parts[0] if parts else problem).layout
        placed = _placement_groups(layout)
        if placed is not None and not parts:
            g, _ = _single_groups(layout)
            return placed, g, ("leave one placement out (its deviations and scans held out together); "
                               "uncertainty from the spread over balls")
        posed = None if parts else _pose_groups(problem)
        if posed is not None:
            g, how = _single_groups(layout)
            unit = "balls" if layout.artefact is not None else "positions"
            return posed[0], g, (f"leave one digitizer pose out ({posed[1]} poses, by their angles: the {unit} each "
                                 f"scanned, with their scans, held out together); uncertainty from the spread over "
                                 f"{unit}")
        g, how = _single_groups(layout)
        if not parts:
            return g, g, f"{how}; {INTERPOLATION_ONLY}"
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
    :meth:`Problem.wls` takes them (:meth:`Problem.prior_design`)."""
    X, ridge, target, _ = problem.prior_design(model, extra)
    return X, ridge, target


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
    return CVDesign(problem, r0, X, ridge, target, sigma, groups, items).score_with()


class CVDesign:
    """A model's design with its per-fold normal-equation blocks, computed
    once: :meth:`score_with` cross-validates it with extra columns (a
    candidate) added, solving every fold at once.

    Each fold's fit is the full data's normal equations minus the fold's
    own block (exact leave-one-group-out, the same as refitting without the
    fold); the folds' small systems are solved as one stacked
    pseudo-inverse (singular directions cut as the full fit's ``lstsq``
    cuts them, at 1e-12 of the largest). The held-out squared residuals of
    each item follow from the item's own blocks, ``r'r + 2 beta'X'r +
    beta'X'X beta`` with its fold's beta, so no candidate touches the rows
    of the design again: the extra columns' blocks are summed over the rows
    where they are not zero only (a map correction's: centres and radii, not
    the point residuals). Parameters as :func:`cv_score`.
    """

    def __init__(self, problem, r0, X, ridge, target, sigma, groups, items=None):
        if isinstance(groups, tuple):
            groups, items = groups[0], groups[1]
        self.problem = problem
        items = groups if items is None else items
        self.r0 = r0
        self.X = X
        self.ridge = np.asarray(ridge, float)
        self.target = np.asarray(target, float)
        self.s = s = sigma[problem.classes]
        self.Xw = Xw = X / s[:, None]
        self.rw = rw = r0 / s
        n = len(r0)
        sel = groups >= 0
        self.ids, ginv = np.unique(groups[sel], return_inverse=True)
        self.gidx = np.full(n, -1)
        self.gidx[sel] = ginv
        self.head = head = (problem.classes % len(CLASSES)) == 0
        # An artefact's deviations count per ball (3 rows), as its rms deviation does (of |deviation|).
        parts = getattr(problem, "parts", None) or [problem]
        self.per_row = np.concatenate([np.where(p.classes == 0, 1.0 / 3.0 if p.layout.artefact is not None else 1.0,
                                                0.0) for p in parts])
        # Items (the units the figures sum over): held rows with an item, each inside one fold.
        it = np.where(sel & (items >= 0), items, -1)
        isel = it >= 0
        self.uniq, iinv = np.unique(it[isel], return_inverse=True)
        self.iidx = np.full(n, -1)
        self.iidx[isel] = iinv
        m = len(self.uniq)
        self.item_fold = np.zeros(m, int)
        self.item_fold[iinv] = self.gidx[isel]
        if not np.array_equal(self.item_fold[iinv], self.gidx[isel]):
            raise ValueError("cross-validation: an item spans two folds")
        self.n_w = np.bincount(iinv, minlength=m).astype(float)
        self.n_h = np.bincount(iinv, self.per_row[isel], minlength=m)
        self.A, self.b = Xw.T @ Xw, Xw.T @ rw
        self.A_g, self.b_g = self._blocks(self.gidx, len(self.ids), Xw, rw)
        # The items' blocks about the full fit (r0 holds the nuisances' whole size, a ball's radius:
        # its squares would swamp the held-out residuals' in the sums).
        k = X.shape[1]
        R2 = np.diag(self.ridge ** 2)
        self.beta0 = (np.linalg.lstsq(self.A + R2, -self.b + self.ridge ** 2 * self.target, rcond=1e-12)[0]
                      if k else np.zeros(0))
        self.rt = r0 + X @ self.beta0
        self.rtw = self.rt / s
        self.Aw_i, self.bw_i, self.rw_i = self._blocks(self.iidx, m, Xw, self.rtw, True)
        hi = np.where(head, self.iidx, -1)
        self.Ah_i, self.bh_i, self.rh_i = self._blocks(hi, m, X, self.rt, True)
        self.head_rows = np.flatnonzero(head)

    @staticmethod
    def _blocks(index, m, X, r, with_rr=False):
        """Per block b of ``index`` (-1: none): X_b'X_b (m, k, k), X_b'r_b
        (m, k) and, with ``with_rr``, r_b'r_b (m,)."""
        k = X.shape[1]
        keep = np.flatnonzero(index >= 0)
        order = keep[np.argsort(index[keep], kind="stable")]
        ids = index[order]
        starts = np.searchsorted(ids, np.arange(m))
        stops = np.searchsorted(ids, np.arange(m), side="right")
        Xs, rs = X[order], r[order]
        A = np.zeros((m, k, k))
        b = np.zeros((m, k))
        rr = np.zeros(m)
        for g, (a, z) in enumerate(zip(starts, stops)):
            A[g] = Xs[a:z].T @ Xs[a:z]
            b[g] = Xs[a:z].T @ rs[a:z]
            rr[g] = rs[a:z] @ rs[a:z]
        return (A, b, rr) if with_rr else (A, b)

    @staticmethod
    def _extend(A0, b0, index, m, Xn, Jn, rn):
        """Blocks (m, k0 + kj, k0 + kj) and (m, k0 + kj) of [X | J] from the
        blocks of X and sums over the rows of J (Xn, Jn, rn at them, their
        block ``index``)."""
        k0, kj = A0.shape[1], Jn.shape[1]
        on = index >= 0
        H = csr_matrix((np.ones(int(on.sum())), (index[on], np.flatnonzero(on))), shape=(m, len(index)))
        cross = (H @ (Xn[:, :, None] * Jn[:, None, :]).reshape(len(index), -1)).reshape(m, k0, kj)
        jj = (H @ (Jn[:, :, None] * Jn[:, None, :]).reshape(len(index), -1)).reshape(m, kj, kj)
        A = np.empty((m, k0 + kj, k0 + kj))
        A[:, :k0, :k0] = A0
        A[:, :k0, k0:] = cross
        A[:, k0:, :k0] = cross.transpose(0, 2, 1)
        A[:, k0:, k0:] = jj
        return A, np.concatenate([b0, np.asarray(H @ (Jn * rn[:, None])).reshape(m, kj)], axis=1)

    def score_with(self, J: np.ndarray | None = None, ridge: float | None = None, target: float = 0.0,
                   rows: np.ndarray | None = None) -> CVScore:
        """The cross-validated score of the design with columns ``J`` added
        (prior ``ridge``, default the diagnosis's weak prior, about
        ``target``); None: the design alone. ``J`` is (n, kj), or
        (len(rows), kj) at ``rows`` and zero elsewhere."""
        n_g, m = len(self.ids), len(self.uniq)
        k0 = self.X.shape[1]
        kj = 0 if J is None else J.shape[1]
        A_all, b_all, A_g, b_g = self.A, self.b, self.A_g, self.b_g
        Aw, bw, Ah, bh = self.Aw_i, self.bw_i, self.Ah_i, self.bh_i
        ridge_all, target_all = self.ridge, self.target
        J_head = np.zeros((len(self.head_rows), 0))
        if kj:
            ridge = _pw() if ridge is None else ridge
            if rows is None:
                rows = np.arange(len(self.r0))
            nzm = np.any(J != 0, axis=1)
            nz, Jn = rows[nzm], J[nzm]
            Jnw = Jn / self.s[nz, None]
            Xn, rn = self.Xw[nz], self.rw[nz]
            A_all = np.block([[self.A, Xn.T @ Jnw], [Jnw.T @ Xn, Jnw.T @ Jnw]])
            b_all = np.r_[self.b, Jnw.T @ rn]
            A_g, b_g = self._extend(self.A_g, self.b_g, self.gidx[nz], n_g, Xn, Jnw, rn)
            Aw, bw = self._extend(self.Aw_i, self.bw_i, self.iidx[nz], m, Xn, Jnw, self.rtw[nz])
            hn = self.head[nz]
            Ah, bh = self._extend(self.Ah_i, self.bh_i, np.where(hn, self.iidx[nz], -1), m, self.X[nz], Jn,
                                  self.rt[nz])
            J_head = np.zeros((len(self.head_rows), kj))
            J_head[np.searchsorted(self.head_rows, nz[hn])] = Jn[hn]
            ridge_all = np.r_[self.ridge, np.full(kj, ridge)]
            target_all = np.r_[self.target, np.full(kj, target)]
        k = k0 + kj
        R2 = np.diag(ridge_all ** 2)
        prior_rhs = ridge_all ** 2 * target_all
        if k and n_g:
            A = A_all[None] - A_g + R2[None]
            rhs = -(b_all[None] - b_g) + prior_rhs[None]
            beta = np.einsum("gij,gj->gi", np.linalg.pinv(A, rcond=1e-12), rhs)[self.item_fold]  # (m, k)
            d = beta - np.r_[self.beta0, np.zeros(kj)][None]  # about the full fit of the design alone
            e_w = self.rw_i + 2 * np.einsum("mk,mk->m", d, bw) + np.einsum("mi,mij,mj->m", d, Aw, d)
            e_h = self.rh_i + 2 * np.einsum("mk,mk->m", d, bh) + np.einsum("mi,mij,mj->m", d, Ah, d)
        else:
            e_w, e_h = self.rw_i.copy(), self.rh_i.copy()
        e_w, e_h = np.maximum(e_w, 0.0), np.maximum(e_h, 0.0)  # sums of squares (rounding)
        # In sample: the same fit on every row.
        h = self.head_rows
        res = self.r0[h].copy()
        if k:
            beta = np.linalg.lstsq(A_all + R2, -b_all + prior_rhs, rcond=1e-12)[0]
            res += self.X[h] @ beta[:k0] + J_head @ beta[k0:]
        ins = float(np.sqrt(np.sum(res ** 2) / np.sum(self.per_row))) * 1e3 if len(res) else float("nan")
        return CVScore(e_h, self.n_h.copy(), e_w, self.n_w.copy(), ins)


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


def current_state(problem, step):
    """(r0, X0, ridge0, target0, sigma) of a step's model: its residual
    observables (mm), its design with the weak prior and each class's noise
    level (mm)."""
    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge0, target0 = model_design(problem, step.model)
    sigma = problem.wls(r0, X0, ridge=ridge0, target=target0).sigma
    return r0, X0, ridge0, target0, sigma


def step_cv(problem, step, groups: np.ndarray, split: str) -> CVScore:
    """Set ``step.cv`` (the step's model cross-validated) and return its score."""
    r0, X0, ridge0, target0, sigma = current_state(problem, step)
    score = cv_score(problem, r0, X0, ridge0, target0, sigma, groups)
    step.cv = _clean({**score.to_dict(), "split": split, "items": len(score.n_head)})
    step._cv_state = (r0, X0, ridge0, target0, sigma, score)
    return score


def judge_candidate(problem, step, candidate, groups: np.ndarray, split: str, columns: np.ndarray | None = None) -> bool:
    """Cross-validate ``candidate`` added to ``step``'s model; set
    ``candidate.cv`` and return whether it passes :func:`judge`. ``columns``:
    its columns when they are not the problem's (a sibling shape,
    :func:`cmmpose.diagnosis.ambiguity.sibling_candidates`)."""
    state = getattr(step, "_cv_state", None)
    if state is None:
        step_cv(problem, step, groups, split)
        state = step._cv_state
    r0, X0, ridge0, target0, sigma, old = state
    by_run = False
    if getattr(candidate.spec, "family", None) in ("map", "cross") and map_runs_out(problem):
        # A map shape is a function of position: it must carry from one
        # set-up to the next, so with three runs or more it is judged holding
        # out whole runs (a periodic shape that fits the balls between others
        # can still fail a placement it never saw); with two, within each run
        # (map_runs_out).
        folds, items, split = cv_groups(problem, by_run=True)
        groups = (folds, items)
        by_run = True
    # The model's design and its folds' blocks, once per step and split; each candidate adds its columns.
    designs = step.__dict__.setdefault("_cv_by_run", {})
    if by_run not in designs:
        design = CVDesign(problem, r0, X0, ridge0, target0, sigma, groups)
        designs[by_run] = (design, design.score_with() if by_run else old)
    design, old = designs[by_run]
    J = problem.columns[candidate.name] if columns is None else columns
    new = design.score_with(J, _pw(), 0.0)
    change = compare(old, new)
    ok, why = judge(change)
    candidate.cv = _clean({**new.to_dict(), **change, "passes": ok, "why": why, "split": split})
    return ok


def _pw() -> float:

    return PRIOR_WEIGHT


def verify(model, run) -> dict:
    """Does ``model`` hold on ``run``, which it was not fitted to? The model
    applied as saved, through the evaluation ``cmmpose evaluate --model``
    uses, beside its plain maps (:func:`cmmpose.evaluation.model_check.check_model`);
    nothing is refitted on ``run``.

    Returns
    -------
    dict
        ``model_rms_um``, ``model_rms_u_um``, ``plain_rms_um``,
        ``plain_rms_u_um``, ``change_um`` and ``change_u_um`` (model minus
        plain), ``holds`` (bool: the model does not raise the error by more
        than its uncertainty), ``worse``, ``notes`` (where the run is
        outside the model's domain) and ``verdict`` (words).
    """
    return check_model(run, model).to_dict()
