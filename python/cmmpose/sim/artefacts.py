"""Artefacts to scan: spheres (with the form error of thesis Appendix A), ballbars,
planes and the reference sphere on its tower. Lengths in mm."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .._validate import vector3

#: Radius of the thesis's optically coated grade 200 balls (76.25 mm diameter, Appendix A).
BALL_RADIUS = 76.25 / 2


@dataclass(frozen=True)
class Sphere:
    """A ball.

    Parameters
    ----------
    centre : array_like, shape (3,)
        Centre in machine coordinates, mm.
    radius : float
        Equatorial radius, mm.
    polar_radius : float, optional
        Semi-axis along ``axis`` (mm): smaller is oblate, larger prolate
        (Appendix A: 38.1225 and 38.1275 mm for a 38.125 mm ball). Default: a
        perfect sphere.
    axis : array_like, shape (3,)
        Polar axis direction. Default +Z.
    """

    centre: np.ndarray
    radius: float = BALL_RADIUS
    polar_radius: float | None = None
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self):
        object.__setattr__(self, "centre", vector3("centre", self.centre, unit="mm"))
        object.__setattr__(self, "axis", vector3("axis", self.axis, unit="mm"))
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise InputError(f"radius: must be positive (mm), got {self.radius}")

    def surfaces(self) -> list[tuple[str, list[float]]]:
        if self.polar_radius is None or self.polar_radius == self.radius:
            return [("sphere", [*self.centre, self.radius])]
        return [("spheroid", [*self.centre, *self.axis, self.radius, float(self.polar_radius)])]


@dataclass(frozen=True)
class Ballbar:
    """Two balls a fixed length apart (the thesis's optical ballbar, section 6.2)."""

    ball1: Sphere
    ball2: Sphere

    @classmethod
    def between(cls, centre1, centre2, radius: float = BALL_RADIUS) -> Ballbar:
        return cls(Sphere(centre1, radius), Sphere(centre2, radius))

    @property
    def length(self) -> float:
        """Centre-to-centre length, mm."""
        return float(np.linalg.norm(self.ball2.centre - self.ball1.centre))

    def surfaces(self):
        return self.ball1.surfaces() + self.ball2.surfaces()


@dataclass(frozen=True)
class Plane:
    """A flat disc: a point on it, its normal and its radius (mm)."""

    centre: np.ndarray
    normal: np.ndarray
    radius: float = 100.0

    def __post_init__(self):
        object.__setattr__(self, "centre", vector3("centre", self.centre, unit="mm"))
        object.__setattr__(self, "normal", vector3("normal", self.normal, unit="mm"))

    def surfaces(self):
        return [("disc", [*self.centre, *self.normal, self.radius])]


def reference_sphere(centre=(450.0, 380.0, -420.0), radius: float = 12.7) -> Sphere:
    """The calibration sphere on its tower (thesis Figure 4-7); default a 1 in ball."""
    return Sphere(centre, radius)
