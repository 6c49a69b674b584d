"""Sphere-centre distance errors in the manner of ASTM E3125 (point-to-point
distances of a terrestrial laser scanner's sphere targets).

Each sphere's centre comes from its raw scan by the E3125-style segmentation
(:func:`cmmpose.e3125`: closest-point start, cone and cylinder about the line
of sight, radius fixed at its calibrated value). For each pair (a, b) with a
reference distance L_ref (from a reference instrument, e.g. a laser tracker),
the distance error is

    E_ab = |c_b - c_a| - L_ref,

and its standard uncertainty combines the two centres' covariances along the
line between them with the reference's:

    u(E_ab)^2 = n^T (C_a + C_b) n + u(L_ref)^2,    n = (c_b - c_a) / |c_b - c_a|,

treating the two scans' centres as independent (separate scans). A scan given
as compensated points with their uncertainty
(:class:`cmmpose.point_uncertainty.UncertainPoints`, ``uncertainty_detail='split'``)
gives its centre the covariance of :mod:`cmmpose.centre_uncertainty`: the
points' common part (maps, temperature, pose) whole, their noise through the
fit (docs/uncertainty.md, section 5); counted independent for both centres,
the common part that a pair shares is counted twice, not cancelled (an upper
bound). Lengths in mm. Errors may be judged against an MPE (A or A + L/K) with the same ISO
14253-1 style rule as :mod:`.acceptance` (the test uncertainty counted against
the user): pass when |E| + U <= MPE, fail when |E| - U > MPE, else not proven.

A pair whose measured distance is off its reference by more than
:data:`GROSS_ERROR_FRACTION` (10 %) of it is refused, not judged: no scanner
errs by that much, a unit mix-up, a swapped target or a wrong reference does.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .._csvtable import read_csv_table
from .._validate import LENGTH_UNIT_NAMES, length_unit_slip
from ..errors import GeometryError, ImplausibleFit, InputError
from ..centre_uncertainty import e3125_uncertain
from ..fitting import e3125
from ..point_uncertainty import UncertainPoints
from ..evaluation.plots import new_figure, save_plot
from .acceptance import DECISION_RULE, MPE, decide

#: The decision rule, with what the test uncertainty holds here.
RULE = f"{DECISION_RULE}; U = 2 u, u from the two centres' covariances along the line and the reference's"

#: A measured distance off its reference by more than this fraction of it is
#: refused. E3125 MPEs for terrestrial laser scanners are about a millimetre
#: plus tens of ppm (1e-4 of the distance and less), and even an uncompensated
#: scanner's range and angle errors stay well under 1 %: 10 % is 100 times the
#: largest plausible instrument error, so no real measurement is refused, while
#: a scan in another unit (x10, x25.4, x1000), a swapped or mislabelled target
#: or a mistyped reference is.
GROSS_ERROR_FRACTION = 0.10

__all__ = ["GROSS_ERROR_FRACTION", "SphereTarget", "DistanceResult", "E3125Distances", "sphere_targets", "distance_errors", "read_pairs"]


@dataclass(frozen=True)
class SphereTarget:
    """One sphere's centre from its raw scan.

    Attributes
    ----------
    name : str
        The target's name.
    centre : ndarray (3,)
        mm.
    covariance : ndarray (3, 3)
        Of the centre, mm^2.
    n_points : int
        Points the segmentation kept.
    """

    name: str
    centre: np.ndarray
    covariance: np.ndarray
    n_points: int


@dataclass(frozen=True)
class DistanceResult:
    """One pair's distance and its error.

    Attributes
    ----------
    a, b : str
        Target names.
    distance : float
        Measured centre distance, mm.
    reference : float
        Reference distance, mm.
    error_um : float
        distance - reference, um.
    u_um : float
        Standard uncertainty of the error, um (k = 1).
    mpe_um : float or None
        The MPE at this distance, um.
    decision : str or None
        'pass', 'fail' or 'not proven' (with an MPE).
    """

    a: str
    b: str
    distance: float
    reference: float
    error_um: float
    u_um: float
    mpe_um: float | None = None
    decision: str | None = None

    def to_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "distance_mm": self.distance, "reference_mm": self.reference,
                "error_um": self.error_um, "u_um": self.u_um, "U_um": 2 * self.u_um, "k": 2,
                "mpe_um": self.mpe_um, "decision": self.decision}


@dataclass(frozen=True)
class E3125Distances:
    """All pairs' distance errors.

    Attributes
    ----------
    targets : dict of str -> SphereTarget
    errors : list of DistanceResult
    rule : str
        The decision rule, in words.
    """

    targets: dict
    errors: list
    rule: str

    @property
    def max_abs_error_um(self) -> float:
        return float(max(abs(e.error_um) for e in self.errors)) if self.errors else float("nan")

    def __rich__(self):
        from rich.table import Table

        table = Table(title=f"ASTM E3125-style distance errors ({len(self.errors)} pairs)")
        for col in ("pair", "distance (mm)", "reference (mm)", "error (um)", "U, k=2 (um)", "MPE (um)", "decision"):
            table.add_column(col, justify="left" if col in ("pair", "decision") else "right")
        for e in self.errors:
            table.add_row(f"{e.a} - {e.b}", f"{e.distance:.4f}", f"{e.reference:.4f}", f"{e.error_um:+.2f}",
                          f"{2 * e.u_um:.2f}", "-" if e.mpe_um is None else f"{e.mpe_um:.1f}", e.decision or "-")
        table.caption = self.rule
        return table

    def to_markdown(self) -> str:
        """A report section: every pair's error with U (k = 2), the MPE and the decision."""
        lines = [f"## Sphere-centre distance errors in the manner of ASTM E3125 ({len(self.errors)} pairs)", "",
                 "| pair | distance (mm) | reference (mm) | error (um) | U, k = 2 (um) | MPE (um) | decision |",
                 "|" + "---|" * 7]
        for e in self.errors:
            lines.append(f"| {e.a} - {e.b} | {e.distance:.4f} | {e.reference:.4f} | {e.error_um:+.2f} | "
                         f"{2 * e.u_um:.2f} | {'-' if e.mpe_um is None else f'{e.mpe_um:.1f}'} | {e.decision or '-'} |")
        lines += ["", f"Decision rule: {self.rule}.", "",
                  "| target | centre x, y, z (mm) | points used |", "|---|---|---|"]
        lines += [f"| {t.name} | {', '.join(f'{v:.4f}' for v in t.centre)} | {t.n_points} |"
                  for t in self.targets.values()]
        return "\n".join(lines) + "\n"

    def plot(self, path=None):
        """Distance errors against the reference distance, U (k = 2) as error
        bars, and the MPE if one was given; saved to ``path`` if given.

        Parameters
        ----------
        path : str or PathLike, optional
            Image file to write.

        Returns
        -------
        matplotlib.figure.Figure
        """
        fig = new_figure(figsize=(7, 4.2), layout="constrained")
        ax = fig.subplots()
        ref = np.array([e.reference for e in self.errors])
        ax.errorbar(ref, [e.error_um for e in self.errors], yerr=[2 * e.u_um for e in self.errors], fmt="o", ms=4,
                    capsize=3, label="E (error bar: U, k = 2)")
        for e in self.errors:
            ax.annotate(f"{e.a}-{e.b}", (e.reference, e.error_um), textcoords="offset points", xytext=(4, 4),
                        fontsize=7)
        limits = [e.mpe_um for e in self.errors if e.mpe_um is not None]
        if limits:
            order = np.argsort(ref)
            mpe = np.array([self.errors[i].mpe_um for i in order])
            ax.plot(ref[order], mpe, "r-", label="MPE")
            ax.plot(ref[order], -mpe, "r-")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel("reference distance (mm)")
        ax.set_ylabel("distance error (um)")
        ax.set_title("Sphere-centre distance errors (ASTM E3125 manner)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        return save_plot(fig, path)

    def to_dict(self) -> dict:
        return {"targets": {n: {"centre_mm": t.centre.tolist(), "covariance_mm2": t.covariance.tolist(),
                                "n_points": t.n_points} for n, t in self.targets.items()},
                "errors": [e.to_dict() for e in self.errors], "max_abs_error_um": self.max_abs_error_um,
                "decision_rule": self.rule}


def sphere_targets(scans: dict, radius: float, scanner_origin=(0.0, 0.0, 0.0)) -> dict[str, SphereTarget]:
    """Each named raw scan's sphere centre by the E3125-style segmentation.

    Parameters
    ----------
    scans : dict of str -> array_like (N, 3) or UncertainPoints
        Raw scans, mm, all in the scanner's frame. Points with their
        uncertainty (split) give the centre's covariance from it
        (:func:`cmmpose.centre_uncertainty.e3125_uncertain`), else from the
        fit's residuals (noise only).
    radius : float
        Calibrated sphere radius, mm.
    scanner_origin : array_like (3,)
        mm.
    """
    out = {}
    for name, points in scans.items():
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", ImplausibleFit)
                r = e3125_uncertain(points, radius, scanner_origin).fit if isinstance(points, UncertainPoints) \
                    else e3125(points, radius, scanner_origin)
        except (InputError, GeometryError) as exc:
            raise type(exc)(f"target {name!r}: {exc.message}", **exc.fields) from None
        for w in caught:  # each implausible fit again, naming its target
            if issubclass(w.category, ImplausibleFit):
                warnings.warn(f"target {name!r}: {w.message}", ImplausibleFit, stacklevel=2)
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        out[name] = SphereTarget(name, np.asarray(r.centre, float), np.asarray(r.covariance, float), int(r.n_points))
    return out


def distance_errors(targets: dict[str, SphereTarget], pairs, mpe: MPE | None = None) -> E3125Distances:
    """Distance errors of ``pairs`` of ``targets``.

    Parameters
    ----------
    targets : dict of str -> SphereTarget
        From :func:`sphere_targets` (or built from centres measured elsewhere).
    pairs : sequence of (str, str, float, float)
        (a, b, reference distance mm, its standard uncertainty um).
    mpe : MPE, optional
        Maximum permissible error (um, A or A + L/K with L in mm).

    Raises
    ------
    InputError
        A pair naming an unknown target, a target paired with itself, a
        non-positive or non-finite reference, a negative uncertainty; a
        measured distance off the reference by more than
        :data:`GROSS_ERROR_FRACTION` of it (no decision is made on a blunder:
        the message names the likely unit mix-up).
    """
    errors = []
    for k, pair in enumerate(pairs):
        try:
            a, b, ref, u_ref = pair
            ref, u_ref = float(ref), float(u_ref)
        except (TypeError, ValueError):
            raise InputError(f"pairs[{k}]: expected (a, b, reference mm, u um), got {pair!r}") from None
        for n in (a, b):
            if n not in targets:
                raise InputError(f"pairs[{k}]: no target named {n!r} (have: {', '.join(sorted(targets))})")
        if a == b:
            raise InputError(f"pairs[{k}]: {a!r} paired with itself")
        if not (math.isfinite(ref) and ref > 0) or not (math.isfinite(u_ref) and u_ref >= 0):
            raise InputError(f"pairs[{k}]: reference {ref!r} mm must be > 0 and its u {u_ref!r} um >= 0")
        d = targets[b].centre - targets[a].centre
        dist = float(np.linalg.norm(d))
        n = d / dist
        var = float(n @ (targets[a].covariance + targets[b].covariance) @ n) * 1e6 + u_ref**2  # um^2
        err = (dist - ref) * 1e3
        if not abs(dist - ref) <= GROSS_ERROR_FRACTION * ref:
            raise InputError(_gross(k, a, b, dist, ref), what="distance", value=dist, unit="mm")
        u = math.sqrt(var)
        limit = decision = None
        if mpe is not None:
            limit = mpe.at(ref)
            decision = decide(err, limit, 2 * u)
        errors.append(DistanceResult(a, b, dist, ref, err, u, limit, decision))
    return E3125Distances(dict(targets), errors, RULE)


def _gross(k: int, a: str, b: str, dist: float, ref: float) -> str:
    """The refusal of a pair off its reference by more than GROSS_ERROR_FRACTION."""
    ratio = ref / dist if dist > 0 else math.inf
    scans, reference = length_unit_slip(ratio, 0.1), length_unit_slip(1 / ratio, 0.1, units=("m",))
    if scans is not None:
        likely = (f": the reference is {ratio:.4g} times the distance, as with {LENGTH_UNIT_NAMES[scans[0]]} read "
                  "as mm (check the scans' units)")
    elif reference is not None:
        likely = (f": the reference is {ratio:.4g} times the distance, as with the reference in metres (the "
                  "reference must be in mm)")
    else:
        likely = ": a unit mix-up, a swapped or mislabelled target or a wrong reference"
    return (f"pairs[{k}] ({a} - {b}): the measured distance {dist:.6g} mm is {100 * abs(dist - ref) / ref:.3g} % off "
            f"the reference {ref:.6g} mm (over {100 * GROSS_ERROR_FRACTION:g} %: no instrument errs by that much, "
            f"so no decision is made){likely}")


def read_pairs(path) -> list[tuple[str, str, float, float]]:
    """Pairs from a CSV with columns ``a, b, reference_mm[, u_um]``.

    Raises
    ------
    InputError
        Naming the file and line: a missing column or a non-number.
    """
    _, rows = read_csv_table(path, ("a", "b", "reference_mm"))
    out = []
    for line, row in rows:
        try:
            out.append((row["a"], row["b"], float(row["reference_mm"]), float(row.get("u_um") or 0.0)))
        except ValueError:
            raise InputError(f"{path}:{line}: reference_mm and u_um must be numbers, got {row}") from None
    return out
