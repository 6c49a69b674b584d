"""The machine's squareness differs from the map's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Squareness(Effect):
    """S_xy, S_yz, S_zx differ from the map's by (xy, yz, zx) arc-seconds.

    Physics: squareness drifts after a crash, relevelling or a change of the
    granite's support; the map keeps the old value. Typical: 2-20 a-s.
    Residual: a shear, -E dS_xy in x etc., growing with travel.
    """

    name: ClassVar[str] = "squareness"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {"dx*dy": "squareness xy", "dy*dz": "squareness yz", "dz*dx": "squareness zx"}}
    summary: ClassVar[str] = "the machine's squareness differs from the map's (relevelling, a crash)"
    reveal: ClassVar[str] = "ballbar positions on the face diagonals of each plane"
    params: ClassVar[dict[str, Param]] = {p: Param("arc-second", 5.0) for p in ("xy", "yz", "zx")}

    xy: float = 0.0
    yz: float = 0.0
    zx: float = 0.0
