"""What compensation and evaluation call on a machine model: an
:class:`~cmmpose.ErrorMap`, an :class:`~cmmpose.ErrorMapSet` or a found
:class:`~cmmpose.Model` answer the same calls, so that nothing that applies
a model asks which kind it holds."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["MachineModel"]


@runtime_checkable
class MachineModel(Protocol):
    """A machine model as the code that applies it sees it.

    Attributes
    ----------
    error_maps : ErrorMap or ErrorMapSet
        The maps under the model (maps alone: themselves).
    effects : tuple of (EffectSpec, ndarray)
        Effects beyond the maps with their values (maps alone: none).
    uncertainty : dict of str -> ndarray
        Standard uncertainty of each effect's parameters, in their units.
    alternatives : tuple
        Effects the training data could not tell from a held one.
    domain : Domain or None
        Where the model was fitted (:class:`cmmpose.model.Domain`); None for
        measured maps.
    expansion_ppm_per_kelvin : float
        The artefact expansion the model holds, ppm/K.
    reads_run : bool
        Whether it reads a run's own inputs (thermocouple log, time stamps)
        itself; maps alone are given the machine temperature.
    reads_sweeps : bool
        Whether it reads each sweep's velocity (latency): a point file is
        then compensated sweep by sweep.
    """

    effects: tuple
    alternatives: tuple
    reads_run: bool
    reads_sweeps: bool

    @property
    def error_maps(self): ...

    @property
    def uncertainty(self) -> dict: ...

    @property
    def expansion_ppm_per_kelvin(self) -> float: ...

    def provenance(self) -> dict:
        """What compensated, for an evaluation's JSON (``kind``: map, set or model)."""

    def without_effects(self) -> MachineModel:
        """The plain maps (a found model judged against them reads a run the same way)."""

    def with_policy(self, **policy) -> MachineModel:
        """The model with the caller's temperature policy (``out_of_range``,
        ``temperature_tolerance`` K, ``log_hold`` s, ``temperature`` C; each
        None: the model's own)."""

    def compensate_points(self, uv: np.ndarray, scales: np.ndarray, pose, offset, temperature=None, *,
                          policy=None, nan_policy: str = "raise", out=None, columns=None, where: str = "points",
                          once: set | None = None) -> tuple[np.ndarray, dict]:
        """Compensated X, Y, Z (mm) of points at one pose and the kernel's
        report (a dict of :class:`cmmpose.KernelReport` fields), under the
        caller's :class:`cmmpose.TemperaturePolicy` (None: the model's own)."""

    def compensate_points_uncertainty(self, uv: np.ndarray, scales: np.ndarray, pose, offset, temperature=None, *,
                                      sources, detail: str = "standard", policy=None, nan_policy: str = "raise",
                                      columns=None, where: str = "points", once: set | None = None):
        """As :meth:`compensate_points`, and each point's uncertainty from
        ``sources`` (:class:`cmmpose.point_uncertainty.UncertaintySources`):
        ``(UncertainPoints, report)``."""

    def compensate_run(self, run, temperature=None, *, policy=None, reports: list | None = None, compare=None,
                       once: set | None = None) -> np.ndarray:
        """All points of ``run`` in machine coordinates, mm (N, 3)."""
