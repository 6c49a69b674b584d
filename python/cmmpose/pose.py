"""Digitizer pose (Euler 3-1-3, thesis eq. 7) and mount offset l1."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import _core
from ._arrays import as_triple
from .errors import InputError


@dataclass(frozen=True)
class Pose:
    """Orientation of the scan plane in machine axes.

    Parameters
    ----------
    alpha : float
        First rotation, about the machine Z axis, in degrees.
    beta : float
        Second rotation, about the new X' axis, in degrees.
    gamma : float
        Third rotation, about the new Z'' axis (the scanner's w), in degrees.

    Notes
    -----
    W along +X is ``Pose(90, 90, gamma)``; W along +Y is ``Pose(180, 90, gamma)``.
    """

    alpha: float
    beta: float
    gamma: float = 0.0

    def __post_init__(self) -> None:
        as_triple("pose", (self.alpha, self.beta, self.gamma))

    def matrix(self) -> np.ndarray:
        """E313 (3, 3): columns are the u, v, w directions in machine axes (eq. 8)."""
        return _core.euler313(self.alpha, self.beta, self.gamma)

    @property
    def normal(self) -> np.ndarray:
        """Unit scan-plane normal w in machine axes, (3,)."""
        return self.matrix()[:, 2].copy()

    @classmethod
    def from_normal(cls, normal, gamma: float = 0.0) -> Pose:
        """Pose whose w axis is ``normal`` (any length, (3,)), with ``gamma`` in degrees.

        beta = acos(n_z), alpha = atan2(n_x, -n_y) (quadrant-safe eq. 6). For a
        normal along Z alpha is undefined and set to 0.
        """
        return cls(*_core.pose_from_normal(as_triple("normal", normal), float(gamma)))

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.alpha, self.beta, self.gamma)


class MountOffset(NamedTuple):
    """l1 = (U1, V1, W1): the mount point P seen from the laser origin L, in mm
    along u, v, w."""

    u1: float
    v1: float
    w1: float

    @classmethod
    def thesis(cls) -> MountOffset:
        """The Hyscan 45C of the thesis (section 5.3): 1.001, 264.505, 129.575 mm."""
        return cls(1.001, 264.505, 129.575)


#: The largest magnitude of a pose angle a user may give, degrees: an Euler
#: angle beyond a full turn is a typo or a unit error (radians read as
#: degrees give small numbers, but 1e9 is no orientation).
ANGLE_LIMIT_DEG = 360.0


def check_pose_angles(name: str, angles) -> tuple[float, float, float]:
    """Three finite angles (degrees) within +-``ANGLE_LIMIT_DEG``.

    Parameters
    ----------
    name : str
        What gave them (an option or a file's key), first in any message.
    angles : sequence of 3 float
        alpha, beta, gamma, degrees.

    Returns
    -------
    tuple of 3 float

    Raises
    ------
    InputError
        ``"<name>: pose angle <value> deg is beyond +-360 deg"``.
    """
    vals = as_triple(name, angles)
    for label, v in zip(("alpha", "beta", "gamma"), vals):
        if abs(v) > ANGLE_LIMIT_DEG:
            raise InputError(f"{name}: pose angle {label} = {v:g} deg is beyond +-{ANGLE_LIMIT_DEG:g} deg "
                             "(angles are in degrees)")
    return vals


def pose_tuple(pose) -> tuple[float, float, float]:
    """Accept a Pose or three angles in degrees."""
    if isinstance(pose, Pose):
        return pose.as_tuple()
    return as_triple("pose", pose)


def digitizer(pose, offset) -> _core.Digitizer:
    """The digitizer as the Rust kernels take it (named, validated there).

    Parameters
    ----------
    pose : Pose or sequence of 3 float
        Euler 3-1-3 angles alpha, beta, gamma in degrees.
    offset : MountOffset or sequence of 3 float
        Mount offset l1 = (U1, V1, W1) in mm.
    """
    return _built_digitizer(*pose_tuple(pose), *as_triple("offset", offset))


@functools.lru_cache(maxsize=256)
def _built_digitizer(alpha: float, beta: float, gamma: float, u1: float, v1: float, w1: float) -> _core.Digitizer:
    """The Digitizer for validated angles (degrees) and offset (mm), built
    once: a run uses a handful of poses over many calls, and building one
    costs more than compensating a small call's points."""
    return _core.Digitizer(alpha=alpha, beta=beta, gamma=gamma, offset=(u1, v1, w1))
