"""The scanner mount expands with its own temperature."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ._base import Effect, Param


@dataclass(frozen=True)
class MountExpansion(Effect):
    """The mount offset l1 scales by 1 + alpha (T_mount - 20 C), T_mount from
    a thermocouple on the mount (channel role 'mount').

    The simulator warms the mount ``kelvin`` above the machine mean at t = 0,
    rising by ``kelvin_per_hour``, and logs it on channel 'MT'.
    Physics: an aluminium bracket (23 ppm/K) between the ram and the scanner
    warmed by the scanner's electronics and laser; at 264 mm of offset, 5 K
    moves the laser origin 30 um. Residual: a shift along the offset at each
    pose, growing as the mount warms.
    """

    name: ClassVar[str] = "mount-expansion"
    summary: ClassVar[str] = "the scanner mount expands with its own temperature: l1 (1 + alpha (T_mount - 20 C))"
    reveal: ClassVar[str] = "a thermocouple on the mount (role 'mount') and scans at two or more poses while it warms"
    params: ClassVar[dict[str, Param]] = {"ppm_per_kelvin": Param("ppm/K", 20.0)}
    needs: ClassVar[tuple[str, ...]] = ("mount_temperature",)
    channels: ClassVar[tuple[tuple[str, str], ...]] = (("MT", "mount"),)
    scenario_units: ClassVar[dict[str, str]] = {"kelvin": "K", "kelvin_per_hour": "K/h"}

    ppm_per_kelvin: float = 0.0
    kelvin: float = 0.0
    kelvin_per_hour: float = 0.0

    def role_offsets(self, times):
        return {"mount": self.kelvin + self.kelvin_per_hour * np.asarray(times, dtype=float) / 3600.0}
