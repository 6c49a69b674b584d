"""The cross-axis candidates of a run: an error of one direction varying with
two axes' positions together (a twisted table, the sag of a beam with the
carriage on it; :mod:`cmmpose.model.crossaxis`), offered where the runs move
along both axes and, for a sag's curvatures, stand at three levels or more
along each. Their centre-level columns are the map family's
(:func:`cmmpose.diagnosis.mapfamily.cross_columns`).

Units: mm.
"""

from __future__ import annotations

import numpy as np

from ..model.crossaxis import CrossAxisCorrection, make_cross
from .mapfamily import reading_subset, travel_range

__all__ = ["CROSS_HALF_SPAN_MM", "LEVEL_MM", "axis_levels", "cross_candidates"]

#: Half the travel, mm, both axes of a cross-axis candidate must span (the run moves along both).
CROSS_HALF_SPAN_MM = 15.0


#: mm: scans whose mean readings along an axis lie closer than this stand at one level of it.
LEVEL_MM = 10.0


def axis_levels(problem) -> np.ndarray:
    """How many distinct positions (levels, :data:`LEVEL_MM` apart) the runs'
    scans stand at along each axis (their mean scale readings): a curvature
    along an axis needs three."""
    means = []
    for p in getattr(problem, "parts", None) or [problem]:
        sub = reading_subset(p)
        cnt = np.maximum(np.bincount(sub["scan"], minlength=sub["S"]), 1)
        means.append(np.column_stack([np.bincount(sub["scan"], sub["q"][:, a], minlength=sub["S"]) / cnt
                                      for a in range(3)]))
    q = np.sort(np.concatenate(means), axis=0)
    return 1 + np.sum(np.diff(q, axis=0) > LEVEL_MM, axis=0)


def cross_candidates(problem) -> dict[str, CrossAxisCorrection]:
    """The cross-axis candidates for ``problem``: for each direction and each
    pair of axes the runs move along together (:data:`CROSS_HALF_SPAN_MM`),
    a twist, and a sag where the data determine its curvatures (three levels
    or more along both axes: at two heights a bow along Z is a constant, and
    the sag would be a squareness), over the travel used
    (:mod:`cmmpose.model.crossaxis`)."""
    travel = travel_range(problem)
    levels = axis_levels(problem)
    out = {}
    for d in range(3):
        for axes in ((0, 1), (1, 2), (0, 2)):
            span = [travel[a] for a in axes]
            if any((hi - lo) / 2 < CROSS_HALF_SPAN_MM for lo, hi in span):
                continue
            shapes = ("twist", "sag") if all(levels[a] >= 3 for a in axes) else ("twist",)
            for shape in shapes:
                spec = make_cross(d, axes, shape, span)
                out[spec.name] = spec
    return out
