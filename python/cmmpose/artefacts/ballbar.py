"""A ballbar: two balls a calibrated length apart (the thesis's optical ballbar)."""

from __future__ import annotations

from typing import ClassVar

from .base import ArtefactKind


class Ballbar(ArtefactKind):
    """Two balls; ball 1 at the origin, ball 2 along +x (artefact frame)."""

    kind: ClassVar[str] = "ballbar"
    summary: ClassVar[str] = "two balls a calibrated length apart (ASME B89.4.1, ISO 10360-2 positions)"
    example: ClassVar[str] = "thesis-ballbar"
    min_balls: ClassVar[int] = 2
    max_balls: ClassVar[int] = 2
    layout: ClassVar[str] = "iso10360-2"
    spans: ClassVar[str] = "line"
