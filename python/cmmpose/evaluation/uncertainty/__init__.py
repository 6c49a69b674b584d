"""Measurement uncertainty (GUM): a small toolkit for uncertainty budgets, the
thesis's budgets as code, and propagation through compensation and sphere
fitting, by Monte Carlo (GUM Supplement 1) and by the law of propagation of
uncertainty (GUM eq. 10 / 13) with sensitivity coefficients from the kernels.

Thesis references are to section and line of its plain text (data/SOURCES.md).
Units: the thesis budgets are in um; the propagation functions work in the
package's units (mm, degrees, degrees C) and return mm and mm^2.
See docs/uncertainty.md.

- ``gum``: the toolkit (:class:`Input`, :class:`Budget`, :func:`uncertainty_of_mean`);
- ``thesis``: the thesis's budgets, checked against what it printed;
- ``propagation``: what both propagations share (the problem, the results); ``monte_carlo`` and ``linear``:
  the two methods, each checking the other.
"""

from .gum import Budget, Input, uncertainty_of_mean
from .linear import linear_ballbar_length_uncertainty, linear_sphere_centre_uncertainty
from .monte_carlo import monte_carlo_ballbar_length, monte_carlo_sphere_centre
from .propagation import CentreUncertainty, LengthUncertainty
from .thesis import THESIS_SCALE_ERRORS_UM, ballbar_length_budget, mount_offset_budgets, sphere_centre_budget

__all__ = [
    "Input",
    "Budget",
    "CentreUncertainty",
    "LengthUncertainty",
    "mount_offset_budgets",
    "sphere_centre_budget",
    "ballbar_length_budget",
    "uncertainty_of_mean",
    "THESIS_SCALE_ERRORS_UM",
    "monte_carlo_sphere_centre",
    "monte_carlo_ballbar_length",
    "linear_sphere_centre_uncertainty",
    "linear_ballbar_length_uncertainty",
]
