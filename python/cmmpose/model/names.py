"""The spec of any effect name a model file or a command line holds: a
library effect, its variants ('alignment@3', 'squareness-temperature@z_scale'),
a map correction ('map:dx(X):sine170.2[-120,780]') and a cross-axis
correction ('cross:z(XY):twist[170,730][40,515]')."""

from __future__ import annotations

from ..errors import InputError
from .crossaxis import parse_cross
from .mapshape import parse
from .spec import LIBRARY, EffectSpec, effect_spec, library

__all__ = ["resolve"]


def resolve(name: str) -> EffectSpec:
    """The spec of a library name, variants included: 'alignment@3' (pose 3)
    or 'squareness-temperature@z_scale' (following the z-scale thermocouples)."""
    if isinstance(name, str) and name.startswith("map:"):  # a map correction (cmmpose.model.mapshape)
        return parse(name)
    if isinstance(name, str) and name.startswith("cross:"):  # a cross-axis correction (cmmpose.model.crossaxis)
        return parse_cross(name)
    base, at, suffix = name.partition("@")
    if at and base in LIBRARY:
        try:
            pose = int(suffix)
        except ValueError:
            return effect_spec(name, library(sensors=[suffix]) if LIBRARY[base].sensor_input else LIBRARY)
        return effect_spec(name, library([pose, pose + 1]))  # two poses: library() adds the per-pose specs
    if base in LIBRARY and LIBRARY[base].sensor_input:
        raise InputError(f"effect {name!r} follows a thermocouple group: name it, e.g. '{name}@z_scale' "
                         f"(one of the run's thermocouple roles)")
    return effect_spec(name)
