"""A granite top-minus-bottom gradient changing squareness."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ._base import Effect, Param


@dataclass(frozen=True)
class GraniteGradient(Effect):
    """A granite top-minus-bottom temperature difference (K) bends the base
    and changes squareness by (xy, yz, zx) arc-seconds per K. The difference
    is ``kelvin`` at t = 0 and changes by ``kelvin_per_hour`` (the room
    warming the top through the day).

    Physics: the thesis saw S_yz and S_zx vary with temperature (Table 7,
    section 3.4) and suspected the granite. Typical: 0.5-2 K, 5-20 a-s/K.
    """

    name: ClassVar[str] = "granite-gradient"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {"dy*dz": "granite gradient", "dz*dx": "granite gradient", "time": "granite gradient",
                        "temperature": "granite gradient"}}
    summary: ClassVar[str] = "granite top-minus-bottom gradient bending the base and changing squareness"
    reveal: ClassVar[str] = "a run over which the granite gradient changes (otherwise it equals a squareness offset)"
    params: ClassVar[dict[str, Param]] = {p: Param("arc-second/K", 5.0) for p in ("xy", "yz", "zx")}
    needs: ClassVar[tuple[str, ...]] = ("gradient",)
    scenario_units: ClassVar[dict[str, str]] = {"kelvin": "K", "kelvin_per_hour": "K/h"}

    kelvin: float = 0.0
    xy: float = 0.0
    yz: float = 10.0
    zx: float = 10.0
    kelvin_per_hour: float = 0.0

    def gradient(self, times) -> np.ndarray:
        """Top minus bottom (K) at ``times`` (s)."""
        return self.kelvin + self.kelvin_per_hour * np.asarray(times, dtype=float) / 3600.0

    def role_offsets(self, times):
        g = self.gradient(times)
        return {"granite_top": g / 2, "granite_bottom": -g / 2}
