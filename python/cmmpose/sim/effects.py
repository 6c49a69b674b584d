"""Physical effects the simulator can switch on beyond the error maps.

Each effect is a frozen dataclass with named parameters in stated units and
one or more hooks the simulator calls:

- ``machine(fx)``: add to the truth machine's ``MachineEffects`` arrays;
- ``states(states, times)``: change the (K, 5) temperatures the machine
  really has at ``times`` (s) (carriage X, Y, Z map temperatures,
  squareness temperature, granite top-minus-bottom), returning a new array;
- ``artefact_scale(temperature)``: the factor by which the artefact's length
  differs from its length at 20 C;
- ``pose(pose, offset)``: the true digitizer pose and mount offset;
- ``latency()``: seconds between the scale reading and the profile;
- ``scanner(u, v, cos_incidence)``: what the scanner reports for a true (u, v).

The compensation model (thesis) knows none of these: switched on, each leaves
a residual that the diagnosis has to find.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from ..errors import InputError

_REGISTRY: dict[str, type[Effect]] = {}


@dataclass(frozen=True)
class Effect:
    """Base class: every hook does nothing."""

    name: ClassVar[str] = ""
    units: ClassVar[dict[str, str]] = {}

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.name:
            _REGISTRY[cls.name] = cls

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            arr = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise InputError(f"effect {self.name}: {f.name} must be finite, got {value!r}")

    def machine(self, fx: dict[str, np.ndarray]) -> None:
        pass

    def states(self, states: np.ndarray, times: np.ndarray) -> np.ndarray:
        return states

    def artefact_scale(self, temperature: float) -> float:
        return 1.0

    def pose(self, pose: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return pose, offset

    def latency(self) -> float:
        return 0.0

    def scanner(self, u: np.ndarray, v: np.ndarray, cos_incidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return u, v


def _triple(name, value) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != (3,):
        raise InputError(f"{name}: expected three values, got {value!r}")
    return a


@dataclass(frozen=True)
class SquarenessOffset(Effect):
    """The machine's squareness differs from the map's by (xy, yz, zx) arc-seconds.

    Physics: squareness drifts after a crash, relevelling or a change of the
    granite's support; the map keeps the old value. Typical: 2-20 a-s.
    Residual: a shear, -E dS_xy in x etc., growing with travel.
    """

    name: ClassVar[str] = "squareness"
    units: ClassVar[dict[str, str]] = {"xy": "arc-second", "yz": "arc-second", "zx": "arc-second"}
    xy: float = 0.0
    yz: float = 0.0
    zx: float = 0.0

    def machine(self, fx):
        fx["squareness_offset"] += [self.xy, self.yz, self.zx]


@dataclass(frozen=True)
class ScaleError(Effect):
    """Per-axis scale error in ppm: the linear error grows by ppm 1e-6 x reading.

    Physics: scale expansion not in the map (a scale at another temperature
    than mapped, scale pitch error). Typical: 1-12 ppm (steel/glass ~ 10 ppm/K).
    """

    name: ClassVar[str] = "scale"
    units: ClassVar[dict[str, str]] = {"x": "ppm", "y": "ppm", "z": "ppm"}
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def machine(self, fx):
        fx["scale_error_ppm"] += [self.x, self.y, self.z]


@dataclass(frozen=True)
class UnmeasuredRoll(Effect):
    """Roll of each carriage about its own axis, linear in the reading, in
    arc-seconds per metre of travel from home.

    Physics: the thesis maps store roll as 0 (section 3.3: not measured).
    Typical: 1-5 a-s over the travel. Residual grows with the digitizer lever.
    """

    name: ClassVar[str] = "roll"
    units: ClassVar[dict[str, str]] = {"x": "arc-second/m", "y": "arc-second/m", "z": "arc-second/m"}
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def machine(self, fx):
        fx["roll_slope"] += [self.x, self.y, self.z]


@dataclass(frozen=True)
class AxisTemperature(Effect):
    """Each carriage is at the machine mean plus (x, y, z) kelvin: its map
    should be taken at its own scale thermocouples, not at the mean.

    Physics: vertical and horizontal gradients in a room; the ram is warmer
    near its motor. Typical: 0.2-2 K.
    """

    name: ClassVar[str] = "axis-temperature"
    units: ClassVar[dict[str, str]] = {"x": "K", "y": "K", "z": "K"}
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def states(self, states, times):
        out = states.copy()
        out[:, 0:3] += [self.x, self.y, self.z]
        # Squareness follows the machine mean as the scale thermocouples
        # see it (thesis 6.4), which includes the carriages' offsets.
        out[:, 3] += (self.x + self.y + self.z) / 3.0
        return out


@dataclass(frozen=True)
class GraniteGradient(Effect):
    """A granite top-minus-bottom temperature difference (K) bends the base
    and changes squareness by (xy, yz, zx) arc-seconds per K. The difference
    is ``kelvin`` at t = 0 and changes by ``kelvin_per_hour`` (the room
    warming the top through the day).

    Physics: the thesis saw S_yz and S_zx vary with temperature (Table 7,
    section 3.4) and suspected the granite. Typical: 0.5-2 K, 5-20 a-s/K.
    """

    name: ClassVar[str] = "granite-gradient"
    units: ClassVar[dict[str, str]] = {"kelvin": "K", "xy": "arc-second/K", "yz": "arc-second/K",
                                       "zx": "arc-second/K", "kelvin_per_hour": "K/h"}
    kelvin: float = 0.0
    xy: float = 0.0
    yz: float = 10.0
    zx: float = 10.0
    kelvin_per_hour: float = 0.0

    def gradient(self, times) -> np.ndarray:
        """Top minus bottom (K) at ``times`` (s)."""
        return self.kelvin + self.kelvin_per_hour * np.asarray(times, dtype=float) / 3600.0

    def machine(self, fx):
        fx["granite_squareness"] += [self.xy, self.yz, self.zx]

    def states(self, states, times):
        out = states.copy()
        out[:, 4] += self.gradient(times)
        return out


@dataclass(frozen=True)
class ScannerLatency(Effect):
    """The profile is taken ``seconds`` after the scale reading recorded with it.

    Physics: camera exposure and transfer vs the controller's position latch.
    Typical: 1-20 ms. Residual: a shift of speed x latency along the sweep,
    changing sign with the sweep direction.
    """

    name: ClassVar[str] = "latency"
    units: ClassVar[dict[str, str]] = {"seconds": "s"}
    seconds: float = 0.0

    def latency(self):
        return self.seconds


@dataclass(frozen=True)
class ScannerScale(Effect):
    """Scanner scale errors: reported u = (1 + lateral) u, v = (1 + depth) v (dimensionless, e.g. 1e-4).

    Physics: triangulation calibration error across and along the beam.
    Typical: 1e-4-1e-3 (6-60 um over 60 mm).
    """

    name: ClassVar[str] = "scanner-scale"
    units: ClassVar[dict[str, str]] = {"lateral": "1", "depth": "1"}
    lateral: float = 0.0
    depth: float = 0.0

    def scanner(self, u, v, cos_incidence):
        return u * (1.0 + self.lateral), v * (1.0 + self.depth)


@dataclass(frozen=True)
class IncidenceError(Effect):
    """Depth error growing with the incidence angle theta (degrees, between
    surface normal and beam) and depth: dv = per_degree theta + per_degree_mm v theta
    (bilinear, thesis section 7.2 after Feng 2001).

    Typical: 0.1-0.5 um per degree. Residual: spheres fit slightly small or
    large, depending on the cap.
    """

    name: ClassVar[str] = "incidence"
    units: ClassVar[dict[str, str]] = {"per_degree": "mm/degree", "per_degree_mm": "1/degree"}
    per_degree: float = 0.0
    per_degree_mm: float = 0.0

    def scanner(self, u, v, cos_incidence):
        theta = np.degrees(np.arccos(np.clip(cos_incidence, -1.0, 1.0)))
        return u, v + self.per_degree * theta + self.per_degree_mm * v * theta


@dataclass(frozen=True)
class AlignmentError(Effect):
    """The true pose differs from the calibrated one by (alpha, beta, gamma) degrees.

    Physics: alignment uncertainty (thesis section 4: about 0.01-0.05 deg).
    Residual: a rotation of every profile about the mount point.
    """

    name: ClassVar[str] = "alignment"
    units: ClassVar[dict[str, str]] = {"alpha": "degree", "beta": "degree", "gamma": "degree"}
    alpha: float = 0.0
    beta: float = 0.0
    gamma: float = 0.0

    def pose(self, pose, offset):
        return pose + [self.alpha, self.beta, self.gamma], offset


@dataclass(frozen=True)
class MountOffsetError(Effect):
    """The true mount offset differs from the calibrated l1 by (u1, v1, w1) mm.

    Physics: the offset calibration's uncertainty, 40 um per component in the
    thesis (section 5.3, eqs. 22-24). Residual: a constant shift per pose.
    """

    name: ClassVar[str] = "mount-offset"
    units: ClassVar[dict[str, str]] = {"u1": "mm", "v1": "mm", "w1": "mm"}
    u1: float = 0.0
    v1: float = 0.0
    w1: float = 0.0

    def pose(self, pose, offset):
        return pose, offset + [self.u1, self.v1, self.w1]


@dataclass(frozen=True)
class ArtefactExpansion(Effect):
    """The artefact expands with the part temperature (the machine mean):
    length = length at 20 C x (1 + ppm_per_kelvin 1e-6 (T - 20)).

    Physics: a steel ballbar (11.5 ppm/K) or an Invar one (~1 ppm/K);
    the thesis corrected lengths to 20 C with a coefficient (Table 21).
    Residual: every length off by the same amount, visible only against a
    calibrated length or across temperatures.
    """

    name: ClassVar[str] = "artefact-expansion"
    units: ClassVar[dict[str, str]] = {"ppm_per_kelvin": "ppm/K"}
    ppm_per_kelvin: float = 0.0

    def artefact_scale(self, temperature):
        return 1.0 + self.ppm_per_kelvin * 1e-6 * (float(temperature) - 20.0)


def available_effects() -> dict[str, type[Effect]]:
    """Effect classes by CLI name."""
    return dict(_REGISTRY)


def parse_effect(text: str) -> Effect:
    """``NAME:param=value,param=value`` (CLI form) -> an Effect."""
    name, _, rest = text.partition(":")
    cls = _REGISTRY.get(name.strip())
    if cls is None:
        raise InputError(f"effect {name!r}: unknown; available: {', '.join(sorted(_REGISTRY))}")
    kwargs = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in cls.units:
            raise InputError(f"effect {name}: parameter {item!r} is not one of {sorted(cls.units)} (write key=value)")
        try:
            kwargs[key.strip()] = float(value)
        except ValueError:
            raise InputError(f"effect {name}: {key.strip()}={value!r} is not a number") from None
    return cls(**kwargs)
