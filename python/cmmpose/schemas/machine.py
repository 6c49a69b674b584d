"""The schema of a machine file (TOML, :func:`cmmpose.machine.load_machine`,
docs/your-machine.md). Its ranges are the physical bounds; the loader keeps
its own checks that go further (a travel's low end below its high end, one
of ``maps.bundled`` and ``maps.files``, map files that exist)."""

from __future__ import annotations

from .. import _core
from .._validate import MAX_REPRODUCIBILITY_MM
from ..effects import channel_roles
from ._common import ANGLE_DEG, DRAFT, ID_BASE, MAX_ITEMS, NO_CONTROL, array, integer, number, obj, own_words, \
    pair, text, triple

__all__ = ["schema", "CHANNELS", "TRAVEL_LIMIT_MM", "OFFSET_LIMIT_MM", "EXPANSION_RANGE_PPM", "MAX_POINTS_PER_PROFILE", "MAX_PROFILE_RATE_HZ", "MAX_NOISE_UM", "MAX_FIELD_MM"]

#: The thesis machine's thermocouple channels (name, role), in log order.
CHANNELS = (
    ("X1", "x_scale"), ("X2", "x_scale"), ("X3", "x_scale"),
    ("Y1", "y_scale"), ("Y2", "y_scale"), ("Y3", "y_scale"),
    ("Z1", "z_scale"), ("Z2", "z_scale"), ("Z3", "z_scale"),
    ("GT", "granite_top"), ("GB", "granite_bottom"),
)  # fmt: skip
#: Physical ranges of a machine file's numbers, in the file's units; a value
#: outside is a typo or a unit error and is refused, naming the key.
TRAVEL_LIMIT_MM = 100_000.0  # |scale reading|; the largest CMMs travel some 30 m
OFFSET_LIMIT_MM = 10_000.0  # |U1|, |V1|, |W1|
#: Expansion coefficient of an artefact, ppm/K: from carbon fibre and glass
#: ceramics (slightly negative to zero) to the light metals (~25) and beyond.
EXPANSION_RANGE_PPM = (-1.0, 100.0)
#: Most points a scanner gives per profile (a line of 1e6 points is beyond any sensor).
MAX_POINTS_PER_PROFILE = 1_000_000
#: Fastest profile rate, Hz.
MAX_PROFILE_RATE_HZ = 1e6
#: Largest scanner noise, um (1 cm: a unit slip beyond).
MAX_NOISE_UM = 1e4
#: |field or depth of view|, mm.
MAX_FIELD_MM = 1e4


def schema() -> dict:
    """The machine file's schema (draft 2020-12)."""
    travel = pair(own_words(number(-TRAVEL_LIMIT_MM, TRAVEL_LIMIT_MM, "mm"),
                            f"{{parent}}: {{value}} mm is beyond +-{TRAVEL_LIMIT_MM:g} mm"), "[low, high] in mm")
    offset = own_words(own_words(number(-OFFSET_LIMIT_MM, OFFSET_LIMIT_MM, "mm"),
                                 f"{{parent}}: {{value}} mm is beyond +-{OFFSET_LIMIT_MM:g} mm"),
                       "{parent}: expected three numbers [U1, V1, W1], got {value} as {item}", ["type"])
    offset["x-item-names"] = ["U1", "V1", "W1"]
    angle = own_words(number(-ANGLE_DEG, ANGLE_DEG, "degree"),
                      f"{{parent}}: pose angle {{item}} = {{value}} deg is beyond +-{ANGLE_DEG:g} deg (angles are in "
                      "degrees)")
    angle["x-item-names"] = ["alpha", "beta", "gamma"]
    lo, hi = EXPANSION_RANGE_PPM
    expansion = own_words(own_words(number(lo, hi, "ppm/K"), f"{{path}} = {{value}} ppm/K is outside {lo:g}..{hi:g} "
                                    "ppm/K (a coefficient of expansion in ppm/K, e.g. 11.5 for steel)"),
                          "{path}: expected a finite number, got {value}", ["type"])
    field = pair(number(-MAX_FIELD_MM, MAX_FIELD_MM, "mm"), "[low, high], mm")
    kinematics = [c["name"] for c in _core.kinematics_configurations()]
    roles = sorted({r for _, r in CHANNELS} | set(channel_roles()))
    body = obj({
        "name": text("what the machine is called"),
        "kinematics": {"enum": kinematics, "description": f"one of {', '.join(kinematics)}: how the carriages are "
                                                         "stacked"},
        "travel": obj({a: travel for a in "xyz"}, "xyz", description="x, y, z = [low, high] in mm"),
        "maps": obj({
            "bundled": {"enum": ["thesis", "appendix-b"]},
            "files": array({"type": "string", "minLength": 1, "maxLength": 4096, "pattern": NO_CONTROL}, 1,
                           MAX_ITEMS, "map files, relative to the machine file"),
        }, description="bundled = 'thesis' | 'appendix-b' or files = [...]"),
        "scanner": obj({
            "field_of_view_mm": field,
            "depth_of_view_mm": field,
            "points_per_profile": integer(2, MAX_POINTS_PER_PROFILE),
            "profile_rate_hz": number(0.0, MAX_PROFILE_RATE_HZ, "Hz", exclusive_lo=True),
            "noise_um": number(0.0, MAX_NOISE_UM, "um"),
        }, description="the scanner's optics and noise"),
        "mount": obj({
            "offset_mm": triple(offset, "[U1, V1, W1], mm"),
            "pose_deg": triple(angle, "[alpha, beta, gamma], degrees"),
            "alignments": {"type": "string", "minLength": 1, "maxLength": 4096, "pattern": NO_CONTROL},
        }, ["offset_mm", "pose_deg"], description="offset_mm = [U1, V1, W1] and pose_deg = [alpha, beta, gamma]",
            **{"x-messages": {"required": "{missing} is missing ({hint})"}}),
        "thermocouples": {"type": "object", "minProperties": 1, "maxProperties": MAX_ITEMS,
                          "propertyNames": text(), "additionalProperties": {"enum": roles, "x-what": "role"},
                          "description": "channel = 'role' for each thermocouple"},
        "expansion": obj({"artefact": expansion}),
        "uncertainty": obj({
            "position_um": triple(triple(number(0.0, 1000.0, "um")), "[carriage X, Y, Z][dx, dy, dz], um"),
            "rotation_arcsec": triple(triple(number(0.0, 3600.0, "arc-second")),
                                      "[carriage X, Y, Z][ex, ey, ez], arc-seconds"),
            "squareness_arcsec": triple(number(0.0, 3600.0, "arc-second"), "S_xy, S_yz, S_zx, arc-seconds"),
            "positioning_ppm": triple(number(0.0, 1000.0, "ppm"), "X's dx, Y's dy, Z's dz: ppm of the distance"),
            "reference_mm": triple(number(-TRAVEL_LIMIT_MM, TRAVEL_LIMIT_MM, "mm"), "where each axis was zeroed"),
            "source": {"type": "string", "maxLength": 100_000, "pattern": NO_CONTROL},
        }, description="the maps' stated standard uncertainty (k = 1) per component (docs/uncertainty.md, "
                       "section 5)"),
        "reproducibility": obj({
            # The loader's own words (cmmpose._validate.check_reproducibility), which commands and tests quote.
            "per_scan_um": own_words(own_words(
                number(0.0, MAX_REPRODUCIBILITY_MM * 1e3, "um", exclusive_lo=True,
                       description="the per-scan centre reproducibility, um per axis"),
                "{path}: expected a positive number of um, got {given}", ("exclusiveMinimum", "type")),
                f"{{path}}: {{value}} um per axis is implausible for a sphere centre (more than "
                f"{MAX_REPRODUCIBILITY_MM * 1e3:g} um, ten times a whole uncompensated machine's errors): a unit "
                "slip? (um expected)", ("maximum",)),
            "source": own_words({"type": "string", "maxLength": 100_000, "pattern": NO_CONTROL},
                                "{path} must be a non-empty text, got {given}", ("type",)),
        }, ["per_scan_um"], **{"x-messages": {
            "required": "{missing} is missing (the per-scan centre reproducibility, um per axis, from a repeat test: "
                        "cmmpose machine reproducibility)"}}),
    }, ["travel", "maps", "mount", "thermocouples", "kinematics"],
        **{"x-messages": {"required": "{header} is missing ({hint}); a machine file states it (cmmpose machine "
                                      "example)"}})
    return {"$schema": DRAFT, "$id": ID_BASE + "machine", "title": "cmmpose machine file",
            "description": "One CMM with its scanner (docs/your-machine.md). Units: mm, um, degrees, degrees C, "
                           "ppm/K.", **body}
