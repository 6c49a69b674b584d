"""The schema of an artefact file (TOML, :func:`cmmpose.artefacts.load_artefact`,
docs/artefacts.md), also the ``artefact.definition`` a run embeds. Its
ranges are the loader's (a reference temperature within 0..40 C, an
expansion within -1..30 ppm/K, defined in :mod:`cmmpose.artefacts`); the
loader keeps the checks a schema cannot state (a calibrated radius within
5 % of the nominal, balls a diameter apart, each id once, a kind's ball
count)."""

from __future__ import annotations

from pathlib import Path

from .._registry import discover
from ._common import DRAFT, ID_BASE, INT64, LENGTH_MM, NO_CONTROL, array, integer, number, obj, own_words, \
    text, triple

__all__ = ["schema", "definition", "EXPANSION_RANGE_PPM", "REFERENCE_TEMPERATURE_RANGE_C", "MAX_BALLS", "MAX_RADIUS_MM", "MIN_RADIUS_MM", "MAX_U_UM"]

#: Coefficients of expansion accepted, ppm/K: Zerodur and carbon fibre (about 0,
#: slightly negative) to aluminium (23) and a margin.
EXPANSION_RANGE_PPM = (-1.0, 30.0)
#: Certificate reference temperatures accepted, degrees C.
REFERENCE_TEMPERATURE_RANGE_C = (0.0, 40.0)
#: Most balls an artefact may hold: the largest plates hold some 100; 1,000 keeps every check of the
#: balls' spacing within memory.
MAX_BALLS = 1_000
#: Largest ball radius, mm.
MAX_RADIUS_MM = 1e4
#: Smallest ball radius, mm (a sphere a line scanner can measure: 0.1 mm; 5e-324 mm is a typo).
MIN_RADIUS_MM = 0.1
#: Largest standard uncertainty of a centre or a radius, um (1 cm).
MAX_U_UM = 1e4


def definition() -> dict:
    """The artefact's object (without ``$schema``): embedded as a run's ``artefact.definition`` too."""
    from ..artefacts.base import ArtefactKind  # on first use: the artefacts package imports this module

    package = Path(__file__).resolve().parents[1] / "artefacts"
    kinds = sorted(discover("cmmpose.artefacts", [str(package)], ArtefactKind, "kind", "artefact kind"))

    u = own_words(number(0.0, MAX_U_UM, "um"), "{path} = {value} is not a standard uncertainty: must be >= 0 um "
                  f"and at most {MAX_U_UM:g} um")
    ball = obj({
        "id": integer(1, INT64[1], "the ball's number (>= 1, fits a C long)"),
        "xyz_mm": triple(number(-LENGTH_MM, LENGTH_MM, "mm"), "the calibrated centre [x, y, z], mm"),
        "u_um": triple(u, "its standard uncertainties [ux, uy, uz], um"),
    }, ["id", "xyz_mm", "u_um"])
    return obj({
        "kind": {"enum": kinds, "description": "the artefact kind (cmmpose artefact kinds)"},
        "name": text("what the artefact is called"),
        "certificate": {"type": "string", "minLength": 1, "maxLength": 100_000, "pattern": NO_CONTROL},
        "reference_temperature_C": own_words(
            number(*REFERENCE_TEMPERATURE_RANGE_C, "C", "the certificate's reference temperature"),
            "{path} = {value} is outside " + "{:g}..{:g} C".format(*REFERENCE_TEMPERATURE_RANGE_C)),
        "expansion_ppm_per_K": own_words(
            number(*EXPANSION_RANGE_PPM, "ppm/K"),
            "{path} = {value} is not physical: a solid's coefficient of expansion is between "
            + "{:g} and {:g} ppm/K (steel 11.5, Invar 1, Zerodur 0)".format(*EXPANSION_RANGE_PPM)),
        "radius": obj({
            "nominal_mm": number(MIN_RADIUS_MM, MAX_RADIUS_MM, "mm"),
            "calibrated_mm": number(MIN_RADIUS_MM, MAX_RADIUS_MM, "mm"),
            "u_um": u,
        }, ["nominal_mm", "calibrated_mm", "u_um"], description="nominal_mm, calibrated_mm, u_um"),
        "balls": array(ball, 1, MAX_BALLS, "a list of { id = 1, xyz_mm = [x, y, z], u_um = [ux, uy, uz] }"),
    }, ["kind", "name", "certificate", "reference_temperature_C", "expansion_ppm_per_K", "radius", "balls"])


def schema() -> dict:
    """The artefact file's schema (draft 2020-12)."""
    return {"$schema": DRAFT, "$id": ID_BASE + "artefact", "title": "cmmpose artefact file",
            "description": "A calibration certificate of an artefact (docs/artefacts.md). Units: mm, um, ppm/K, "
                           "degrees C.", **definition()}
