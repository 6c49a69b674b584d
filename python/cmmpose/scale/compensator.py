"""The kernel a worker holds: the maps, the pose and the options, sent to each worker once and called per
block of points.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..compensation import compensate
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..temperature import TEMPERATURE_TOLERANCE, TemperaturePolicy, as_policy
from ..pose import pose_tuple
from .._arrays import as_triple
from ..kernel_report import KernelReport
from ..point_uncertainty import UncertainPoints, UncertaintySources
from ..uncertainty_columns import check_detail, require_stated, uncertainty_columns

#: Columns a dataset file must have (T: machine temperature, C, for a map set).
INPUT_COLUMNS = ("u", "v", "D", "E", "F")
#: Columns the compensation writes first; the input's other columns follow.
OUTPUT_COLUMNS = ("X", "Y", "Z")


@dataclass(frozen=True)
class Compensator:
    """What every block needs to be compensated: the maps, the pose and the
    options. Sent to each worker once; called per block.

    Parameters
    ----------
    error_map : ErrorMap or ErrorMapSet
        The machine's component errors (a set needs a temperature).
    pose : tuple of 3 float
        Euler 3-1-3 angles alpha, beta, gamma, degrees.
    offset : tuple of 3 float
        Mount offset l1 = (U1, V1, W1), mm.
    temperature : float, optional
        Machine temperature for every point, C; with a set and no value, each
        block's T column.
    out_of_range, nan_policy, temperature_tolerance
        As in :func:`cmmpose.compensate`.
    uncertainty : UncertaintySources, optional
        Also each point's uncertainty from these sources (:meth:`uncertain`).
    uncertainty_detail : {'standard', 'covariance', 'split'}
        What of it (:mod:`cmmpose.uncertainty_columns`).
    """

    error_map: ErrorMap | ErrorMapSet
    pose: tuple[float, float, float]
    offset: tuple[float, float, float]
    temperature: float | None = None
    out_of_range: str = "raise"
    nan_policy: str = "raise"
    temperature_tolerance: float = TEMPERATURE_TOLERANCE
    uncertainty: UncertaintySources | None = None
    uncertainty_detail: str = "standard"

    @classmethod
    def make(cls, error_map, pose, offset, temperature=None, *, out_of_range=None, nan_policy="raise",
             temperature_tolerance=None, temperature_policy: TemperaturePolicy | None = None,
             uncertainty: bool | UncertaintySources | None = None,
             uncertainty_detail: str = "standard") -> Compensator:
        """Checked arguments, as :func:`cmmpose.compensate` takes them (the
        keywords override ``temperature_policy``'s map side); with
        ``uncertainty`` (True: the maps' stated sources), a set of sources
        that states none is an ``InputError`` (every u would be 0)."""
        if not isinstance(error_map, (ErrorMap, ErrorMapSet)):
            raise InputTypeError(f"error_map: expected an ErrorMap or ErrorMapSet, got {type(error_map).__name__}")
        policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
        out_of_range, temperature_tolerance = policy.out_of_range, policy.temperature_tolerance
        if nan_policy not in ("raise", "propagate"):
            raise InputError(f"nan_policy: expected 'raise' or 'propagate', got {nan_policy!r}")
        if temperature is not None:
            try:
                temperature = float(temperature)
            except (TypeError, ValueError):
                raise InputError(f"temperature: expected a number (C), got {temperature!r}") from None
        if uncertainty is not None and uncertainty is not False:
            uncertainty = UncertaintySources() if uncertainty is True else uncertainty
            if not isinstance(uncertainty, UncertaintySources):
                raise InputTypeError(f"uncertainty: expected True or an UncertaintySources, "
                                     f"got {type(uncertainty).__name__}")
            require_stated(uncertainty, error_map)
        else:
            uncertainty = None
        return cls(error_map, pose_tuple(pose), as_triple("offset", offset), temperature, out_of_range, nan_policy,
                   float(temperature_tolerance), uncertainty, check_detail(uncertainty_detail))

    @property
    def needs_temperature_column(self) -> bool:
        """Whether each block must bring its own temperatures (a set, no fixed value)."""
        return isinstance(self.error_map, ErrorMapSet) and self.temperature is None

    @property
    def columns(self) -> tuple[str, ...]:
        """The uncertainty columns each block gains (none without ``uncertainty``)."""
        return () if self.uncertainty is None else uncertainty_columns(self.uncertainty_detail)

    def _temperature(self, temps):
        if not isinstance(self.error_map, ErrorMapSet):
            return None
        t = self.temperature if self.temperature is not None else temps
        if t is None:
            raise InputError("temperature: a map set needs a temperature or a T column")
        return t

    def __call__(self, uv: np.ndarray, scales: np.ndarray, temps: np.ndarray | None) -> tuple[np.ndarray, KernelReport]:
        """Compensated X, Y, Z (N, 3) mm of one block, and the kernel's report
        (no warnings: the caller sums the reports and warns once)."""
        t = self._temperature(temps)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return compensate(uv, scales, self.error_map, self.pose, self.offset, t, out_of_range=self.out_of_range,
                              nan_policy=self.nan_policy, temperature_tolerance=self.temperature_tolerance,
                              return_report=True)

    def uncertain(self, uv: np.ndarray, scales: np.ndarray,
                  temps: np.ndarray | None) -> tuple[UncertainPoints, KernelReport]:
        """With ``uncertainty``: one block's points and their uncertainty,
        the same kernel call as ``compensate(..., uncertainty=)``."""
        t = self._temperature(temps)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return compensate(uv, scales, self.error_map, self.pose, self.offset, t, out_of_range=self.out_of_range,
                              nan_policy=self.nan_policy, temperature_tolerance=self.temperature_tolerance,
                              return_report=True, uncertainty=self.uncertainty,
                              uncertainty_detail=self.uncertainty_detail)
