"""Each carriage's map taken at its own scale temperature."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ._base import Effect, Param


@dataclass(frozen=True)
class AxisTemperature(Effect):
    """Each carriage is at the machine mean plus (x, y, z) kelvin at t = 0,
    changing by (x_per_hour, y_per_hour, z_per_hour) K/h (a ram warming by
    its motor): its map should be taken at its own scale thermocouples, not
    at the mean.

    Model: carriage k's map at T + gain (T_k - T) (gain 1: fully per axis).
    Physics: vertical and horizontal gradients in a room; the ram is warmer
    near its motor. Typical: 0.2-2 K.
    """

    name: ClassVar[str] = "axis-temperature"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {**{f"d{a}^2": f"per-axis temperature {a}" for a in "xyz"},
                        "time": "per-axis temperature", "temperature": "per-axis temperature"}}
    summary: ClassVar[str] = ("each carriage's map taken at its own scale thermocouples instead of the machine mean "
                              "(gain 1: fully per axis)")
    reveal: ClassVar[str] = "axis-scale thermocouples that differ between axes (a run with a vertical gradient)"
    params: ClassVar[dict[str, Param]] = {"gain": Param("1", 1.0, step=0.25)}
    needs: ClassVar[tuple[str, ...]] = ("axis_temperature",)
    scenario_units: ClassVar[dict[str, str]] = {"x": "K", "y": "K", "z": "K", "x_per_hour": "K/h",
                                                 "y_per_hour": "K/h", "z_per_hour": "K/h"}

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    x_per_hour: float = 0.0
    y_per_hour: float = 0.0
    z_per_hour: float = 0.0

    def truth_terms(self):
        # The real carriages are at their own temperatures.
        return {self.name: [1.0]}

    def role_offsets(self, times):
        hours = np.asarray(times, dtype=float) / 3600.0
        return {"x_scale": self.x + self.x_per_hour * hours, "y_scale": self.y + self.y_per_hour * hours,
                "z_scale": self.z + self.z_per_hour * hours}
