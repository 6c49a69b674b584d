"""A ball plate: balls on a flat plate, calibrated in its plane and across it."""

from __future__ import annotations

from typing import ClassVar

from ..errors import InputError
from .base import Artefact, ArtefactKind, line_distance, plane_distance


class BallPlate(ArtefactKind):
    """Balls on a plate; the plate is the artefact's xy plane, the balls on its +z side."""

    kind: ClassVar[str] = "ball-plate"
    summary: ClassVar[str] = "balls on a flat plate (KOBA, APMP): placements in the three coordinate planes"
    example: ClassVar[str] = "koba-0620"
    min_balls: ClassVar[int] = 4
    layout: ClassVar[str] = "planes"
    spans: ClassVar[str] = "plane"

    @classmethod
    def check(cls, artefact: Artefact, where: str) -> None:
        super().check(artefact, where)
        if line_distance(artefact.centres).max() <= artefact.nominal_radius:
            raise InputError(f"{where}: the balls are in a row: kind = 'step-gauge', not a ball plate")
        off = plane_distance(artefact.centres)
        k = int(off.argmax())
        if off[k] > artefact.nominal_radius:
            raise InputError(f"{where}: balls[{k}] (ball {artefact.ids[k]}) is {off[k]:.3f} mm off the plane of the "
                             f"others: a ball plate's balls are in one plane")
