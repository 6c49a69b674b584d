"""Evaluations in the terms of the standards a customer, an auditor or an
acceptance test asks for (docs/standards.md):

- :mod:`.iso230_2`: positioning accuracy and repeatability of an axis (ISO 230-2:2014);
- :mod:`.acceptance`: optical probing and length tests in the manner of ISO 10360-8,
  decided against MPEs by an ISO 14253-1 style rule;
- :mod:`.interim`: squareness and scale from one ballbar run;
- :mod:`.e3125_distances`: sphere-centre distance errors in the manner of ASTM E3125.
"""

from .acceptance import MPE, AcceptanceResult, Check, acceptance_test, decide, parse_mpe, probing_test
from .e3125_distances import DistanceResult, E3125Distances, SphereTarget, distance_errors, read_pairs, sphere_targets
from .interim import InterimCheck, InterimValue, interim_check
from .iso230_2 import (
    PositioningData,
    PositioningError,
    PositioningResult,
    TargetResult,
    evaluate_iso230_2,
    load_positioning,
    positioning_from_interferometer,
    read_positioning_csv,
)

__all__ = [
    "DistanceResult",
    "E3125Distances",
    "SphereTarget",
    "distance_errors",
    "read_pairs",
    "sphere_targets",
    "MPE",
    "AcceptanceResult",
    "Check",
    "acceptance_test",
    "decide",
    "parse_mpe",
    "probing_test",
    "InterimCheck",
    "InterimValue",
    "interim_check",
    "PositioningData",
    "PositioningError",
    "PositioningResult",
    "TargetResult",
    "evaluate_iso230_2",
    "load_positioning",
    "positioning_from_interferometer",
    "read_positioning_csv",
]
