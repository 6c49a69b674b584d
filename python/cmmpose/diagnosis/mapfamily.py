"""A generic family of candidates: corrections to the error map itself.

Where no named effect of the library explains what the run shows, the
structure may be in the map: one of its components is wrong by a smooth
function of its axis's position. Each candidate here corrects one of the 18
per-axis map components (:data:`COMPONENTS`) or one squareness
(:data:`SQUARENESS`):

- the *translational* components of an axis: its position error (``dx(X)``,
  ``dy(Y)``, ``dz(Z)``) and its two straightnesses (``dy(X)``, ``dz(X)``,
  ``dx(Y)``, ``dz(Y)``, ``dx(Z)``, ``dy(Z)``), um;
- the *rotational* components: each axis's three angles as functions of its
  own position, ``ex(A)``, ``ey(A)``, ``ez(A)`` (rotation about x, y, z:
  roll of X is ``ex(X)``, pitch ``ey(X)``, yaw ``ez(X)``; roll of Y
  ``ey(Y)``, pitch ``ex(Y)``, yaw ``ez(Y)``; roll of Z ``ez(Z)``, its tilts
  ``ex(Z)`` and ``ey(Z)``), arc-seconds. An angle eps of carriage A moves the
  probe by ``eps x (arm(A) + p)`` (docs/conventions.md: ``arm(A)`` the
  travel of the carriages it carries, from the machine configuration, and
  ``p`` the probe's lever from the ram, the compensated point minus the
  scale reading);
- the *squarenesses* ``sq(xy)``, ``sq(yz)``, ``sq(zx)`` as a constant
  (arc-seconds; the map's shear ``-E S_xy`` in x etc.). A squareness that
  varies with position is not a new component: its change along the reading
  is the slope of a straightness (``dx(Y)`` for ``sq(xy)``), which the
  translational shapes hold. The library's named ``squareness`` is the same
  physics; the squareness corrections are offered only when that named
  effect is not a candidate (a restricted library), and the component
  report (below) always covers them.

Each component is corrected by one of these shapes of the axis's scale
reading q (mm) over the travel the run used, ``[lo, hi]``:

- ``poly``: Legendre polynomials in ``t = (2q - lo - hi) / (hi - lo)``:
  degrees 2 and 3 for a translational component (degrees 0 and 1 are a
  rigid offset and a scale or squareness, which the nuisances and the
  library's named ``scale`` and ``squareness`` hold), degrees 1 to 3 for an
  angle (a constant angle is a squareness or a tilt of the whole run; a
  linear roll is also the library's named ``roll``, which ranks first);
- ``hat<h>``: local linear B-splines (hats) with knots every ``h`` mm over the
  travel; ``h`` chosen by cross-validation (:mod:`cmmpose.diagnosis.cv`)
  among a few spacings;
- ``sine<P>``: a sine and a cosine of period ``P`` mm, the period found by a
  search over the whole range from PERIOD_MIN (10 mm) to the travel (the
  likelihood profile over periods; ``P`` and its uncertainty from where
  -2 log L rises by 1 from its minimum);
- ``const``: a squareness (one value).

A correction as a model term (its name, ``map:<component>:<shape>[lo,hi]``,
how a model applies it, and the maps with it written in) is
:mod:`cmmpose.model.mapshape`'s; this module searches a run for them.

Sensitivities are taken at the centre level, linear in each shape's
coefficients: a correction moves each sphere scan's points by the
component's function at their readings times a per-point displacement (a
unit along one direction for a translational component, ``e_j x lever``
for an angle), and the linearised sphere fit of the scan turns the normal
parts of those displacements into the centre's move (radius and point
residuals do not change at first order for a shape smooth over one ball's
scan). The ballbar lengths (or an artefact's deviations after each
placement's rigid fit) follow from the moved centres. For speed, each
component's per-point weights are spread once onto a fine grid of its
axis's reading (GRID_MM, linear interpolation; at the shortest period the
interpolation errs by (pi GRID_MM / PERIOD_MIN)^2 / 2, about 1 %): a shape's
columns are then one sparse product with the shape's values at the grid
nodes, shared by every shape and period of the search. No kernel call,
no finite differences and no loop over points in Python.

Statistics. The map candidates are a family of their own: a significance
threshold ALPHA / (number of map candidates), and a periodic candidate's
p-value multiplied by the number of independent periods searched
(Bonferroni over the search), so a noise-only run adds one with probability
at most ALPHA. The library's named effects are judged first (they are the
better physics where they explain the structure); a map correction is added
only where no named effect is both significant and better out of sample.

Observability (:func:`component_report`): for each component, the whitened
sensitivities of its shape basis (the polynomials above and hats at a fifth of
the travel; a squareness's constant) after the nuisances and the model's
effects are projected out; its singular values say how many shapes the data
determine (above 2 sigma at the prior), and the principal angles between two
components' spaces say which are aliased (cosine above 0.95: the data cannot
tell them apart), with other components and with the library's named effects.

Units: positions mm, translational corrections um, angles and squareness
arc-seconds (parameters), priors in the same units.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.sparse import csr_matrix

from .cv import CVDesign, cv_groups, map_runs_out, model_design

from ..model.crossaxis import CrossAxisCorrection, is_cross
from ..model.mapshape import (ARCSEC, COMPONENTS, PERIOD_MIN, PRIOR_AS, PRIOR_UM, ROTATIONAL, SQUARENESS, TRANSLATIONAL,
                               MapCorrection, arms, corrected_maps, is_map, kind_of, make, parse, reading_axis)

__all__ = ["COMPONENTS", "GRID_MM", "PERIOD_MIN", "PRIOR_AS", "PRIOR_UM", "ROTATIONAL", "SQUARENESS", "TRANSLATIONAL",
           "MapCorrection", "component_report", "corrected_maps", "is_map", "map_candidates", "model_kinematics",
           "parse", "sibling_shapes"]

#: Knot spacings tried, as fractions of the travel.
HAT_FRACTIONS = (1 / 3, 1 / 5, 1 / 8, 1 / 12, 1 / 18)
#: Spacing of the reading grid the centre-level sensitivities are spread on, mm.
GRID_MM = 0.5

def _lever(S: np.ndarray, xyz: np.ndarray, axis: int, kinematics: str) -> np.ndarray:
    """(N, 3) mm: the arm an angle of carriage ``axis`` turns the probe tip
    over: its arm (the carriages it carries) plus the probe's lever from the
    ram (the point minus the scale reading)."""
    return S * arms(kinematics)[axis][None, :] + (xyz - S)


def _turn(j: int, lever: np.ndarray) -> np.ndarray:
    """(N, 3): e_j x lever."""
    out = np.zeros_like(lever)
    a, b = (j + 1) % 3, (j + 2) % 3
    out[:, b] = lever[:, a]
    out[:, a] = -lever[:, b]
    return out


#: Points per scan the linearised sphere fits use.


READINGS_PER_SCAN = 128


def reading_subset(problem) -> dict:
    """Up to READINGS_PER_SCAN of each scan's sampled points, evenly spread,
    with their readings ``q`` (m, 3) mm, compensated points ``xyz`` (m, 3)
    mm, scan index, outward normals ``n`` (m, 3) from the base model's fits,
    and each scan's inverse normal matrix of the linearised sphere fit
    ``Minv`` (S, 4, 4) (cached on the problem)."""
    cache = problem.__dict__.get("_map_subset")
    if cache is not None:
        return cache
    layout = problem.layout
    ss = layout.sample_scan
    S = len(layout.labels)
    cnt = np.bincount(ss, minlength=S)
    start = np.r_[0, np.cumsum(cnt)[:-1]]
    rank = np.arange(len(ss)) - start[ss]
    step = np.maximum(cnt // READINGS_PER_SCAN, 1)[ss]
    keep = rank % step == 0
    rows = layout.sample[keep]
    scan = ss[keep]
    xyz = _compensate_rows(problem, rows)
    n = xyz - problem.base_obs.centres[scan]
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    a = np.column_stack([n, np.ones(len(n))])
    M = np.zeros((S, 4, 4))
    np.add.at(M, scan, a[:, :, None] * a[:, None, :])
    Minv = np.linalg.pinv(M)
    cache = {"q": np.ascontiguousarray(problem.inputs.scales[rows]), "xyz": xyz, "scan": scan, "n": n, "a": a,
             "Minv": Minv, "S": S,
             # Row 4 s + j sums a_j over scan s's points: (4 S, m), sparse.
             "sum": csr_matrix((a.reshape(-1), (((4 * scan)[:, None] + np.arange(4)).reshape(-1),
                                                np.repeat(np.arange(len(a)), 4))), shape=(4 * S, len(a))),
             "weights": {}, "grids": {}, "rigid": {}}
    problem.__dict__["_map_subset"] = cache
    return cache


def _compensate_rows(problem, rows: np.ndarray) -> np.ndarray:
    """The base model's compensated points at ``rows`` (mm): those of the
    problem's base observation when it kept them, else one compensation."""
    xyz = getattr(problem, "_base_xyz", None)
    if xyz is None:
        xyz = problem.base.compensate(problem.inputs)
    return xyz[rows]


def _weights(problem, component: str, kinematics: str = "thesis") -> np.ndarray:
    """Per subset point (m,): the normal part of its displacement per unit
    of the component's function (mm per um, or per arc-second)."""
    sub = reading_subset(problem)
    key = (component, kinematics)
    w = sub["weights"].get(key)
    if w is not None:
        return w
    n, q = sub["n"], sub["q"]
    kind = kind_of(component)
    if kind == "translational":
        w = n[:, COMPONENTS[component][1]] * 1e-3
    elif kind == "squareness":
        r, d = SQUARENESS[component]
        w = -n[:, d] * q[:, r] * ARCSEC
    else:
        axis, j = COMPONENTS[component]
        w = np.einsum("mi,mi->m", n, _turn(j, _lever(q, sub["xyz"], axis, kinematics))) * ARCSEC
    sub["weights"][key] = w
    return w


def _grid(problem, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reading grid of ``axis`` over the subset: nodes (G,), and each
    point's lower node index and interpolation fraction."""
    sub = reading_subset(problem)
    g = sub["grids"].get(axis)
    if g is None:
        q = sub["q"][:, axis]
        lo = math.floor(float(q.min()) / GRID_MM) * GRID_MM
        G = math.ceil((float(q.max()) - lo) / GRID_MM) + 2
        nodes = lo + GRID_MM * np.arange(G)
        x = (q - lo) / GRID_MM
        i = np.minimum(np.floor(x).astype(int), G - 2)
        g = sub["grids"][axis] = (nodes, i, x - i)
    return g


def _spread(problem, component: str, kinematics: str):
    """(nodes, W): the component's sparse (4 S, G) map from values of its
    function at the grid nodes to each scan's right-hand side of the
    linearised sphere fit (cached)."""
    sub = reading_subset(problem)
    key = ("spread", component, kinematics)
    out = sub["grids"].get(key)
    if out is not None:
        return out
    nodes, i, t = _grid(problem, reading_axis(component))
    w = _weights(problem, component, kinematics)
    aw = sub["a"] * w[:, None]  # (m, 4)
    row = ((4 * sub["scan"])[:, None] + np.arange(4)).reshape(-1)
    rows = np.r_[row, row]
    cols = np.r_[np.repeat(i, 4), np.repeat(i + 1, 4)]
    data = np.r_[(aw * (1 - t)[:, None]).reshape(-1), (aw * t[:, None]).reshape(-1)]
    W = csr_matrix((data, (rows, cols)), shape=(4 * sub["S"], len(nodes)))
    W.sum_duplicates()
    out = sub["grids"][key] = (nodes, W)
    return out


def component_columns(problem, obs, component: str, basis, kinematics: str = "thesis", *,
                      compact: bool = False) -> np.ndarray:
    """Change of ``problem``'s observables (n, k) when the component is off
    by ``basis(q)`` (a function of the reading returning (N, k), um or
    arc-seconds per unit): centre level, through the reading grid. A joint
    problem stacks its runs'. ``compact``: only the rows of the lengths (or
    deviations), centres and radii (the point residuals' rows are zero),
    in the order of ``_rows(problem)``."""
    parts = getattr(problem, "parts", None)
    if parts:
        return np.concatenate([component_columns(p, o, component, basis, kinematics, compact=compact)
                               for p, o in zip(parts, obs.parts)])
    nodes, W = _spread(problem, component, kinematics)
    return _through_fits(problem, obs, W @ basis(nodes), compact)


def _rows(problem) -> np.ndarray:
    """Indices of the observables a map correction moves: lengths (or an
    artefact's deviations), centre deviations and radii of every run."""
    return np.flatnonzero(np.isin(problem.classes % 4, (0, 1, 2)))


def _through_fits(problem, obs, rhs: np.ndarray, compact: bool = False) -> np.ndarray:
    """Observables (n, k) from the scans' right-hand sides (4 S, k)."""
    sub = reading_subset(problem)
    S = sub["S"]
    theta = np.einsum("sij,sjk->sik", sub["Minv"], np.asarray(rhs).reshape(S, 4, -1))
    return _centre_level(problem.layout, obs, theta[:, :3, :], theta[:, 3, :], sub["rigid"], compact)


def observable_change(problem, obs, field: np.ndarray, direction: int | None = None) -> np.ndarray:
    """Change of ``problem``'s observables (n, k) when the subset's points
    (:func:`reading_subset`) move by ``field`` (m, 3, k) mm per unit: each scan's
    centre and radius by the linearised sphere fit, the lengths (or an
    artefact's deviations) from the moved centres; point residuals are taken
    as unchanged (a shape smooth over one ball's scan). With ``direction``
    (0, 1, 2), ``field`` is (m, k): the displacement along that axis."""
    sub = reading_subset(problem)
    if direction is None:
        normal_move = np.einsum("mj,mjk->mk", sub["n"], field)  # (m, k)
    else:  # field (m, k) along one direction
        normal_move = sub["n"][:, direction, None] * field
    return _through_fits(problem, obs, sub["sum"] @ normal_move)


def _sphere_means(layout, per_scan_vec: np.ndarray) -> np.ndarray:
    n_sph = len(layout.sphere_kind)
    counts = np.bincount(layout.sphere_of_scan, minlength=n_sph)
    out = np.zeros((n_sph,) + per_scan_vec.shape[1:])
    np.add.at(out, layout.sphere_of_scan, per_scan_vec)
    return out / np.maximum(counts, 1).reshape((-1,) + (1,) * (per_scan_vec.ndim - 1))


def _rigid_projectors(layout, obs, cache: dict | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per placement of an artefact: its rigid motions' columns G (3 n_b, 6)
    and their pseudo-inverse (6, 3 n_b); ``D - G (G^+ D)`` removes what the
    placement's best-fit rigid transform takes up, to first order."""
    key = id(obs)
    if cache is not None and key in cache and cache[key][0] is obs:
        return cache[key][1]
    mean_c = _sphere_means(layout, obs.centres)
    out = []
    for idx in layout.artefact.spheres:
        m = mean_c[idx]
        r = m - m.mean(axis=0)
        n_b = len(idx)
        G = np.zeros((n_b, 3, 6))
        G[:, 0, 0] = G[:, 1, 1] = G[:, 2, 2] = 1.0
        # omega x r for omega along x, y, z
        G[:, 1, 3], G[:, 2, 3] = -r[:, 2], r[:, 1]
        G[:, 0, 4], G[:, 2, 4] = r[:, 2], -r[:, 0]
        G[:, 0, 5], G[:, 1, 5] = -r[:, 1], r[:, 0]
        G = G.reshape(3 * n_b, 6)
        out.append((G, np.linalg.pinv(G)))
    if cache is not None:
        cache[key] = (obs, out)
    return out


def _centre_level(layout, obs, dc: np.ndarray, dr: np.ndarray | None = None, cache: dict | None = None,
                  compact: bool = False) -> np.ndarray:
    """Observable changes (n, k) when scan s's centre moves by dc[s, :, j]
    (S, 3, k) and its radius by dr[s, j] (S, k); ``compact``: without the
    point residuals' rows (zero), which come last."""
    k = dc.shape[2]
    sizes = layout.sizes
    n = sum(sizes.values())
    if compact:
        n = sizes["length"] + 3 * len(layout.repeated) + len(layout.labels)
    out = np.zeros((n, k))
    shift = _sphere_means(layout, dc)  # (K, 3, k)
    P = sizes["length"]
    if layout.artefact is None:
        if P:
            mean_c = _sphere_means(layout, obs.centres)
            u = mean_c[layout.ends[:, 1]] - mean_c[layout.ends[:, 0]]
            u /= np.linalg.norm(u, axis=1)[:, None]
            out[:P] = np.einsum("pj,pjk->pk", u, shift[layout.ends[:, 1]] - shift[layout.ends[:, 0]])
    elif P:
        # Each placement's best-fit rigid transform takes up, to first order,
        # the part of the centres' shifts that is a rigid motion of its balls.
        at = 0
        for idx, (G, Gp) in zip(layout.artefact.spheres, _rigid_projectors(layout, obs, cache)):
            n_b = len(idx)
            D = shift[idx].reshape(3 * n_b, k)
            # Thin products by einsum: small, and free of the BLAS threads' start-up on a busy machine.
            out[at:at + 3 * n_b] = D - np.einsum("ir,rk->ik", G, np.einsum("ri,ik->rk", Gp, D))
            at += 3 * n_b
    rep = layout.repeated
    if len(rep):
        dev = dc[rep] - shift[layout.sphere_of_scan[rep]]  # (R, 3, k)
        out[P:P + 3 * len(rep)] = dev.reshape(-1, k)
    if dr is not None:
        at = P + 3 * len(rep)
        out[at:at + len(layout.labels)] = dr
    return out


def centre_columns(problem, obs, spec) -> np.ndarray:
    """Change of ``problem``'s observables per prior magnitude of each
    parameter of the map correction or cross-axis correction ``spec``
    (centre level: see the module docstring), mm."""
    if is_cross(spec):
        return cross_columns(problem, obs, spec)
    return component_columns(problem, obs, spec.component, spec.basis, spec.kinematics) * np.asarray(spec.prior)


def cross_columns(problem, obs, spec: CrossAxisCorrection) -> np.ndarray:
    """:func:`centre_columns` of a cross-axis correction: the sample's points
    moved along its direction by its shape functions of their readings (a
    joint problem stacks its runs')."""
    parts = getattr(problem, "parts", None)
    if parts:
        return np.concatenate([cross_columns(p, o, spec) for p, o in zip(parts, obs.parts)])
    q = reading_subset(problem)["q"]
    field = spec.basis(q) * (1e-3 * np.asarray(spec.prior, float))  # mm per prior magnitude
    return observable_change(problem, obs, field, direction=spec.direction)


# -- candidates for a run -------------------------------------------------


def travel_range(problem) -> list[tuple[float, float]]:
    parts = getattr(problem, "parts", None) or [problem]
    lo = np.min([p.inputs.scales[p.layout.sample].min(axis=0) for p in parts], axis=0)
    hi = np.max([p.inputs.scales[p.layout.sample].max(axis=0) for p in parts], axis=0)
    return [(math.floor(a), math.ceil(b)) for a, b in zip(lo, hi)]


def model_kinematics(model) -> str:
    """The machine configuration of ``model``'s maps (whose arms an angle acts over); 'thesis' when they name none."""
    try:
        return str(model.maps.kinematics)
    except AttributeError:
        return "thesis"


_kinematics = model_kinematics


def _columns(problem, spec: MapCorrection) -> np.ndarray:
    return centre_columns(problem, problem.base_obs, spec)


def whitened_gain(W0q, r, Wj, rows=None) -> float:
    """Fall of the whitened chi-square when columns Wj join (fixed noise),
    from inner products over ``rows`` (where Wj is not zero)."""
    if rows is not None:
        Wj = Wj[rows]
        Q = W0q[rows]
        rr = r[rows]
    else:
        Q, rr = W0q, r
    if not np.any(Wj):
        return 0.0
    C = Wj.T @ Q
    b = Wj.T @ rr - C @ (W0q.T @ r)
    M = Wj.T @ Wj - C @ C.T
    w, V = np.linalg.eigh(M)
    keep = w > 1e-9 * max(w.max(), 1e-300)
    z = V[:, keep].T @ b
    return float(np.sum(z * z / w[keep]))


def _pair_gains(W0q, r, J, rows) -> np.ndarray:
    """:func:`whitened_gain` of each column pair (2 i, 2 i + 1) of ``J``
    (len(rows), 2 K: the columns at ``rows``, zero elsewhere) at once: (K,)."""
    Jr = J
    Q = W0q[rows]
    K = J.shape[1] // 2
    C = (Jr.T @ Q).reshape(K, 2, -1)
    b = (Jr.T @ r[rows]).reshape(K, 2) - C @ (W0q.T @ r)
    J3 = Jr.reshape(len(rows), K, 2)
    M = np.einsum("nka,nkb->kab", J3, J3) - np.einsum("kaq,kbq->kab", C, C)
    w, V = np.linalg.eigh(M)
    top = np.maximum(w[:, -1:], 1e-300)
    z = np.einsum("kab,ka->kb", V, b)
    keep = w > 1e-9 * top
    return np.sum(np.where(keep, z * z / np.where(keep, w, 1.0), 0.0), axis=1)


def coverage_gap(problem, axis: int) -> float:
    """The widest gap, mm, between the positions along ``axis`` at which the
    runs' scans lie (each scan's mean reading): what the data sample of a
    function of that axis's reading. A map correction moves each scan's
    centre by the component's function over that scan's points, so between
    two neighbouring scan positions the function is not observed."""
    parts = getattr(problem, "parts", None) or [problem]
    pos = []
    for p in parts:
        sub = reading_subset(p)
        cnt = np.bincount(sub["scan"], minlength=sub["S"])
        tot = np.bincount(sub["scan"], sub["q"][:, axis], minlength=sub["S"])
        pos.append(tot[cnt > 0] / cnt[cnt > 0])
    x = np.sort(np.concatenate(pos)) if pos else np.zeros(0)
    return float(np.max(np.diff(x))) if len(x) > 1 else math.inf


def hat_spacings(span: float, gap: float) -> list[float]:
    """The knot spacings tried over a travel of ``span`` mm whose scans leave
    gaps of up to ``gap`` mm: the fractions HAT_FRACTIONS of the travel,
    none finer than the gap (a knot interval with no scan in it leaves its
    hats to the prior: the fit zig-zags between the scans and misplaces the
    function where the next placement's balls lie), and, where that left
    some out, the finest whole division of the travel the coverage supports."""
    out = [round(span * f, 1) for f in HAT_FRACTIONS if span * f >= gap]
    if len(out) < len(HAT_FRACTIONS) and math.isfinite(gap) and gap > 0:  # the coverage left some out
        n = int(span // gap)
        if n >= 3 and round(span / n, 1) not in out:
            out.append(round(span / n, 1))
    return sorted(set(out), reverse=True) or [round(span * HAT_FRACTIONS[0], 1)]


def map_candidates(problem, model=None, *, periods: int = 120) -> dict[str, MapCorrection]:
    """The map-correction candidates for ``problem`` (a Problem or
    JointProblem at its base model): for each of the 18 components of an
    axis the run moves along, a ``poly``, a ``hat`` with its knot spacing
    chosen by cross-validation, and a ``sine`` with its period found by the
    search over [the scans' coverage gap (at least PERIOD_MIN), travel]; and a constant squareness of each
    plane the run spans when the library's named ``squareness`` is not a
    candidate."""

    model = problem.base if model is None else model
    kin = _kinematics(model)
    travel = travel_range(problem)
    r0 = problem.base_obs.residual
    X0, ridge0, target0 = model_design(problem, model)
    fit = problem.wls(r0, X0, ridge=ridge0, target=target0)
    sigma = fit.sigma
    s = sigma[problem.classes]
    rw = fit.residual / s
    W0 = X0 / s[:, None]
    W0q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(r0), 0))
    # Knot spacing must carry from one set-up to the next: the folds that judge a map correction (map_runs_out).
    folds, items, _ = cv_groups(problem, by_run=map_runs_out(problem))
    design = CVDesign(problem, r0, X0, ridge0, target0, sigma, (folds, items))
    # Map corrections move centres and radii only (point residuals at first order unchanged).
    rows = _rows(problem)
    out: dict[str, MapCorrection] = {}
    gaps = [coverage_gap(problem, a) for a in range(3)]  # each axis's, once (six components read each axis)
    for comp in COMPONENTS:
        axis = reading_axis(comp)
        lo, hi = travel[axis]
        span = hi - lo
        if span < 3 * PERIOD_MIN:  # the run does not move along this axis
            continue
        poly = make(comp, "poly", lo, hi, kinematics=kin)
        out[poly.name] = poly
        # Knot spacing by cross-validation (the base design's folds solved once, each spacing added to it).
        best = None
        spacings = hat_spacings(span, gaps[axis])
        for spacing in spacings:
            h = make(comp, "hat", lo, hi, spacing, kinematics=kin)
            J = component_columns(problem, problem.base_obs, comp, h.basis, kin, compact=True) * np.asarray(h.prior)
            sc = design.score_with(J, rows=rows)
            if best is None or sc.whitened < best[0]:
                best = (sc.whitened, h)
        out[best[1].name] = replace(best[1], trials=len(spacings))
        # Period search: log-spaced from the shortest period the scans can carry to the travel. A period shorter
        # than the widest gap between neighbouring scans completes a cycle where nothing is observed: a sine
        # fitted there is an alias of one the scans sample (a 110 mm Y error on a plate of 83 mm pitch came out
        # at 19.7 mm), so it is never offered.
        shortest = min(max(PERIOD_MIN, gaps[axis]), span / 3)
        grid = np.exp(np.linspace(math.log(shortest), math.log(span), periods))
        gains = _sine_gains(problem, comp, kin, lo, hi, grid, W0q, rw, s, rows)
        i = int(np.argmax(gains))
        P, u = _refine_period(problem, comp, kin, lo, hi, grid, i, W0q, rw, s, rows)
        # Independent periods: frequencies resolvable over the travel down to PERIOD_MIN (not the shortest period
        # searched: the search's lower end follows the data, and the penalty the null-run rate was measured with
        # stays; conservative where the scans lie far apart).
        trials = max(int(math.ceil(span / PERIOD_MIN - 1)), 1)
        sine = make(comp, "sine", lo, hi, P, scale_u_mm=u, trials=trials, kinematics=kin)
        out[sine.name] = sine
    if "squareness" not in problem.candidates and "squareness" not in model.names:
        for comp, (r, _d) in SQUARENESS.items():
            lo, hi = travel[r]
            if hi - lo >= 3 * PERIOD_MIN:
                sq = make(comp, "const", lo, hi)
                out[sq.name] = sq
    return out


def sibling_shapes(spec: MapCorrection, kinematics: str = "thesis") -> list[MapCorrection]:
    """The shape of the map correction ``spec`` on the other components of
    the same carriage (issue 33, section 3): the same basis over the same
    travel (the same knots, the same period) on its axis's other
    translational components (its position error and two straightnesses)
    and its three angles (roll, pitch and yaw, acting over the lever arms
    the machine configuration ``kinematics`` gives), in
    :data:`COMPONENTS`'s order. A plate in one plane, or a bar at one
    height, may not tell them apart (a Y straightness along X and a roll of
    X move the balls of an XY plane alike); the ambiguity set
    (:mod:`cmmpose.diagnosis.ambiguity`) judges them as rivals. A
    squareness or a cross-axis correction has none.

    Returns
    -------
    list of MapCorrection
        Each with the chosen shape's search cost (``trials``) and period
        uncertainty, so its p-value pays for the same search.
    """
    if not is_map(spec) or spec.component not in COMPONENTS:
        return []
    axis = reading_axis(spec.component)
    out = []
    for comp in COMPONENTS:
        if comp == spec.component or reading_axis(comp) != axis:
            continue
        out.append(make(comp, spec.shape, spec.lo, spec.hi, spec.scale_mm, kinematics=kinematics,
                        scale_u_mm=spec.scale_u_mm, trials=spec.trials))
    return out


def _sine_basis(lo: float, hi: float, periods: np.ndarray):
    periods = np.asarray(periods, float)

    def basis(q):
        w = 2 * np.pi * np.clip(q, lo, hi)[:, None] / periods[None, :]
        out = np.empty((len(q), 2 * len(periods)))
        out[:, 0::2] = np.sin(w)
        out[:, 1::2] = np.cos(w)
        return out

    return basis


def _sine_columns(problem, comp: str, kin: str, lo: float, hi: float, periods) -> np.ndarray:
    """(n, 2 len(periods)) sensitivities of sin and cos at every period, per
    prior magnitude, mm: one sparse product per run."""
    prior = PRIOR_UM if kind_of(comp) == "translational" else PRIOR_AS
    return component_columns(problem, problem.base_obs, comp, _sine_basis(lo, hi, periods), kin, compact=True) * prior


def _sine_gains(problem, comp, kin, lo, hi, periods, W0q, rw, s, rows) -> np.ndarray:
    """Whitened chi-square gain of a sine and cosine at each period (the
    columns only at ``rows``, where they are not zero)."""
    J = _sine_columns(problem, comp, kin, lo, hi, periods) / s[rows, None]
    return _pair_gains(W0q, rw, J, rows)


def _refine_period(problem, comp, kin, lo, hi, grid, i, W0q, rw, s, rows):
    """The period at the peak of the gain (a finer grid around it) and its
    standard uncertainty: half the width where the gain is within 1 of the
    peak (-2 log L up by 1), from a grid of offsets about it."""
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    fine = np.linspace(a, b, 21)
    g = _sine_gains(problem, comp, kin, lo, hi, fine, W0q, rw, s, rows)
    j = int(np.argmax(g))
    P, top = float(fine[j]), float(g[j])
    offsets = P * np.geomspace(1e-3, 0.5, 48)
    Ps = np.r_[P - offsets, P + offsets]
    ok = (Ps > PERIOD_MIN / 2) & (Ps < 2 * (hi - lo))
    gs_all = np.full(len(Ps), -np.inf)
    if ok.any():
        gs_all[ok] = _sine_gains(problem, comp, kin, lo, hi, Ps[ok], W0q, rw, s, rows)
    half = []
    for side in (slice(0, 48), slice(48, 96)):
        oks, gs = ok[side], gs_all[side][ok[side]]
        if not oks.any():
            continue
        below = np.flatnonzero(gs < top - 1.0)
        if len(below):
            k = below[0]
            # Linear interpolation of where the gain crosses top - 1.
            x0, g0 = (0.0, top) if k == 0 else (offsets[oks][k - 1], gs[k - 1])
            x1, g1 = offsets[oks][k], gs[k]
            half.append(x0 + (g0 - (top - 1.0)) * (x1 - x0) / max(g0 - g1, 1e-12))
    u = float(np.mean(half)) if half else float("nan")
    return P, u


# -- what the data determine ----------------------------------------------


def _report_spec(comp: str, lo: float, hi: float, kin: str) -> list[MapCorrection]:
    if comp in SQUARENESS:
        return [make(comp, "const", lo, hi)]
    return [make(comp, "poly", lo, hi, kinematics=kin), make(comp, "hat", lo, hi, round((hi - lo) / 5, 1),
                                                            kinematics=kin)]


def component_report(problem, model=None, *, cos_alias: float = 0.95, detect: float = 2.0) -> dict:
    """For each of the 18 map components and the three squarenesses: how
    many shapes the run determines, which other components (and which of
    the library's named effects) it is aliased with, or whether it is
    invisible (see the module docstring).

    Returns
    -------
    dict
        component -> {'kind': 'translational' | 'rotational' | 'squareness',
        'status': 'determined' | 'aliased' | 'invisible', 'shapes_determined':
        int, 'shapes_tried': int, 'singular_values': [...] (whitened, per
        prior magnitude, largest first), 'aliased_with': [components],
        'aliased_with_effects': [named effects], 'why': str}.
    """

    model = problem.base if model is None else model
    kin = _kinematics(model)
    travel = travel_range(problem)
    r0 = problem.base_obs.residual
    X0, ridge0, target0 = model_design(problem, model)
    sigma = problem.wls(r0, X0, ridge=ridge0, target=target0).sigma
    s = sigma[problem.classes]
    W0 = X0 / s[:, None]
    W0q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(r0), 0))
    # Everything below is inner products of whitened columns with the
    # nuisances and the model's effects projected out: P^T P' = J^T J' -
    # (Q^T J)^T (Q^T J'), with J zero outside ``rows`` for a map component.
    rows = _rows(problem)
    Qr, sr = W0q[rows], s[rows]

    def space(G):
        w, V = np.linalg.eigh(G)
        sv = np.sqrt(np.clip(w[::-1], 0.0, None))
        V = V[:, ::-1]
        keep = sv > detect
        return sv, V[:, keep] / sv[keep]  # P @ B: an orthonormal basis of what the data determine

    spaces, out = {}, {}
    for comp in [*COMPONENTS, *SQUARENESS]:
        axis = reading_axis(comp)
        lo, hi = travel[axis]
        base = {"kind": kind_of(comp), "aliased_with": [], "aliased_with_effects": []}
        if hi - lo < 3 * PERIOD_MIN:
            out[comp] = {**base, "status": "invisible", "shapes_determined": 0, "shapes_tried": 0,
                         "singular_values": [], "why": f"the run does not move along {'XYZ'[axis]}"}
            continue
        specs = _report_spec(comp, lo, hi, kin)
        J = np.column_stack([component_columns(problem, problem.base_obs, comp, sp.basis, kin, compact=True)
                             * np.asarray(sp.prior) for sp in specs]) / sr[:, None]
        C = Qr.T @ J
        sv, B = space(J.T @ J - C.T @ C)
        spaces[comp] = (J, C, B)
        determined = B.shape[1]
        out[comp] = {**base, "status": "determined" if determined else "invisible",
                     "shapes_determined": int(determined), "shapes_tried": int(J.shape[1]),
                     "singular_values": [float(x) for x in sv],
                     "why": ("" if determined else
                             "no shape of it moves the observables by 2 sigma at a typical size, beyond what the "
                             "nuisances and the model's effects take up")}
    names = [c for c in spaces if spaces[c][2].shape[1]]
    for i, a in enumerate(names):
        Ja, Ca, Ba = spaces[a]
        for b in names[i + 1:]:
            Jb, Cb, Bb = spaces[b]
            c = float(np.linalg.svd(Ba.T @ (Ja.T @ Jb - Ca.T @ Cb) @ Bb, compute_uv=False)[0])
            if c > cos_alias:
                out[a]["aliased_with"].append(b)
                out[b]["aliased_with"].append(a)
    # The library's named effects (not in the model: those are projected out already).
    named = {n: J for n, J in getattr(problem, "columns", {}).items()
             if n not in model.names and not is_map(problem.candidates.get(n))}
    for n, Jn in named.items():
        Jw = Jn / s[:, None]
        Cn = W0q.T @ Jw
        _, Bn = space(Jw.T @ Jw - Cn.T @ Cn)
        if not Bn.shape[1]:
            continue
        Jwr = Jw[rows]
        for comp in names:
            Ja, Ca, Ba = spaces[comp]
            c = float(np.linalg.svd(Ba.T @ (Ja.T @ Jwr - Ca.T @ Cn) @ Bn, compute_uv=False)[0])
            if c > cos_alias:
                out[comp]["aliased_with_effects"].append(n)
    for comp, r in out.items():
        if r["status"] == "determined" and r["aliased_with"]:
            r["status"] = "aliased"
        if r["status"] != "invisible":
            parts = []
            if r["aliased_with"]:
                parts.append(f"the run cannot tell it from {', '.join(r['aliased_with'])}")
            if r["aliased_with_effects"]:
                parts.append(f"it looks like the named effect{'s' if len(r['aliased_with_effects']) > 1 else ''} "
                             f"{', '.join(r['aliased_with_effects'])}")
            r["why"] = (f"{r['shapes_determined']} of {r['shapes_tried']} shapes determined"
                        + (f"; {'; '.join(parts)}" if parts else ""))
    return out


# -- ranking map corrections on the rows they move -------------------------


class _PaddedColumns(dict):
    """A problem's columns at the kept rows, zero on the pseudo-rows (lazy)."""

    def __init__(self, columns, keep, pts, n_pseudo):
        super().__init__()
        self._columns, self._keep, self._pts, self._n = columns, keep, pts, n_pseudo

    def __missing__(self, name):
        J = self._columns[name]
        if np.any(J[self._pts]):
            raise KeyError(f"{name}: moves the point residuals (not a centre-level column)")
        out = self[name] = np.vstack([J[self._keep], np.zeros((self._n, J.shape[1]))])
        return out


def compressed_view(problem, r0: np.ndarray, X0: np.ndarray):
    """``problem`` with each run's point residuals replaced by the R factor
    of their ``[X0 | r0]``: at most ``X0.shape[1] + 1`` pseudo-rows a class
    instead of thousands of points. A column that is zero on the point
    residuals (a map correction's: centre level) keeps every inner product,
    so every fit, likelihood ratio and uncertainty of such a candidate
    against the model ``X0`` is the same on the view (an orthogonal
    transformation of rows where it is zero), at a fraction of the cost.

    Returns
    -------
    (view, r0, X0) : the view (a shallow copy of the problem whose
    ``classes``, ``_class_rows`` and ``columns`` are the compressed ones;
    its ``columns`` hold only what is zero on the point residuals), and r0
    and X0 on its rows.
    """
    import copy

    classes = problem.classes
    pts = classes % 4 == 3
    keep = np.flatnonzero(~pts)
    xs, rs, cs = [X0[keep]], [r0[keep]], [classes[keep]]
    k0 = X0.shape[1]
    for c in np.unique(classes[pts]):
        rows = problem._class_rows[c]
        R = np.linalg.qr(np.column_stack([X0[rows], r0[rows]]), mode="r")
        xs.append(R[:, :k0])
        rs.append(R[:, k0])
        cs.append(np.full(len(R), c))
    view = copy.copy(problem)
    view.classes = np.concatenate(cs)
    view._class_rows = [np.flatnonzero(view.classes == c) for c in range(len(problem._class_rows))]
    n_pseudo = len(view.classes) - len(keep)
    view.columns = _PaddedColumns(problem.columns, keep, pts, n_pseudo)
    return view, np.concatenate(rs), np.vstack(xs)
