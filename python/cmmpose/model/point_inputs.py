"""What a model reads from a point file (``cmmpose compensate IN OUT --model
m.json``, ``cmmpose.compensate(..., maps=model, columns=...)``), and the
checks of those inputs before a model is applied (docs/plan.md, "A found
model compensates").

A model (:class:`~cmmpose.Model`: maps plus named
effects with fitted values) needs, beyond a point's u, v and scale readings,
whatever its effects read. A run has them (its thermocouple log, time
stamps, sweeps, poses); a point file has only the columns it holds:

==========================  ====================================================
the model's effect needs     the point file's columns
==========================  ====================================================
machine temperature          ``T`` (C), or ``temperature=`` (a map set; the
                             effects that take the maps at another temperature)
axis_temperature             ``T_x_scale``, ``T_y_scale``, ``T_z_scale`` (C)
gradient                     ``T_granite_top``, ``T_granite_bottom`` (C)
``<role>_temperature``       ``T_<role>`` (C), e.g. ``T_mount``
a followed thermocouple      ``T_<role>`` (C) of the role in the effect's name
                             (``squareness-temperature@z_scale``: ``T_z_scale``)
velocity (latency)           ``t`` (s) and ``scan_id``: each sweep's scale
                             velocity is the slope of its readings against time
incidence                    ``incidence`` (degrees)
a per-pose alignment         ``pose_id`` (which rows are that pose)
==========================  ====================================================

A model needing an input the data lack is refused, naming the effect and the
input (never applied without it). A model holding aliased choices (effects
its run could not tell apart, saved as ``alternatives``) warns where they
predict the data at hand differently (:mod:`cmmpose.model.alternatives`).
Units: mm, s, degrees C, degrees.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errormap import ErrorMap, warn_single_map
from ..errors import InputError, MapTemperatureWarning
from .inputs import RunInputs

__all__ = ["POINT_COLUMNS", "check_inputs", "point_inputs", "single_map_warning"]

#: Point-file columns each kernel input is read from (module docstring).
POINT_COLUMNS = {"axis_temperature": ("T_x_scale", "T_y_scale", "T_z_scale"),
                 "gradient": ("T_granite_top", "T_granite_bottom"),
                 "velocity": ("t", "scan_id"),
                 "incidence": ("incidence",)}
#: Kernel terms that read the machine mean temperature besides the maps.
_READS_MEAN = ("axis-temperature", "squareness-temperature")


def _input_text(need: str) -> str:
    if need == "axis_temperature":
        return "each axis's scale thermocouples (roles x_scale, y_scale, z_scale)"
    if need == "gradient":
        return "the granite's top and bottom thermocouples (roles granite_top, granite_bottom)"
    if need == "velocity":
        return "each point's time stamp and sweep (the scale velocity)"
    if need.endswith("_temperature"):
        return f"thermocouples of role {need[:-len('_temperature')]!r}"
    return need


def single_map_warning(model, temperature, name: str | None = None) -> str | None:
    """A model holding one map (not a set) used at temperatures (C) other
    than the map's own: the ``MapTemperatureWarning`` that evaluating with
    the map alone gives (:func:`cmmpose.errormap.warn_single_map`), its
    text prefixed by ``name`` when given; returns the text (None: no warning)."""
    if not isinstance(model.maps, ErrorMap):
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MapTemperatureWarning)
        note = warn_single_map(model.maps, temperature, model.temperature_tolerance)
    if note:
        note = f"{name}: {note}" if name else note
        warnings.warn(note, MapTemperatureWarning, stacklevel=3)
    return note


def check_inputs(model, inputs: RunInputs, where: str) -> None:
    """Refuse a model whose effects need an input ``inputs`` lacks, naming
    the effect and the input (the incidence is computed from the run's
    sphere fits, so it is never lacking)."""
    for spec, _ in model.effects:
        for need in spec.needs:
            if need in ("poses>1", "incidence") or inputs.available(need):
                continue
            raise InputError(f"{where}: the model's effect {spec.name!r} needs {_input_text(need)}; "
                             f"the {where} has none (remove the effect from the model, or measure it)")
        if spec.sensor is not None and spec.sensor not in inputs.sensors:
            have = ", ".join(inputs.sensors) or "none"
            raise InputError(f"{where}: the model's effect {spec.name!r} follows the thermocouples of role "
                             f"{spec.sensor!r}; the {where} has none (its roles: {have})")


def _column(path, extras: dict, name: str, spec_name: str, why: str) -> np.ndarray:
    if name not in extras:
        have = ", ".join(sorted(extras)) or "none beyond u, v, D, E, F, T"
        raise InputError(f"{path}: the model's effect {spec_name!r} needs {why}: column {name!r}, which the file "
                         f"lacks (its other columns: {have})")
    try:
        out = np.ascontiguousarray(extras[name], dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{path}: column {name!r} is not numeric") from None
    if not np.all(np.isfinite(out)):
        row = int(np.argmax(~np.isfinite(out)))
        raise InputError(f"{path}: column {name!r} holds a value that is not finite (chunk row {row})")
    return out


def _velocity(path, t: np.ndarray, scans: np.ndarray, scan_id: np.ndarray) -> np.ndarray:
    """Each point's scale velocity, mm/s: the least-squares slope of its
    sweep's readings against time (vectorised over the sweeps)."""
    keys, inv = np.unique(scan_id, return_inverse=True)
    n = np.bincount(inv).astype(float)
    tm = np.bincount(inv, t) / n
    dt = t - tm[inv]
    stt = np.bincount(inv, dt * dt)
    bad = stt <= 1e-18 * np.maximum(n, 1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{path}: scan {keys[k]:g} has one time stamp only (t): its sweep velocity, which the model's "
                         f"latency needs, cannot be found from it")
    v = np.column_stack([np.bincount(inv, dt * scans[:, j]) / stt for j in range(3)])
    return np.ascontiguousarray(v[inv])


def point_inputs(model, uv: np.ndarray, scales: np.ndarray, pose, offset, temperature=None, temps=None,
                 extras: dict | None = None, path="points") -> RunInputs:
    """The inputs the model's kernel reads for points of a point file.

    Parameters
    ----------
    model : Model
    uv : ndarray (N, 2)
        Scan-plane coordinates, mm.
    scales : ndarray (N, 3)
        Scale readings D, E, F, mm.
    pose, offset : sequence of 3 float
        Euler 3-1-3 angles (degrees) and mount offset (mm) of the points.
    temperature : float, optional
        Machine temperature, C, for every point (before the T column).
    temps : ndarray (N,), optional
        The T column, C.
    extras : dict of str -> ndarray
        The file's other columns (module docstring: ``T_<role>``, ``t``,
        ``scan_id``, ``incidence``, ``pose_id``).
    path : str
        The file, for messages.

    Raises
    ------
    InputError
        An input an effect needs is missing, naming the effect and the column.
    """
    extras = {} if extras is None else extras
    pose = pose.as_tuple() if hasattr(pose, "as_tuple") else tuple(float(x) for x in pose)
    offset = tuple(float(x) for x in offset)
    n = len(uv)
    mean = None
    if temperature is not None:
        mean = np.full(n, float(temperature))
    elif temps is not None:
        mean = np.ascontiguousarray(temps, dtype=float)
    elif model.temperature is not None:
        mean = np.full(n, float(model.temperature))
    else:
        reads = [s.name for s, _ in model.effects if s.key in _READS_MEAN]
        if hasattr(model.maps, "maps") or reads:  # a map set, or an effect that reads the mean
            what = f"the model's effect {reads[0]!r}" if reads else "the model's map set"
            raise InputError(f"{path}: {what} needs the machine temperature: a T column (C) or a temperature "
                             f"(--temperature)")
        own = getattr(model.maps, "temperature", None)
        mean = np.full(n, 20.0 if own is None else float(own))
    per_pose = [s for s, _ in model.effects if s.pose_id is not None]
    if "pose_id" in extras:
        ids = np.asarray(extras["pose_id"])
        pose_ids = tuple(int(p) for p in np.unique(ids))
        pose_index = np.searchsorted(np.array(pose_ids), ids).astype(np.uint32)
    elif per_pose:
        raise InputError(f"{path}: the model's effect {per_pose[0].name!r} is for pose {per_pose[0].pose_id} of the "
                         f"run it was found on: the file needs a pose_id column (which points that pose took)")
    else:
        pose_ids, pose_index = (0,), np.zeros(n, np.uint32)
    poses = np.tile(np.array([*pose, *offset], dtype=float), (len(pose_ids), 1))
    axis_t = gradient = incidence = None
    velocity = np.zeros((n, 3))
    sensors, role_t = {}, {}
    for spec, _ in model.effects:
        for need in spec.needs:
            if need == "poses>1":
                continue
            if need == "axis_temperature":
                axis_t = np.column_stack([_column(path, extras, c, spec.name, "each axis's scale temperature")
                                          for c in POINT_COLUMNS[need]])
            elif need == "gradient":
                top, bottom = (_column(path, extras, c, spec.name, "the granite's temperature gradient")
                               for c in POINT_COLUMNS[need])
                gradient = np.ascontiguousarray(top - bottom)
            elif need == "velocity":
                t = _column(path, extras, "t", spec.name, "each point's time stamp (s)")
                sid = _column(path, extras, "scan_id", spec.name, "each point's sweep")
                velocity = _velocity(path, t, scales, sid)
            elif need == "incidence":
                incidence = _column(path, extras, "incidence", spec.name, "each point's incidence angle (degrees)")
            elif need.endswith("_temperature"):
                role = need[:-len("_temperature")]
                role_t[need] = _column(path, extras, f"T_{role}", spec.name, f"the {role} thermocouples' temperature")
        if spec.sensor is not None:
            sensors[spec.sensor] = _column(path, extras, f"T_{spec.sensor}", spec.name,
                                           f"the {spec.sensor} thermocouples' temperature")
    t = np.asarray(extras["t"], float) if "t" in extras else np.full(n, np.nan)
    sid = np.asarray(extras["scan_id"]) if "scan_id" in extras else np.zeros(n, np.int64)
    inputs = RunInputs(uv=np.ascontiguousarray(uv, dtype=float), scales=np.ascontiguousarray(scales, dtype=float),
                       t=t, scan_id=sid, pose_ids=pose_ids, pose_index=np.ascontiguousarray(pose_index), poses=poses,
                       temperature=np.ascontiguousarray(mean), axis_temperature=axis_t, gradient=gradient,
                       velocity=np.ascontiguousarray(velocity), incidence=incidence, role_temperatures=role_t,
                       sensors=sensors)
    return inputs
