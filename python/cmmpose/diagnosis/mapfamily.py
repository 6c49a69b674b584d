"""A generic family of candidates: corrections to the error map itself.

Where no named effect of the library explains what the run shows, the
structure may be in the map: one of its components is wrong by a smooth
function of its axis's position. Each candidate here corrects one
translational map component -- the position error of an axis (``dx(X)``,
``dy(Y)``, ``dz(Z)``) or one of its two straightnesses (``dy(X)``, ``dz(X)``,
``dx(Y)``, ``dz(Y)``, ``dx(Z)``, ``dy(Z)``) -- by one of three shapes of the
axis's scale reading q (mm) over the travel the run used, ``[lo, hi]``:

- ``poly``: Legendre polynomials of degree 2 and 3 in ``t = (2q - lo - hi) /
  (hi - lo)`` (degrees 0 and 1 are a rigid offset and a scale or squareness,
  which the nuisances and the library's named ``scale`` and ``squareness``
  hold);
- ``hat<h>``: local linear B-splines (hats) with knots every ``h`` mm over the
  travel; ``h`` chosen by cross-validation (:mod:`cmmpose.diagnosis.cv`)
  among a few spacings;
- ``sine<P>``: a sine and a cosine of period ``P`` mm, the period found by a
  search over the whole range from PERIOD_MIN (10 mm) to the travel (the
  likelihood profile over periods; ``P`` and its uncertainty from where
  -2 log L rises by 1 from its minimum).

Names read ``map:<component>:<shape>[lo,hi]``, e.g. ``map:dx(X):sine170.2[-120,780]``
(:func:`parse`): a model file records the correction by its name and
parameters (um), so ``Model.load`` rebuilds it with no code from the user,
and :func:`corrected_maps` writes it into the maps themselves (a corrected map
file in any format the project reads, :mod:`cmmpose.mapfiles`).

Sensitivities are taken at the centre level: the correction moves each
sphere scan's points by the component's function at their readings, so the
scan's centre moves by its mean over the scan (to first order, for a shape
smooth over a ball's scan) and the radius and point residuals do not change;
the ballbar lengths (or an artefact's deviations after each placement's
rigid fit) follow from the moved centres. No kernel call and no finite
differences over the point cloud.

Statistics. The map candidates are a family of their own: a significance
threshold ALPHA / (number of map candidates), and a periodic candidate's
p-value multiplied by the number of independent periods searched
(Bonferroni over the search), so a noise-only run adds one with probability
at most ALPHA. The library's named effects are judged first (they are the
better physics where they explain the structure); a map correction is added
only where no named effect is both significant and better out of sample.

Observability (:func:`component_report`): for each component, the whitened
sensitivities of its shape basis (Legendre degrees 2-5 and hats at a fifth of
the travel) after the nuisances and the model's effects are projected out;
its singular values say how many shapes the data determine (above 2 sigma at
the prior), and the principal angles between two components' spaces say
which are aliased (cosine above 0.95: the data cannot tell them apart).

Units: positions mm, corrections um (parameters), priors um.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import csr_matrix

from ..errors import InputError
from .effects import EffectSpec

__all__ = [
    "COMPONENTS",
    "PERIOD_MIN",
    "PRIOR_UM",
    "MapCorrection",
    "component_report",
    "corrected_maps",
    "is_map",
    "map_candidates",
    "parse",
]

#: The translational map components a correction can act on: name -> (axis
#: index whose reading it follows, direction index it moves the point along).
COMPONENTS = {f"d{d}({a})": ("XYZ".index(a), "xyz".index(d)) for a in "XYZ" for d in "xyz"}
#: Shortest period searched, mm.
PERIOD_MIN = 10.0
#: Typical size of a map correction's coefficient, um (a map calibrated to
#: a few um leaves errors of this size).
PRIOR_UM = 3.0
#: Knot spacings tried, as fractions of the travel.
HAT_FRACTIONS = (1 / 3, 1 / 5, 1 / 8, 1 / 12, 1 / 18)
_NAME = re.compile(r"^map:(d[xyz]\([XYZ]\)):(poly|hat|sine)([0-9.]*)\[(-?[0-9.]+),(-?[0-9.]+)\]$")


@dataclass(frozen=True)
class MapCorrection(EffectSpec):
    """A correction of one map component by a smooth function of its axis's
    reading (a ``python`` effect whose sensitivities are analytic at the
    centre level).

    Attributes (beyond :class:`EffectSpec`)
    ---------------------------------------
    component : str
        'dx(X)', 'dy(X)', ... (:data:`COMPONENTS`).
    shape : {'poly', 'hat', 'sine'}
    scale_mm : float
        Knot spacing (hat) or period (sine), mm; 0 for poly.
    lo, hi : float
        Travel the shape spans, mm (the readings are clipped to it).
    scale_u_mm : float
        Standard uncertainty of the period found by the search, mm (sine).
    trials : int
        Independent alternatives the search chose among (the p-value's
        Bonferroni factor).
    """

    component: str = ""
    shape: str = "poly"
    scale_mm: float = 0.0
    lo: float = 0.0
    hi: float = 1.0
    scale_u_mm: float = float("nan")
    trials: int = 1
    family: str = field(default="map", compare=False)

    # -- the shape ---------------------------------------------------------

    def basis(self, q: np.ndarray) -> np.ndarray:
        """(N, k) basis functions at readings ``q`` (mm), unitless (x prior um)."""
        q = np.clip(np.asarray(q, float), self.lo, self.hi)
        if self.shape == "poly":
            t = (2 * q - self.lo - self.hi) / (self.hi - self.lo)
            return np.column_stack([(3 * t ** 2 - 1) / 2, (5 * t ** 3 - 3 * t) / 2])
        if self.shape == "sine":
            w = 2 * np.pi * q / self.scale_mm
            return np.column_stack([np.sin(w), np.cos(w)])
        knots = self.knots()
        return np.clip(1 - np.abs(q[:, None] - knots[None, :]) / self.scale_mm, 0.0, None)

    def knots(self) -> np.ndarray:
        n = max(int(math.ceil((self.hi - self.lo) / self.scale_mm - 1e-9)), 1)
        return self.lo + self.scale_mm * np.arange(n + 1)

    def function_um(self, q: np.ndarray, values) -> np.ndarray:
        """The correction of the component at readings ``q`` (mm), um."""
        return self.basis(q) @ np.asarray(values, float)

    def correction(self, inputs: dict, values) -> np.ndarray:
        """(N, 3) mm added to the compensated points (the UserEffect interface)."""
        axis, d = COMPONENTS[self.component]
        q = inputs["DEF"[axis]]
        out = np.zeros((len(q), 3))
        out[:, d] = self.function_um(q, values) * 1e-3
        return out

    def describe(self, values) -> str:
        v = np.asarray(values, float)
        if self.shape == "sine":
            amp = float(np.hypot(*v))
            per = f"{self.scale_mm:.1f}" + (f" ± {self.scale_u_mm:.1g}" if math.isfinite(self.scale_u_mm) else "")
            return f"{self.component}: {amp:.3g} um amplitude at a period of {per} mm"
        return f"{self.component}: " + ", ".join(f"{p}={x:+.3g} um" for p, x in zip(self.params, v))

    # -- sensitivities -----------------------------------------------------

    def centre_columns(self, problem, obs) -> np.ndarray:
        """Change of ``problem``'s observables per prior magnitude of each
        parameter (centre level: see the module docstring), mm."""
        axis, d = COMPONENTS[self.component]
        sub = _subset(problem)
        B = self.basis(sub["q"][:, axis])  # (m, k)
        return observable_change(problem, obs, B, d) * (np.asarray(self.prior) * 1e-3)


#: Points per scan the linearised sphere fits use.
READINGS_PER_SCAN = 128


def _subset(problem) -> dict:
    """Up to READINGS_PER_SCAN of each scan's sampled points, evenly spread,
    with their readings ``q`` (m, 3) mm, scan index, outward normals ``n``
    (m, 3) from the base model's fits, and each scan's inverse normal matrix
    of the linearised sphere fit ``Minv`` (S, 4, 4) (cached on the problem)."""
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
    xyz = problem.base.compensate(problem.inputs)[rows]
    n = xyz - problem.base_obs.centres[scan]
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    a = np.column_stack([n, np.ones(len(n))])
    M = np.zeros((S, 4, 4))
    np.add.at(M, scan, a[:, :, None] * a[:, None, :])
    Minv = np.linalg.pinv(M)
    cache = {"q": np.ascontiguousarray(problem.inputs.scales[rows]), "scan": scan, "n": n, "a": a, "Minv": Minv,
             # Row 4 s + j sums a_j over scan s's points: (4 S, m), sparse.
             "sum": csr_matrix((a.reshape(-1), (((4 * scan)[:, None] + np.arange(4)).reshape(-1),
                                                np.repeat(np.arange(len(a)), 4))), shape=(4 * S, len(a)))}
    problem.__dict__["_map_subset"] = cache
    return cache


def observable_change(problem, obs, field: np.ndarray, direction: int | None = None) -> np.ndarray:
    """Change of ``problem``'s observables (n, k) when the subset's points
    (:func:`_subset`) move by ``field`` (m, 3, k) mm per unit: each scan's
    centre and radius by the linearised sphere fit, the lengths (or an
    artefact's deviations) from the moved centres; point residuals are taken
    as unchanged (a shape smooth over one ball's scan). With ``direction``
    (0, 1, 2), ``field`` is (m, k): the displacement along that axis."""
    sub = _subset(problem)
    layout = problem.layout
    if direction is None:
        normal_move = np.einsum("mj,mjk->mk", sub["n"], field)  # (m, k)
    else:  # field (m, k) along one direction
        normal_move = sub["n"][:, direction, None] * field
    # The subset's points come scan by scan: sum each scan's block.
    S = len(layout.labels)
    rhs = (sub["sum"] @ normal_move).reshape(S, 4, -1)
    theta = np.einsum("sij,sjk->sik", sub["Minv"], rhs)  # (S, 4, k): centre (3) and radius
    return _centre_level(layout, obs, theta[:, :3, :], theta[:, 3, :])


def _sphere_means(layout, per_scan_vec: np.ndarray) -> np.ndarray:
    n_sph = len(layout.sphere_kind)
    counts = np.bincount(layout.sphere_of_scan, minlength=n_sph)
    out = np.zeros((n_sph,) + per_scan_vec.shape[1:])
    np.add.at(out, layout.sphere_of_scan, per_scan_vec)
    return out / np.maximum(counts, 1).reshape((-1,) + (1,) * (per_scan_vec.ndim - 1))


def _centre_level(layout, obs, dc: np.ndarray, dr: np.ndarray | None = None) -> np.ndarray:
    """Observable changes (n, k) when scan s's centre moves by dc[s, :, j]
    (S, 3, k) and its radius by dr[s, j] (S, k)."""
    k = dc.shape[2]
    sizes = layout.sizes
    n = sum(sizes.values())
    out = np.zeros((n, k))
    mean_c = _sphere_means(layout, obs.centres)
    shift = _sphere_means(layout, dc)  # (K, 3, k)
    P = sizes["length"]
    if layout.artefact is None:
        if P:
            u = mean_c[layout.ends[:, 1]] - mean_c[layout.ends[:, 0]]
            u /= np.linalg.norm(u, axis=1)[:, None]
            out[:P] = np.einsum("pj,pjk->pk", u, shift[layout.ends[:, 1]] - shift[layout.ends[:, 0]])
    elif P:
        # Each placement's best-fit rigid transform takes up, to first order,
        # the part of the centres' shifts that is a rigid motion of its balls.
        at = 0
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
            D = shift[idx].reshape(3 * n_b, k)
            out[at:at + 3 * n_b] = D - G @ np.linalg.lstsq(G, D, rcond=None)[0]
            at += 3 * n_b
    rep = layout.repeated
    if len(rep):
        dev = dc[rep] - shift[layout.sphere_of_scan[rep]]  # (R, 3, k)
        out[P:P + 3 * len(rep)] = dev.reshape(-1, k)
    if dr is not None:
        at = P + 3 * len(rep)
        out[at:at + len(layout.labels)] = dr
    return out


def is_map(spec) -> bool:
    return getattr(spec, "family", None) == "map"


def make(component: str, shape: str, lo: float, hi: float, scale_mm: float = 0.0, **changes) -> MapCorrection:
    """A map correction spec (see the module docstring for the shapes)."""
    if component not in COMPONENTS:
        raise InputError(f"map correction: component {component!r} is not one of {', '.join(COMPONENTS)}")
    if not (hi > lo):
        raise InputError(f"map correction {component}: travel [{lo}, {hi}] mm is empty")
    if shape == "poly":
        params = ("p2_um", "p3_um")
        tag = ""
    elif shape == "sine":
        if not scale_mm > 0:
            raise InputError(f"map correction {component}: period must be > 0 mm, got {scale_mm}")
        params = ("sin_um", "cos_um")
        tag = f"{scale_mm:.6g}"
    elif shape == "hat":
        if not scale_mm > 0:
            raise InputError(f"map correction {component}: knot spacing must be > 0 mm, got {scale_mm}")
        n = max(int(math.ceil((hi - lo) / scale_mm - 1e-9)), 1) + 1
        params = tuple(f"k{i}_um" for i in range(n))
        tag = f"{scale_mm:.6g}"
    else:
        raise InputError(f"map correction {component}: shape {shape!r} is not poly, hat or sine")
    axis, d = COMPONENTS[component]
    what = {"poly": "a smooth bow (Legendre degrees 2-3)", "hat": f"local bumps (knots every {scale_mm:.4g} mm)",
            "sine": f"a periodic error of period {scale_mm:.4g} mm"}[shape]
    kind = "position error" if axis == d else "straightness"
    name = f"map:{component}:{shape}{tag}[{lo:.6g},{hi:.6g}]"
    return MapCorrection(name=name, params=params, units=("um",) * len(params), prior=(PRIOR_UM,) * len(params),
                         kind="python", key="map",
                         physics=f"the map's {kind} {component} is off by {what} along {'XYZ'[axis]}",
                         reveal=f"scans spread along {'XYZ'[axis]} (bar positions or plate placements along it)",
                         component=component, shape=shape, scale_mm=float(scale_mm), lo=float(lo), hi=float(hi),
                         **changes)


def parse(name: str) -> MapCorrection:
    """The spec of a map-correction name ('map:dx(X):sine170.2[-120,780]')."""
    m = _NAME.match(name)
    if not m:
        raise InputError(f"effect {name!r}: not a map correction name (map:<component>:<shape>[lo,hi], e.g. "
                         f"'map:dy(X):poly[0,900]')")
    comp, shape, scale, lo, hi = m.groups()
    return make(comp, shape, float(lo), float(hi), float(scale) if scale else 0.0)


# -- candidates for a run -------------------------------------------------


def _travel(problem) -> list[tuple[float, float]]:
    parts = getattr(problem, "parts", None) or [problem]
    lo = np.min([p.inputs.scales[p.layout.sample].min(axis=0) for p in parts], axis=0)
    hi = np.max([p.inputs.scales[p.layout.sample].max(axis=0) for p in parts], axis=0)
    return [(math.floor(a), math.ceil(b)) for a, b in zip(lo, hi)]


def _columns(problem, spec: MapCorrection) -> np.ndarray:
    return problem._columns(problem.base, spec, np.zeros(spec.size), problem.base_obs)


def _whitened_gain(W0q, r, Wj, rows=None) -> float:
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


def map_candidates(problem, model=None, *, periods: int = 120) -> dict[str, MapCorrection]:
    """The map-correction candidates for ``problem`` (a Problem or
    JointProblem at its base model): for each of the nine translational
    components of an axis the run moves along, a ``poly``, a ``hat`` with
    its knot spacing chosen by cross-validation, and a ``sine`` with its
    period found by the search over [PERIOD_MIN, travel]."""
    from .cv import cv_groups, cv_score, model_design

    model = problem.base if model is None else model
    travel = _travel(problem)
    r0 = problem.base_obs.residual
    X0, ridge0, target0 = model_design(problem, model)
    fit = problem.wls(r0, X0, ridge=ridge0, target=target0)
    sigma = fit.sigma
    s = sigma[problem.classes]
    rw = fit.residual / s
    W0 = X0 / s[:, None]
    W0q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(r0), 0))
    # Knot spacing must carry from one set-up to the next: whole runs held out when there are several.
    folds, items, _ = cv_groups(problem, by_run=True if getattr(problem, "parts", None) else None)
    groups = (folds, items)
    # Map corrections move centres and radii only (point residuals at first order unchanged).
    rows = np.flatnonzero(np.isin(problem.classes % 4, (0, 1, 2)))
    out: dict[str, MapCorrection] = {}
    for comp, (axis, _d) in COMPONENTS.items():
        lo, hi = travel[axis]
        span = hi - lo
        if span < 3 * PERIOD_MIN:  # the run does not move along this axis
            continue
        poly = make(comp, "poly", lo, hi)
        out[poly.name] = poly
        # Knot spacing by cross-validation.
        best = None
        for f in HAT_FRACTIONS:
            h = make(comp, "hat", lo, hi, round(span * f, 1))
            J = _columns(problem, h)
            X = np.column_stack([X0, J])
            from .identify import PRIOR_WEIGHT

            sc = cv_score(problem, r0, X, np.r_[ridge0, np.full(J.shape[1], PRIOR_WEIGHT)],
                          np.r_[target0, np.zeros(J.shape[1])], sigma, groups)
            if best is None or sc.whitened < best[0]:
                best = (sc.whitened, h)
        out[best[1].name] = replace(best[1], trials=len(HAT_FRACTIONS))
        # Period search: log-spaced from PERIOD_MIN to the travel.
        grid = np.exp(np.linspace(math.log(PERIOD_MIN), math.log(span), periods))
        gains = _sine_gains(problem, comp, lo, hi, grid, W0q, rw, s, rows)
        i = int(np.argmax(gains))
        P, u = _refine_period(problem, comp, lo, hi, grid, i, W0q, rw, s, rows)
        # Independent periods in the range: frequencies resolvable over the travel.
        trials = max(int(math.ceil(span / PERIOD_MIN - 1)), 1)
        sine = make(comp, "sine", lo, hi, P, scale_u_mm=u, trials=trials)
        out[sine.name] = sine
    return out


def _sine_columns(problem, comp: str, lo: float, hi: float, periods) -> np.ndarray:
    """(n, 2 len(periods)) sensitivities of sin and cos at every period, per
    prior magnitude, mm: one batched centre-level evaluation per run."""
    axis, d = COMPONENTS[comp]
    periods = np.asarray(periods, float)
    prior = PRIOR_UM * 1e-3
    out = []
    for p in getattr(problem, "parts", None) or [problem]:
        q = np.clip(_subset(p)["q"][:, axis], lo, hi)
        w = 2 * np.pi * q[:, None] / periods[None, :]
        field = np.empty((len(q), 2 * len(periods)))
        field[:, 0::2] = np.sin(w)
        field[:, 1::2] = np.cos(w)
        out.append(observable_change(p, p.base_obs, field, d) * prior)
    return np.concatenate(out)


def _sine_gains(problem, comp, lo, hi, periods, W0q, rw, s, rows) -> np.ndarray:
    """Whitened chi-square gain of a sine and cosine at each period."""
    J = _sine_columns(problem, comp, lo, hi, periods) / s[:, None]
    return np.array([_whitened_gain(W0q, rw, J[:, 2 * i:2 * i + 2], rows) for i in range(len(periods))])


def _refine_period(problem, comp, lo, hi, grid, i, W0q, rw, s, rows):
    """The period at the peak of the gain (a finer grid around it) and its
    standard uncertainty: half the width where the gain is within 1 of the
    peak (-2 log L up by 1), from a grid of offsets about it."""
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    fine = np.linspace(a, b, 21)
    g = _sine_gains(problem, comp, lo, hi, fine, W0q, rw, s, rows)
    j = int(np.argmax(g))
    P, top = float(fine[j]), float(g[j])
    offsets = P * np.geomspace(1e-3, 0.5, 48)
    half = []
    for sign in (-1, 1):
        Ps = P + sign * offsets
        ok = (Ps > PERIOD_MIN / 2) & (Ps < 2 * (hi - lo))
        if not ok.any():
            continue
        gs = _sine_gains(problem, comp, lo, hi, Ps[ok], W0q, rw, s, rows)
        below = np.flatnonzero(gs < top - 1.0)
        if len(below):
            k = below[0]
            # Linear interpolation of where the gain crosses top - 1.
            x0, g0 = (0.0, top) if k == 0 else (offsets[ok][k - 1], gs[k - 1])
            x1, g1 = offsets[ok][k], gs[k]
            half.append(x0 + (g0 - (top - 1.0)) * (x1 - x0) / max(g0 - g1, 1e-12))
    u = float(np.mean(half)) if half else float("nan")
    return P, u


# -- what the data determine ----------------------------------------------


def component_report(problem, model=None, *, cos_alias: float = 0.95, detect: float = 2.0) -> dict:
    """For each translational map component: how many shapes the run
    determines, which other components it is aliased with, or whether it is
    invisible (see the module docstring).

    Returns
    -------
    dict
        component -> {'status': 'determined' | 'aliased' | 'invisible',
        'shapes_determined': int, 'shapes_tried': int, 'singular_values':
        [...] (whitened, per prior magnitude), 'aliased_with': [names]}.
    """
    from .cv import model_design

    model = problem.base if model is None else model
    travel = _travel(problem)
    r0 = problem.base_obs.residual
    X0, ridge0, target0 = model_design(problem, model)
    sigma = problem.wls(r0, X0, ridge=ridge0, target=target0).sigma
    s = sigma[problem.classes]
    W0 = X0 / s[:, None]
    W0q = np.linalg.qr(W0)[0] if W0.shape[1] else np.zeros((len(r0), 0))
    spaces, out = {}, {}
    for comp, (axis, _d) in COMPONENTS.items():
        lo, hi = travel[axis]
        if hi - lo < 3 * PERIOD_MIN:
            out[comp] = {"status": "invisible", "shapes_determined": 0, "shapes_tried": 0, "singular_values": [],
                         "aliased_with": [], "why": f"the run does not move along {'XYZ'[axis]}"}
            continue
        poly = make(comp, "poly", lo, hi)
        hat = make(comp, "hat", lo, hi, round((hi - lo) / 5, 1))
        J = np.column_stack([_columns(problem, poly), _columns(problem, hat)]) / s[:, None]
        P = J - W0q @ (W0q.T @ J)
        u, sv, _ = np.linalg.svd(P, full_matrices=False)
        keep = sv > detect
        spaces[comp] = u[:, keep]
        out[comp] = {"status": "determined" if keep.any() else "invisible",
                     "shapes_determined": int(keep.sum()), "shapes_tried": int(J.shape[1]),
                     "singular_values": [float(x) for x in sv], "aliased_with": []}
    names = list(spaces)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            A, B = spaces[a], spaces[b]
            if not A.shape[1] or not B.shape[1]:
                continue
            c = float(np.linalg.svd(A.T @ B, compute_uv=False)[0])
            if c > cos_alias:
                out[a]["aliased_with"].append(b)
                out[b]["aliased_with"].append(a)
    for comp, r in out.items():
        if r["status"] == "determined" and r["aliased_with"]:
            r["status"] = "aliased"
    return out


# -- the corrected maps ---------------------------------------------------

#: Sign of a map table's entry against the correction added to the
#: compensated point (a map error adds to the compensated coordinate; checked by tests).
_TABLE_SIGN = 1.0


def corrected_maps(model):
    """``model``'s maps with its map corrections written into the component
    tables (the other effects are not maps: they stay in the model). The
    tables keep their nodes: within the travel a correction spans, one node
    in from its ends, the maps correct as the model does; over the end
    intervals they interpolate linearly towards the value held beyond it.

    Returns
    -------
    ErrorMap or ErrorMapSet
        Write it with ``.write(path, format)`` (:mod:`cmmpose.mapfiles`).
    """
    from ..errormap import ErrorMap, ErrorMapSet

    maps = model.maps.maps if isinstance(model.maps, ErrorMapSet) else [model.maps]
    corr = [(spec, v) for spec, v in model.effects if is_map(spec)]
    new = []
    for m in maps:
        tables = {c: m.table(c).copy() for c in "XYZ"}
        for spec, v in corr:
            axis, d = COMPONENTS[spec.component]
            t = tables["XYZ"[axis]]
            t[:, 1 + d] += _TABLE_SIGN * spec.function_um(t[:, 0], v)
        out = ErrorMap(tables["X"], tables["Y"], tables["Z"], m.squareness, m.temperature,
                       source=f"{getattr(m, 'source', None) or 'maps'} + map corrections")
        new.append(out.with_kinematics(m.kinematics) if hasattr(out, "with_kinematics") else out)
    return ErrorMapSet(new) if isinstance(model.maps, ErrorMapSet) else new[0]
