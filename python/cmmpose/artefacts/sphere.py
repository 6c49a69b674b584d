"""A single calibrated sphere (a reference sphere): its radius and form only."""

from __future__ import annotations

from typing import ClassVar

from .base import ArtefactKind


class Sphere(ArtefactKind):
    """One ball at the origin of its frame; evaluated for size and form."""

    kind: ClassVar[str] = "sphere"
    summary: ClassVar[str] = "one calibrated ball: probing size and form (no lengths)"
    example: ClassVar[str] = "reference-sphere"
    min_balls: ClassVar[int] = 1
    max_balls: ClassVar[int] = 1
    layout: ClassVar[str] = "xy"
    spans: ClassVar[str] = "point"
