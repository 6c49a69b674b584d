"""Per-point inputs of a run that the model kernel needs beyond (u, v) and
the scale readings: the pose of each point, the machine mean temperature,
each axis's scale temperature, the granite gradient, the scale velocity and
the incidence angle. Built once per run, vectorised, read-only. The
temperatures come from :func:`cmmpose.temperature.run_sensor_temperatures`
under the model's :class:`~cmmpose.temperature.TemperaturePolicy`, with
their provenance (``RunInputs.thermal``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from .._core import euler313
from ..effects import channel_roles
from ..errors import InputError, InputTypeError
from ..run import Run
from ..temperature import GRADIENT_WINDOW, TemperaturePolicy, as_policy, run_sensor_temperatures

_log = logging.getLogger(__name__)

__all__ = ["RunInputs", "incidence_angles", "GRADIENT_WINDOW"]

#: Per-point inputs handed to the kernel by name (rust/core/src/effects.rs).
_NAMED = ("temperature", "axis_temperature", "gradient", "velocity", "incidence")



@dataclass(frozen=True)
class RunInputs:
    """What the model kernel reads of a run, point by point.

    Attributes
    ----------
    uv : ndarray (N, 2)
        Scan-plane coordinates, mm.
    t : ndarray (N,)
        Time stamps, s.
    scan_id : ndarray (N,)
        Scan of each point.
    scales : ndarray (N, 3)
        Scale readings D, E, F, mm.
    pose_ids : tuple of int
        The run's pose ids; ``pose_index`` indexes this tuple.
    pose_index : ndarray (N,) of uint32
        Pose of each point.
    poses : ndarray (P, 6)
        alpha, beta, gamma (degrees) and U1, V1, W1 (mm) of each pose.
    temperature : ndarray (N,)
        Machine mean temperature, C (thesis policy).
    axis_temperature : ndarray (N, 3) or None
        Mean of each axis's scale thermocouples, C.
    gradient : ndarray (N,) or None
        Granite top minus bottom, K (running mean over ``GRADIENT_WINDOW``).
    velocity : ndarray (N, 3)
        Scale velocity of each point's sweep, mm/s.
    incidence : ndarray (N,) or None
        Angle between the surface normal and the beam, degrees (from a sphere
        fit; see :func:`incidence_angles`).
    role_temperatures : dict of str -> ndarray (N,)
        ``<role>_temperature``, C: the mean of the channels of each
        thermocouple role that an effect brings (e.g. 'mount'), per point.
    sensors : dict of str -> ndarray (N,)
        Every thermocouple role of the run's log (x_scale, ..., granite_top,
        ...) -> the machine mean plus the role's departure from it (the mean
        of its channels minus the machine mean, averaged over
        ``GRADIENT_WINDOW``) at each point, C: what an effect that follows a
        sensor group the data choose reads.
    thermal : dict or None
        How the temperatures were read from the log (channels dropped and
        why, points held and for how long, the channels each role read, the
        policy: :func:`cmmpose.temperature.log_provenance`); None when a
        temperature was given.
    """

    uv: np.ndarray
    scales: np.ndarray
    t: np.ndarray
    scan_id: np.ndarray
    pose_ids: tuple[int, ...]
    pose_index: np.ndarray
    poses: np.ndarray
    temperature: np.ndarray
    axis_temperature: np.ndarray | None
    gradient: np.ndarray | None
    velocity: np.ndarray
    incidence: np.ndarray | None = None
    role_temperatures: dict = field(default_factory=dict)
    sensors: dict = field(default_factory=dict)
    thermal: dict | None = None

    @classmethod
    def from_run(cls, run: Run, temperature: float | None = None, *, log_hold: float | None = None,
                 temperature_policy: TemperaturePolicy | None = None) -> RunInputs:
        """Inputs of ``run``; ``temperature`` (C) overrides the log's machine mean.

        Parameters
        ----------
        run : Run
            The measurement run.
        temperature : float, optional
            Machine temperature for every point, degrees C; default the mean of
            the axis-scale thermocouples at each time stamp.
        log_hold : float, optional
            s: points this far outside the thermocouple log take its nearest
            reading; farther raise; overrides the policy's.
        temperature_policy : TemperaturePolicy, optional
            How the log becomes temperatures (cmmpose.temperature); default
            ``TemperaturePolicy()``.
        """
        if not isinstance(run, Run):
            raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
        n = run.n_points
        t = run.points["t"]
        pose_ids = tuple(int(p) for p in np.sort(run.poses["pose_id"]))
        scan_ids = run.scans["scan_id"]
        order = np.argsort(scan_ids)
        pos = np.searchsorted(scan_ids[order], run.points["scan_id"])
        if n and (np.any(pos >= len(scan_ids)) or np.any(scan_ids[order][np.minimum(pos, len(scan_ids) - 1)]
                                                          != run.points["scan_id"])):
            raise InputError("run: points refer to scans missing from the scans table")
        scan_row = order[pos] if n else np.zeros(0, int)
        pose_of_scan = np.searchsorted(np.array(pose_ids), run.scans["pose_id"])
        pose_index = pose_of_scan[scan_row].astype(np.uint32)
        poses = np.array([[*run.pose(p)[0], *run.pose(p)[1]] for p in pose_ids], dtype=float)
        axis_of_scan = np.array(["XYZ".index(a) for a in run.scans["sweep_axis"]], dtype=int)
        v_scan = np.zeros((len(scan_ids), 3))
        v_scan[np.arange(len(scan_ids)), axis_of_scan] = run.scans["sweep_direction"] * run.scans["sweep_speed"]
        velocity = np.ascontiguousarray(v_scan[scan_row])
        axis_t = gradient = thermal = None
        role_t: dict[str, np.ndarray] = {}
        sensors: dict[str, np.ndarray] = {}
        if temperature is not None:
            temps = np.full(n, float(temperature))
        elif run.temperatures is None:
            raise InputError("run has no temperature log", option="temperature", remedy="temperature")
        else:
            read = run_sensor_temperatures(run, t, as_policy(temperature_policy, log_hold=log_hold))
            temps, axis_t, gradient, sensors, thermal = (read.temperature, read.axis_temperature, read.gradient,
                                                         read.sensors, read.provenance)
            role_t = {f"{role}_temperature": sensors[role] for role in channel_roles() if role in sensors}
        return cls(uv=run.uv, scales=run.scales, t=run.points["t"], scan_id=run.points["scan_id"], pose_ids=pose_ids, pose_index=np.ascontiguousarray(pose_index),
                   poses=poses, temperature=np.ascontiguousarray(temps, dtype=float),
                   axis_temperature=None if axis_t is None else np.ascontiguousarray(axis_t, dtype=float),
                   gradient=None if gradient is None else np.ascontiguousarray(gradient, dtype=float),
                   velocity=velocity, role_temperatures=role_t, sensors=sensors, thermal=thermal)

    def take(self, rows: np.ndarray) -> RunInputs:
        """The inputs of the points ``rows`` only (every per-point array taken; the poses kept)."""
        def take(a):
            return None if a is None else np.ascontiguousarray(a[rows])

        return replace(self, uv=take(self.uv), scales=take(self.scales), t=take(self.t), scan_id=take(self.scan_id),
                       pose_index=take(self.pose_index), temperature=take(self.temperature),
                       axis_temperature=take(self.axis_temperature), gradient=take(self.gradient),
                       velocity=take(self.velocity), incidence=take(self.incidence),
                       role_temperatures={k: take(v) for k, v in self.role_temperatures.items()},
                       sensors={k: take(v) for k, v in self.sensors.items()})

    def with_incidence(self, incidence: np.ndarray) -> RunInputs:
        """A copy holding incidence angles (degrees, (N,))."""
        incidence = np.ascontiguousarray(incidence, dtype=float)
        if incidence.shape != (len(self.uv),):
            raise InputError(f"incidence: expected shape ({len(self.uv)},), got {incidence.shape}")
        return RunInputs(**{**self.__dict__, "incidence": incidence})

    @property
    def sensor_roles(self) -> tuple[str, ...]:
        """The thermocouple roles of the run's log."""
        return tuple(self.sensors)

    def sensor(self, role: str) -> np.ndarray:
        """Mean of the channels of thermocouple role ``role`` at each point, C."""
        if role not in self.sensors:
            have = ", ".join(self.sensors) or "none (no thermocouple log, or a temperature was given)"
            raise InputError(f"the run has no thermocouples of role {role!r} (roles: {have})")
        return self.sensors[role]

    def available(self, need: str) -> bool:
        """Whether the input an effect ``needs`` is there ('poses>1' too)."""
        if need == "poses>1":
            return len(self.pose_ids) > 1
        if need in self.role_temperatures:
            return True
        return need in _NAMED and getattr(self, need) is not None

    def named(self) -> dict[str, np.ndarray]:
        """The per-point inputs the kernel's effect terms read, by name."""
        out = {k: getattr(self, k) for k in _NAMED if getattr(self, k) is not None}
        return out | self.role_temperatures


def incidence_angles(xyz, labels, centres: dict, inputs: RunInputs) -> np.ndarray:
    """Angle (degrees) between each point's outward sphere normal and the
    beam: the scanner looks along -v, so the beam towards the sensor is the
    pose's v axis (E313 column 2) in machine coordinates.

    Parameters
    ----------
    xyz : ndarray (N, 3)
        Compensated points, mm.
    labels : ndarray (N,)
        Sphere of each point (scan id).
    centres : dict
        Label -> fitted centre (3,), mm.
    inputs : RunInputs
        For each point's pose.
    """
    keys = np.array(sorted(centres))
    c = np.array([centres[k] for k in keys]).reshape(-1, 3)
    idx = np.searchsorted(keys, labels)
    normal = xyz - c[idx]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    v_dirs = np.array([np.asarray(euler313(*p[:3]))[:, 1] for p in inputs.poses]).reshape(-1, 3)
    cos = np.einsum("ij,ij->i", normal, v_dirs[inputs.pose_index])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
