"""The mount offset differs from the calibrated one."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class MountOffset(Effect):
    """The true mount offset differs from the calibrated l1 by (u1, v1, w1) mm.

    Physics: the offset calibration's uncertainty, 40 um per component in the
    thesis (section 5.3, eqs. 22-24). Residual: a constant shift per pose.
    """

    name: ClassVar[str] = "mount-offset"
    summary: ClassVar[str] = "the mount offset l1 differs from the calibrated one"
    reveal: ClassVar[str] = "the same sphere scanned from two or more poses (e.g. the reference sphere at STANDARD_POSES)"
    params: ClassVar[dict[str, Param]] = {p: Param("mm", 0.02) for p in ("u1", "v1", "w1")}
    acts: ClassVar[str] = "pose"

    u1: float = 0.0
    v1: float = 0.0
    w1: float = 0.0

    def pose(self, pose, offset):
        return pose, offset + [self.u1, self.v1, self.w1]

    @classmethod
    def adjust_poses(cls, values, poses, rows):
        poses[rows, 3:6] += values
