"""The schema of an alignment library (JSON, :class:`cmmpose.calibration.AlignmentLibrary`,
docs/calibration.md): one record per trunnion pose name. Its ranges are the
physical bounds; the library keeps its own checks that go further (a
covariance symmetric positive semi-definite and agreeing with its standard
uncertainties, an ISO 8601 date, the ``units`` it writes)."""

from __future__ import annotations

from ._common import (ANGLE_DEG, DRAFT, ID_BASE, LENGTH_MM, MAX_ITEMS, NO_CONTROL, TEMPERATURE_C, array, nullable,
                      number, obj, text, triple)

__all__ = ["schema", "LIBRARY_FORMAT", "LIBRARY_VERSION", "FIELDS", "OFFSET_LIMIT_MM", "MAX_READING_U_MM",
           "MAX_POSE_U_DEG", "MAX_LEVER", "MAX_JACOBIAN_MM_PER_DEG"]

#: Value of ``format`` in an alignment library.
LIBRARY_FORMAT = "cmmpose-alignment-library"
#: The one version read and written.
LIBRARY_VERSION = 1
#: The fields of a pose's record, in the order written.
FIELDS = ("pose", "reading", "offset", "pose_uncertainty", "reading_uncertainty", "offset_uncertainty",
          "temperature", "date", "residuals", "note", "pose_covariance", "reading_covariance", "pose_jacobian",
          "position", "lever", "offset_covariance")
#: |U1|, |V1|, |W1|, mm (as a machine file's mount offset).
OFFSET_LIMIT_MM = 10_000.0
#: Largest standard uncertainty of a reading or an offset, mm (a metre: a unit slip beyond).
MAX_READING_U_MM = 1_000.0
#: Largest standard uncertainty of a pose angle, degrees.
MAX_POSE_U_DEG = 90.0
#: |element| of a record's lever (d sphere centre / d(-offset), 1: a rotation's is within 1).
MAX_LEVER = 1_000.0
#: |element| of a pose Jacobian, mm/degree (a lever of 57 m at 1 mm/degree per metre).
MAX_JACOBIAN_MM_PER_DEG = 1e3


def _matrix(bound: float, unit: str, description: str) -> dict:
    """A 3 x 3 matrix of numbers within +-``bound`` in ``unit``, or null."""
    return nullable(triple(triple(number(-bound, bound, unit)), description))


def record() -> dict:
    """One pose's record (``poses.<name>``)."""
    mm = number(-LENGTH_MM, LENGTH_MM, "mm")
    return obj({
        "pose": triple(number(-ANGLE_DEG, ANGLE_DEG, "degree"), "alpha, beta, gamma, degrees (Euler 3-1-3)"),
        "reading": triple(mm, "D0, E0, F0: the scale reading with the laser origin at the sphere centre, mm"),
        "offset": triple(number(-OFFSET_LIMIT_MM, OFFSET_LIMIT_MM, "mm"), "the mount offset U1, V1, W1, mm"),
        "pose_uncertainty": nullable(triple(number(0.0, MAX_POSE_U_DEG, "degree"), "degrees")),
        "reading_uncertainty": nullable(triple(number(0.0, MAX_READING_U_MM, "mm"), "the reading's own, mm")),
        "offset_uncertainty": nullable(triple(number(0.0, MAX_READING_U_MM, "mm"), "mm")),
        "temperature": nullable(number(*TEMPERATURE_C, "C", "machine temperature during the alignment, C")),
        "date": {"type": "string", "minLength": 1, "maxLength": 100, "pattern": NO_CONTROL,
                 "description": "when it was aligned, ISO 8601"},
        "residuals": {"type": "object", "propertyNames": text(), "maxProperties": MAX_ITEMS,
                      "additionalProperties": number(-LENGTH_MM, LENGTH_MM, "mm"),
                      "description": "fit residuals worth keeping, mm"},
        "note": {"type": "string", "maxLength": 100_000, "pattern": NO_CONTROL},
        "pose_covariance": _matrix(MAX_POSE_U_DEG**2, "degree^2", "covariance of alpha, beta, gamma"),
        "reading_covariance": _matrix(MAX_READING_U_MM**2, "mm^2", "covariance of D0, E0, F0 (the reading's own)"),
        "pose_jacobian": _matrix(MAX_JACOBIAN_MM_PER_DEG, "mm/degree", "d reading / d pose"),
        "position": nullable(triple(mm, "the mount point's position, mm")),
        "lever": _matrix(MAX_LEVER, "1", "d sphere centre / d(-offset)"),
        "offset_covariance": _matrix(MAX_READING_U_MM**2, "mm^2", "covariance of U1, V1, W1 (the mount-offset fit's)"),
    }, ["pose", "reading", "offset"], description="the stored alignment of one trunnion pose")


def schema() -> dict:
    """The alignment library's schema (draft 2020-12)."""
    units = {"type": "string", "minLength": 1, "maxLength": 1_000, "pattern": NO_CONTROL}
    body = obj({
        "format": {"const": LIBRARY_FORMAT},
        "version": {"const": LIBRARY_VERSION},
        "units": obj({k: units for k in FIELDS if k not in ("note",)}, description="field -> unit, as written"),
        "poses": {"type": "object", "propertyNames": text("a trunnion pose's name, e.g. A90B90"),
                  "maxProperties": MAX_ITEMS, "additionalProperties": {"$ref": "#/$defs/record"},
                  "description": "pose name -> its record"},
    }, ["format", "version", "poses"])
    return {"$schema": DRAFT, "$id": ID_BASE + "alignments", "title": "cmmpose alignment library",
            "description": "The alignments of trunnion poses, by name (docs/calibration.md; `cmmpose calibrate "
                           "alignment --library`, `calibrate offset --store`). Units: degrees, mm, degrees C.",
            **body, "$defs": {"record": record()}}
