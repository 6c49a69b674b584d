"""Time between the scale latch and the profile."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ._base import Effect, Param


@dataclass(frozen=True)
class Latency(Effect):
    """The profile is taken ``seconds`` after the scale reading recorded with it.

    The simulator latches the scales ``seconds`` earlier on the trajectory;
    the model moves the recorded reading on by latency x scale velocity.
    Physics: camera exposure and transfer vs the controller's position latch.
    Typical: 1-20 ms. Residual: a shift of speed x latency along the sweep,
    changing sign with the sweep direction.
    """

    name: ClassVar[str] = "latency"
    hints: ClassVar[dict[str, dict[str, str]]] = {"length": {a: f"scanner latency (the two balls swept in opposite directions along {a[1]})"
                       for a in ("dx", "dy", "dz")},
             "point": {"t in scan": "latency with non-uniform motion"}}
    summary: ClassVar[str] = "time between the scale latch and the profile: a shift of speed x latency along the sweep"
    reveal: ClassVar[str] = "the same ball swept in both directions (bidirectional sweeps)"
    params: ClassVar[dict[str, Param]] = {"seconds": Param("s", 0.005)}
    needs: ClassVar[tuple[str, ...]] = ("velocity",)

    seconds: float = 0.0

    def truth_terms(self):
        return {}  # acts on the trajectory (the latch time), not on a reading

    def latency(self):
        return self.seconds
