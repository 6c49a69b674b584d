"""Dask arrays and dataframes compensated lazily, partition by partition; the maps travel as one graph key that
every block's task depends on.
"""

from __future__ import annotations

import numpy as np

from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..temperature import TemperaturePolicy
from ..point_uncertainty import UncertaintySources
from ..uncertainty_columns import columns_of
from .compensator import INPUT_COLUMNS, OUTPUT_COLUMNS, Compensator
from .scheduler import require_distributed


def _block(points: np.ndarray, kernel: Compensator) -> np.ndarray:
    """One (n, 5 or 6) block of u, v, D, E, F[, T] -> (n, 3) X, Y, Z mm
    (with uncertainty: and the uncertainty columns, mm and mm^2)."""
    uv = np.ascontiguousarray(points[:, 0:2], dtype=np.float64)
    scales = np.ascontiguousarray(points[:, 2:5], dtype=np.float64)
    temps = np.ascontiguousarray(points[:, 5], dtype=np.float64) if points.shape[1] == 6 else None
    if kernel.uncertainty is None:
        return kernel(uv, scales, temps)[0]
    p = kernel.uncertain(uv, scales, temps)[0]
    return np.column_stack([p.xyz, *columns_of(p).values()])


def compensate_array(points, error_map: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                     out_of_range: str | None = None, nan_policy: str = "raise",
                     temperature_tolerance: float | None = None, temperature_policy: TemperaturePolicy | None = None,
                     uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard"):
    """Compensate a Dask array of points, lazily, block by block.

    Parameters
    ----------
    points : dask.array.Array, shape (N, 5) or (N, 6)
        Columns u, v (mm), D, E, F (mm)[, T (C)], chunked along rows (the
        columns are made one chunk).
    error_map, pose, offset, temperature, out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As in :func:`cmmpose.compensate` (``temperature`` a float, C; with a
        set and none, column T).
    uncertainty, uncertainty_detail
        As in :func:`cmmpose.compensate`: each block's uncertainty by the
        same kernel call.

    Returns
    -------
    dask.array.Array, shape (N, 3) or (N, 3 + k)
        X, Y, Z in mm, float64, chunked as ``points`` along rows; computing it
        calls the kernel once per block. With ``uncertainty``, k more columns
        in the order of :func:`cmmpose.uncertainty_columns.uncertainty_columns`
        (u_x, u_y, u_z mm; the covariance and its common part, mm^2: k = 3,
        9 or 15). The maps are one key of the graph,
        sent to each worker once. Kernel warnings are not raised per block;
        ``out_of_range='raise'`` still raises.
    """
    require_distributed()
    import dask
    import dask.array as da

    if not isinstance(points, da.Array) or points.ndim != 2 or points.shape[1] not in (5, 6):
        raise InputError(f"points: expected a dask array of shape (N, 5) or (N, 6) (u, v, D, E, F[, T]), "
                         f"got {type(points).__name__} {getattr(points, 'shape', '')}")
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    if kernel.needs_temperature_column and points.shape[1] != 6:
        raise InputError("points: a map set without a temperature needs a sixth column T (C)")
    points = points.rechunk({1: -1})
    shared = dask.delayed(kernel, pure=True, traverse=False)
    width = 3 + len(kernel.columns)
    return da.map_blocks(_block, points, shared, dtype=np.float64, chunks=(points.chunks[0], (width,)),
                         meta=np.empty((0, width), dtype=np.float64))


def _partition(frame, kernel: Compensator, passthrough: list[str]):
    """One pandas partition -> X, Y, Z and the pass-through columns."""
    import pandas as pd

    uv = np.column_stack([frame[c].to_numpy(dtype=np.float64) for c in ("u", "v")]) if len(frame) else np.empty((0, 2))
    scales = np.column_stack([frame[c].to_numpy(dtype=np.float64) for c in ("D", "E", "F")]) if len(frame) \
        else np.empty((0, 3))
    temps = frame["T"].to_numpy(dtype=np.float64) if kernel.needs_temperature_column else None
    u_cols = {}
    if not len(frame):
        xyz = np.empty((0, 3))
        u_cols = {c: np.empty(0) for c in kernel.columns}
    elif kernel.uncertainty is None:
        xyz = kernel(uv, scales, temps)[0]
    else:
        p = kernel.uncertain(uv, scales, temps)[0]
        xyz, u_cols = p.xyz, columns_of(p)
    out = pd.DataFrame({**{c: xyz[:, k] for k, c in enumerate(OUTPUT_COLUMNS)}, **u_cols}, index=frame.index)
    for c in passthrough:
        out[c] = frame[c]
    return out


def compensate_dataframe(frame, error_map: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                         out_of_range: str | None = None, nan_policy: str = "raise",
                         temperature_tolerance: float | None = None, temperature_policy: TemperaturePolicy | None = None,
                         uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard"):
    """Compensate a Dask dataframe, lazily, partition by partition.

    Parameters
    ----------
    frame : dask.dataframe.DataFrame
        Columns u, v, D, E, F (mm)[, T (C)] and any others.
    error_map, pose, offset, temperature, out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As in :func:`compensate_array`.
    uncertainty, uncertainty_detail
        As in :func:`compensate_array`: the uncertainty columns
        (``u_x_mm`` ..., :mod:`cmmpose.uncertainty_columns`) after X, Y, Z.

    Returns
    -------
    dask.dataframe.DataFrame
        X, Y, Z (mm, float64), the uncertainty columns when asked, and the
        other columns of ``frame`` (all but u, v, D, E, F, T), partitioned as
        ``frame``; e.g. ``.to_parquet(folder)`` writes it partition by partition.
    """
    require_distributed()
    import dask

    if not hasattr(frame, "map_partitions") or not hasattr(frame, "columns"):
        raise InputTypeError(f"frame: expected a dask dataframe, got {type(frame).__name__}")
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    names = list(frame.columns)
    for c in INPUT_COLUMNS + (("T",) if kernel.needs_temperature_column else ()):
        if c not in names:
            raise InputError(f"frame: missing column {c!r}")
    for c in OUTPUT_COLUMNS + kernel.columns:
        if c in names:
            raise InputError(f"frame: has a column {c!r}, which the output would write over")
    passthrough = [c for c in names if c not in INPUT_COLUMNS + ("T",)]
    meta = _partition(frame._meta, kernel, passthrough)
    shared = dask.delayed(kernel, pure=True, traverse=False)
    return frame.map_partitions(_partition, shared, passthrough, meta=meta)
