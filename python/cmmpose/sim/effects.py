"""The simulator's view of the physical effects: the classes live one per
file in :mod:`cmmpose.effects` (their simulator hooks with them); this
module keeps the names the simulator has always exported."""

from __future__ import annotations

from ..effects import Effect, available, parse
from ..effects.alignment import Alignment, AlignmentError
from ..effects.artefact_expansion import ArtefactExpansion
from ..effects.axis_temperature import AxisTemperature
from ..effects.granite_gradient import GraniteGradient
from ..effects.incidence import Incidence, IncidenceError
from ..effects.latency import Latency, ScannerLatency
from ..effects.mount_offset import MountOffset, MountOffsetError
from ..effects.roll import Roll, UnmeasuredRoll
from ..effects.scale import Scale, ScaleError
from ..effects.scanner_scale import ScannerScale
from ..effects.squareness import Squareness, SquarenessOffset

__all__ = ["Effect", "available_effects", "parse_effect", "AlignmentError", "ArtefactExpansion", "AxisTemperature",
           "GraniteGradient", "IncidenceError", "ScannerLatency", "MountOffsetError", "UnmeasuredRoll", "ScaleError",
           "ScannerScale", "SquarenessOffset",
           "Alignment", "Incidence", "Latency", "MountOffset", "Roll", "Scale", "Squareness"]


def available_effects():
    """Effect classes by name (see :func:`cmmpose.effects.available`)."""
    return available()


def parse_effect(text: str) -> Effect:
    """``NAME:param=value,param=value`` (CLI form) -> an effect."""
    return parse(text)
