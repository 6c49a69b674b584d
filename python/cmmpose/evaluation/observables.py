"""The observables a diagnosis compares with the model, computed from the
compensated points of a run: ballbar lengths, centre disagreement between
scans of the same sphere, radii, and point residuals of the sphere fits.

The vector of observables has four blocks (classes), each with its own
noise level estimated from the data:

- ``length`` (P): centre distance of each ballbar position, mm (a ball
  scanned several times counts with its mean centre);
- ``centre`` (3 per scan of a sphere scanned more than once): the scan's
  centre minus the mean of that sphere's scans, mm;
- ``radius`` (one per sphere scan), mm;
- ``point`` (a fixed subsample of each scan's points): signed residual from
  the scan's fitted sphere, mm.

What the model predicts for them, with the nuisance parameters that the run
cannot pin (an uncalibrated bar length or ball radius), is in
:class:`ObservationLayout`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import length_unit_slip
from ..errors import InputError
from ..fitting import fit_spheres
from .metrics import b89_value, rms_accuracy_error
from ..run import Run
from .artefact_balls import is_artefact_run
from .artefact_layout import ArtefactLayout, artefact_deviations, check_placements
from ..model.alternatives import observables_difference_um
from ..model.inputs import RunInputs
from ..model.model import check_kinematics, run_label

__all__ = ["ObservationLayout", "Observed", "observe", "figures", "ModelFigures", "CLASSES",
           "check_calibrated_length", "check_first_observation", "figures_difference", "mean_centres", "model_figures"]

#: Observable classes, in vector order.
CLASSES = ("length", "centre", "radius", "point")
#: Point residuals kept per scan: enough to see a pattern, few enough to be fast.
POINTS_PER_SCAN = 400
#: Largest relative difference between run.json's calibrated bar length and
#: the mean length the run measures before it is refused as a slip. A CMM's
#: uncompensated errors are ~1e-4 of a length (the thesis machine: 71 um rms
#: on a 404 mm bar, 2e-4), a bar's expansion over 20 K at 25 ppm/K is 5e-4:
#: 1 % is 20 times both, while any unit or decimal slip (10, 25.4, 1000 x)
#: lies far beyond it.
CALIBRATED_LENGTH_TOLERANCE = 0.01


@dataclass(frozen=True)
class ObservationLayout:
    """Which scans make which observables in one run (fixed for the run).

    Attributes
    ----------
    labels : ndarray (S,)
        Scan ids of the sphere scans, ascending.
    sphere_of_scan : ndarray (S,)
        Index of the physical sphere each scan measured.
    sphere_kind : ndarray (K,) of str
        'ball' or 'reference' per physical sphere.
    positions : ndarray (P,)
        Ballbar positions with both balls scanned.
    ends : ndarray (P, 2)
        Physical sphere index of ball 1 and ball 2 of each position.
    position_temperature : ndarray (P,)
        Mean machine temperature while each position was scanned, C.
    repeated : ndarray (R,)
        Indices into ``labels`` of the scans of spheres scanned more than once.
    sample : ndarray (M,)
        Rows of the run's points whose residuals are observed.
    sample_scan : ndarray (M,)
        Index into ``labels`` of each sampled point's scan.
    calibrated_length, calibrated_radius : float or None
        Calibrated bar length at 20 C and ball radius, mm.
    artefact : ArtefactLayout or None
        For an artefact run (ball plate, step gauge; ``run.artefact``
        embeds its definition): which spheres are which balls of which
        placement. Then the first block holds each ball's deviation after its
        placement's best-fit rigid transform (3 per ball) instead of ballbar
        lengths (:mod:`cmmpose.evaluation.artefact_layout`).
    """

    labels: np.ndarray
    sphere_of_scan: np.ndarray
    sphere_kind: np.ndarray
    positions: np.ndarray
    ends: np.ndarray
    position_temperature: np.ndarray
    repeated: np.ndarray
    sample: np.ndarray
    sample_scan: np.ndarray
    calibrated_length: float | None
    calibrated_radius: float | None
    artefact: ArtefactLayout | None = None
    #: Points of the run on the sphere scans (all of them: observe fits in place).
    n_sphere_points: int = -1

    @classmethod
    def from_run(cls, run: Run, inputs: RunInputs, points_per_scan: int = POINTS_PER_SCAN) -> ObservationLayout:
        """The observables of ``run``: every scan of a 'ball' or 'reference'
        feature is a sphere scan.

        Parameters
        ----------
        run : Run
            The run.
        inputs : RunInputs
            Its per-point inputs (for the temperatures).
        points_per_scan : int
            Point residuals observed per scan (evenly spread over the scan).
        """
        sc = run.scans
        keep = np.isin(sc["feature"], ["ball", "reference"])
        if not keep.any():
            raise InputError("run: no scans of a ball or reference sphere to diagnose")
        order = np.argsort(sc["scan_id"][keep])
        labels = sc["scan_id"][keep][order]
        feature = sc["feature"][keep][order]
        position = sc["position"][keep][order]
        ball = sc["ball"][keep][order]
        keys = [(f, int(p), int(b)) if f == "ball" else (f, -1, -1) for f, p, b in zip(feature, position, ball)]
        uniq = sorted(set(keys))
        sphere_of_scan = np.array([uniq.index(k) for k in keys])
        kinds = np.array([k[0] for k in uniq])
        counts = np.bincount(sphere_of_scan, minlength=len(uniq))
        repeated = np.flatnonzero(counts[sphere_of_scan] > 1)
        positions, ends = [], []
        artefact_run = is_artefact_run(run)
        for p in [] if artefact_run else sorted({k[1] for k in uniq if k[0] == "ball" and k[1] >= 0}):
            if ("ball", p, 1) in uniq and ("ball", p, 2) in uniq:
                positions.append(p)
                ends.append((uniq.index(("ball", p, 1)), uniq.index(("ball", p, 2))))
        sid = run.points["scan_id"]
        temp = np.array([inputs.temperature[np.isin(sid, labels[np.isin(sphere_of_scan, e)])].mean()
                         for e in ends]) if ends else np.zeros(0)
        # Evenly spread sample of each scan's rows, in the order fit_spheres keeps them.
        rows = np.argsort(sid, kind="stable")
        sorted_sid = sid[rows]
        starts = np.searchsorted(sorted_sid, labels)
        stops = np.searchsorted(sorted_sid, labels, side="right")
        if np.any(stops - starts < 4):
            bad = labels[np.argmax(stops - starts < 4)]
            raise InputError(f"scan {bad}: fewer than 4 points, cannot fit its sphere")
        sample, sample_scan = [], []
        for i, (a, b) in enumerate(zip(starts, stops)):
            k = min(points_per_scan, b - a)
            pick = a + (np.arange(k) * (b - a)) // k
            sample.append(rows[pick])
            sample_scan.append(np.full(k, i))
        art = run.artefact
        plate = None
        if artefact_run:
            def sphere_temperature(idx):
                return inputs.temperature[np.isin(sid, labels[np.isin(sphere_of_scan, idx)])].mean()

            plate = ArtefactLayout.from_run(run, uniq, sphere_temperature)
        return cls(labels, sphere_of_scan, kinds, np.array(positions, int), np.array(ends, int).reshape(-1, 2),
                   temp, repeated, np.concatenate(sample), np.concatenate(sample_scan),
                   art.get("calibrated_length_mm"), art.get("calibrated_radius_mm"), plate,
                   int(np.sum(stops - starts)))

    @property
    def sizes(self) -> dict[str, int]:
        first = len(self.positions) if self.artefact is None else self.artefact.size
        return {"length": first, "centre": 3 * len(self.repeated), "radius": len(self.labels),
                "point": len(self.sample)}

    @property
    def classes(self) -> np.ndarray:
        """Class index (into CLASSES) of each observable."""
        return np.repeat(np.arange(len(CLASSES)), [self.sizes[c] for c in CLASSES])

    def nuisance(self) -> tuple[np.ndarray, list[str]]:
        """Columns of the parameters the run cannot pin: bar length (unless
        calibrated), ball radius (unless calibrated), reference radius."""
        n = sum(self.sizes.values())
        cls = self.classes
        cols, names = [], []
        if self.calibrated_length is None and len(self.positions):
            cols.append((cls == 0).astype(float))
            names.append("bar length")
        radius_rows = np.flatnonzero(cls == 2)
        kind_of_scan = self.sphere_kind[self.sphere_of_scan]
        for kind in ("ball", "reference"):
            if kind == "ball" and self.calibrated_radius is not None:
                continue
            mine = kind_of_scan == kind
            if mine.any():
                c = np.zeros(n)
                c[radius_rows[mine]] = 1.0
                cols.append(c)
                names.append(f"{kind} radius")
        return (np.column_stack(cols) if cols else np.zeros((n, 0))), names

    def expansion_column(self, reference_length: float) -> np.ndarray:
        """Change of the residuals per ppm/K of artefact expansion."""
        col = np.zeros(sum(self.sizes.values()))
        col[: len(self.positions)] = -reference_length * 1e-6 * (self.position_temperature - 20.0)
        return col


def _slip(ratio: float) -> str:
    """The likely cause of a calibrated length ``ratio`` times the measured one."""
    # Centimetres are left to the decimal-point slip below (a factor 10 either way).
    what = {"in": "inches for millimetres", "m": "metres or micrometres for millimetres"}
    for r in (ratio, 1 / ratio):
        slip = length_unit_slip(r, CALIBRATED_LENGTH_TOLERANCE, units=tuple(what))
        if slip is not None:
            return f"likely {what[slip[0]]}"
    k = round(math.log10(ratio))
    if k != 0 and abs(ratio / 10.0 ** k - 1) < CALIBRATED_LENGTH_TOLERANCE:
        return f"likely a decimal-point slip (a factor 1e{k:+d})"
    return "another bar's length, or a typing slip"


def check_calibrated_length(layout: ObservationLayout, lengths: np.ndarray, where: str = "run") -> None:
    """Refuse run.json's ``artefact.calibrated_length_mm`` when it differs
    from the mean ballbar length the run measures (``lengths``, mm) by more
    than CALIBRATED_LENGTH_TOLERANCE: the diagnosis would subtract it from
    every length (a 10x slip: a cross-validated rms of metres beside an rms
    accuracy error of micrometres) without a word.

    Raises
    ------
    InputError
        Naming run.json's key, both lengths and the likely slip.
    """
    cal = layout.calibrated_length
    lengths = np.asarray(lengths, dtype=float)
    if cal is None or layout.artefact is not None or not len(lengths) or not np.all(np.isfinite(lengths)):
        return
    measured = float(np.mean(lengths))
    if measured <= 0:
        return
    ratio = float(cal) / measured
    if abs(ratio - 1) <= CALIBRATED_LENGTH_TOLERANCE:
        return
    raise InputError(f"{where}: run.json's artefact.calibrated_length_mm is {cal:g} mm, but the run's {len(lengths)} "
                     f"ballbar lengths measure {measured:.4f} mm on average ({ratio:.4g} times): "
                     f"{_slip(ratio)}; correct the key (or remove it: the diagnosis then fits the bar length)")


@dataclass(frozen=True)
class Observed:
    """Observables of one compensation of a run.

    Attributes
    ----------
    values : ndarray
        The observables in CLASSES order (mm).
    residual : ndarray
        Observables minus what the model predicts with the nuisances at zero
        (a calibrated length or radius subtracted), mm.
    centres : ndarray (S, 3)
        Fitted centre of each scan, mm.
    radii, rms, form : ndarray (S,)
        Fitted radius, residual rms and form of each scan, mm.
    lengths : ndarray (P,)
        Ballbar lengths, mm.
    fits : SphereFits
        The sphere fits.
    deviations : ndarray (n, 3) or None
        Of an artefact run: each ball's deviation per placement after the
        placement's best-fit rigid transform, mm (placements in order).
    """

    values: np.ndarray
    residual: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    rms: np.ndarray
    form: np.ndarray
    lengths: np.ndarray
    fits: dict
    deviations: np.ndarray | None = None


def mean_centres(layout: ObservationLayout, centres: np.ndarray) -> np.ndarray:
    """Mean centre of each physical sphere over its scans, mm."""
    n_sph = len(layout.sphere_kind)
    counts = np.bincount(layout.sphere_of_scan, minlength=n_sph)
    mean_c = np.zeros((n_sph, 3))
    np.add.at(mean_c, layout.sphere_of_scan, centres)
    return mean_c / np.maximum(counts, 1)[:, None]


def check_first_observation(layout: ObservationLayout, observed: Observed, where: str = "run") -> None:
    """The slips a run's first observation shows, refused: a calibrated bar
    length off the measured (:func:`check_calibrated_length`) and an
    artefact's ball far from its calibrated place
    (:func:`cmmpose.evaluation.artefact_layout.check_placements`)."""
    check_calibrated_length(layout, observed.lengths, where)
    if layout.artefact is not None:
        check_placements(layout.artefact, mean_centres(layout, observed.centres))


def observe(layout: ObservationLayout, xyz: np.ndarray, expansion_ppm_per_kelvin: float = 0.0,
            sid: np.ndarray | None = None) -> Observed:
    """The observables of compensated points ``xyz`` (N, 3, mm).

    Parameters
    ----------
    layout : ObservationLayout
        Which scans make which observables.
    xyz : ndarray (N, 3)
        Compensated points of the whole run, mm, in the run's point order.
    expansion_ppm_per_kelvin : float
        The model's artefact expansion, ppm/K (for the predicted length).
    sid : ndarray (N,)
        Scan id of each point.
    """
    # Usually every point is on a sphere: fit in place rather than copy the run (nor test each point).
    if layout.n_sphere_points == len(sid):
        fits = fit_spheres(xyz, sid)
    else:
        keep = np.isin(sid, layout.labels)
        fits = fit_spheres(xyz, sid) if keep.all() else fit_spheres(xyz[keep], sid[keep])
    at = fits.positions(layout.labels)
    centres, radii, rms, form = fits.centre[at], fits.radius[at], fits.rms[at], fits.form[at]
    mean_c = mean_centres(layout, centres)
    lengths = np.linalg.norm(mean_c[layout.ends[:, 1]] - mean_c[layout.ends[:, 0]], axis=1)
    deviations = None
    if layout.artefact is not None:  # ball deviations after each placement's rigid fit, in place of lengths
        deviations = artefact_deviations(layout.artefact, mean_c, expansion_ppm_per_kelvin)
    dev = (centres - mean_c[layout.sphere_of_scan])[layout.repeated].reshape(-1)
    # Residuals of the sampled points from their scan's sphere.
    p = xyz[layout.sample]
    c = centres[layout.sample_scan]
    point = np.linalg.norm(p - c, axis=1) - radii[layout.sample_scan]
    first = lengths if deviations is None else deviations.reshape(-1)
    values = np.concatenate([first, dev, radii, point])
    residual = values.copy()
    P = len(first)
    # An artefact's deviations are predicted zero: its calibrated centres and expansion are in them.
    if deviations is None and layout.calibrated_length is not None:
        residual[:P] -= layout.calibrated_length * (1 + expansion_ppm_per_kelvin * 1e-6 *
                                                    (layout.position_temperature - 20.0))
    elif deviations is None:
        # The bar length is a nuisance; the expansion still shapes lengths
        # taken at different temperatures.
        residual[:P] -= np.mean(lengths) * expansion_ppm_per_kelvin * 1e-6 * (layout.position_temperature - 20.0)
    if layout.calibrated_radius is not None:
        balls = layout.sphere_kind[layout.sphere_of_scan] == "ball"
        residual[P + len(dev):P + len(dev) + len(radii)][balls] -= layout.calibrated_radius
    return Observed(values, residual, centres, radii, rms, form, lengths, fits, deviations)


@dataclass(frozen=True)
class ModelFigures:
    """Ballbar and sphere figures of one model on one run (mm).

    Attributes
    ----------
    lengths : ndarray (P,)
        Ballbar lengths, mm (as measured at the run's temperature).
    lengths_20c : ndarray (P,)
        Lengths brought to 20 C with the model's artefact expansion, mm.
    rms_accuracy_error : float
        Sample standard deviation (n - 1) of ``lengths_20c``, mm (eq. 36).
    b89 : float
        Largest |L - mean| of ``lengths_20c``, mm.
    length_error : float or None
        Mean of ``lengths_20c`` minus the calibrated length, mm.
    form : float
        Mean form (max - min residual) of the sphere fits, mm.
    fit_rms : float
        Mean residual rms of the sphere fits, mm.
    centre_spread : float or None
        RMS disagreement of repeated scans of one sphere, mm.
    deviation_rms, deviation_largest : float or None
        Of an artefact run (no ballbar lengths: ``rms_accuracy_error`` and
        ``b89`` NaN): rms and largest magnitude of the balls' deviations
        after each placement's best-fit rigid transform, mm.
    """

    lengths: np.ndarray
    lengths_20c: np.ndarray
    rms_accuracy_error: float
    b89: float
    length_error: float | None
    form: float
    fit_rms: float
    centre_spread: float | None
    deviation_rms: float | None = None
    deviation_largest: float | None = None

    @property
    def headline(self) -> tuple[str, float]:
        """The run's main figure: ('rms accuracy error', mm) of a ballbar run,
        ('rms deviation', mm) of an artefact run."""
        if self.deviation_rms is not None:
            return "rms deviation", self.deviation_rms
        return "rms accuracy error", self.rms_accuracy_error

    def to_dict(self) -> dict:
        def um(x):  # NaN (no ballbar lengths) is null: JSON has no NaN
            return None if x is None or not np.isfinite(x) else x * 1e3

        out = {"rms_accuracy_error_um": um(self.rms_accuracy_error), "b89_um": um(self.b89),
               "length_error_um": um(self.length_error), "form_um": um(self.form), "fit_rms_um": um(self.fit_rms),
               "centre_spread_um": um(self.centre_spread)}
        if self.deviation_rms is not None:
            out |= {"rms_deviation_um": um(self.deviation_rms), "largest_deviation_um": um(self.deviation_largest)}
        return out


def figures(layout: ObservationLayout, xyz: np.ndarray, model, sid=None, observed: Observed | None = None) -> ModelFigures:
    """Ballbar (or artefact) figures of compensated points ``xyz`` under ``model``."""
    if observed is None:
        if sid is None:
            raise InputError("figures: give sid (scan id per point) or observed")
        observed = observe(layout, xyz, model.expansion_ppm_per_kelvin, sid)
    a = model.expansion_ppm_per_kelvin * 1e-6
    l20 = observed.lengths / (1 + a * (layout.position_temperature - 20.0))
    n_rep = len(layout.repeated)
    spread = None
    if n_rep:
        first = layout.sizes["length"]
        dev = observed.residual[first:first + 3 * n_rep]
        spread = float(np.sqrt(np.mean(dev ** 2) * 3))
    if len(l20) >= 2:
        rms, b89 = rms_accuracy_error(l20), b89_value(l20)
    else:
        rms = b89 = float("nan")
    err = None if layout.calibrated_length is None or not len(l20) else float(np.mean(l20) - layout.calibrated_length)
    d_rms = d_max = None
    if observed.deviations is not None:
        size = np.linalg.norm(observed.deviations, axis=1)
        d_rms, d_max = float(np.sqrt(np.mean(size ** 2))), float(size.max())
    return ModelFigures(observed.lengths, l20, rms, b89, err, float(np.mean(observed.form)),
                        float(np.mean(observed.rms)), spread, d_rms, d_max)


def model_figures(model, run: Run) -> ModelFigures:
    """The diagnosis's figures of ``run`` under ``model`` (its lengths brought
    to 20 C with the model's own expansion, or an artefact's deviations): the
    scale a diagnosis step is judged on. A run of another machine
    configuration, a calibrated length far from the lengths measured, or an
    artefact's ball far from its calibrated place is refused. To judge a
    model on a run it was not fitted to, use
    :func:`cmmpose.evaluation.model_check.check_model` (the figures
    ``cmmpose evaluate --model`` prints)."""
    check_kinematics(model, run)
    inputs = model.inputs(run)
    layout = ObservationLayout.from_run(run, inputs)
    observed = observe(layout, model.compensate(inputs), model.expansion_ppm_per_kelvin, inputs.scan_id)
    check_first_observation(layout, observed, run_label(run))
    return figures(layout, None, model, observed=observed)


def figures_difference(run: Run):
    """How a run's figures differ under an alternative to a model's choice
    (:mod:`cmmpose.model.alternatives`): ``compare(model, other, inputs, xyz)``
    gives the largest difference of the run's lengths (an artefact run: its
    balls' deviations after each placement's rigid fit), less their common
    change, um."""
    def compare(model, other, inputs, xyz) -> float:
        layout = ObservationLayout.from_run(run, inputs)
        groups = [np.arange(layout.sizes["length"])]
        a = observe(layout, xyz, model.expansion_ppm_per_kelvin, inputs.scan_id)
        b = observe(layout, other.compensate(inputs), other.expansion_ppm_per_kelvin, inputs.scan_id)
        return observables_difference_um(b.residual, a.residual, groups)

    return compare
