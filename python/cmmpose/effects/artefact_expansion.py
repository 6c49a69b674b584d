"""The artefact's length follows the part temperature."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class ArtefactExpansion(Effect):
    """The artefact expands with the part temperature (the machine mean):
    length = length at 20 C x (1 + ppm_per_kelvin 1e-6 (T - 20)).

    Physics: a steel ballbar (11.5 ppm/K) or an Invar one (~1 ppm/K);
    the thesis corrected lengths to 20 C with a coefficient (Table 21).
    Residual: every length off by the same amount, visible only against a
    calibrated length or across temperatures.
    """

    name: ClassVar[str] = "artefact-expansion"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {"time": "artefact expansion", "temperature": "artefact expansion"}}
    summary: ClassVar[str] = "the artefact's length follows the part temperature: L = L20 (1 + a (T - 20))"
    reveal: ClassVar[str] = "a calibrated bar length at 20 C, or runs at two temperatures"
    params: ClassVar[dict[str, Param]] = {"ppm_per_kelvin": Param("ppm/K", 5.0)}
    acts: ClassVar[str] = "length"

    ppm_per_kelvin: float = 0.0

    def artefact_scale(self, temperature):
        return 1.0 + self.ppm_per_kelvin * 1e-6 * (float(temperature) - 20.0)
