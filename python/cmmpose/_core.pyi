"""Type stubs of the Rust extension ``cmmpose._core`` (rust/py/src/*.rs)."""

from typing import Any, Literal, Protocol, TypedDict, final

import numpy as np
import numpy.typing as npt

__version__: str
#: The core's bounds of a machine's numbers (cmmpose_core::units): lengths, mm; a map's
#: translations, um; its angles and squareness, arc-seconds; map temperatures, C.
MAX_LENGTH_MM: float
MAX_TRANSLATION_UM: float
MAX_ANGLE_ARCSEC: float
TEMPERATURE_RANGE_C: tuple[float, float]

# Errors are raised as the classes of cmmpose.errors (rust/py/src/errors.rs).

class Report(TypedDict):
    points: int
    clamped_position: tuple[int, int, int]
    clamped_temperature: int
    clamped_points: int
    held_temperature: int
    extrapolated_temperature: int
    max_extrapolation: float
    nan_rows: int

_F64_2D = npt.NDArray[np.float64]
_OutOfRange = Literal["raise", "clamp", "extrapolate"]


class _MapPolicy(Protocol):
    """The map side of a cmmpose.TemperaturePolicy, read by attribute."""

    out_of_range: _OutOfRange
    temperature_tolerance: float

_NanPolicy = Literal["raise", "propagate"]

@final
class ErrorMap:
    def __new__(
        cls,
        x: _F64_2D,
        y: _F64_2D,
        z: _F64_2D,
        squareness: tuple[float, float, float] | list[float],
        temperature: float | None = None,
    ) -> ErrorMap: ...
    def table(self, carriage: str) -> _F64_2D: ...
    @property
    def squareness(self) -> tuple[float, float, float]: ...
    @property
    def temperature(self) -> float | None: ...
    @property
    def ranges(self) -> list[tuple[float, float]]: ...
    def with_temperature(self, temperature: float | None) -> ErrorMap: ...
    @property
    def kinematics(self) -> str: ...
    def with_kinematics(self, kinematics: str) -> ErrorMap: ...
    def position_error(
        self, scales: _F64_2D, out_of_range: _OutOfRange = "raise", nan_policy: _NanPolicy = "raise"
    ) -> tuple[_F64_2D, Report]: ...
    def rotation_error(
        self, scales: _F64_2D, out_of_range: _OutOfRange = "raise", nan_policy: _NanPolicy = "raise"
    ) -> tuple[npt.NDArray[np.float64], Report]: ...
    def __eq__(self, other: object) -> bool: ...

@final
class ErrorMapSet:
    def __new__(cls, maps: list[ErrorMap]) -> ErrorMapSet: ...
    @property
    def temperatures(self) -> list[float]: ...
    @property
    def maps(self) -> list[ErrorMap]: ...
    @property
    def kinematics(self) -> str: ...
    def with_kinematics(self, kinematics: str) -> ErrorMapSet: ...
    def at(self, temperature: float, policy: _MapPolicy) -> ErrorMap: ...
    def __eq__(self, other: object) -> bool: ...

def _error_map_from_state(state: Any) -> ErrorMap: ...
def _error_map_set_from_state(states: list[Any]) -> ErrorMapSet: ...

class KinematicsConfiguration(TypedDict):
    name: str
    description: str
    stack: list[tuple[str, str]]

def kinematics_configurations() -> list[KinematicsConfiguration]: ...

@final
class Digitizer:
    def __new__(cls, *, alpha: float, beta: float, gamma: float, offset: tuple[float, float, float] | list[float]) -> Digitizer: ...
    @property
    def alpha(self) -> float: ...
    @property
    def beta(self) -> float: ...
    @property
    def gamma(self) -> float: ...
    @property
    def offset(self) -> tuple[float, float, float]: ...

class TrueFrames(TypedDict):
    p: _F64_2D
    r: npt.NDArray[np.float64]
    mount_scale: npt.NDArray[np.float64]

class Profiles(TypedDict):
    profile: npt.NDArray[np.int64]
    u: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    cos_incidence: npt.NDArray[np.float64]
    xyz: _F64_2D

class EffectTerm(TypedDict):
    name: str
    params: list[str]
    inputs: list[tuple[str, int]]

_Inputs = dict[str, npt.NDArray[np.float64]]
_Effects = dict[str, list[float] | float]

def compensate(
    uv: _F64_2D,
    scales: _F64_2D,
    error_map: ErrorMap | ErrorMapSet,
    digitizer: Digitizer,
    policy: _MapPolicy,
    temperature: float | npt.NDArray[np.float64] | None = None,
    nan_policy: _NanPolicy = "raise",
    out: _F64_2D | None = None,
) -> tuple[_F64_2D, Report]: ...
def uncompensated(
    uv: _F64_2D,
    scales: _F64_2D,
    digitizer: Digitizer,
    nan_policy: _NanPolicy = "raise",
    out: _F64_2D | None = None,
) -> tuple[_F64_2D, Report]: ...
def streaming_reference(
    uv: _F64_2D,
    scales: _F64_2D,
    temperature: npt.NDArray[np.float64] | None = None,
    out: _F64_2D | None = None,
) -> _F64_2D: ...
def compensate_model(
    uv: _F64_2D,
    scales: _F64_2D,
    maps: ErrorMap | ErrorMapSet,
    digitizers: list[Digitizer],
    policy: _MapPolicy,
    *,
    pose_index: npt.NDArray[np.uint32] | None = None,
    inputs: _Inputs | None = None,
    effects: _Effects | None = None,
    nan_policy: _NanPolicy = "raise",
) -> tuple[_F64_2D, Report]: ...
def compensate_uncertainty(
    uv: _F64_2D,
    scales: _F64_2D,
    maps: ErrorMap | ErrorMapSet,
    digitizers: list[Digitizer],
    policy: _MapPolicy,
    sources: Any,
    *,
    pose_index: npt.NDArray[np.uint32] | None = None,
    inputs: _Inputs | None = None,
    effects: _Effects | None = None,
    nan_policy: _NanPolicy = "raise",
    detail: Literal["standard", "covariance", "split"] = "standard",
) -> tuple[_F64_2D, _F64_2D, Report]: ...
def effect_terms() -> list[EffectTerm]: ...
def euler313(alpha: float, beta: float, gamma: float) -> _F64_2D: ...
def pose_from_normal(normal: tuple[float, float, float] | list[float], gamma: float) -> tuple[float, float, float]: ...
def thread_count() -> int: ...
def true_frames(scales: _F64_2D, maps: ErrorMapSet, *, inputs: _Inputs, effects: _Effects | None = None) -> TrueFrames: ...
def scanner_forward(uv: _F64_2D, *, inputs: _Inputs | None = None, effects: _Effects | None = None) -> _F64_2D: ...
def scan_profiles(
    frames: TrueFrames,
    digitizer: Digitizer,
    surfaces: list[tuple[str, list[float]]],
    *,
    u_range: tuple[float, float] = (-30.0, 30.0),
    v_range: tuple[float, float] = (-30.0, 30.0),
    points_per_profile: int = 1024,
    max_incidence_deg: float = 70.0,
) -> Profiles: ...
def fit_sphere(
    points: _F64_2D,
    radius: float | None = None,
    *,
    reject: float | None = None,
    rule: str | None = None,
    start: str = "algebraic",
    centre: tuple[float, float, float] | None = None,
    samples: int = 500,
    seed: int = 0,
    max_iterations: int = 100,
    min_coverage: float = 2.0,
) -> dict[str, Any]: ...
def fit_spheres(
    points: _F64_2D,
    bounds: npt.NDArray[np.int64],
    radius: float | None = None,
    *,
    reject: float | None = None,
    rule: str | None = None,
    start: str = "algebraic",
    samples: int = 500,
    seed: int = 0,
    max_iterations: int = 100,
    min_coverage: float = 2.0,
) -> dict[str, Any]: ...
def segment_sphere(
    points: _F64_2D,
    radius: float,
    origin: tuple[float, float, float],
    *,
    start: tuple[float, float, float] | None = None,
    half_angle: float = 60.0,
    rule: str = "e3125",
    reject: float | None = None,
    max_rounds: int = 50,
    samples: int = 500,
    seed: int = 0,
    max_iterations: int = 100,
) -> dict[str, Any]: ...
def fit_plane(points: _F64_2D, reject: float | None = None) -> dict[str, Any]: ...
