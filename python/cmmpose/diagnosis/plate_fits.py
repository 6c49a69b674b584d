"""Diagnosis of an artefact (ball plate, step gauge) from its measured ball
centres alone, as :mod:`cmmpose.diagnosis.spheres` does for a ballbar: a
table of sphere fits (placement, ball, centre, radius) and the artefact file
(its certificate), no raw points.

Each placement's calibrated centres (expanded to the measuring temperature
with the artefact's coefficient) are moved onto the measured ones by the
best-fit rigid transform; the balls' deviations are then fitted, by linear
least squares, with the six linear geometric errors a CMM's map most often
misses, to first order in the machine frame (docs/conventions.md, thesis
eqs. 11-12), in the sense of the effects ``squareness`` and ``scale`` of the
library (the values ``cmmpose simulate --effect`` takes): a measured centre
at (x, y, z) is moved by

    (y S_xy + z S_zx, z S_yz, 0) (squareness, arc-seconds)
  - (x s_x, y s_y, z s_z) 1e-6    (scale, ppm)

less what each placement's rigid motion takes away. A parameter the
placements cannot show (S_yz from a plate in the XY plane alone) is reported
as undetermined. The noise is estimated from the residuals (3 per ball less 6
per placement and the parameters fitted); the radii are tested against the
calibrated radius as the ballbar fits are.

Units: mm in, um and arc-seconds out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..evaluation.artefact_balls import rigid_fit, rigid_projection
from ..artefacts import Artefact
from .._csvtable import read_csv_table
from ..errors import InputError
from ..evaluation.artefact_layout import rigid_dof
from .pattern_results import Patterns
from .patterns import categorical_pattern, mean_offset_pattern, ranked_patterns

__all__ = ["PlateFitDiagnosis", "diagnose_plate_fits", "read_plate_fits", "LINEAR_ERRORS"]

#: The linear geometric errors fitted: (name, unit).
LINEAR_ERRORS = (("squareness xy", "arc-second"), ("squareness yz", "arc-second"), ("squareness zx", "arc-second"),
                 ("scale x", "ppm"), ("scale y", "ppm"), ("scale z", "ppm"))
_ARCSEC = math.pi / 648000.0
_UM = 1e3
_COLUMNS = ("placement", "ball", "x_mm", "y_mm", "z_mm", "radius_mm")
#: Smallest change of the deviations (root sum of squares over all balls, mm)
#: per unit of a linear error for the placements to show it (10 nm).
SEEN_MM = 1e-5


@dataclass(frozen=True)
class PlateFitDiagnosis:
    """What the measured centres of an artefact show.

    Attributes
    ----------
    placements : tuple of int
        The placements, ascending.
    balls : tuple of ndarray
        Ball ids of each placement.
    deviations_um : tuple of ndarray (n, 3)
        Each ball's deviation after its placement's best-fit rigid transform, um.
    rms_um : float
        Rms of the deviations' magnitudes over all balls, um.
    values, uncertainties : ndarray (6,)
        The linear errors of ``LINEAR_ERRORS`` (arc-seconds, ppm) and their
        standard uncertainties (NaN and inf: the placements cannot show it).
    residual_rms_um : float
        Rms of the deviations' magnitudes once the linear errors are taken out, um.
    patterns : Patterns
        The radius patterns (constant offset from the calibrated radius,
        between placements), ranked, with Bonferroni significance.
    radius_mean : float
        Mean fitted radius, mm.
    nominal_radius : float or None
        The artefact's calibrated radius, mm.
    """

    placements: tuple[int, ...]
    balls: tuple[np.ndarray, ...]
    deviations_um: tuple[np.ndarray, ...]
    rms_um: float
    values: np.ndarray
    uncertainties: np.ndarray
    residual_rms_um: float
    patterns: Patterns = field(repr=False)
    radius_mean: float = math.nan
    nominal_radius: float | None = None

    def to_dict(self) -> dict:
        def num(x):
            return float(x) if math.isfinite(x) else None  # JSON has no inf

        return {"rms_deviation_um": self.rms_um, "residual_rms_um": self.residual_rms_um,
                "linear_errors": [{"name": n, "unit": u, "value": num(v), "u": num(s)}
                                  for (n, u), v, s in zip(LINEAR_ERRORS, self.values, self.uncertainties)],
                "placements": [{"placement": p, "balls": [{"ball": int(b), **{f"deviation_{a}_um": float(d[k])
                                                                             for k, a in enumerate("xyz")}}
                                                          for b, d in zip(bs, ds)]}
                               for p, bs, ds in zip(self.placements, self.balls, self.deviations_um)],
                "radius_mean_mm": self.radius_mean, "nominal_radius_mm": self.nominal_radius,
                "patterns": self.patterns.to_dict()}


def _linear_columns(centres: np.ndarray) -> np.ndarray:
    """(3n, 6) shift of each centre (n, 3, mm) per unit of each linear error, mm."""
    x, y, z = centres.T
    n = len(centres)
    a = np.zeros((n, 3, 6))
    a[:, 0, 0] = y * _ARCSEC
    a[:, 1, 1] = z * _ARCSEC
    a[:, 0, 2] = z * _ARCSEC
    a[:, 0, 3] = -x * 1e-6  # a positive scale error (the 'scale' effect) reads short
    a[:, 1, 4] = -y * 1e-6
    a[:, 2, 5] = -z * 1e-6
    return a.reshape(3 * n, 6)


def _pose_group_shifts(pose: np.ndarray) -> np.ndarray:
    """The columns of a placement's balls (in rows of three) that translate each pose group but the first on
    its own: balls scanned with another pose read the scales at another offset from their centres."""
    groups = sorted(set(pose.tolist()))
    shift = np.zeros((3 * len(pose), 3 * (len(groups) - 1)))
    for g, name in enumerate(groups[1:]):
        for k in np.flatnonzero(pose == name):
            shift[3 * k:3 * k + 3, 3 * g:3 * g + 3] = np.eye(3)
    return shift


def _without_pose_groups(y: np.ndarray, X: np.ndarray, shifts: list[np.ndarray]):
    """The deviations ``y`` and the columns ``X`` with every placement's pose-group translations (``shifts``,
    block-diagonal) projected out, and how many such translations there are."""
    nuisance = np.zeros((len(y), sum(n.shape[1] for n in shifts)))
    r0 = c0 = 0
    for n in shifts:
        nuisance[r0:r0 + n.shape[0], c0:c0 + n.shape[1]] = n
        r0, c0 = r0 + n.shape[0], c0 + n.shape[1]
    if nuisance.shape[1]:  # the pose groups' translations taken out of the data and the columns
        q = np.linalg.qr(nuisance)[0]
        y = y - q @ (q.T @ y)
        X = X - q @ (q.T @ X)
    return y, X, nuisance.shape[1]


def _linear_errors(X: np.ndarray, y: np.ndarray, n_rigid: int, where: str, n_placements: int):
    """The six linear errors by least squares on the columns ``X`` (their units) with their standard
    uncertainties (inf, value NaN: not determined), and the residual deviations, mm. ``n_rigid``: the degrees
    of freedom the rigid fits and the pose groups took."""
    # A parameter whose unit (1 arc-second, 1 ppm) moves the deviations, over
    # all balls, by less than SEEN_MM is one the placements cannot show. The
    # others' columns are scaled to unit norm for the solution.
    norms = np.linalg.norm(X, axis=0)
    seen = norms > SEEN_MM
    if not seen.any():
        raise InputError(f"{where}: the placements show none of the linear errors (balls at one point?)")
    Xs = X[:, seen] / norms[seen]
    u_, s, vt = np.linalg.svd(Xs, full_matrices=False)
    keep = s > 1e-6 * s[0]
    beta_s = vt[keep].T @ ((u_[:, keep].T @ y) / s[keep])
    residual = y - Xs @ beta_s
    dof = len(y) - n_rigid - int(keep.sum())
    if dof < 1:
        raise InputError(f"{where}: {len(y) // 3} balls over {n_placements} placement(s) leave no degrees of "
                         f"freedom for the noise after the rigid fits and the linear errors")
    sigma2 = float(residual @ residual) / dof
    values = np.full(6, math.nan)
    unc = np.full(6, math.inf)
    # A direction the placements do not determine (a small singular value) leaves its parameters undetermined.
    cov_s = (vt[keep].T / s[keep] ** 2) @ vt[keep] * sigma2
    undetermined = np.abs(vt[~keep]).max(axis=0) > 1e-6 if (~keep).any() else np.zeros(int(seen.sum()), bool)
    idx = np.flatnonzero(seen)
    values[idx] = beta_s / norms[seen]
    unc[idx] = np.where(undetermined, math.inf, np.sqrt(np.clip(np.diag(cov_s), 0, None)) / norms[seen])
    values[~np.isfinite(unc)] = math.nan
    return values, unc, residual


def diagnose_plate_fits(artefact: Artefact, table: dict, *, temperature: float = 20.0,
                        alpha: float = 1e-3) -> PlateFitDiagnosis:
    """Diagnose an artefact from its measured ball centres.

    Parameters
    ----------
    artefact : Artefact
        Its certificate (``cmmpose.artefacts.load_artefact``).
    table : dict
        From :func:`read_plate_fits`: ``placement`` (M,) int, ``ball`` (M,)
        int, ``centres`` (M, 3) mm, ``radii`` (M,) mm, optionally ``pose``
        (M,) labels.
    temperature : float
        Temperature of the artefact while measured, C: its calibrated
        centres are expanded to it with its own coefficient.
    alpha : float
        Family-wise significance level of the radius patterns.

    Raises
    ------
    InputError
        A ball the artefact lacks, a placement with fewer than 3 balls, too
        few balls for the six degrees of freedom of each placement and the
        fitted errors.
    """
    if not (isinstance(temperature, (int, float)) and math.isfinite(temperature) and -50 < temperature < 100):
        raise InputError(f"temperature: expected a part temperature in C, got {temperature!r}")
    place = np.asarray(table["placement"], dtype=int)
    ball = np.asarray(table["ball"], dtype=int)
    centres = np.asarray(table["centres"], dtype=float)
    radii = np.asarray(table["radii"], dtype=float)
    where = table.get("source", "table")
    known = set(artefact.ids.tolist())
    for k, b in enumerate(ball.tolist()):
        if b not in known:
            line = table.get("lines", [None] * len(ball))[k]
            raise InputError(f"{where}" + (f":{line}" if line else "") + f": ball {b}: "
                             f"{artefact.source or artefact.name} has no ball {b}")
    scale = float(artefact.scale_to(temperature))
    placements = sorted(set(place.tolist()))
    pose = np.asarray(table.get("pose", np.zeros(len(ball), dtype=int))).astype(str)
    balls, devs, blocks, cols, shifts, n_rigid = [], [], [], [], [], 0
    for p in placements:
        rows = np.flatnonzero(place == p)
        rows = rows[np.argsort(ball[rows])]
        if len(rows) < 3:
            raise InputError(f"{where}: placement {p} has {len(rows)} ball(s); its rigid fit needs at least 3")
        m = centres[rows]
        c = artefact.centres[[artefact.index(b) for b in ball[rows]]] * scale
        _check_length_unit(where, p, m, c)
        r, t = rigid_fit(c, m)
        devs.append(m - (c @ r.T + t))
        proj = rigid_projection(m)
        blocks.append(devs[-1].reshape(-1))
        cols.append(proj @ _linear_columns(m))
        # Balls scanned with another pose read the scales at another offset
        # from their centres: a translation of that group of its own.
        shifts.append(proj @ _pose_group_shifts(pose[rows]))
        balls.append(ball[rows])
        n_rigid += rigid_dof(c, artefact.nominal_radius)
    y = np.concatenate(blocks)
    X = np.vstack(cols)
    y, X, n_groups = _without_pose_groups(y, X, shifts)
    n_rigid += n_groups
    values, unc, residual = _linear_errors(X, y, n_rigid, where, len(placements))
    rr = radii
    nominal = artefact.calibrated_radius
    rdev = (rr - nominal) * _UM
    obs = "sphere radius deviation from calibrated"
    found = [mean_offset_pattern("sphere", obs, rdev, "a coating, a scanner scale or an incidence error "
                          "(a constant radius offset)"),
             categorical_pattern("sphere", obs, "placement", place.astype(str), rdev,
                          "the view or place matters: incidence, scanner scale with the cap, local error")]
    ranked, threshold = ranked_patterns(found, alpha)
    size = np.linalg.norm(np.concatenate(devs), axis=1)
    left = np.linalg.norm(residual.reshape(-1, 3), axis=1)
    return PlateFitDiagnosis(tuple(placements), tuple(balls), tuple(d * _UM for d in devs),
                             float(np.sqrt(np.mean(size ** 2))) * _UM, values, unc,
                             float(np.sqrt(np.mean(left ** 2))) * _UM, Patterns(ranked, alpha, threshold),
                             float(rr.mean()), float(nominal))


#: Largest relative difference between the measured and the certified ball spacing (1 %, 1e4 ppm: a scale
#: error of any CMM is far smaller; centres in um, inches or metres are 1000, 1/25.4 or 1/1000 times apart).
MAX_SPACING_RATIO_ERROR = 0.01
#: Largest placement number or ball id (fits a C long).
_MAX_ID = 2**63 - 1


def _check_length_unit(where, placement, measured: np.ndarray, certified: np.ndarray) -> None:
    """Refuse a placement whose measured centres are not as far apart as the certificate's (within
    ``MAX_SPACING_RATIO_ERROR``): centres in another unit than mm would read as a scale error of -999,000 ppm."""
    d_cert = float(np.linalg.norm(np.diff(certified, axis=0), axis=1).sum())
    if not d_cert > 0:
        return
    ratio = float(np.linalg.norm(np.diff(measured, axis=0), axis=1).sum()) / d_cert
    if abs(ratio - 1.0) <= MAX_SPACING_RATIO_ERROR:
        return
    units = {1e3: "um", 1 / 25.4: "inches", 1e-3: "metres", 0.1: "centimetres"}
    guess = min(units, key=lambda u: abs(math.log(max(ratio, 1e-300) / u)))
    hint = f": the centres look like {units[guess]}, not mm" if abs(math.log(max(ratio, 1e-300) / guess)) < 0.05 else ""
    raise InputError(f"{where}: placement {placement}: the measured centres are {ratio:.6g} times as far apart as the "
                     f"certificate's (more than {MAX_SPACING_RATIO_ERROR:.0%} off){hint}; x_mm, y_mm, z_mm are in mm",
                     what="x_mm", value=f"{ratio:.6g}", unit="mm")


def read_plate_fits(path, state: str | None = None) -> dict:
    """Measured ball centres from a CSV: columns ``placement`` (1, 2, ...),
    ``ball`` (the artefact's ball id), ``x_mm``, ``y_mm``, ``z_mm``,
    ``radius_mm`` (machine frame, mm) and optionally ``pose`` (which pose
    scanned the ball: balls of one placement scanned with different poses
    read the scales at different offsets from their centres, so each pose
    group gets a translation of its own; without it, one pose per placement)
    and ``state`` (rows of other states skipped when ``state`` is given);
    lines starting with '#' are comments.

    Returns
    -------
    dict
        ``placement`` (M,), ``ball`` (M,), ``centres`` (M, 3) mm, ``radii``
        (M,) mm, ``pose`` (M,) labels ('' without the column), ``lines`` (M,)
        the file's line numbers, ``source``.

    Raises
    ------
    InputError
        Naming the file and line: no header, a missing or repeated column, a
        non-number, a non-finite value or a radius <= 0, a (placement, ball)
        given twice, no rows.
    """
    path = Path(path)
    header, rows = read_csv_table(path, _COLUMNS)
    place, ball, xyz, radii, where, seen, poses = [], [], [], [], [], {}, []
    for line, row in rows:
        if state is not None and "state" in header and row["state"] != state:
            continue
        try:
            p, b = int(row["placement"]), int(row["ball"])
            vals = [float(row[k]) for k in ("x_mm", "y_mm", "z_mm", "radius_mm")]
        except ValueError:
            raise InputError(f"{path}:{line}: expected whole numbers in placement and ball and numbers in x_mm, "
                             f"y_mm, z_mm, radius_mm") from None
        if not all(math.isfinite(v) and abs(v) < 1e7 for v in vals) or vals[3] <= 0:
            raise InputError(f"{path}:{line}: centre and radius must be finite mm (below 1e7), the radius > 0")
        if not (1 <= p <= _MAX_ID and 1 <= b <= _MAX_ID):  # an id beyond a C long is no ball's
            shown = [v if abs(v) < 10**20 else f"a {len(str(abs(v)))}-digit number" for v in (p, b)]
            raise InputError(f"{path}:{line}: placement and ball are numbers >= 1 that fit a C long (at most "
                             f"{_MAX_ID}), got {shown[0]}, {shown[1]}")
        if (p, b) in seen:
            raise InputError(f"{path}:{line}: placement {p}, ball {b} is given twice (also line {seen[(p, b)]})")
        seen[(p, b)] = line
        place.append(p)
        ball.append(b)
        xyz.append(vals[:3])
        radii.append(vals[3])
        where.append(line)
        poses.append(row.get("pose", ""))
    if not place:
        raise InputError(f"{path}: no rows" + (f" of state {state!r}" if state is not None else "")
                         + " after the header")
    return {"placement": np.array(place), "ball": np.array(ball), "centres": np.array(xyz), "radii": np.array(radii),
            "pose": np.array(poses), "lines": where, "source": str(path)}
