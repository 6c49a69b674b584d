"""An artefact run's balls: which scans measured which ball at which
placement, the rigid fit that puts the calibrated balls onto the measured
ones, and the checks of gross errors (a mislabelled or mismeasured ball).
Units: mm."""

from __future__ import annotations

import numpy as np

from .. import artefacts
from ..artefacts.base import line_distance
from ..errors import InputError
from ..run import Run

__all__ = ["ball_scans", "check_ball_positions", "check_labels", "gross_tolerance", "is_artefact_run", "rigid_fit",
           "rigid_projection"]


def is_artefact_run(run: Run) -> bool:
    """Whether ``run`` embeds an artefact definition (``cmmpose simulate --artefact``)."""
    return isinstance(run.artefact.get("definition"), dict)


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` and translation ``t`` minimising
    ``sum |R source_i + t - target_i|^2`` (Kabsch; any optimal rotation when
    the points are collinear; the identity for one point)."""
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    if len(source) == 1:
        return np.eye(3), ct - cs
    h = (source - cs).T @ (target - ct)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, ct - r @ cs


def rigid_projection(points: np.ndarray) -> np.ndarray:
    """(3n, 3n) projection that removes what a small rigid motion of
    ``points`` (n, 3) explains: residual = P @ displacement (linearised fit)."""
    n = len(points)
    p = points - points.mean(axis=0)
    a = np.zeros((3 * n, 6))
    for i, (x, y, z) in enumerate(p):
        a[3 * i:3 * i + 3, :3] = np.eye(3)
        a[3 * i:3 * i + 3, 3:] = [[0.0, z, -y], [-z, 0.0, x], [y, -x, 0.0]]
    return np.eye(3 * n) - a @ np.linalg.pinv(a)


def ball_scans(run: Run, artefact: artefacts.Artefact, n_placements: int | None) -> dict[int, dict[int, list[int]]]:
    """placement -> ball id -> scan ids, checked against the artefact."""
    scans = run.scans
    out: dict[int, dict[int, list[int]]] = {}
    for sid, feature, pos, ball in zip(scans["scan_id"].tolist(), scans["feature"].tolist(),
                                       scans["position"].tolist(), scans["ball"].tolist()):
        if feature != "ball":
            continue
        if pos < 1 or (n_placements is not None and pos > n_placements):
            have = f"1..{n_placements}" if n_placements else "1 or more"
            raise InputError(f"scans: scan {sid} is labelled position {pos}; the run's placements are {have}")
        if ball not in set(artefact.ids.tolist()):
            artefact.index(ball)  # raises, naming the balls the artefact has
        out.setdefault(pos, {}).setdefault(ball, []).append(sid)
    if not out:
        raise InputError("scans: the run has no ball scans (feature 'ball')")
    return out


def check_labels(groups, fits, radius: float) -> None:
    """Two scans of one placement labelled as different balls must not have
    measured the same ball, nor two scans of one label different balls."""
    for pos, balls in groups.items():
        ids = [(b, s) for b, scans in balls.items() for s in scans]
        c = np.array([fits.centre[np.searchsorted(fits.labels, s)] for _, s in ids])
        gap = np.linalg.norm(c[:, None] - c[None], axis=2)
        for i in range(len(ids)):
            for j in range(i + 1, len(ids)):
                if ids[i][0] == ids[j][0] and gap[i, j] > radius:
                    raise InputError(f"scans: scans {ids[i][1]} and {ids[j][1]} are both labelled ball {ids[i][0]} of "
                                     f"position {pos} but lie {gap[i, j]:.3f} mm apart: one of them is mislabelled")
                if ids[i][0] != ids[j][0] and gap[i, j] < radius:
                    raise InputError(f"scans: scan {ids[i][1]} (ball {ids[i][0]}) and scan {ids[j][1]} (ball "
                                     f"{ids[j][0]}) of position {pos} measured the same ball ({gap[i, j] * 1e3:.1f} "
                                     f"um apart): one of them is mislabelled")


#: How far (mm) a ball's centre may be from where the placement's best fit
#: puts it before it is mislabelled or mismeasured rather than measured with
#: a machine error: ``min(GROSS_FRACTION * smallest ball spacing,
#: max(GROSS_RESIDUAL, GROSS_PER_LENGTH * largest ball spacing))``
#: (:func:`gross_tolerance`). A machine's error leaves after the rigid fit
#: what no rigid motion explains, and grows with the artefact: the thesis
#: machine uncompensated (its maps, 20-29.5 C) leaves up to 0.22 mm on a KOBA
#: 0620 (752 mm diagonal), 0.29 um per mm, and 0.14 mm on the 0420 and the
#: APMP plate (tests/evaluation/test_artefact_labels.py measures it); 1 mm, or 2 um per
#: mm of the artefact's largest spacing (2000 ppm, 400 arcsec of shear: a
#: machine no one measures a calibrated plate on), is 6.9 times the worst of
#: these. A swapped or wrong label moves a ball to another ball's place, at
#: least the smallest spacing (the pitch: 20-133 mm on the bundled
#: artefacts) away: a tenth of it leaves a margin of 10 the other way, and
#: caps the tolerance of an artefact whose balls are close together.
GROSS_RESIDUAL = 1.0
GROSS_PER_LENGTH = 2e-3
GROSS_FRACTION = 0.1


def gross_tolerance(artefact: artefacts.Artefact) -> float:
    """The residual (mm) beyond which a ball of ``artefact`` is mislabelled
    or mismeasured (GROSS_RESIDUAL explains the choice)."""
    c = artefact.centres
    if len(c) < 2:
        return GROSS_RESIDUAL
    gap = np.linalg.norm(c[:, None] - c[None], axis=2)[~np.eye(len(c), dtype=bool)]
    return float(min(GROSS_FRACTION * gap.min(), max(GROSS_RESIDUAL, GROSS_PER_LENGTH * gap.max())))


def _balls(ids) -> str:
    ids = [str(int(b)) for b in ids]
    return f"ball {ids[0]}" if len(ids) == 1 else "balls " + ", ".join(ids[:-1]) + " and " + ids[-1]


def check_ball_positions(artefact: artefacts.Artefact, where: str, ids, measured: np.ndarray,
                         calibrated: np.ndarray, scans_of=None) -> None:
    """Refuse a placement whose balls are not where their labels put them.

    The measured centres are judged first by the distances between them,
    which need no fit: a ball stays trusted while its distances to the other
    trusted balls match the calibrated ones within twice
    :func:`gross_tolerance` (what two balls each within it can differ by);
    the ball with the most (then the largest) mismatches is left out until
    the rest agree, so one swapped or stray ball cannot spoil the fit that
    judges it. The rigid fit (Kabsch) of the trusted balls then places the
    whole artefact; a ball further than the tolerance from its calibrated
    place is an error, which says which ball it did measure where one of
    the placed balls is within the tolerance (two labels swapped, or a
    permutation among the offending balls). Vectorised over balls
    (n^2 distances, n at most a few hundred).

    Parameters
    ----------
    artefact : Artefact
    where : str
        Names the run and placement in the message.
    ids : sequence of int (n,)
        The placement's ball labels.
    measured : ndarray (n, 3)
        Their measured centres, mm.
    calibrated : ndarray (N, 3)
        Every ball of the artefact (``artefact.ids`` order), calibrated, in
        the measured centres' temperature state, mm.
    scans_of : sequence of sequences of int, optional
        Each ball's scan ids, for the message.

    Raises
    ------
    InputError
        A ball further than the tolerance from its calibrated place.
    """
    ids = np.asarray(ids, dtype=np.int64)
    n = len(ids)
    if n < 2:
        return
    tol = gross_tolerance(artefact)
    c = calibrated[[artefact.index(int(b)) for b in ids]]
    err = np.abs(np.linalg.norm(measured[:, None] - measured[None], axis=2)
                 - np.linalg.norm(c[:, None] - c[None], axis=2))
    # Balls each within tol of their places change their distance by at most 2 tol: such balls stay trusted.
    gross = err > 2.0 * tol
    trusted = np.ones(n, dtype=bool)
    while gross.any():
        among = gross & trusted[:, None] & trusted[None, :]
        count = among.sum(axis=1)
        if not count.any():
            break
        size = np.where(among, err, 0.0).sum(axis=1)
        trusted[np.lexsort((size, count))[-1]] = False

    def scans(mask) -> str:
        if scans_of is None:
            return ""
        return " (" + ", ".join(f"scan{'s' if len(s) > 1 else ''} {', '.join(map(str, s))} labelled ball {b}"
                                for b, s, m in zip(ids.tolist(), scans_of, mask) if m) + ")"

    in_a_row = line_distance(artefact.centres).max() <= artefact.nominal_radius
    if trusted.sum() < (2 if in_a_row else 3):  # too few agree to place the artefact
        i, j = np.unravel_index(int(np.argmax(err)), err.shape)
        which = "" if n == 2 else f"; the distances of {_balls(ids[~trusted])} disagree with the others'"
        named = scans(~trusted if n > 2 else np.ones(n, dtype=bool))
        raise InputError(
            f"{where}: the balls' centres do not match the artefact's geometry: balls {ids[i]} and {ids[j]} lie "
            f"{np.linalg.norm(measured[i] - measured[j]):.3f} mm apart, calibrated {np.linalg.norm(c[i] - c[j]):.3f} "
            f"mm, more than the {2 * tol:.3f} mm machine errors could explain{which}{named}: mislabelled or "
            f"mismeasured balls (check the 'ball' column of the scans)")
    r, t = rigid_fit(c[trusted], measured[trusted])
    placed = calibrated @ r.T + t
    own = placed[[artefact.index(int(b)) for b in ids]]
    off = np.linalg.norm(measured - own, axis=1)
    bad = off > tol
    if not bad.any():
        return
    near = np.linalg.norm(measured[bad][:, None] - placed[None], axis=2)
    nearest = near.argmin(axis=1)
    guess = {int(a): int(artefact.ids[k]) for a, k, d in zip(ids[bad], nearest, near.min(axis=1)) if d <= tol}
    k = int(bad.sum())
    offs = " and ".join(", ".join(f"{d:.3f}" for d in off[bad]).rsplit(", ", 1))
    msg = (f"{where}: {_balls(ids[bad])} {'lies' if k == 1 else 'lie'} {offs} mm from where the best fit of the "
           f"artefact to the other {int(trusted.sum())} balls puts {'it' if k == 1 else 'them'}, more than the "
           f"{tol:.3f} mm a machine error could explain{scans(bad)}: mislabelled or mismeasured")
    bad_ids = set(ids[bad].tolist())
    if guess and set(guess) == bad_ids and set(guess.values()) == bad_ids:
        pairs = sorted({tuple(sorted((a, b))) for a, b in guess.items()})
        if all(guess[b] == a for a, b in pairs):
            msg += "; " + "; ".join(f"labels {a} and {b} look swapped" for a, b in pairs)
        else:
            msg += "; the labels look permuted: " + ", ".join(f"the ball labelled {a} is ball {b}"
                                                               for a, b in sorted(guess.items()))
    elif guess:
        msg += "; " + ", ".join(f"the ball labelled {a} looks like ball {b}" +
                                ("" if b in ids.tolist() else " (not otherwise measured)")
                                for a, b in sorted(guess.items()))
    raise InputError(msg + " (check the 'ball' column of the scans)")
