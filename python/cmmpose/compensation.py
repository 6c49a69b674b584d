"""Per-point compensation of scanner points (thesis eqs. 10-13, 26-35)."""

from __future__ import annotations

import numpy as np

from . import _core
from ._arrays import as_rows, as_triple, as_vector
from .errormap import scalar_temperature
from .errors import InputError, InputTypeError, warn_clamped
from .kernel_report import KernelReport
from .model.protocol import MachineModel
from .point_uncertainty import UncertaintySources
from .uncertainty_columns import require_stated
from .pose import MountOffset, Pose, digitizer
from .temperature import TemperaturePolicy, as_policy, check_policy


def compensate(
    uv,
    scales,
    maps: MachineModel,
    pose,
    offset,
    temperature=None,
    *,
    out_of_range: str | None = None,
    nan_policy: str = "raise",
    temperature_tolerance: float | None = None,
    return_report: bool = False,
    out: np.ndarray | None = None,
    columns: dict | None = None,
    temperature_policy: TemperaturePolicy | None = None,
    uncertainty: bool | UncertaintySources | None = None,
    uncertainty_detail: str = "standard",
):
    """Compensated machine coordinates of scanner points.

    X_H = S + e(S) + R(S) . E313 . ((u, v, 0) - l1)   (docs/conventions.md, The compensation)

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Scan-plane coordinates u, v in mm (laser frame; w = 0).
    scales : array_like, shape (N, 3)
        Scale readings D, E, F in mm at which each point was taken.
    maps : ErrorMap, ErrorMapSet or Model
        The machine's component errors; a set needs ``temperature``. Or a
        model a diagnosis found (``cmmpose.Model.load('m.json')``): its maps
        and effects, with the inputs its effects read from ``columns``
        (``cmmpose.model.point_inputs``; one missing is an ``InputError``
        naming it); ``out=`` and ``nan_policy='propagate'`` are not taken then.
    pose : Pose or sequence of 3 float
        Euler 3-1-3 angles alpha, beta, gamma in degrees.
    offset : MountOffset or sequence of 3 float
        Mount offset l1 = (U1, V1, W1) in mm.
    temperature : float or array_like of shape (N,), optional
        Machine temperature in degrees C, one for all points or one per point;
        only with an ErrorMapSet. The set is blended once per temperature
        interval, never per point.
    out_of_range : {'raise', 'clamp', 'extrapolate'}, optional
        Default the policy's ('raise'). A scale reading outside a table or a temperature farther than
        ``temperature_tolerance`` outside the set raises ``OutOfRangeError``
        naming the first such row; or is clamped to the end value with a
        ``ClampWarning`` giving the counts; or (temperatures) the maps are
        extended linearly, with an ``ExtrapolationWarning`` giving the
        largest distance (docs/conventions.md).
    nan_policy : {'raise', 'propagate'}
        NaN or inf in a row raises ``InputError`` naming the first such row, or
        gives a NaN output row.
    temperature_tolerance : float, optional
        K: temperatures this close outside the set's range are held at the
        edge and counted in the report (thermocouple noise at 20 C); default
        the policy's (0.5 K).
    return_report : bool
        Also return a ``KernelReport`` with the clamp and NaN counts.
    out : ndarray, shape (N, 3), optional
        Where to write the result (mm): float64, C-contiguous, writeable and
        sharing no memory with ``uv`` or ``scales``. It is returned. Saves
        the allocation when the same buffer serves call after call: a fresh
        output per call costs 1.33-1.60x the time of ``out=`` on profile data
        of 4,000,000 points with a temperature per point (the new array's
        pages are faulted in as the kernel writes them; ``python
        benches/speed.py``, "fresh output vs out=", min-max of 5 runs on an
        Intel Xeon, 2 threads). After an error its contents are unspecified.
    columns : dict of str -> ndarray (N,), optional
        With a model: the points' other columns its effects read (``t`` s,
        ``scan_id``, ``T_<role>`` C, ``incidence`` degrees, ``pose_id``).
    temperature_policy : TemperaturePolicy, optional
        The temperature policy (cmmpose.temperature); its map side
        (``out_of_range``, ``temperature_tolerance``) applies here, the two
        keywords above override it. Default ``TemperaturePolicy()``.
    uncertainty : bool or UncertaintySources, optional
        Also each point's standard uncertainty (k = 1), propagated in the
        kernel's pass (docs/uncertainty.md, "Per point"): True takes the
        sources the inputs state (the maps' ``stated_uncertainty``, a model's
        parameter covariance); an :class:`cmmpose.point_uncertainty.UncertaintySources`
        states them (temperature K, scanner scale ppm and noise um, pose
        covariance). ``out=`` is not taken then.
    uncertainty_detail : {'standard', 'covariance', 'split'}
        With ``uncertainty``: u_x, u_y, u_z only; also the covariance (mm^2);
        also its part common to nearby points.

    Returns
    -------
    ndarray, shape (N, 3)
        Compensated X, Y, Z in mm (machine frame H). With ``uncertainty``, an
        :class:`cmmpose.point_uncertainty.UncertainPoints` (``xyz``, ``u``,
        ``covariance``, ``common``). With ``return_report``, a tuple
        ``(result, report)``.

    Notes
    -----
    Inputs are never modified. float64 C-contiguous inputs are read without a
    copy; others are converted once.
    """
    policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
    out_of_range, temperature_tolerance = policy.out_of_range, policy.temperature_tolerance
    uv = as_rows("uv", uv, 2)
    scales = as_rows("scales", scales, 3)
    if not isinstance(maps, MachineModel):
        raise InputTypeError(f"maps: expected an ErrorMap, ErrorMapSet or Model, got {type(maps).__name__}")
    if temperature is not None and np.ndim(temperature) > 0:
        temperature = as_vector("temperature", temperature, scales.shape[0])
    elif temperature is not None:
        temperature = scalar_temperature(temperature, finite=False)  # NaN: left to nan_policy
    check_policy(out_of_range, temperature_tolerance)
    pose = pose.as_tuple() if isinstance(pose, Pose) else as_triple("pose", pose)
    offset = tuple(offset) if isinstance(offset, MountOffset) else as_triple("offset", offset)
    if uncertainty is not None and uncertainty is not False:
        if out is not None:
            raise InputError("out: not taken with uncertainty= (the points and their uncertainty are returned)")
        if uncertainty is True:
            uncertainty = UncertaintySources()
        if not isinstance(uncertainty, UncertaintySources):
            raise InputTypeError(f"uncertainty: expected True or an UncertaintySources, got {type(uncertainty).__name__}")
        require_stated(uncertainty, maps)  # every u 0 would be a silent wrong answer
        points, report = maps.compensate_points_uncertainty(
            uv, scales, pose, offset, temperature, sources=uncertainty, detail=uncertainty_detail, policy=policy,
            nan_policy=nan_policy, columns=dict(columns or {}))
        return _finish(points, report, return_report)
    xyz, report = maps.compensate_points(uv, scales, pose, offset, temperature, policy=policy, nan_policy=nan_policy,
                                         out=out, columns=dict(columns or {}))
    return _finish(xyz, report, return_report)


def _finish(xyz: np.ndarray, raw: dict, return_report: bool):
    """The result of a compensation call: warn on what the report says (the
    KernelReport is only built when something is to be said or returned,
    which keeps the per-call cost of small calls down)."""
    if return_report or raw["clamped_points"] or raw["held_temperature"] or raw["extrapolated_temperature"]:
        report = KernelReport(**raw)
        warn_clamped(report)
        if return_report:
            return xyz, report
    return xyz


def uncompensated(uv, scales, pose, offset, *, nan_policy: str = "raise", out: np.ndarray | None = None) -> np.ndarray:
    """What the digitizer software reports: S + E313 . ((u, v, 0) - l1).

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Scan-plane coordinates u, v in mm.
    scales : array_like, shape (N, 3)
        Scale readings D, E, F in mm.
    pose : Pose or sequence of 3 float
        Euler 3-1-3 angles in degrees.
    offset : MountOffset or sequence of 3 float
        Mount offset l1 = (U1, V1, W1) in mm.
    nan_policy : {'raise', 'propagate'}
        As in :func:`compensate`.
    out : ndarray, shape (N, 3), optional
        As in :func:`compensate`.

    Returns
    -------
    ndarray, shape (N, 3)
        X, Y, Z in mm, uncorrected for the machine's errors.
    """
    xyz, _ = _core.uncompensated(as_rows("uv", uv, 2), as_rows("scales", scales, 3), digitizer(pose, offset), nan_policy,
                                 out)
    return xyz
