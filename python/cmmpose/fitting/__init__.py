"""Least-squares fits of measured artefacts: spheres (geometric, Rust core:
rust/core/src/fit/sphere.rs) with robust rules and a high-breakdown start,
the ASTM E3125-style segmentation of a sphere from a raw scan
(rust/core/src/fit/segment.rs), and planes (total least squares). Lengths in
mm, angles in degrees; docs/fitting.md describes the rules.

``sphere`` (fit_sphere, fit_spheres, fit_plane), ``segment`` (segment_sphere, e3125), ``plausibility`` (the sanity
checks and their thresholds), ``results`` (what the fits return)."""

from .plausibility import (FAR_POINT_RATIO, ILL_CONDITIONED_CORRELATION, MAX_RMS_FRACTION, RADIUS_MISFIT_FRACTION,
                           RADIUS_MISFIT_RMS_RATIO)
from .results import PlaneFit, SphereFit, SphereFits
from .segment import E3125Result, SphereSegmentation, e3125, segment_sphere
from .sphere import RULES, STARTS, fit_plane, fit_sphere, fit_spheres

__all__ = ["fit_sphere", "fit_spheres", "fit_plane", "segment_sphere", "e3125", "SphereFit", "SphereFits", "PlaneFit",
           "SphereSegmentation", "E3125Result", "RULES", "STARTS", "ILL_CONDITIONED_CORRELATION", "FAR_POINT_RATIO",
           "MAX_RMS_FRACTION", "RADIUS_MISFIT_RMS_RATIO", "RADIUS_MISFIT_FRACTION"]
