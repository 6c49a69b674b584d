"""What every artefact kind declares, and the artefact itself: calibrated
ball centres in the artefact's own frame with their standard uncertainties
(a calibration certificate), the ball radius, the coefficient of expansion
and the certificate's reference temperature.

Units: the file holds mm, um, ppm/K and degrees C; an :class:`Artefact`
holds mm, 1/K and degrees C (converted here and nowhere else).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import InputError

__all__ = ["Artefact", "ArtefactKind", "id_ranges", "line_distance", "plane_distance"]


@dataclass(frozen=True)
class Artefact:
    """One calibrated artefact.

    Attributes
    ----------
    kind : str
        A registered kind (:func:`cmmpose.artefacts.available`).
    name : str
        What the artefact is called (maker, type, serial number).
    certificate : str
        Where the calibrated values come from.
    ids : ndarray (n,) of int
        Ball numbers, as engraved (positive, unique).
    centres : ndarray (n, 3)
        Calibrated ball centres in the artefact's own frame, mm, at
        ``reference_temperature``.
    u_centres : ndarray (n, 3)
        Their standard uncertainties per axis, mm.
    nominal_radius, calibrated_radius : float
        Ball radius, mm.
    u_radius : float
        Standard uncertainty of the calibrated radius, mm.
    expansion : float
        Coefficient of linear expansion, 1/K.
    reference_temperature : float
        Temperature of the certificate's values, degrees C.
    source : str
        The file (or bundled example) it was read from.
    """

    kind: str
    name: str
    certificate: str
    ids: np.ndarray
    centres: np.ndarray
    u_centres: np.ndarray
    nominal_radius: float
    calibrated_radius: float
    u_radius: float
    expansion: float
    reference_temperature: float
    source: str = ""

    def __post_init__(self):
        for name in ("ids", "centres", "u_centres"):
            a = np.array(getattr(self, name), dtype=np.int64 if name == "ids" else float)
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @property
    def n_balls(self) -> int:
        return len(self.ids)

    @property
    def centroid(self) -> np.ndarray:
        """Mean of the calibrated centres, mm (artefact frame)."""
        return self.centres.mean(axis=0)

    def index(self, ball_id: int) -> int:
        """Row of ball ``ball_id``; ``InputError`` when the artefact lacks it."""
        hits = np.flatnonzero(self.ids == int(ball_id))
        if not len(hits):
            raise InputError(f"{self.source or self.name}: has no ball {ball_id} (balls {id_ranges(self.ids)})")
        return int(hits[0])

    def scale_to(self, temperature) -> np.ndarray | float:
        """Factor on the certificate's lengths at ``temperature`` (C): 1 + alpha (T - T_ref)."""
        return 1.0 + self.expansion * (np.asarray(temperature, dtype=float) - self.reference_temperature)

    def centres_at_20c(self) -> np.ndarray:
        """Calibrated centres at 20 C, mm."""
        return self.centres * float(self.scale_to(20.0))

    def to_dict(self) -> dict:
        """The artefact as its file says it (mm, um, ppm/K, C): embedded in a
        run's ``run.json`` and read back by :func:`cmmpose.artefacts.from_dict`."""
        return {
            "kind": self.kind,
            "name": self.name,
            "certificate": self.certificate,
            "reference_temperature_C": float(self.reference_temperature),
            "expansion_ppm_per_K": float(round(self.expansion * 1e6, 9)),
            "radius": {"nominal_mm": float(self.nominal_radius), "calibrated_mm": float(self.calibrated_radius),
                       "u_um": float(round(self.u_radius * 1e3, 9))},
            "balls": [{"id": int(i), "xyz_mm": [float(x) for x in c], "u_um": [float(round(u * 1e3, 9)) for u in uc]}
                      for i, c, uc in zip(self.ids, self.centres, self.u_centres)],
        }


class ArtefactKind:
    """Base class of the artefact kinds: one module per kind in this package.

    Class attributes (set by each kind)
    -----------------------------------
    kind : str
        The one name everywhere: the file's ``kind``, the CLI, run.json.
    summary : str
        One line: what the artefact is.
    example : str
        Name of its bundled example (``data/artefacts/<example>.toml``).
    min_balls, max_balls : int
        How many balls it has (max 0: no limit).
    layout : str
        The named placement layout that suits it (:mod:`cmmpose.placement`).
    spans : str
        What its balls span, which decides the placements a measurement plan
        tries (:func:`cmmpose.diagnosis.plan.candidate_placements`):
        ``"plane"`` (a plate: turned in the XY, XZ and YZ planes), ``"line"``
        (a bar or a gauge: along the axes and the diagonals) or ``"point"``
        (one ball: nothing to plan).
    """

    kind: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    example: ClassVar[str] = ""
    min_balls: ClassVar[int] = 1
    max_balls: ClassVar[int] = 0
    layout: ClassVar[str] = "planes"
    spans: ClassVar[str] = "point"

    @classmethod
    def check(cls, artefact: Artefact, where: str) -> None:
        """Raise ``InputError`` naming ``where`` if the geometry does not
        fit the kind (ball count here; shape in the kinds)."""
        n = artefact.n_balls
        if n < cls.min_balls or (cls.max_balls and n > cls.max_balls):
            want = (f"exactly {cls.min_balls}" if cls.min_balls == cls.max_balls
                    else f"at least {cls.min_balls}" + (f" and at most {cls.max_balls}" if cls.max_balls else ""))
            raise InputError(f"{where}: a {cls.kind} has {want} balls, the file has {n}")


def line_distance(centres: np.ndarray) -> np.ndarray:
    """Distance of each centre from the best-fit line through them, mm."""
    d = centres - centres.mean(axis=0)
    direction = np.linalg.svd(d, full_matrices=False)[2][0]
    return np.linalg.norm(d - np.outer(d @ direction, direction), axis=1)


def plane_distance(centres: np.ndarray) -> np.ndarray:
    """Distance of each centre from the best-fit plane through them, mm."""
    d = centres - centres.mean(axis=0)
    normal = np.linalg.svd(d, full_matrices=False)[2][-1]
    return np.abs(d @ normal)


def id_ranges(ids) -> str:
    """Ball numbers as runs, ``"1-4, 7, 9-10"``."""
    ids = sorted(int(i) for i in ids)
    out, start = [], ids[0]
    for a, b in zip(ids, ids[1:] + [None]):
        if b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(out)
