"""Squareness follows one group of thermocouples, not the machine mean."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class SquarenessTemperature(Effect):
    """The maps' squareness (which changes with temperature: Table 7 of the
    thesis, up to 8 arc-seconds per K) is taken at the temperature of the
    thermocouples of role ``sensor`` instead of the machine mean.

    Model: S at T + gain (T_sensor - T), T the machine mean (gain 1: fully at
    the sensor). Which sensor is a choice the data make: the diagnosis tries
    one candidate per thermocouple role of the run
    ('squareness-temperature@z_scale', ...), and only runs in which those
    sensors move differently can tell them apart.
    Physics: squareness is set by the joints between the bridge, the
    carriages and the granite; when the axes sit at different temperatures
    (a warm ram, a vertical gradient) the joint that bends follows its own
    part's temperature. Typical: gain 1 on one sensor, 1-3 K from the mean.
    """

    name: ClassVar[str] = "squareness-temperature"
    summary: ClassVar[str] = ("the maps' squareness taken at one sensor group's temperature instead of the machine "
                              "mean (gain 1: fully at that sensor)")
    reveal: ClassVar[str] = ("runs in which the candidate sensors move differently (one axis warmed at a time, or "
                             "runs at several temperatures)")
    params: ClassVar[dict[str, Param]] = {"gain": Param("1", 1.0, step=0.25)}
    sensor_input: ClassVar[str] = "squareness_sensor"
    scenario_units: ClassVar[dict[str, str]] = {"sensor": "(thermocouple role)"}

    gain: float = 1.0
    sensor: str = "z_scale"

    def truth_inputs(self, role_temperature):
        return {self.sensor_input: role_temperature(self.sensor)}
