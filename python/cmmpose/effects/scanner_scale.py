"""Triangulation scale errors of the scanner."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class ScannerScale(Effect):
    """Scanner scale errors: reported u = (1 + lateral) u, v = (1 + depth) v (dimensionless, e.g. 1e-4).

    Physics: triangulation calibration error across and along the beam.
    Typical: 1e-4-1e-3 (6-60 um over 60 mm).
    """

    name: ClassVar[str] = "scanner-scale"
    hints: ClassVar[dict[str, dict[str, str]]] = {"point": {"u": "scanner lateral scale", "v": "scanner depth scale"}}
    summary: ClassVar[str] = "triangulation scale errors across (u) and along (v) the beam"
    reveal: ClassVar[str] = "a calibrated sphere radius"
    on_scanner: ClassVar[bool] = True
    params: ClassVar[dict[str, Param]] = {"lateral": Param("1", 5e-4), "depth": Param("1", 5e-4)}

    lateral: float = 0.0
    depth: float = 0.0
