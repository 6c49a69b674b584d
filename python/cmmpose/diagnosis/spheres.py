"""Diagnosis at the level users of scanning software often keep: the sphere
fits only (centre, radius, fit rms, points per ball), not the raw points.

From the ballbar lengths (centre to centre) and the radii this tests, with
the same statistics as the point-level diagnosis (:mod:`.patterns`: F-tests,
Bonferroni over every pattern tested):

- the length deviations against the bar's direction cosines (scale:
  squares; squareness: products), its mid-point along each axis;
- the radius against its calibrated value (a constant offset: coating,
  scanner scale, incidence error), against the ball, the position, the points
  per scan (a proxy for the cap covered) and the fit rms.

Thesis Appendix C (20 positions at 20 C, uncompensated and pose compensated)
is bundled: :func:`appendix_c_sphere_fits`; docs/appendix-c.md writes up
what its remaining error holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from .._csvtable import read_csv_table
from .._validate import length_unit_slip
from ..errors import InputError
from .pattern_results import Patterns
from .patterns import categorical_pattern, continuous_pattern, mean_offset_pattern, length_shape_patterns, ranked_patterns

__all__ = ["SphereFitDiagnosis", "diagnose_sphere_fits", "read_sphere_fits", "appendix_c_sphere_fits",
           "NOMINAL_RADIUS_MM"]

#: The thesis's balls: grade 200 bearings of 76.25 +- 0.025 mm diameter,
#: painted with an optical coating (thesis line 1828).
NOMINAL_RADIUS_MM = 38.125
_UM = 1e3

#: A reference length off the mean measured length by more than this fraction
#: of it is refused: a CMM's length error over a ballbar, even uncompensated
#: and a few kelvin off 20 C, is of order 1e-4 of the length (the thesis's
#: Appendix C: tens of um on 404 mm), 1e-3 at worst; 1 % is ten times that,
#: so only a wrong unit (0.4042 m), another bar's length or a typing error
#: reaches it, and its deviations (everything off by the same millimetres)
#: would swamp what the diagnosis looks for.
REFERENCE_LENGTH_FRACTION = 0.01

#: A mean fitted radius off the nominal by more than this fraction of it is
#: refused: a coating is microns thick, and a line scanner's radius bias
#: (incidence, scale, penetration) tens of microns, at most a few tenths of a
#: millimetre on the thesis's 38 mm balls (Appendix C: +41 um, 0.1 %); 5 % of
#: the radius is no physical offset but a diameter column, a nominal diameter,
#: another unit or another ball.
RADIUS_FRACTION = 0.05


@dataclass(frozen=True)
class SphereFitDiagnosis:
    """What sphere fits alone show.

    Attributes
    ----------
    lengths : ndarray (P,)
        Ball-centre distance per position, mm.
    length_deviation_um : ndarray (P,)
        From the reference length (or the mean length), um.
    rms_um : float
        Rms of ``length_deviation_um`` about the mean deviation (the thesis's
        rms accuracy error uses the sample standard deviation), um.
    radius_mean : float
        Mean fitted radius over every ball, mm.
    radius_excess_um : float
        ``radius_mean`` minus the nominal radius, um (nan without one).
    radius_excess_u_um : float
        Its standard uncertainty from the radii's scatter (s / sqrt(n)), um.
    radius_sd_um : float
        Sample standard deviation of the radii, um.
    patterns : Patterns
        Length and radius patterns, ranked, with Bonferroni significance.
    nominal_radius : float or None
        mm.
    """

    lengths: np.ndarray
    length_deviation_um: np.ndarray
    rms_um: float
    radius_mean: float
    radius_excess_um: float
    radius_excess_u_um: float
    radius_sd_um: float
    patterns: Patterns = field(repr=False)
    nominal_radius: float | None = None
    reference_length: float | None = None

    @property
    def mean_length(self) -> float:
        """Mean ball-centre distance, mm."""
        return float(np.mean(self.lengths))

    @property
    def mean_deviation_um(self) -> float:
        """Mean of ``length_deviation_um``: the mean length minus the
        reference length, um (0 without a reference: the mean is the reference)."""
        return float(np.mean(self.length_deviation_um))

    @property
    def significant(self) -> list:
        """The significant patterns, strongest first."""
        return [p for p in self.patterns if p.significant]

    def to_dict(self) -> dict:
        return {"lengths_mm": self.lengths.tolist(), "length_deviation_um": self.length_deviation_um.tolist(),
                "reference_length_mm": self.reference_length, "mean_length_mm": self.mean_length,
                "mean_length_deviation_um": self.mean_deviation_um, "rms_um": self.rms_um, "radius_mean_mm": self.radius_mean, "radius_excess_um": self.radius_excess_um,
                "radius_excess_u_um": self.radius_excess_u_um, "radius_sd_um": self.radius_sd_um,
                "nominal_radius_mm": self.nominal_radius, "patterns": self.patterns.to_dict()}


def diagnose_sphere_fits(centres, radii, *, nominal_radius: float | None = None,
                         reference_length: float | None = None, points=None, fit_rms=None,
                         alpha: float = 1e-3) -> SphereFitDiagnosis:
    """Diagnose a ballbar run from its sphere fits alone.

    Parameters
    ----------
    centres : array_like, shape (P, 2, 3)
        Ball 1 and ball 2 centre per position, mm (any frame that differs from
        the machine's by a translation).
    radii : array_like, shape (P, 2)
        Fitted radii, mm.
    nominal_radius : float, optional
        Calibrated radius, mm: tests a constant radius offset. Refused when
        the mean fitted radius is off it by more than :data:`RADIUS_FRACTION`
        (5 %) of it (radii holding diameters, a nominal diameter, another unit).
    reference_length : float, optional
        Calibrated bar length, mm; default the mean length (only the
        differences between positions are then tested). Refused when off the
        mean measured length by more than :data:`REFERENCE_LENGTH_FRACTION`
        (1 %) of it (a length in metres, another bar's).
    points : array_like, shape (P, 2), optional
        Points per ball (a proxy for the cap covered).
    fit_rms : array_like, shape (P, 2), optional
        Fit rms per ball, mm.
    alpha : float
        Family-wise significance level, dimensionless.

    Returns
    -------
    SphereFitDiagnosis

    Raises
    ------
    InputError
        Wrong shapes, fewer than 3 positions, NaN or inf, a non-positive radius;
        an implausible reference length or nominal radius (``option`` names
        the argument, ``cli_option`` the flag).
    """
    c = np.asarray(centres, dtype=float)
    r = np.asarray(radii, dtype=float)
    if c.ndim != 3 or c.shape[1:] != (2, 3):
        raise InputError(f"centres: expected shape (P, 2, 3) in mm, got {c.shape}")
    if r.shape != c.shape[:2]:
        raise InputError(f"radii: expected shape {c.shape[:2]} (one per ball), got {r.shape}")
    if len(c) < 3:
        raise InputError(f"centres: at least 3 positions, got {len(c)}")
    if not (np.isfinite(c).all() and np.isfinite(r).all()) or (r <= 0).any():
        raise InputError("centres and radii: must be finite, radii > 0 mm")
    extra = {}
    for name, a in (("points", points), ("fit_rms", fit_rms)):
        if a is not None:
            a = np.asarray(a, dtype=float)
            if a.shape != r.shape or not np.isfinite(a).all():
                raise InputError(f"{name}: expected finite values of shape {r.shape}, got {a.shape}")
            extra[name] = a
    bar = c[:, 1] - c[:, 0]
    length = np.linalg.norm(bar, axis=1)
    if reference_length is not None:
        _check_reference_length(float(reference_length), float(np.mean(length)))
    ref = float(np.mean(length)) if reference_length is None else float(reference_length)
    dev = (length - ref) * _UM
    rms = float(np.std(dev, ddof=1))
    d = bar / length[:, None]
    mid = c.mean(axis=1)
    found = length_shape_patterns(d, mid, dev)
    rr = r.ravel()
    calibrated = nominal_radius is not None
    if calibrated:
        _check_radii(float(nominal_radius), float(rr.mean()))
    ref_r = float(nominal_radius) if calibrated else float(rr.mean())
    rdev = (rr - ref_r) * _UM
    robs = "sphere radius deviation" + (" from nominal" if calibrated else " from mean")
    if calibrated:
        found.append(mean_offset_pattern("sphere", robs, rdev, "a coating, a scanner scale or an incidence error "
                                  "(a constant radius offset)"))
    balls = np.tile(np.array(["1", "2"]), len(c))
    positions = np.repeat(np.arange(1, len(c) + 1), 2).astype(str)
    found.append(categorical_pattern("sphere", robs, "ball", balls, rdev, "the two balls differ (size, coating)"))
    found.append(categorical_pattern("sphere", robs, "position", positions, rdev,
                              "the view or place matters: incidence, scanner scale with the cap, local error"))
    if "points" in extra:
        found.append(continuous_pattern("sphere", robs, "points", "", extra["points"].ravel(), rdev,
                                 "the cap covered: incidence or scanner scale (more points, larger cap)"))
    if "fit_rms" in extra:
        found.append(continuous_pattern("sphere", robs, "fit rms", "mm", extra["fit_rms"].ravel(), rdev,
                                 "noise or form error biasing the fitted radius"))
    ranked, threshold = ranked_patterns(found, alpha)
    excess = float(rr.mean() - nominal_radius) * _UM if calibrated else float("nan")
    return SphereFitDiagnosis(length, dev, rms, float(rr.mean()), excess,
                              float(np.std(rr, ddof=1) / math.sqrt(len(rr))) * _UM, float(np.std(rr, ddof=1)) * _UM,
                              Patterns(ranked, alpha, threshold), None if not calibrated else float(nominal_radius),
                              None if reference_length is None else float(reference_length))


def _unit_of(ratio: float) -> str | None:
    """The unit a length is in when the millimetres it should be are
    ``ratio`` times it (within 5 %), or None."""
    slip = length_unit_slip(ratio, 0.05)
    return None if slip is None else slip[0]


def _check_reference_length(reference: float, mean: float) -> None:
    if not (math.isfinite(reference) and reference > 0):
        raise InputError(f"reference_length: must be a positive length in mm, got {reference}",
                         option="reference_length", cli_option="--reference-length", value=reference, unit="mm")
    if abs(reference - mean) <= REFERENCE_LENGTH_FRACTION * mean:
        return
    unit = _unit_of(mean / reference)
    why = (f": the reference looks like a length in {unit}, not mm" if unit else
           ": another bar's length, a typing error or another unit")
    raise InputError(f"reference_length: {reference:g} mm is {100 * abs(reference - mean) / mean:.3g} % off the mean "
                     f"measured bar length {mean:.4f} mm (over {100 * REFERENCE_LENGTH_FRACTION:g} %: no machine "
                     f"errs by that much){why}; give the calibrated length in mm, or none to test only the "
                     f"differences between positions", option="reference_length", cli_option="--reference-length",
                     value=reference, unit="mm")


def _check_radii(nominal: float, mean: float) -> None:
    if not (math.isfinite(nominal) and nominal > 0):
        raise InputError(f"nominal_radius: must be a positive length in mm, got {nominal}",
                         option="nominal_radius", cli_option="--nominal-radius", value=nominal, unit="mm")
    if abs(mean - nominal) <= RADIUS_FRACTION * nominal:
        return
    ratio = mean / nominal
    if abs(ratio - 2) < 0.1:
        why = ": the radii are twice the nominal: does the radius column hold diameters?"
    elif abs(ratio - 0.5) < 0.025:
        why = ": the radii are half the nominal: is the nominal radius a diameter?"
    else:
        radii_unit, nominal_unit = _unit_of(1 / ratio), _unit_of(ratio)
        why = (f": the radii look like lengths in {radii_unit}, not mm" if radii_unit else
               f": the nominal radius looks like a length in {nominal_unit}, not mm" if nominal_unit else
               ": another ball's nominal, or radii from failed fits")
    raise InputError(f"radii: the mean fitted radius {mean:.4f} mm is {100 * abs(ratio - 1):.3g} % off the nominal "
                     f"radius {nominal:g} mm (over {100 * RADIUS_FRACTION:g} %: no coating or scanner bias is that "
                     f"large){why}", option="nominal_radius", cli_option="--nominal-radius", column="radius_mm",
                     value=mean, unit="mm")


def read_sphere_fits(path, state: str | None = None) -> dict[str, np.ndarray]:
    """Sphere fits from a CSV in the layout of ``data/thesis/appendix_c_ballbar.csv``.

    Columns ``position`` (1..P), ``ball`` (1 or 2), ``x_mm``, ``y_mm``, ``z_mm``,
    ``radius_mm`` and optionally ``points``, ``fit_mm`` and ``state`` (rows of
    other states are skipped when ``state`` is given); lines starting with '#'
    are comments.

    Returns
    -------
    dict
        As :func:`appendix_c_sphere_fits`.

    Raises
    ------
    InputError
        Naming the file and line: a missing or repeated column, a
        non-number, a ball other than 1 or 2, a (position, ball) given twice
        (naming both lines), a position without both balls, no rows at all.
    """
    header, table = read_csv_table(path, ("position", "ball", "x_mm", "y_mm", "z_mm", "radius_mm"))
    rows = {}
    line_of = {}
    seen = {}  # (state, position, ball) of every row, selected or not: a repeated row makes the file ambiguous
    for line, row in table:
        try:
            key = (row.get("state"), int(row["position"]), int(row["ball"]))
        except (TypeError, ValueError):
            key = None  # a selected row's bad number is named below
        if key is not None and key in seen:
            raise InputError(f"{path}:{line}: position {key[1]} ball {key[2]}"
                             + (f" (state {key[0]!r})" if key[0] is not None else "")
                             + f" is given twice (lines {seen[key]} and {line})")
        if key is not None:
            seen[key] = line
        if state is not None and row.get("state", state) != state:
            continue
        try:
            p, b = int(row["position"]), int(row["ball"])
            vals = [float(row[k]) for k in ("x_mm", "y_mm", "z_mm", "radius_mm")]
            extra = [float(row[k]) if row.get(k) not in (None, "") else math.nan for k in ("points", "fit_mm")]
        except (TypeError, ValueError):
            raise InputError(f"{path}:{line}: expected numbers in position, ball, x_mm, y_mm, z_mm, radius_mm") from None
        if b not in (1, 2):
            raise InputError(f"{path}:{line}: ball must be 1 or 2, got {b}")
        if (p, b) in rows:
            first_line, first_state = line_of[(p, b)]
            hint = (f" in states {first_state!r} and {row.get('state')!r}: choose the rows of one state"
                    if state is None and first_state != row.get("state") else "")
            raise InputError(f"{path}:{line}: position {p} ball {b} is given twice (lines {first_line} and "
                             f"{line}{hint})")
        rows[(p, b)] = vals + extra
        line_of[(p, b)] = (line, row.get("state"))
    if not rows:
        chosen = f" of state {state!r}" if state is not None and table else ""
        raise InputError(f"{path}: no sphere fits{chosen} (a header and no rows); expected a row per position "
                         f"and ball")
    positions = sorted({p for p, _ in rows})
    lonely = [p for p in positions if (p, 1) not in rows or (p, 2) not in rows]
    if lonely:
        raise InputError(f"{path}: position(s) {lonely} lack ball 1 or ball 2")
    a = np.array([[rows[(p, b)] for b in (1, 2)] for p in positions])
    out = {"centres": a[:, :, :3], "radii": a[:, :, 3]}
    if np.isfinite(a[:, :, 4]).all():
        out["points"] = a[:, :, 4]
    if np.isfinite(a[:, :, 5]).all():
        out["fit_rms"] = a[:, :, 5]
    return out


def appendix_c_sphere_fits(state: str = "compensated") -> dict[str, np.ndarray]:
    """Thesis Appendix C's sphere fits (20 C), as printed.

    Parameters
    ----------
    state : {'compensated', 'uncompensated'}

    Returns
    -------
    dict
        ``centres`` (20, 2, 3) mm in the thesis's measuring frame, ``radii``
        (20, 2) mm, ``points`` (20, 2), ``fit_rms`` (20, 2) mm.
    """
    if state not in ("compensated", "uncompensated"):
        raise InputError(f"state: expected 'uncompensated' or 'compensated', got {state!r}")
    with resources.as_file(resources.files("cmmpose").joinpath("data", "thesis", "appendix_c_ballbar.csv")) as p:
        return read_sphere_fits(p, state)
