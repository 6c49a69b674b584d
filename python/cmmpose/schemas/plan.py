"""The schema of an acquisition plan (JSON, :meth:`cmmpose.acquire.plan.Plan.read`,
docs/protocols.md, "Plan"): what the serial streams do not say. Every key
is optional. Its ranges are the physical bounds and the run's column types
(an id fits the int32 column it becomes); the plan keeps its own checks that
go further (each scan's pose among the poses, ids and channels unique, an
artefact plan's balls and placements those of its artefact)."""

from __future__ import annotations

from ._common import ANGLE_DEG, DRAFT, ID_BASE, LENGTH_MM, MAX_ITEMS, array, integer, number, obj, text, triple
from .artefact import definition
from .model import record
from .run import CHANNEL_ROLES, SWEEP_AXES, artefact_record, maps_record

__all__ = ["schema", "INT32", "MAX_SPEED_MM_S", "OFFSET_LIMIT_MM", "MAX_CHANNEL"]

#: The range of an id stored in an int32 column of the run (scan, pose, position, ball).
INT32 = (-(2**31), 2**31 - 1)
#: Fastest sweep, mm/s (10 m/s: beyond any CMM's scanning speed).
MAX_SPEED_MM_S = 1e4
#: |U1|, |V1|, |W1|, mm (as a machine file's mount offset).
OFFSET_LIMIT_MM = 10_000.0
#: Largest multiplexer channel number (slot * 100 + channel).
MAX_CHANNEL = 100_000


def schema() -> dict:
    """The plan's schema (draft 2020-12)."""
    rec = {"$ref": "#/$defs/record"}
    artefact = artefact_record("the artefact measured, copied into run.json")
    maps = maps_record("which error maps apply, copied into run.json")
    offset = number(-OFFSET_LIMIT_MM, OFFSET_LIMIT_MM, "mm")
    angle = number(-ANGLE_DEG, ANGLE_DEG, "degree")
    pose = obj({
        "pose_id": integer(*INT32, "the pose's id (the poses table's int32 column)"),
        "alpha": angle, "beta": angle, "gamma": angle,
        "U1": offset, "V1": offset, "W1": offset,
    }, ["pose_id", "alpha", "beta", "gamma", "U1", "V1", "W1"], description="a row of the poses table")
    scan = obj({
        "scan_id": integer(*INT32, "the scanner's sweep number"),
        "pose_id": integer(*INT32),
        "feature": text("what the sweep measured, e.g. ball"),
        "position": integer(*INT32, "the artefact position or placement"),
        "ball": integer(*INT32),
        "sweep_axis": {"enum": list(SWEEP_AXES)},
        "sweep_direction": {"enum": [1, -1]},
        "sweep_speed": number(0.0, MAX_SPEED_MM_S, "mm/s", exclusive_lo=True),
        "sweep_start_mm": triple(number(-LENGTH_MM, LENGTH_MM, "mm"), "the scale readings D, E, F it starts from"),
        "sweep_length_mm": number(0.0, LENGTH_MM, "mm"),
    }, ["scan_id", "pose_id", "feature", "position", "ball", "sweep_axis", "sweep_direction", "sweep_speed"],
        description="a row of the scans table")
    channel = obj({
        "name": text("the column of the temperatures table"),
        "role": {"enum": list(CHANNEL_ROLES)},
        "channel": integer(1, MAX_CHANNEL, "the multiplexer channel (slot * 100 + channel, e.g. 101)"),
    }, ["name", "role"])
    body = obj({
        "artefact": artefact,
        "maps": maps,
        "metadata": {"type": "object", "propertyNames": text(), "maxProperties": MAX_ITEMS,
                     "additionalProperties": rec},
        "poses": array(pose, 0, MAX_ITEMS, "the poses table (degrees, mm)"),
        "scans": array(scan, 0, MAX_ITEMS, "the scans table, by the scanner's sweep number"),
        "temperature_channels": array(channel, 0, MAX_ITEMS, "the thermocouples, in scan order"),
    })
    return {"$schema": DRAFT, "$id": ID_BASE + "plan", "title": "cmmpose acquisition plan",
            "description": "What the serial streams do not say: poses, scans, thermocouple channels, artefact and "
                           "maps (docs/protocols.md; `cmmpose artefact plan`, `cmmpose acquire --plan`).",
            **body, "$defs": {"record": record(), "artefact": definition()}}
