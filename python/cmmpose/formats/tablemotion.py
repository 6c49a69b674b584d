"""A moving table's own measured motion turned into map components
(docs/conventions.md, "The compensation": moving tables).

Map components are the probe's motion relative to the part. An instrument
riding on a moving table (an interferometer's optics, a level) reads the
table's own motion relative to the base instead: its translation d_T at the
point r_T where it was measured and its rotation eps_T. The part is fixed to
the table at p, so the probe relative to the part moves by

    d_map = -(d_T + eps_T x (p - r_T)),      eps_map = -eps_T

to first order in the angles (the truth machine's rotation differs from the
small-angle cross product by |eps|^2 |p - r_T| / 2: below 1 nm for 10
arc-seconds over 500 mm). The table's yaw and roll swing the part point under
the probe: a first-order term, micrometres for arc-seconds over hundreds of
mm, which a map imported without this conversion misses. Lengths in mm,
deltas in um, angles in arc-seconds, as in the map tables.
"""

from __future__ import annotations

import numpy as np

from .._arrays import as_triple
from ..errormap import CARRIAGES, ErrorMap
from ..errors import InputError, InputTypeError

__all__ = ["table_motion_to_map"]

_ARCSEC = np.pi / 648000.0  # rad per arc-second


def _check_near_travel(error_map: ErrorMap, what: str, flag: str, point: np.ndarray) -> None:
    """``InputError`` when ``point`` (mm) lies farther beyond the map's travel (its X, Y, Z ranges) than the
    travel's largest size: a point on a table rides within the travel (the table's frame may sit anywhere in
    it, and the part overhang the table), so one a whole travel beyond is a typo or a unit mix-up, whose
    lever would swing the map by the angles times kilometres."""
    ranges = np.asarray(error_map.ranges, dtype=float)  # (3, 2): lo, hi per axis, mm
    margin = float(np.max(ranges[:, 1] - ranges[:, 0]))
    for axis, v, (lo, hi) in zip(CARRIAGES, point, ranges):
        if not lo - margin <= v <= hi + margin:
            raise InputError(f"{what}: {axis} {v:g} mm is far outside the map's travel {axis} {lo:g}..{hi:g} mm "
                             f"(more than its largest size, {margin:g} mm, beyond it): a point on the table is "
                             "within the travel; is it in mm, in the table's frame?",
                             what=what, value=float(v), allowed=(lo - margin, hi + margin), unit="mm", option=what,
                             cli_option=flag)


def table_motion_to_map(error_map: ErrorMap, carriage: str, measured_at, part_point) -> ErrorMap:
    """The map of a machine whose ``carriage`` table holds a moving table's
    own measured motion, converted into map components.

    Parameters
    ----------
    error_map : ErrorMap
        A map whose ``carriage`` table holds the table's own motion as an
        instrument riding on it read it (deltas in um at ``measured_at``,
        angles in arc-seconds); the other carriages and the squareness are
        map components already and are kept.
    carriage : {'X', 'Y', 'Z'}
        The carriage that carries the part.
    measured_at : sequence of 3 float
        r_T: where on the table the translations were measured, mm, in the
        table's frame (the frame the part point is given in).
    part_point : sequence of 3 float
        p: where the part sits on the table, mm, same frame. The converted
        map is exact (to first order) for points there; a part far from it
        sees the angles times the distance, as on any machine.

    Returns
    -------
    ErrorMap
        A new map (the input is not modified): for ``carriage``,
        d = -(d_T + eps_T x (p - r_T)) and eps = -eps_T.

    Raises
    ------
    InputError
        A point farther beyond the map's travel than the travel's largest
        size (``option`` and ``cli_option`` name it).
    """
    if not isinstance(error_map, ErrorMap):
        raise InputTypeError(f"error_map: expected an ErrorMap, got {type(error_map).__name__}", option="error_map")
    name = str(carriage).upper()
    if name not in CARRIAGES:
        raise InputError(f"carriage: expected X, Y or Z, got {carriage!r}", option="carriage",
                         cli_option="--carriage")
    r_t = np.array(as_triple("measured_at", measured_at))
    p = np.array(as_triple("part_point", part_point))
    for what, flag, point in (("measured_at", "--measured-at", r_t), ("part_point", "--part-point", p)):
        _check_near_travel(error_map, what, flag, point)
    lever = p - r_t  # mm
    tables = {c: error_map.table(c).copy() for c in CARRIAGES}
    t = tables[name]
    d_t, eps_t = t[:, 1:4], t[:, 4:7]  # um, arc-seconds
    swing = np.cross(eps_t * _ARCSEC, lever) * 1000.0  # rad x mm -> um
    t[:, 1:4] = -(d_t + swing)
    t[:, 4:7] = -eps_t
    converted = ErrorMap(tables["X"], tables["Y"], tables["Z"], error_map.squareness, error_map.temperature,
                         source=f"{error_map.source or 'map'}: carriage {name} converted from the table's own motion "
                                f"(measured at {tuple(r_t.tolist())} mm, part at {tuple(p.tolist())} mm)")
    return converted.with_kinematics(error_map.kinematics)
