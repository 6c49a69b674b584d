"""The schema of a saved model file (JSON, :meth:`cmmpose.Model.save`).

Each library effect's parameters are bounded by their unit
(:data:`UNIT_BOUNDS`): a squareness of 1e30 arc-seconds, a scale of 1e9 ppm
or an alignment of 1e4 degrees is refused by name, where the model would
otherwise compensate points by metres. A user-defined effect's parameters
(units the schema cannot know) are bounded by :data:`USER_PARAMETER_BOUND`.
"""

from __future__ import annotations

import re

from .. import _core
from .. import effects as effects_registry
from ..temperature.policy import BROKEN_CHANNELS, ON_GAP, OUT_OF_RANGE
from ._common import (ANGLE_DEG, DRAFT, ID_BASE, LENGTH_MM, MAX_ITEMS, NO_CONTROL, TEMPERATURE_C, array,
                      integer, nullable, number, obj, pair, text, triple)

__all__ = ["MODEL_SCHEMA", "UNIT_BOUNDS", "USER_PARAMETER_BOUND", "UNCERTAINTY_BOUND", "record", "schema"]

#: ``schema`` of a saved model file.
MODEL_SCHEMA = "cmmpose-model"
#: |parameter| of a library effect, by its unit: beyond any CMM by a wide margin, within what a unit slip gives.
UNIT_BOUNDS = {
    "degree": ANGLE_DEG,  # an alignment: one turn
    "arc-second": 3600.0,  # a squareness or a map's angle: one degree
    "arc-second/K": 3600.0,  # a granite gradient's tilt per kelvin
    "arc-second/m": 3600.0,  # a roll per metre of travel
    "ppm": 1e4,  # a scale error: 1 %
    "ppm/K": 1e3,  # an expansion: ten times a plastic's
    "mm": 1e4,  # a mount offset's correction: 10 m
    "um": 1e5,  # a map's translation correction: 10 cm
    "s": 3600.0,  # a latency: one hour
    "1": 1e3,  # a gain or a relative scale
    "mm/degree": 1e3,  # an incidence term
    "1/degree": 1e3,
}
#: |parameter| of a user-defined effect (its units are its own).
USER_PARAMETER_BOUND = 1e12
#: Largest standard uncertainty of a parameter, in its units (larger: say null, "not determined").
UNCERTAINTY_BOUND = 1e12
#: Suffix of a map or cross-axis correction's parameter name -> its unit (cmmpose.model.mapshape, crossaxis).
_SUFFIX_UNITS = {"_um": "um", "_as": "arc-second"}
_MAX_EFFECTS = 1_000
_MAX_MAPS = 1_000

#: A JSON value kept as a record (a log's provenance, free metadata): any shape, numbers bounded.
RECORD_BOUND = 1e15


def record(ref: str = "#/$defs/record") -> dict:
    """Any JSON value, nested lists and tables of it; every number within +-:data:`RECORD_BOUND`."""
    return {"type": ["object", "array", "string", "number", "boolean", "null"],
            "minimum": -RECORD_BOUND, "maximum": RECORD_BOUND, "maxItems": MAX_ITEMS,
            "items": {"$ref": ref}, "additionalProperties": {"$ref": ref},
            "description": "a record: any JSON value, every number within +-1e15"}


def _parameter(unit: str) -> dict:
    bound = UNIT_BOUNDS.get(unit, USER_PARAMETER_BOUND)
    return number(-bound, bound, unit)


def _uncertainty() -> dict:
    return {**nullable(number(0.0, UNCERTAINTY_BOUND, "", "standard uncertainty (k = 1) in the parameter's unit; "
                                                          "null: not determined")),
            "x-template": "effect {name}: the uncertainty of parameter {key!r} ({path}) is {value}; expected a "
                          f"standard uncertainty >= 0 and at most {UNCERTAINTY_BOUND:g} in the parameter's unit, or "
                          "null for a parameter the data did not determine"}


def _library_rules() -> list[dict]:
    """One if/then per library effect: its parameters bounded by their units (variants 'name@...' too)."""
    rules = []
    for name, effect in sorted(effects_registry.available().items()):
        params = {p: _parameter(param.unit) for p, param in effect.params.items()}
        rules.append({"if": {"properties": {"name": {"pattern": f"^{re.escape(name)}(@.*)?$"}}, "required": ["name"]},
                      "then": {"properties": {"params": {"properties": params}}}})
    suffixed = {f"{re.escape(s)}$": _parameter(u) for s, u in _SUFFIX_UNITS.items()}
    rules.append({"if": {"properties": {"name": {"pattern": "^(map|cross):"}}, "required": ["name"]},
                  "then": {"properties": {"params": {"patternProperties": suffixed}}}})
    return rules


def _effect() -> dict:
    generic = number(-USER_PARAMETER_BOUND, USER_PARAMETER_BOUND, "")
    return obj({
        "name": text("the effect's name (cmmpose effects list), a map or cross-axis correction's, or a user effect's"),
        "kind": {"enum": ["kernel", "pose", "length", "python"], "description": "how the effect acts"},
        "params": {"type": "object", "additionalProperties": generic, "maxProperties": MAX_ITEMS,
                   "description": "each parameter's value in its unit"},
        "units": {"type": "object", "additionalProperties": text(), "maxProperties": MAX_ITEMS},
        "uncertainty": {"type": "object", "additionalProperties": _uncertainty(), "maxProperties": MAX_ITEMS},
    }, ["name", "params"], allOf=_library_rules())


def _alternative() -> dict:
    effect = _effect()
    effect["properties"] |= {
        "chosen": text("the effect of the model this one could not be told from"),
        "in_sample_difference_um": number(0.0, 1e9, "um"),
        "warn_above_um": nullable(number(0.0, 1e9, "um")),
        "reason": {"type": "string", "maxLength": 100_000, "pattern": NO_CONTROL},
    }
    effect["required"] = ["chosen", "name", "params"]
    return effect


def _policy() -> dict:
    return obj({
        "out_of_range": {"enum": list(OUT_OF_RANGE)},
        "temperature_tolerance_K": number(0.0, 200.0, "K"),
        "log_hold_s": number(0.0, 1e9, "s"),
        "on_gap": {"enum": list(ON_GAP)},
        "max_gap_s": nullable(number(0.0, 1e9, "s", exclusive_lo=True)),
        "broken_channels": {"enum": list(BROKEN_CHANNELS)},
        "sensors": {"type": "object", "propertyNames": text(), "maxProperties": MAX_ITEMS,
                    "additionalProperties": array(text(), 0, MAX_ITEMS)},
    }, description="the temperature policy the model applies (cmmpose.TemperaturePolicy)")


def _domain() -> dict:
    travel = pair(number(-LENGTH_MM, LENGTH_MM, "mm"))
    return obj({
        "kinematics": text(),
        "poses_deg": array(triple(number(-2 * ANGLE_DEG, 2 * ANGLE_DEG, "degree")), 0, MAX_ITEMS),
        "travel_mm": obj({a: travel for a in "XYZ"}, "XYZ"),
        "temperature_C": pair(number(*TEMPERATURE_C, "C")),
        "layouts": array(text(), 0, MAX_ITEMS),
        "runs": integer(1, MAX_ITEMS),
    }, ["kinematics", "poses_deg", "travel_mm", "temperature_C"],
        description="where the model was fitted (cmmpose.model.domain)")


def schema() -> dict:
    """The model file's schema (draft 2020-12)."""
    kinematics = [c["name"] for c in _core.kinematics_configurations()]
    body = obj({
        "schema": {"const": MODEL_SCHEMA},
        "schema_version": {"const": 1},
        "maps": obj({
            "kind": {"enum": ["set", "map"], "description": "a set interpolated in temperature, or one map",
                     "x-template": "{path} must be 'set' or 'map', got {value}"},
            "csv": {**array({"type": "string", "maxLength": 64 << 20}, 1, _MAX_MAPS,
                            "each map as a canonical map CSV (docs/formats.md)"),
                    "x-messages": {"minItems": "{path} lists no map"}},
            "kinematics": {"enum": kinematics, "description": "the machine configuration the maps are stacked for"},
        }, ["kind", "csv"], description="the error maps"),
        "temperature": nullable(number(*TEMPERATURE_C, "C", "machine temperature of every point, C; null: the "
                                       "run's thermocouple log")),
        "out_of_range": {"enum": list(OUT_OF_RANGE)},
        "temperature_tolerance_K": number(0.0, 200.0, "K"),
        "log_hold_s": number(0.0, 1e9, "s"),
        "temperature_policy": _policy(),
        "temperature_log": {"$ref": "#/$defs/record"},
        "effects": array(_effect(), 0, _MAX_EFFECTS, "the effects with their values, in the order added"),
        "alternatives": array(_alternative(), 0, _MAX_EFFECTS),
        "domain": nullable(_domain()),
        "covariance": obj({
            "parameters": array(text(), 0, MAX_ITEMS),
            "matrix": array(array(number(-UNCERTAINTY_BOUND**2, UNCERTAINTY_BOUND**2, ""),
                                  0, MAX_ITEMS), 0, MAX_ITEMS),
        }, ["parameters", "matrix"]),
        "non_finite": array(obj({"key": {"type": "string", "maxLength": 10_000, "pattern": NO_CONTROL},
                                 "value": {"enum": ["inf", "-inf"]}}, ["key", "value"]), 0, MAX_ITEMS),
    }, ["schema", "schema_version", "maps", "effects"])
    return {"$schema": DRAFT, "$id": ID_BASE + "model", "title": "cmmpose model file",
            "description": "A model saved by cmmpose (Model.save, cmmpose diagnose --save-model): error maps plus "
                           "physical effects with their values (docs/diagnosis.md).",
            **body, "$defs": {"record": record()}}
