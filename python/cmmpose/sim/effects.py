"""The simulator's view of the physical effects: the classes live one per
file in :mod:`cmmpose.effects` (their simulator hooks with them); this
module gathers them for the simulator."""

from __future__ import annotations

from dataclasses import fields

from ..effects import Effect, available, parse
from ..effects.alignment import Alignment
from ..effects.artefact_expansion import ArtefactExpansion
from ..effects.axis_temperature import AxisTemperature
from ..effects.granite_gradient import GraniteGradient
from ..effects.incidence import Incidence
from ..effects.latency import Latency
from ..effects.mount_offset import MountOffset
from ..effects.roll import Roll
from ..effects.scale import Scale
from ..effects.scanner_scale import ScannerScale
from ..effects.squareness import Squareness

__all__ = ["Effect", "available_effects", "parse_effect", "inert", "ArtefactExpansion", "AxisTemperature",
           "GraniteGradient", "ScannerScale",
           "Alignment", "Incidence", "Latency", "MountOffset", "Roll", "Scale", "Squareness"]


def available_effects():
    """Effect classes by name (see :func:`cmmpose.effects.available`)."""
    return available()


def parse_effect(text: str) -> Effect:
    """``NAME:param=value,param=value`` (CLI form) -> an effect."""
    return parse(text)


def inert(effect: Effect) -> str | None:
    """Why ``effect`` would simulate nothing, or None when it acts (or may).

    An effect is inert when every number it holds is at its default and those
    defaults do nothing: all its model parameters zero (a zero magnitude:
    ``latency`` with ``seconds`` 0, ``scale`` with x, y, z 0), or all its
    scenario fields zero (``axis-temperature`` with no axis warmer than the
    mean, ``granite-gradient`` with no gradient). An effect given some number
    other than its default is the caller's choice and is not judged.

    Returns
    -------
    str or None
        The reason, naming the fields and an example that acts.
    """
    cls = type(effect)
    numbers = [f for f in fields(cls) if f.name not in cls.text_fields()]
    if any(getattr(effect, f.name) != f.default for f in numbers):
        return None
    defaults = {f.name: f.default for f in numbers}
    units = cls.units()
    scenario = [n for n in getattr(cls, "scenario_units", {}) if n in defaults]
    if cls.params and all(defaults.get(n) == 0 for n in cls.params):
        group, example = list(cls.params), f"{cls.name}:{next(iter(cls.params))}={cls.params[next(iter(cls.params))].prior:g}"
    elif scenario and all(defaults[n] == 0 for n in scenario):
        group, example = scenario, f"{cls.name}:{scenario[0]}=1"
    else:
        return None
    named = ", ".join(f"{n} ({units[n]})" if units.get(n) else n for n in group)
    if len(group) == 1:
        return f"{cls.name} simulates nothing with {named} at 0 (its default): give it, e.g. {example}"
    return f"{cls.name} simulates nothing with {named} all at 0 (their defaults): give one, e.g. {example}"
