"""The simulator's view of the physical effects: the classes live one per
file in :mod:`cmmpose.effects` (their simulator hooks with them); this
module keeps the names the simulator has always exported."""

from __future__ import annotations

from ..effects import Effect, available, parse
from ..effects.alignment import AlignmentError
from ..effects.artefact_expansion import ArtefactExpansion
from ..effects.axis_temperature import AxisTemperature
from ..effects.granite_gradient import GraniteGradient
from ..effects.incidence import IncidenceError
from ..effects.latency import ScannerLatency
from ..effects.mount_offset import MountOffsetError
from ..effects.roll import UnmeasuredRoll
from ..effects.scale import ScaleError
from ..effects.scanner_scale import ScannerScale
from ..effects.squareness import SquarenessOffset

__all__ = ["Effect", "available_effects", "parse_effect", "AlignmentError", "ArtefactExpansion", "AxisTemperature",
           "GraniteGradient", "IncidenceError", "ScannerLatency", "MountOffsetError", "UnmeasuredRoll", "ScaleError",
           "ScannerScale", "SquarenessOffset"]


def available_effects():
    """Effect classes by name (see :func:`cmmpose.effects.available`)."""
    return available()


def parse_effect(text: str) -> Effect:
    """``NAME:param=value,param=value`` (CLI form) -> an effect."""
    return parse(text)
