"""Is what the final model leaves noise? The noise floor from the data, a
stated test against it, and errors that vary along two axes at once.

Noise floor (:func:`noise_floor`). The headline figure (ballbar lengths, or
an artefact's ball deviations) cannot be noisier than the centres it is
made of. The per-scan centre reproducibility comes from the data where the
run repeats scans of a sphere (Type A: the centre-disagreement class's
standard deviation per axis, with its (k - 1) degrees of freedom per sphere
of k scans); else from a stated ``reproducibility_um`` (per scan, per
axis; one per run of a joint diagnosis), combined in quadrature with the
run's own spheres' fit scatter (the fixture's and machine's reproducibility
and this run's fit noise are independent; a stated value measured with
repeated scans of a denser set-up already holds some fit noise, so the
floor is then conservative); else there is no floor, the verdict
says so first, and the floor taken is the spheres' fit scatter
(:func:`fit_scatter_um`: the centre sd the sphere fits imply, a lower bound
on the reproducibility), so that "noise" is said only where even that floor
supports it and everything above it is reported, never called noise. The floor of a
length is ``sqrt(1/n1 + 1/n2) * sigma_c`` (two ball centres, each the mean of
its n scans); of a deviation component ``sigma_c / sqrt(n)``.

The test: the final model's headline residuals r (after its fit: dof = rows
- fitted parameters acting on them) against the floor f; chi2 = sum (r/f)^2
is chi-square with dof degrees of freedom if the residuals are noise at the
floor (a stated floor, or the fit scatter, taken as exact). When every
run's floor is Type A the floor is itself an estimate on dof_A degrees of
freedom (3 per repeated scan beyond the first of each sphere), and
(chi2 / dof) is F(dof, dof_A) distributed instead: a few repeated scans give
a floor known to some 20 %, which the chi-square test would take as exact
and call noise at the true floor "unexplained" far more often than
FLOOR_ALPHA. "The residuals look like noise" is said only when its upper-tail p
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

from ..errors import InputError
from ..evaluation.observables import CLASSES, ObservationLayout, mean_centres, observe
from ..model.model import as_model, run_kinematics
from .cv import model_design
from .mapfamily import observable_change, reading_subset, travel_range, whitened_gain
from .statistics import ALPHA, chi2_sf

__all__ = ["FLOOR_ALPHA", "FIT_SCATTER", "NO_FLOOR", "fit_scatter_um", "headline_floors", "noise_floor",
           "repeats_scans", "reproducibility_from_runs", "two_axis_findings"]

#: Upper-tail probability below which the residual scatter is not noise at the floor: "N um is unexplained above
#: a floor" is a claim about the machine like an effect added, one of the diagnosis's CLAIM_FAMILIES families of
#: tests, and takes the same ALPHA (at 0.01 it alone made 1 % of runs on a machine with no error beyond its maps
#: carry a claim: the floor test's p-values are uniform there, benches/diagnosis_false_alarms.py).
FLOOR_ALPHA = ALPHA


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


def fit_scatter_um(problem) -> np.ndarray:
    """The per-scan centre scatter each run's sphere fits alone imply, um per
    axis, one per run of ``problem`` (a Problem or a JointProblem): the rms
    over the run's sphere scans of the fits' centre standard deviations
    (the square root of the mean of the covariance's x, y, z variances,
    from the fits' point residuals). A lower bound on the per-scan
    reproducibility: a real fixture and machine move the centre by more
    (docs/appendix-c.md: about 0.2 um from the fits where the thesis's
    lengths scatter by 12.8 um)."""
    out = []
    for p in _parts(problem):
        fits = p.base_obs.fits
        cov = fits.covariance[fits.positions(p.layout.labels)]
        var = np.trace(cov[:, :3, :3], axis1=1, axis2=2) / 3.0
        out.append(math.sqrt(float(np.mean(var[np.isfinite(var)]))) * 1e3 if np.isfinite(var).any() else 0.0)
    return np.asarray(out)


def repeats_scans(problem) -> np.ndarray:
    """Whether each run of ``problem`` repeats scans of a sphere enough for a
    Type A floor (at least 3 degrees of freedom of centre disagreement)."""
    return np.array([bool(np.any(p.classes == 1)) and float(p.n_eff[1]) >= 3 for p in _parts(problem)])


#: The source of a floor taken from the spheres' fit scatter, when no run repeats a scan and none is stated.
FIT_SCATTER = "the spheres' fit scatter (a lower bound: no floor stated or measured)"

#: What the verdict says first when there is no floor (a stated or a measured one).
NO_FLOOR = ("no noise floor: the run repeats no scan of a sphere and no per-scan reproducibility was stated "
            "(--reproducibility UM, or [reproducibility] in the machine file)")


def per_run(value, n: int, name: str = "reproducibility_um") -> list:
    """``value`` (None, a number, or one per run) as a list of n."""
    if value is None or np.ndim(value) == 0:
        return [value] * n
    values = list(value)
    if len(values) != n:
        raise InputError(f"{name}: one value, or one per run ({n}), got {len(values)}", what=name, option=name,
                         cli_option="--reproducibility",
                         remedy="reproducibility_um" if name == "reproducibility_um" else None)
    return values


def noise_floor(problem, step, reproducibility_um=None, stated_as: str = "stated") -> dict:
    """The noise floor of the headline figure and whether ``step``'s model
    reaches it (see the module docstring).

    Parameters
    ----------
    problem : Problem or JointProblem
    step : Step
        The model whose residuals are tested.
    reproducibility_um : float or sequence of float, optional
        Stated per-scan centre reproducibility, um per axis: one, or one per
        run of a joint problem (None entries: not stated for that run). A
        run that repeats scans measures its own (Type A) instead; a run
        with neither takes its spheres' fit scatter (:func:`fit_scatter_um`),
        a lower bound, and the verdict says first that there is no floor.
    stated_as : str
        The source's words for a stated value (e.g. 'stated in the machine
        file m.toml').

    Returns
    -------
    dict
        ``source`` ('repeated scans (Type A)', ``stated_as``,
        :data:`FIT_SCATTER`, or several joined by '; ' for runs that differ),
        ``floor_stated_or_measured`` (False when every run's floor is the
        fit scatter), ``centre_reproducibility_um`` (rms over the runs, as
        measured or stated), ``runs`` (each run's ``source`` and
        ``centre_reproducibility_um``; a stated one also ``fit_scatter_um``
        and ``floor_centre_um``, the two in quadrature, which the floor uses),
        ``floor_um`` (rms of the headline at the floor), ``rms_um`` (the
        model's in-sample headline rms), ``chi2``, ``dof``, ``p_value``,
        ``noise`` (bool), ``unexplained_um`` and ``verdict`` (words; they
        begin with :data:`NO_FLOOR` when there is no floor).
    """
    r0 = step.residual if step.residual is not None else problem.observe(step.model).residual
    X0, ridge, target = model_design(problem, step.model)
    fit = problem.wls(r0, X0, ridge=ridge, target=target)
    res = fit.residual
    head = problem.classes % len(CLASSES) == 0
    parts = _parts(problem)
    stated = per_run(reproducibility_um, len(parts))
    repeated = repeats_scans(problem)
    scatter = fit_scatter_um(problem) if not all(repeated[i] for i in range(len(parts))) else None
    offsets = np.r_[0, np.cumsum([len(p.classes) for p in parts])]
    sc, sources, said = np.zeros(len(parts)), [], np.zeros(len(parts))
    for i, p in enumerate(parts):  # one per run
        if repeated[i]:
            centre = res[offsets[i]:offsets[i + 1]][p.classes == 1]
            sc[i] = math.sqrt(float(np.sum(centre ** 2)) / float(p.n_eff[1]))
            sources.append("repeated scans (Type A)")
        elif stated[i] is not None:
            # A stated reproducibility is the fixture's and the machine's; this run's own sphere fits scatter the
            # centres besides (fewer points per ball, more): the two add in quadrature. (A value measured by
            # repeated scans of another set-up holds its fit scatter already: the floor is then conservative.)
            sc[i] = math.hypot(float(stated[i]), float(scatter[i])) * 1e-3
            said[i] = float(stated[i]) * 1e-3
            sources.append(stated_as)
        else:
            sc[i] = float(scatter[i]) * 1e-3
            sources.append(FIT_SCATTER)
    source = "; ".join(dict.fromkeys(sources))
    measured = any(s != FIT_SCATTER for s in sources)
    # Each run: its per-scan reproducibility as measured or stated, and (stated) with its fit scatter beside it.
    runs = [{"source": s, "centre_reproducibility_um": float((d if d > 0 else c) * 1e3)}
            | ({"fit_scatter_um": float(scatter[i]), "floor_centre_um": float(c * 1e3)} if d > 0 else {})
            for i, (s, c, d) in enumerate(zip(sources, sc, said))]
    what = "ballbar length" if problem.layout.artefact is None else "ball deviation"
    if not head.any() or not np.all(sc > 0):
        return {"source": None, "floor_stated_or_measured": measured, "centre_reproducibility_um": None,
                "runs": runs, "floor_um": None,
                "rms_um": float(np.sqrt(np.mean(res[head] ** 2)) * 1e3) if head.any() else None, "chi2": None,
                "dof": None, "p_value": None, "noise": None, "unexplained_um": None,
                "verdict": (NO_FLOOR if not measured else "no headline figure to test") +
                           ": whether the residuals are noise cannot be said"}
    f = np.concatenate([headline_floors(p.layout, c) for p, c in zip(parts, sc)])
    r = res[head]
    k_head = int(np.linalg.matrix_rank(X0[head])) if X0.shape[1] else 0
    if problem.layout.artefact is not None:
        k_head += 6 * sum(len(p.layout.artefact.positions) for p in parts)  # each placement's rigid fit
    dof = max(len(r) - k_head, 1)
    chi2 = float(np.sum((r / f) ** 2))
    if all(repeated):  # the floor is itself estimated: F(dof, dof_A), not chi-square with an exact floor
        from scipy.special import fdtrc

        dof_a = float(sum(p.n_eff[1] for p in parts))
        p = float(fdtrc(dof, dof_a, chi2 / dof))
        stats = f"F {chi2 / dof:.2f} on {dof} and {dof_a:.0f} dof, p = {p:.2g}"
    else:
        p = chi2_sf(chi2, dof)
        stats = f"chi2 {chi2:.1f} on {dof} dof, p = {p:.2g}"
    rms = float(np.sqrt(np.sum(r ** 2) / dof)) * 1e3
    floor = float(np.sqrt(np.mean(f ** 2))) * 1e3
    noise = p >= FLOOR_ALPHA
    extra = math.sqrt(max(rms ** 2 - floor ** 2, 0.0))
    if not measured:  # the fit scatter: a lower bound, so only "noise" is a firm statement
        lead = (f"{NO_FLOOR}; against the spheres' fit scatter alone ({float(np.sqrt(np.mean(sc ** 2))) * 1e3:.2f} "
                f"um per axis per scan, a lower bound) the {what}s' floor is {floor:.2f} um")
        if noise:
            words = (f"{lead}, and the residuals look like noise even at it: {what} rms {rms:.2f} um "
                     f"({stats} >= {FLOOR_ALPHA:g})")
        else:
            words = (f"{lead}: {extra:.2f} um of the {what}s (rms {rms:.2f} um; {stats} < {FLOOR_ALPHA:g}) is "
                     f"either machine error the model lacks or the per-scan reproducibility, which this run "
                     f"cannot tell apart; repeat a few scans (cmmpose simulate --repeat-scans N shows how) or "
                     f"state the machine's reproducibility")
    elif noise:
        words = (f"the residuals look like noise: {what} rms {rms:.2f} um against a floor of {floor:.2f} um "
                 f"({source}; {stats} >= {FLOOR_ALPHA:g})")
    else:
        words = (f"{extra:.2f} um is unexplained above a floor of {floor:.2f} um in the {what}s "
                 f"(rms {rms:.2f} um; {source}; {stats} < {FLOOR_ALPHA:g})")
    return {"source": source, "floor_stated_or_measured": measured,
            "centre_reproducibility_um": float(np.sqrt(np.mean(np.where(said > 0, said, sc) ** 2))) * 1e3,
            "runs": runs, "floor_um": floor,
            "rms_um": rms, "chi2": chi2, "dof": int(dof), "p_value": p, "noise": bool(noise),
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


def reproducibility_from_runs(runs, maps=None, run_names=None) -> dict:
    """The per-scan centre reproducibility of a machine from runs that repeat
    scans of a sphere (Type A, pooled over the runs): the centre of each
    scan of a sphere scanned more than once, less the mean of that sphere's
    scans, with (k - 1) degrees of freedom per axis for a sphere of k scans;
    as :func:`noise_floor` measures a run's own floor.

    Parameters
    ----------
    runs : sequence of Run
        Runs that each repeat scans of at least one sphere (a ball of a
        position, or the reference sphere, scanned more than once).
    maps : Model, ErrorMap or ErrorMapSet, optional
        What compensates the points before the spheres are fitted (the
        disagreement of repeated scans hardly depends on it); default each
        run's bundled maps, as :func:`cmmpose.diagnose`.
    run_names : sequence of str, optional
        Names of the runs in messages (default: each run's folder).

    Returns
    -------
    dict
        ``per_scan_um`` (the pooled value, um per axis: the rms of the three
        axes'), ``per_axis_um`` (x, y, z), ``u_um`` (its standard
        uncertainty, ``per_scan_um / sqrt(2 dof)``), ``dof``, ``scans``
        (repeated scans used), ``spheres`` (spheres scanned more than once),
        ``runs`` (each run's ``name``, ``per_scan_um``, ``dof``).

    Raises
    ------
    InputError
        No runs, or a run that repeats no scan (naming it: it carries no
        reproducibility, and pooling it would hide that).
    """
    runs = list(runs)
    if not runs:
        raise InputError("runs: none given; give runs that repeat scans of a sphere")
    names = list(run_names) if run_names is not None else [str(r.source or f"run {i + 1}") for i, r in enumerate(runs)]
    layouts = []
    for run, name in zip(runs, names):
        model = as_model(maps, run_kinematics(run))
        inputs = model.inputs(run)
        layout = ObservationLayout.from_run(run, inputs)
        groups = len(np.unique(layout.sphere_of_scan[layout.repeated]))
        if len(layout.repeated) - groups < 1:
            layouts.append((name, None, None, 0))
            continue
        obs = observe(layout, model.compensate(inputs), model.expansion_ppm_per_kelvin, inputs.scan_id)
        mean_c = mean_centres(layout, obs.centres)
        dev = (obs.centres - mean_c[layout.sphere_of_scan])[layout.repeated]
        layouts.append((name, dev, groups, len(layout.repeated) - groups))
    lacking = [name for name, dev, _, _ in layouts if dev is None]
    if lacking:
        raise InputError(f"runs: {', '.join(lacking)} repeat{'s' if len(lacking) == 1 else ''} no scan of a sphere, "
                         "so carr" + ("ies" if len(lacking) == 1 else "y") + " no per-scan reproducibility; give "
                         "runs that scan a sphere several times without moving it (cmmpose simulate "
                         "--repeat-scans N)")
    dev = np.concatenate([d for _, d, _, _ in layouts])
    dof = sum(k for *_, k in layouts)  # per axis
    per_axis = np.sqrt(np.sum(dev ** 2, axis=0) / dof) * 1e3
    per_scan = float(np.sqrt(np.mean(per_axis ** 2)))
    return {"per_scan_um": per_scan, "per_axis_um": [float(v) for v in per_axis],
            "u_um": per_scan / math.sqrt(2 * 3 * dof), "dof": int(3 * dof), "scans": int(len(dev)),
            "spheres": int(sum(g for _, _, g, _ in layouts)),
            "runs": [{"name": n, "per_scan_um": float(np.sqrt(np.sum(d ** 2) / (3 * k))) * 1e3, "dof": int(3 * k)}
                     for n, d, _, k in layouts]}
