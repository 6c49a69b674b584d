"""Competing explanations side by side (issue 33, section 3).

When the diagnosis picks an effect to add, the other significant candidates
of that step (for a named effect, the other named effects: the map-shape
family ranks after them where they explain the structure, and its searched
periods and knot spacings, chosen on all the data, flatter its held-out
figures; for a map-shape correction, every significant candidate) are
judged beside it on data none of them was fitted to
(:mod:`cmmpose.diagnosis.cv`), with folds that follow how the data were
taken (:func:`cmmpose.diagnosis.cv.cv_groups` with ``across=True``: whole
runs, else whole placements, else within one placement, which judges
interpolation only). A map-shape correction is also judged beside the same
shape on the other components of its carriage (:func:`sibling_candidates`:
the same knots or period on its axis's position error, straightnesses and
roll, pitch and yaw), which the map family's per-component search never
offers beside it: a step gauge along X near Y = 0 cannot tell a Y
straightness of X from a roll of X. Every candidate whose cross-validated headline rms is
within one standard uncertainty of the best one's (the one-standard-error
rule) is a member of the *ambiguity set*: the data cannot prefer one. A
member may be a set of effects: two rivals fitted together that explain
the data as the chosen one does, clearly more than either alone
(:func:`_set_members`: a roll of X with an alignment change, say, against a
twist).

Effects that follow a sensor or need other inputs than the position and
the pose (temperatures, velocities) are not compared here: what the data
cannot tell apart among them is kept as aliased alternatives
(:mod:`cmmpose.diagnosis.aliases`) and checked where the model is applied.

Whether the choice matters is decided by predictions, not parameters: each
member's correction (its fitted values added to the step's model, less the
step's model) is computed on a grid over the machine's travel (the maps'
ranges, :data:`GRID` nodes per axis, with every pose the runs used), less
the mean difference over the grid (a common offset no artefact
measurement sees). The members *agree* when every pair's difference is
within :data:`AGREE_K` times its standard uncertainty at every node (each
member's correction uncertainty ``J C J^T`` from its parameters' data-only
covariance fitted beside the step's model and the nuisances, through a step
of each parameter; members independent); then any member is safe and the
diagnosis adds the one it ranked first.
Otherwise the set is reported, with where in the volume the members
disagree most and by how much, and none of them is added: the user chooses
one by name (``diagnose --add NAME``; a member added on request takes the
structure, so the others are no longer significant and the set is
resolved), or measures what tells them apart (``cmmpose plan``, the
T-optimal criterion of :mod:`cmmpose.diagnosis.plan`).

A member with a parameter the data did not determine (free in the
design, or pinned no better than a few typical magnitudes) has an unknown
correction where that parameter acts: the members then do not agree, and
none is added (what a saved model applies of an added effect is, besides,
only what the data determined: :func:`cmmpose.diagnosis.covariance.determined_values`).

Units: mm for positions, um for corrections and their differences, each
parameter in its effect's units.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import Error
from ..model.inputs import RunInputs
from .statistics import INDISTINGUISHABLE_LR

__all__ = ["AGREE_K", "GRID", "MAX_MEMBERS", "AmbiguitySet", "equivalences", "find_ambiguity", "sibling_candidates",
           "travel_grid"]

log = logging.getLogger(__name__)

#: Nodes per axis of the grid over the travel the members' corrections are compared on.
GRID = 5
#: Coverage factor: two corrections agree where they differ by at most this many standard uncertainties.
AGREE_K = 2.0
#: Significant candidates judged beside the one chosen (the strongest by likelihood).
MAX_MEMBERS = 6

# Known equivalences, named in words: (a pattern each member of the pair matches, the words).
_EQUIVALENT = [
    ((r"^scale\b|^scale@|:d[xyz]\((?:[XYZ])\):poly", r"artefact-expansion|expansion"),
     "a scale error and the artefact's expansion change every length in proportion alike: a calibrated "
     "artefact length, or runs at two temperatures, tell them apart"),
    ((r"^scale\b|^scale@", r"sag|:d[xyz]\([XYZ]\):poly|:d[xyz]\([XYZ]\):hat"),
     "a scale error and a sag (a bent guide, a beam bending under the carriage) change the lengths measured "
     "along one line alike: a placement off that line, or at another height, tells them apart"),
    ((r"artefact-expansion|expansion", r"sag"),
     "the artefact's expansion and a sag change the lengths along one line alike: another height or a "
     "calibrated length tells them apart"),
    ((r"^squareness|sq\(", r"twist|two-axis|granite"),
     "a squareness and a twisted table look alike at one height: a placement at another height, or in a "
     "vertical plane, tells them apart"),
    ((r"^roll|:e[xyz]\([XYZ]\)", r"twist|two-axis"),
     "an axis roll varying along another axis and a twisted table move the points alike at one height: a "
     "placement at another height, or in a vertical plane, tells them apart"),
]


def equivalences(names) -> list[str]:
    """The known physical equivalences among ``names`` (effect names), in words.

    Parameters
    ----------
    names : sequence of str

    Returns
    -------
    list of str
        One sentence per equivalence that two of the names fall under (each once).
    """
    out = []
    names = list(names)
    for (pa, pb), words in _EQUIVALENT:
        hit = any(re.search(pa, a) and re.search(pb, b) for a in names for b in names if a != b)
        if hit and words not in out:
            out.append(words)
    out += _sibling_words(names)
    return out


#: A map correction's name: (d or e, direction, its axis, its shape over its travel).
_MAP_NAME = re.compile(r"^map:([de])([xyz])\(([XYZ])\):([a-z]+[0-9.]*\[[^]]*\])")


def _sibling_words(names) -> list[str]:
    """Words for members that are one shape on two components of one carriage (:func:`sibling_candidates`)."""
    count: dict = {}
    for n in names:
        m = _MAP_NAME.match(n)
        if m:
            count[(m.group(3), m.group(4))] = count.get((m.group(3), m.group(4)), 0) + 1
    return [f"the same shape on two components of the {axis} carriage (a position error or straightness of {axis}, "
            f"or its roll, pitch or yaw) moves the points alike where an angle's lever arm hardly changes (one "
            f"plane, one height, one line, one probe pose): a placement in another plane, at another height or "
            f"from another pose tells them apart" for axis in sorted({a for (a, _), k in count.items() if k > 1})]


@dataclass
class AmbiguitySet:
    """Candidates the data cannot choose between, side by side.

    Attributes
    ----------
    members : list of dict
        Each: ``name`` (an effect's, or ``'A + B'`` for a set of effects
        fitted together), ``effects`` (the effects' names), ``physics``
        (words), ``values``, ``uncertainty`` and ``units`` (parameter -> in
        the effect's units; ``'effect.param'`` for a set),
        ``cv_rms_um`` and ``cv_rms_u_um`` (its cross-validated headline rms
        and standard uncertainty, um), ``determined`` (every parameter has a
        finite uncertainty).
    split : str
        How the cross-validation held data out.
    interpolation_only : bool
        The folds lie within one placement: the figure judges interpolation only.
    largest_difference_um : float
        The largest predicted difference of two members' corrections over the travel, um.
    where : dict
        Where it is: ``xyz_mm`` (the scale readings), ``pose`` (Euler angles,
        degrees), ``pair`` (the two members), ``u_um`` (its standard uncertainty).
    agree : bool
        Every pair agrees within AGREE_K standard uncertainties over the travel.
    chosen : str
        The member added to the model ('' when none was: the set stays open).
    equivalences : list of str
        The known physical equivalences among the members, in words.
    travel : list of (lo, hi)
        The travel the corrections were compared over, mm.
    specs : dict of str -> list of (EffectSpec, values)
        Each member's effects with their fitted values (not saved: what
        ``cmmpose plan`` separates).
    """

    members: list
    split: str
    interpolation_only: bool
    largest_difference_um: float
    where: dict
    agree: bool
    chosen: str = ""
    equivalences: list = field(default_factory=list)
    travel: list = field(default_factory=list)
    specs: dict = field(default_factory=dict, repr=False)

    @property
    def rivals(self) -> list:
        """Each member for :func:`cmmpose.diagnosis.plan.plan`'s ``rivals``: (spec, values) of one effect, or a
        list of them for a set of effects."""
        out = []
        for m in self.members:
            parts = self.specs.get(m["name"])
            if parts:
                out.append(parts[0] if len(parts) == 1 else list(parts))
        return out

    @property
    def names(self) -> list[str]:
        """Each member's name (``'A + B'`` for a set of effects)."""
        return [m["name"] for m in self.members]

    @property
    def effects(self) -> list[str]:
        """Every effect in a member, each once."""
        return list(dict.fromkeys(e for m in self.members for e in m.get("effects", [m["name"]])))

    @property
    def resolved(self) -> bool:
        """A member was added: the members agree (any is safe)."""
        return bool(self.chosen)

    def verdict(self) -> str:
        """The set in one sentence."""
        names = ", ".join(self.names)
        if self.agree:
            head = (f"{names} explain the data alike and their corrections agree within their uncertainties over "
                    f"the travel (at most {self.largest_difference_um:.2g} um apart): any of them is safe"
                    + (f"; {self.chosen} was added" if self.chosen else ""))
        else:
            w = self.where
            at = ", ".join(f"{a} {v:.0f}" for a, v in zip("XYZ", w.get("xyz_mm", ())))
            u = w.get("u_um", float("nan"))
            loose = [m["name"] for m in self.members if not m["determined"]]
            size = (f"{self.largest_difference_um:.1f} ± {u:.1f} um" if math.isfinite(u) else
                    f"{self.largest_difference_um:.1f} um (and by an unknown amount where "
                    f"{', '.join(loose) or 'a member'} {'have' if len(loose) > 1 else 'has'} a parameter the data "
                    f"did not determine)")
            head = (f"the data cannot choose between {names} (cross-validated rms within one standard uncertainty "
                    f"of the best), and their corrections differ by up to {size} over the travel "
                    f"({' and '.join(w.get('pair', ()))} at {at} mm): none was added; choose one (diagnose --add "
                    f"NAME{'; a set: --add each of its effects' if any(' + ' in n for n in self.names) else ''}) "
                    f"or measure what tells them apart (cmmpose plan --separate)")
        if self.interpolation_only:
            head += "; the cross-validation held out data within one placement: it judges interpolation only"
        return head

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(float(x)) else float(x)

        members = [{**m, "values": {k: num(v) for k, v in m["values"].items()},
                    "uncertainty": {k: num(v) for k, v in m["uncertainty"].items()},
                    "cv_rms_um": num(m["cv_rms_um"]), "cv_rms_u_um": num(m["cv_rms_u_um"])} for m in self.members]
        where = {k: ([float(x) for x in v] if isinstance(v, (list, tuple, np.ndarray)) and k != "pair" else
                     list(v) if k == "pair" else num(v)) for k, v in self.where.items()}
        return {"members": members, "split": self.split, "interpolation_only": self.interpolation_only,
                "largest_difference_um": num(self.largest_difference_um), "where": where, "agree": self.agree,
                "chosen": self.chosen or None, "equivalences": list(self.equivalences),
                "travel_mm": [list(t) for t in self.travel], "verdict": self.verdict()}


def _travel(model) -> list[tuple[float, float]]:
    """The machine's travel as the model's maps describe it (their ranges), mm."""
    maps = model.maps
    first = maps.maps[0] if hasattr(maps, "maps") else maps
    return [(float(lo), float(hi)) for lo, hi in first.ranges]


def _inputs_of(problem) -> list[RunInputs]:
    return [p.inputs for p in (getattr(problem, "parts", None) or [problem])]


def travel_grid(problem, model, n: int = GRID) -> tuple[RunInputs, np.ndarray]:
    """Virtual points on an ``n`` x ``n`` x ``n`` grid over the travel, one per
    node and pose the runs of ``problem`` used (by angle), at the runs' mean
    temperature: (inputs, the pose angles of each point (m, 3), degrees)."""
    travel = _travel(model)
    axes = [np.linspace(lo, hi, n) for lo, hi in travel]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inputs = _inputs_of(problem)
    rows = {}
    for i in inputs:
        for p in np.asarray(i.poses, float):
            rows.setdefault(tuple(np.round(p[:3], 6)), p)
    poses = np.array(list(rows.values()), float)
    m = len(nodes) * len(poses)
    temp = float(np.mean(np.concatenate([i.temperature for i in inputs])))
    scales = np.tile(nodes, (len(poses), 1))
    pose_index = np.repeat(np.arange(len(poses)), len(nodes)).astype(np.uint32)
    vin = RunInputs(uv=np.zeros((m, 2)), scales=np.ascontiguousarray(scales), t=np.zeros(m), scan_id=np.arange(m),
                    pose_ids=tuple(range(len(poses))), pose_index=pose_index, poses=poses,
                    temperature=np.full(m, temp), axis_temperature=None, gradient=None, velocity=np.zeros((m, 3)))
    return vin, poses[pose_index, :3]


def _member_covariance(problem, r0, X0, J, specs) -> np.ndarray:
    """The data-only covariance of a member's parameters (its effects' units, in order) fitted beside the step's
    model and the nuisances: the whitened design's (:func:`cmmpose.diagnosis.covariance.design_covariance`), with
    a parameter the design leaves free, or pins no better than UNDETERMINED_PRIORS typical magnitudes, at
    infinity."""
    from .covariance import UNDETERMINED_PRIORS, design_covariance

    k = J.shape[1]
    R = problem.wls(r0, np.column_stack([X0, J])).whitened_r
    cov, free = design_covariance(R)
    prior = np.concatenate([np.asarray(s.prior, float) for s in specs])
    C = cov[-k:, -k:] * np.outer(prior, prior)
    u = np.sqrt(np.clip(np.diag(C), 0.0, None))
    bad = free[-k:] | ~np.isfinite(u) | (u > UNDETERMINED_PRIORS * prior)
    C[bad, :] = np.inf
    C[:, bad] = np.inf
    return C


def _with(model, parts):
    """``model`` with each (spec, values) of ``parts`` set."""
    for spec, values in parts:
        model = model.with_values(spec, values)
    return model


def _correction(model, parts, C, grid, base):
    """A member's correction on the grid (m, 3), mm, and its standard uncertainty (m,), mm: the 3-D
    magnitude of sqrt(diag(J C J^T)) per point, through one step of each parameter of each of its effects
    ``parts`` ((spec, values) each; inf where an undetermined parameter acts)."""
    moved = _with(model, parts).compensate(grid)
    jac = []
    for i, (spec, values) in enumerate(parts):
        for j in range(spec.size):
            v = np.array(values, float)
            v[j] += float(spec.steps[j])
            stepped = [(s, v if k == i else x) for k, (s, x) in enumerate(parts)]
            jac.append((_with(model, stepped).compensate(grid) - moved) / float(spec.steps[j]))
    Jg = np.stack(jac, axis=2)  # (m, 3, k) mm per unit
    bad = ~np.isfinite(np.diag(C))
    Cf = np.where(np.isfinite(C), C, 0.0)
    var = np.einsum("mci,ij,mcj->m", Jg, Cf, Jg)
    acts = np.any(np.abs(Jg[:, :, bad]) > 0, axis=(1, 2)) if bad.any() else np.zeros(len(moved), bool)
    return moved - base, np.where(acts, np.inf, np.sqrt(np.clip(var, 0.0, None)))


def _over_travel(spec) -> bool:
    """Whether an effect's correction is a function of the position and pose alone, so that it can be
    compared over a grid of the travel: not one that follows a sensor or needs other inputs (temperatures,
    velocities); those the data cannot tell apart are kept as aliased alternatives instead
    (:mod:`cmmpose.diagnosis.aliases`), checked where the model is applied."""
    return not getattr(spec, "needs", ()) and getattr(spec, "sensor", None) is None


def columns_of(problem, name: str) -> np.ndarray:
    """A candidate's columns: the problem's, or a sibling shape's (:func:`sibling_candidates`)."""
    siblings = problem.__dict__.get("_sibling_columns", {})
    return siblings[name] if name in siblings and name not in problem.columns else problem.columns[name]


def sibling_columns(problem, specs) -> dict:
    """The centre-level columns of map-correction ``specs`` at ``problem``'s base model (cached on the
    problem, not among its candidates: a sibling shape is judged beside a chosen one, never ranked alone)."""
    cache = problem.__dict__.setdefault("_sibling_columns", {})
    for spec in specs:
        if spec.name not in cache:
            cache[spec.name] = problem._columns(problem.base, spec, np.zeros(spec.size), problem.base_obs)
    return {spec.name: cache[spec.name] for spec in specs}


def sibling_candidates(problem, step, chosen) -> list:
    """The shape of ``chosen`` (a map correction) on the other components of
    the same carriage (:func:`cmmpose.diagnosis.mapfamily.sibling_shapes`:
    the same basis, knots or period, on its axis's other translational
    components and its three angles), each evaluated against ``step``'s
    model as the ranking evaluates a candidate (its fitted values, -2 log L
    gain, p-value against ``chosen``'s threshold). The map family searches
    each component's shape separately, so the same shape on a sibling is
    otherwise never offered: a straightness bump along X and a roll of X
    with the same knots move the balls of one plane alike.

    Returns
    -------
    list of Candidate
        One per sibling not in the model: the ranking's own where the
        search offered that very shape, else evaluated here.
    """
    if getattr(chosen.spec, "family", None) != "map":
        return []
    cache = step.__dict__.setdefault("_siblings", {})
    if chosen.name not in cache:
        cache[chosen.name] = _sibling_candidates(problem, step, chosen)
    return list(cache[chosen.name])


def _sibling_candidates(problem, step, chosen) -> list:
    from types import SimpleNamespace

    from .identify import rank_candidates
    from .mapfamily import model_kinematics, sibling_shapes

    model = step.model
    specs = [s for s in sibling_shapes(chosen.spec, model_kinematics(model)) if s.name not in model.names]
    ranked = {c.name: c for c in step.ranking if not c.alternative_to}
    out = [ranked[s.name] for s in specs if s.name in ranked]
    new = {s.name: s for s in specs if s.name not in ranked and s.name not in problem.candidates}
    if not new:
        return out
    cols = sibling_columns(problem, new.values())
    import copy

    view = copy.copy(problem)  # the step's model's effects and the siblings alone
    view.candidates = {**{n: problem.candidates[n] for n in model.names if n in problem.candidates}, **new}
    view.columns = {**{n: problem.columns[n] for n in model.names if n in problem.columns}, **cols}
    residual = step.residual if getattr(step, "residual", None) is not None else problem.observe(model).residual
    for c in rank_candidates(view, model, SimpleNamespace(residual=residual)):
        c.threshold = chosen.threshold  # the map family's threshold, as the ranking set it
        c.significant = c.dof > 0 and c.p_value < c.threshold
        c.indistinguishable_from, c.stands_for = [], []
        out.append(c)
    return out


def find_ambiguity(problem, step, chosen, folds, split: str, interpolation_only: bool) -> AmbiguitySet | None:
    """The ambiguity set of ``chosen`` (the candidate the selection is about
    to add to ``step``'s model), or None when no other candidate explains
    the data as well out of sample.

    Parameters
    ----------
    problem : Problem or JointProblem
    step : Step
        The step whose ranking holds the candidates (its cross-validation
        state set, :func:`cmmpose.diagnosis.cv.step_cv`).
    chosen : Candidate
    folds : tuple of ndarray
        (folds, items) of :func:`cmmpose.diagnosis.cv.cv_groups` with ``across=True``.
    split : str
    interpolation_only : bool

    Returns
    -------
    AmbiguitySet or None
    """
    from .cv import CVDesign, current_state

    if not _over_travel(chosen.spec):
        return None  # a thermal effect: its aliases are kept as alternatives (cmmpose.diagnosis.aliases)
    rivals = [c for c in step.ranking if c.significant and not c.alternative_to and c.name != chosen.name
              and c.name in problem.columns and _over_travel(c.spec)]
    if getattr(chosen.spec, "family", None) != "map":
        # A named effect the selection chose is judged against the other named effects (library and user):
        # the map-shape family ranks after them where they explain the structure, and its searched shapes
        # (periods, knot spacings) were chosen on all the data, which flatters their held-out figures. (Taken
        # out before the strongest are kept: which rivals are judged must not depend on where the maps rank.)
        rivals = [c for c in rivals if getattr(c.spec, "family", None) != "map"]
    rivals = rivals[:MAX_MEMBERS - 1]
    # The chosen map shape on the carriage's other components (the same knots or period): the search never
    # offers them beside it, and one plane or height may not tell them apart.
    named = {c.name for c in rivals}
    rivals += [c for c in sibling_candidates(problem, step, chosen)
               if c.name not in named and c.dof > 0 and c.lr >= chosen.lr - INDISTINGUISHABLE_LR]
    if not rivals:
        return None
    r0, X0, ridge0, target0, sigma = current_state(problem, step)
    design = CVDesign(problem, r0, X0, ridge0, target0, sigma, folds)
    scored = []
    for c in [chosen, *rivals]:
        J = columns_of(problem, c.name)
        s = design.score_with(J)
        if math.isfinite(s.rms_um):
            scored.append(_Member(c.name, [(c.spec, np.asarray(c.values, float))], c.lr, J, s.rms_um, s.u_rms_um))
    if len(scored) < 2 or scored[0].name != chosen.name:
        return None
    best = min(scored, key=lambda t: t.cv_rms_um)
    limit = best.cv_rms_um + (best.cv_rms_u_um if math.isfinite(best.cv_rms_u_um) else 0.0)  # one standard error
    # ... and not rejected in sample: -2 log L within the margin by which the diagnosis says the data cannot
    # choose (a few held-out runs judge coarsely; a likelihood ratio of e^20 is not an equal explanation).
    top = max(t.lr for t in scored)
    members = [t for t in scored if t.cv_rms_um <= limit and t.lr >= top - INDISTINGUISHABLE_LR]
    if all(t.name != chosen.name for t in members):
        return None
    others = [t for t in scored if t.name != chosen.name]
    members += _set_members(problem, design, (r0, X0, ridge0, target0), scored[0], others,
                            [t for t in others if t not in members], limit, top)
    if len(members) < 2:
        return None
    model = step.model
    grid, angles = travel_grid(problem, model)
    base = model.compensate(grid)
    corr, unc, covs = [], [], []
    for t in members:
        C = _member_covariance(problem, r0, X0, t.J, [spec for spec, _ in t.parts])
        covs.append(C)
        try:
            d, u = _correction(model, t.parts, C, grid, base)
        except (Error, ValueError) as exc:  # it cannot be applied on the grid: no prediction, no claim
            log.debug("ambiguity: %s not compared over the travel: %s", t.name, exc)
            d, u = np.zeros_like(base), np.full(len(base), np.inf)
        corr.append(d)
        unc.append(u)
    largest, where, agree = 0.0, {}, True
    for a in range(len(members)):
        for b in range(a + 1, len(members)):
            diff = corr[a] - corr[b]
            diff = diff - diff.mean(axis=0)  # a common offset: no artefact measurement sees it
            size = np.linalg.norm(diff, axis=1)
            u = np.hypot(unc[a], unc[b])
            # Agreement needs a determined difference: where an undetermined parameter acts, it is unknown.
            if np.any(size > AGREE_K * u) or not np.all(np.isfinite(u)):
                agree = False
            k = int(np.argmax(size))
            if size[k] * 1e3 >= largest:
                largest = float(size[k] * 1e3)
                where = {"xyz_mm": grid.scales[k].tolist(), "pose": angles[k].tolist(),
                         "pair": [members[a].name, members[b].name], "u_um": float(u[k] * 1e3)}
    out = [t.to_member(C) for t, C in zip(members, covs)]
    return AmbiguitySet(out, split, interpolation_only, largest, where, agree,
                        equivalences=equivalences([e for m in out for e in m["effects"]]), travel=_travel(model),
                        specs={t.name: t.parts for t in members})


#: Rivals whose pairs are judged as one explanation (the strongest by likelihood), and pair members kept at most.
SET_RIVALS, MAX_SETS = 4, 3


@dataclass(eq=False)
class _Member:
    """One explanation judged in an ambiguity set: one effect, or a set of effects fitted together."""

    name: str
    parts: list  # (spec, fitted values in its units) of each effect
    lr: float  # -2 log L gain over the step's model
    J: np.ndarray  # the centre-level columns of its effects, side by side
    cv_rms_um: float
    cv_rms_u_um: float

    def to_member(self, C: np.ndarray) -> dict:
        """The member as :class:`AmbiguitySet` lists it (``C``: its parameters' covariance)."""
        single = len(self.parts) == 1
        keys = [p if single else f"{spec.name}.{p}" for spec, _ in self.parts for p in spec.params]
        values = [float(v) for _, vals in self.parts for v in vals]
        units = [u for spec, _ in self.parts for u in spec.units]
        unc = np.sqrt(np.clip(np.diag(C), 0.0, None))
        words = [getattr(spec, "physics", "") or "" for spec, _ in self.parts]
        return {"name": self.name, "effects": [spec.name for spec, _ in self.parts],
                "physics": " and ".join(w for w in words if w) if not single else words[0],
                "values": dict(zip(keys, values)), "uncertainty": dict(zip(keys, map(float, unc))),
                "units": dict(zip(keys, units)), "cv_rms_um": float(self.cv_rms_um),
                "cv_rms_u_um": float(self.cv_rms_u_um), "determined": bool(np.all(np.isfinite(unc)))}


def _set_members(problem, design, state, chosen, partners, singles, limit: float, top: float) -> list:
    """Pairs of rival effects that, fitted together, explain the data as the chosen one does, judged as
    pairs are fairly judged: against the chosen effect with its best partner (a second effect the next step
    may add), not against the chosen effect alone. A pair is a member when its cross-validated rms is within
    one standard error of the best of the singles and the chosen effect's pairs (``limit`` is the singles'),
    its -2 log L gain within INDISTINGUISHABLE_LR of the best of those (``top`` the singles'), and clearly
    more than either of its effects alone (INDISTINGUISHABLE_LR beyond: a set, not one effect and noise).
    (A squareness and a scale on a plate: a roll with the scale explains the data about as well as the
    squareness alone, but far worse than the squareness with the scale; it is no rival.) ``partners``: the
    other candidates judged (the chosen one's partners); ``singles``: those no member alone. Only rivals that
    are no member alone pair up (a member alone already says the data cannot choose), the SET_RIVALS
    strongest; at most MAX_SETS pairs, the best cross-validated first. Named effects only (the library's
    and the user's): the map-shape and cross-axis families' shapes were searched on all the data (periods,
    knots, spans), which flatters their held-out figures, and two searched shapes side by side fit the
    noise as a set."""
    from .identify import PRIOR_WEIGHT

    r0, X0, ridge0, target0 = state
    named = [t for t in singles if all(getattr(spec, "family", None) is None for spec, _ in t.parts)]
    pool = sorted(named, key=lambda t: -t.lr)[:SET_RIVALS]
    if len(pool) < 2:
        return []
    base = problem.wls(r0, X0, ridge=ridge0, target=target0)

    def together(a, b):
        J = np.column_stack([a.J, b.J])
        k = J.shape[1]
        fit = problem.wls(r0, np.column_stack([X0, J]), ridge=np.r_[ridge0, np.full(k, PRIOR_WEIGHT)],
                          target=np.r_[target0, np.zeros(k)])
        return J, fit, max(base.neg2loglik - fit.neg2loglik, 0.0)

    # The chosen effect with its best partner (any other named rival): the fair reference of a pair.
    ref_lr, ref_cv = top, limit
    for r in sorted([t for t in partners if all(getattr(spec, "family", None) is None for spec, _ in t.parts)],
                    key=lambda t: -t.lr)[:SET_RIVALS]:
        J, _, lr = together(chosen, r)
        ref_lr = max(ref_lr, lr)
        score = design.score_with(J)
        if math.isfinite(score.rms_um) and math.isfinite(score.u_rms_um):
            ref_cv = min(ref_cv, score.rms_um + score.u_rms_um)
    found = []
    for i in range(len(pool)):
        for j in range(i + 1, len(pool)):
            a, b = pool[i], pool[j]
            if {spec.name for spec, _ in a.parts} & {spec.name for spec, _ in b.parts}:
                continue
            J, fit, lr = together(a, b)
            if lr < ref_lr - INDISTINGUISHABLE_LR or lr < max(a.lr, b.lr) + INDISTINGUISHABLE_LR:
                continue
            score = design.score_with(J)
            if not (math.isfinite(score.rms_um) and score.rms_um <= ref_cv):
                continue
            k = J.shape[1]
            beta = fit.beta[-k:]
            parts, at = [], 0
            for spec, _ in (*a.parts, *b.parts):
                parts.append((spec, beta[at:at + spec.size] * np.asarray(spec.prior, float)))
                at += spec.size
            found.append(_Member(f"{a.name} + {b.name}", parts, lr, J, score.rms_um, score.u_rms_um))
    return sorted(found, key=lambda t: t.cv_rms_um)[:MAX_SETS]
