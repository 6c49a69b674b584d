"""A ball step gauge: balls in a row at a calibrated pitch."""

from __future__ import annotations

from typing import ClassVar

from ..errors import InputError
from .base import Artefact, ArtefactKind, line_distance


class StepGauge(ArtefactKind):
    """Balls along the artefact's x axis; their centres on one line."""

    kind: ClassVar[str] = "step-gauge"
    summary: ClassVar[str] = "balls in a row at a calibrated pitch (ISO 10360-2 positions)"
    example: ClassVar[str] = "step-gauge-31x20"
    min_balls: ClassVar[int] = 3
    layout: ClassVar[str] = "iso10360-2"
    spans: ClassVar[str] = "line"

    @classmethod
    def check(cls, artefact: Artefact, where: str) -> None:
        super().check(artefact, where)
        off = line_distance(artefact.centres)
        k = int(off.argmax())
        if off[k] > artefact.nominal_radius:
            raise InputError(f"{where}: balls[{k}] (ball {artefact.ids[k]}) is {off[k]:.3f} mm off the line of the "
                             f"others: a step gauge's balls are in a row (kind = 'ball-plate' for a plate)")
