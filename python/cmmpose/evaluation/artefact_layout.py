"""The observables of an artefact run (ball plate, step gauge, ...; docs/artefacts.md)
for the evaluation and the diagnosis: each ball's centre per placement relative to its
calibrated centre after the placement's best-fit rigid transform, as
:mod:`cmmpose.evaluation.artefact` defines the deviation.

For each placement the calibrated centres (the certificate's, in the
artefact's frame) are expanded to the placement's mean machine temperature
with the artefact's own coefficient, times the model's
``artefact-expansion`` (an error in that coefficient), and moved onto the
measured centres (the mean of each ball's scans) by the rigid transform that
minimises the sum of squared distances (Kabsch). What is left, three
components per ball in the machine frame, is what the diagnosis explains:
the rigid fit takes away the six (five for balls in a row) degrees of
freedom of each placement, which the statistics count
(:attr:`ArtefactLayout.fitted_dof`).

Units: mm, degrees C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import artefacts
from .artefact_balls import ball_scans, check_ball_positions, rigid_fit
from ..artefacts.base import line_distance

__all__ = ["ArtefactLayout", "artefact_deviations", "check_placements", "rigid_dof"]


@dataclass(frozen=True)
class ArtefactLayout:
    """Which physical spheres of a run are which balls of which placement.

    Attributes
    ----------
    artefact : cmmpose.artefacts.Artefact
        The artefact the run embeds.
    positions : tuple of int
        The placements measured (1-based), ascending.
    spheres : tuple of ndarray
        Per placement, the physical-sphere indices (of the observation
        layout) of its balls, in ascending ball id.
    balls : tuple of ndarray
        Per placement, the ball ids.
    calibrated : tuple of ndarray (n, 3)
        Per placement, the certificate's centres of its balls (artefact
        frame, at the certificate's temperature), mm.
    temperature : ndarray (P,)
        Mean machine temperature while each placement was scanned, C.
    """

    artefact: artefacts.Artefact
    positions: tuple[int, ...]
    spheres: tuple[np.ndarray, ...]
    balls: tuple[np.ndarray, ...]
    calibrated: tuple[np.ndarray, ...]
    temperature: np.ndarray

    @classmethod
    def from_run(cls, run, uniq: list, sphere_temperature) -> ArtefactLayout:
        """The layout of an artefact run.

        Parameters
        ----------
        run : cmmpose.Run
            A run that embeds its artefact (``run.artefact['definition']``).
        uniq : list of (feature, position, ball)
            The observation layout's physical spheres.
        sphere_temperature : callable
            ``sphere_temperature(indices)``: mean machine temperature (C)
            over the points of those spheres' scans.

        Raises
        ------
        InputError
            A scan labelled with a ball the artefact lacks or a placement the
            run does not record (as the evaluation does).
        """
        artefact = artefacts.from_dict(run.artefact["definition"], "run.json: artefact.definition")
        recorded = run.artefact.get("placements")
        ball_scans(run, artefact, len(recorded) if isinstance(recorded, list) else None)  # checks the labels
        positions = sorted({p for f, p, _ in uniq if f == "ball"})
        spheres, balls, calibrated, temps = [], [], [], []
        for pos in positions:
            ids = sorted(b for f, p, b in uniq if f == "ball" and p == pos)
            idx = np.array([uniq.index(("ball", pos, b)) for b in ids], dtype=int)
            spheres.append(idx)
            balls.append(np.array(ids, dtype=int))
            calibrated.append(artefact.centres[[artefact.index(b) for b in ids]])
            temps.append(float(sphere_temperature(idx)))
        return cls(artefact, tuple(positions), tuple(spheres), tuple(balls), tuple(calibrated), np.array(temps))

    @property
    def n_balls(self) -> int:
        """Balls measured over all placements."""
        return int(sum(len(s) for s in self.spheres))

    @property
    def size(self) -> int:
        """Observables: three deviation components per ball and placement."""
        return 3 * self.n_balls

    @property
    def fitted_dof(self) -> int:
        """Degrees of freedom the placements' rigid fits take: 6 per placement
        (5 for balls in a row, within a ball radius of one line, whose roll
        about that line moves them by nanometres; 3 for one ball), never more
        than the placement's observables."""
        return sum(rigid_dof(c, self.artefact.nominal_radius) for c in self.calibrated)


def rigid_dof(centres: np.ndarray, radius: float) -> int:
    """Degrees of freedom a rigid fit of ``centres`` (n, 3, mm) takes: 6; 5
    for balls within ``radius`` (mm) of one line (a step gauge, whose roll
    about its line moves them by nanometres); 3 for one ball; never more
    than the 3n coordinates."""
    n = len(centres)
    if n == 1:
        return 3
    dof = 5 if n == 2 or line_distance(centres).max() <= radius else 6
    return min(dof, 3 * n)


def check_placements(layout: ArtefactLayout, mean_centres: np.ndarray) -> None:
    """``InputError`` when a ball of a placement lies further from its
    calibrated place than any machine error could take it (mislabelled or
    mismeasured), as the evaluation checks it
    (:func:`cmmpose.evaluation.artefact.check_ball_positions`).

    Parameters
    ----------
    layout : ArtefactLayout
    mean_centres : ndarray (S, 3)
        Mean centre of each physical sphere of a run's first observation, mm.
    """
    a = layout.artefact
    for pos, balls, idx, temp in zip(layout.positions, layout.balls, layout.spheres, layout.temperature):
        check_ball_positions(a, f"scans: position {pos} of the run of {a.name!r}", balls, mean_centres[idx],
                             a.centres * float(a.scale_to(temp)))


def artefact_deviations(layout: ArtefactLayout, mean_centres: np.ndarray,
                        expansion_ppm_per_kelvin: float = 0.0) -> np.ndarray:
    """Each ball's deviation per placement, (n_balls, 3) mm, placements in order.

    Parameters
    ----------
    layout : ArtefactLayout
    mean_centres : ndarray (K, 3)
        Mean measured centre of each physical sphere, mm.
    expansion_ppm_per_kelvin : float
        The model's artefact expansion on top of the certificate's
        coefficient, ppm/K.

    """
    a = layout.artefact
    out = []
    for idx, cal, temp in zip(layout.spheres, layout.calibrated, layout.temperature):
        m = mean_centres[idx]
        c = cal * (float(a.scale_to(temp)) * (1.0 + expansion_ppm_per_kelvin * 1e-6 * (temp - 20.0)))
        r, t = rigid_fit(c, m)
        out.append(m - (c @ r.T + t))
    return np.concatenate(out) if out else np.zeros((0, 3))
