"""Unmeasured roll of each carriage."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Roll(Effect):
    """Roll of each carriage about its own axis, linear in the reading, in
    arc-seconds per metre of travel from home.

    Physics: the thesis maps store roll as 0 (section 3.3: not measured).
    Typical: 1-5 a-s over the travel. Residual grows with the digitizer lever.
    """

    name: ClassVar[str] = "roll"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {f"mid {a}": "unmeasured roll" for a in "xyz"},
             "point": {f"{c} in scan": "unmeasured roll" for c in "DEF"}}
    summary: ClassVar[str] = "unmeasured roll of each carriage, linear in travel, acting through the digitizer lever"
    reveal: ClassVar[str] = "a second digitizer pose with a different lever, or the bar along each axis at two heights"
    params: ClassVar[dict[str, Param]] = {p: Param("arc-second/m", 10.0) for p in ("x", "y", "z")}

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
