"""The digitizer's Euler angles differ from the calibrated ones."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Alignment(Effect):
    """The true pose differs from the calibrated one by (alpha, beta, gamma) degrees.

    Physics: alignment uncertainty (thesis section 4: about 0.01-0.05 deg).
    Residual: a rotation of every profile about the mount point. The
    diagnosis also offers one per pose ('alignment@<pose_id>').
    """

    name: ClassVar[str] = "alignment"
    summary: ClassVar[str] = "the digitizer's Euler angles differ from the calibrated ones (all poses alike)"
    reveal: ClassVar[str] = "the same sphere scanned from two or more poses (e.g. the reference sphere at STANDARD_POSES)"
    params: ClassVar[dict[str, Param]] = {p: Param("degree", 0.01) for p in ("alpha", "beta", "gamma")}
    acts: ClassVar[str] = "pose"

    alpha: float = 0.0
    beta: float = 0.0
    gamma: float = 0.0

    def pose(self, pose, offset):
        return pose + [self.alpha, self.beta, self.gamma], offset

    @classmethod
    def adjust_poses(cls, values, poses, rows):
        poses[rows, 0:3] += values
