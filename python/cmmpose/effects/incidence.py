"""Depth error growing with the incidence angle."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Incidence(Effect):
    """Depth error growing with the incidence angle theta (degrees, between
    surface normal and beam) and depth: dv = per_degree theta + per_degree_mm v theta
    (bilinear, thesis section 7.2 after Feng 2001).

    Typical: 0.1-0.5 um per degree. Residual: spheres fit slightly small or
    large, depending on the cap.
    """

    name: ClassVar[str] = "incidence"
    hints: ClassVar[dict[str, dict[str, str]]] = {"point": {"incidence": "scanner incidence-angle error"}}
    summary: ClassVar[str] = "depth error growing with incidence angle and depth (thesis section 7.2)"
    reveal: ClassVar[str] = "a calibrated sphere radius"
    on_scanner: ClassVar[bool] = True
    params: ClassVar[dict[str, Param]] = {"per_degree": Param("mm/degree", 2e-4),
                                          "per_degree_mm": Param("1/degree", 2e-5)}
    needs: ClassVar[tuple[str, ...]] = ("incidence",)

    per_degree: float = 0.0
    per_degree_mm: float = 0.0
