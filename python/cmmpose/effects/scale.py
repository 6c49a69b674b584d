"""Per-axis scale error not in the map."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Scale(Effect):
    """Per-axis scale error in ppm: the linear error grows by ppm 1e-6 x reading.

    Physics: scale expansion not in the map (a scale at another temperature
    than mapped, scale pitch error). Typical: 1-12 ppm (steel/glass ~ 10 ppm/K).
    """

    name: ClassVar[str] = "scale"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {f"d{a}^2": f"scale error {a}" for a in "xyz"}}
    summary: ClassVar[str] = "scale error per axis not in the map (scale at another temperature, pitch)"
    reveal: ClassVar[str] = "a calibrated bar length (the common part of the three scale errors equals a length change)"
    params: ClassVar[dict[str, Param]] = {p: Param("ppm", 5.0) for p in ("x", "y", "z")}

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
