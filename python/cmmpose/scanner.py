"""The line scanner's optics and noise, as a machine file describes them
(``[scanner]``): read by :mod:`cmmpose.machine` and used by the simulator
(:mod:`cmmpose.sim.scanner`), so the machine description does not depend on
the simulator."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError

__all__ = ["Scanner"]


@dataclass(frozen=True)
class Scanner:
    """The scanner's optics and noise.

    Parameters
    ----------
    u_range, v_range : tuple of float
        Field of view across the line and depth of view, mm (laser origin in
        the middle; 60 x 60 mm at 140 mm stand-off).
    points_per_profile : int
        Samples across the line (up to 1024).
    profile_rate : float
        Profiles per second, Hz (mirror 3.3 Hz sinusoidal; bidirectional mirror
        scanning gives two lines per period).
    max_incidence : float
        Largest angle between surface normal and beam that returns a point, degrees.
    noise : float
        Gaussian noise sigma on v (depth), mm (Table 17 probing uncertainty: 8-9 um).
    noise_u : float
        Gaussian noise sigma on u, mm.
    """

    u_range: tuple[float, float] = (-30.0, 30.0)
    v_range: tuple[float, float] = (-30.0, 30.0)
    points_per_profile: int = 1024
    profile_rate: float = 6.6
    max_incidence: float = 70.0
    noise: float = 0.008
    noise_u: float = 0.0

    def __post_init__(self):
        if not (self.profile_rate > 0 and np.isfinite(self.profile_rate)):
            raise InputError(f"profile_rate: must be positive (Hz), got {self.profile_rate}")
        if not (self.noise >= 0 and self.noise_u >= 0):
            raise InputError("noise, noise_u: must be >= 0 (mm)")
