"""The schema of a run's header, ``run.json`` (:meth:`cmmpose.Run.load`,
docs/formats.md). The tables beside it (points, scans, poses, temperatures)
are columns, checked by the run's own reader; ``artefact``, ``maps`` and
``metadata`` are free records whose known keys are typed here."""

from __future__ import annotations

from .. import _core
from ..effects import channel_roles
from ._common import DRAFT, ID_BASE, LENGTH_MM, MAX_ITEMS, NO_CONTROL, array, integer, number, obj, text
from .artefact import definition
from .model import record

__all__ = ["schema", "MAX_ROWS", "SCHEMA", "SCHEMA_VERSION", "SUPPORTED_SCHEMA_VERSIONS", "CHANNEL_ROLES", "TABLES", "SWEEP_AXES"]

#: Value of ``schema`` in run.json.
SCHEMA = "cmmpose-run"
#: Schema version written by :meth:`cmmpose.Run.save`.
SCHEMA_VERSION = 1
#: Schema versions :meth:`cmmpose.Run.load` reads.
SUPPORTED_SCHEMA_VERSIONS = (1,)
#: Allowed ``role`` of a temperature channel: the machine's own, then those
#: the physical effects bring (e.g. 'mount'; see :mod:`cmmpose.effects`).
CHANNEL_ROLES = ("x_scale", "y_scale", "z_scale", "granite_top", "granite_bottom", "air", "part", "other",
                 *channel_roles())
#: The axes a scan may sweep (the scans table's ``sweep_axis``).
SWEEP_AXES = ("X", "Y", "Z")
#: The tables of a run directory, beside run.json.
TABLES = ("points", "scans", "poses", "temperatures")
#: Most rows a table may say it holds (2^53: every count a float holds exactly; memory gives out long before).
MAX_ROWS = 2**53


def artefact_record(description: str) -> dict:
    """The ``artefact`` table of a run (and of a plan, which copies it into run.json): free, its sizes typed;
    ``#/$defs/record`` and ``#/$defs/artefact`` must be defined beside it."""
    size = number(0.0, LENGTH_MM, "mm", exclusive_lo=True)
    rec = {"$ref": "#/$defs/record"}
    return obj({
        "kind": text("the artefact kind"),
        "name": text(),
        "ball_radius_mm": size,
        "calibrated_length_mm": size,
        "calibrated_radius_mm": size,
        "reference_sphere": obj({"radius_mm": size}, closed=False, additionalProperties=rec),
        "definition": {"$ref": "#/$defs/artefact"},
    }, closed=False, additionalProperties=rec, description=description)


def maps_record(description: str) -> dict:
    """The ``maps`` table of a run (and of a plan): which error maps apply."""
    return obj({
        "kind": text(),
        "name": text(),
        "kinematics": {"enum": [c["name"] for c in _core.kinematics_configurations()]},
    }, closed=False, additionalProperties={"$ref": "#/$defs/record"}, description=description)


def schema() -> dict:
    """The run.json schema (draft 2020-12)."""
    rec = {"$ref": "#/$defs/record"}
    artefact = artefact_record("the artefact measured (free, its sizes typed)")
    maps = maps_record("which error maps apply, e.g. bundled thesis")
    channel = obj({"name": text("the column of the temperatures table"), "role": {"enum": list(CHANNEL_ROLES)}},
                  ["name", "role"], closed=False, additionalProperties=rec)
    body = obj({
        "schema": {"const": SCHEMA},
        "schema_version": {"enum": list(SUPPORTED_SCHEMA_VERSIONS)},
        "created": {"type": "string", "minLength": 1, "maxLength": 100, "pattern": NO_CONTROL,
                    "description": "ISO-8601 UTC time"},
        "artefact": artefact,
        "maps": maps,
        "temperature_channels": array(channel, 0, MAX_ITEMS),
        "metadata": {"type": "object", "additionalProperties": rec},
        "rows": {"type": "object", "description": "each table's row count, checked against the table",
                 "propertyNames": {"enum": list(TABLES), "x-template": "'rows' names an unknown table {value} "
                                                                       f"(tables: {', '.join(TABLES)})"},
                 "additionalProperties": {**integer(0, MAX_ROWS), "x-template": "'rows' must be an object of table "
                                          "name -> row count (a whole number >= 0 and at most 2^53): {path} is "
                                          "{value}"}},
    }, ["schema", "schema_version", "created"])
    return {"$schema": DRAFT, "$id": ID_BASE + "run", "title": "cmmpose run.json",
            "description": "The header of a measurement run directory (docs/formats.md).", **body,
            "$defs": {"record": record(), "artefact": definition()}}
