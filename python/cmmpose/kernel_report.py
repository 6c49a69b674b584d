"""What a kernel call did besides its output."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class KernelReport:
    """Counts from one compensation call.

    Attributes
    ----------
    points : int
        Points processed.
    clamped_position : tuple of 3 int
        Points whose X, Y, Z scale reading was clamped into the map.
    clamped_temperature : int
        Points whose temperature was clamped into the map set's range.
    clamped_points : int
        Points where anything (a reading or a temperature) was clamped.
    held_temperature : int
        Points whose temperature lay within the tolerance outside the maps
        and was held at the edge.
    extrapolated_temperature : int
        Points whose temperature was extrapolated beyond the maps.
    max_extrapolation : float
        Largest distance of an extrapolated temperature from the maps, K.
    nan_rows : int
        Rows returned as NaN under ``nan_policy='propagate'``.
    """

    points: int
    clamped_position: tuple[int, int, int]
    clamped_temperature: int
    nan_rows: int
    clamped_points: int = 0
    held_temperature: int = 0
    extrapolated_temperature: int = 0
    max_extrapolation: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "clamped_position", tuple(self.clamped_position))

    @property
    def clamped(self) -> int:
        """Clamp events in total (a point clamped on two axes counts twice)."""
        return sum(self.clamped_position) + self.clamped_temperature

    @classmethod
    def total(cls, reports) -> KernelReport:
        """The counts of several calls (chunks of a file, files of a dataset) added up."""
        reports = list(reports)
        return cls(
            points=sum(r.points for r in reports),
            clamped_position=tuple(sum(r.clamped_position[k] for r in reports) for k in range(3)),
            clamped_temperature=sum(r.clamped_temperature for r in reports),
            nan_rows=sum(r.nan_rows for r in reports),
            clamped_points=sum(r.clamped_points for r in reports),
            held_temperature=sum(r.held_temperature for r in reports),
            extrapolated_temperature=sum(r.extrapolated_temperature for r in reports),
            max_extrapolation=max((r.max_extrapolation for r in reports), default=0.0),
        )
