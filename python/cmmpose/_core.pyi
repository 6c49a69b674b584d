"""Type stubs of the Rust extension ``cmmpose._core`` (rust/py/src/lib.rs)."""

from typing import Any, Literal, TypedDict, final

import numpy as np
import numpy.typing as npt

__version__: str

class Error(Exception): ...
class MapError(Error): ...
class OutOfRangeError(Error): ...
class InputError(Error): ...
class GeometryError(Error): ...

class Report(TypedDict):
    points: int
    clamped_position: tuple[int, int, int]
    clamped_temperature: int
    nan_rows: int

_F64_2D = npt.NDArray[np.float64]
_OutOfRange = Literal["raise", "clamp"]
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
    def at(self, temperature: float, out_of_range: _OutOfRange = "raise") -> ErrorMap: ...

def compensate(
    uv: _F64_2D,
    scales: _F64_2D,
    error_map: ErrorMap | ErrorMapSet,
    pose: tuple[float, float, float],
    offset: tuple[float, float, float],
    temperature: float | npt.NDArray[np.float64] | None = None,
    out_of_range: _OutOfRange = "raise",
    nan_policy: _NanPolicy = "raise",
) -> tuple[_F64_2D, Report]: ...
def uncompensated(
    uv: _F64_2D,
    scales: _F64_2D,
    pose: tuple[float, float, float],
    offset: tuple[float, float, float],
    nan_policy: _NanPolicy = "raise",
) -> tuple[_F64_2D, Report]: ...
def compensate_model(
    uv: _F64_2D,
    scales: _F64_2D,
    pose_index: npt.NDArray[np.uint32],
    temperature: npt.NDArray[np.float64],
    maps: ErrorMap | ErrorMapSet,
    poses: list[tuple[float, float, float, float, float, float]],
    effects: dict[str, list[float] | float] | None = None,
    axis_temperature: _F64_2D | None = None,
    gradient: npt.NDArray[np.float64] | None = None,
    velocity: _F64_2D | None = None,
    incidence: npt.NDArray[np.float64] | None = None,
    clamp: bool = False,
) -> tuple[_F64_2D, int]: ...
def euler313(alpha: float, beta: float, gamma: float) -> _F64_2D: ...
def pose_from_normal(normal: tuple[float, float, float] | list[float], gamma: float) -> tuple[float, float, float]: ...
def thread_count() -> int: ...
def true_frames(
    scales: _F64_2D,
    states: _F64_2D,
    map_set: ErrorMapSet,
    effects: tuple[
        tuple[float, float, float], tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]
    ],
) -> tuple[_F64_2D, npt.NDArray[np.float64]]: ...
def scan_profiles(
    p: _F64_2D,
    r: npt.NDArray[np.float64],
    pose: tuple[float, float, float],
    offset: tuple[float, float, float],
    surfaces: list[tuple[str, list[float]]],
    u_range: tuple[float, float] = (-30.0, 30.0),
    v_range: tuple[float, float] = (-30.0, 30.0),
    points_per_profile: int = 1024,
    max_incidence_deg: float = 70.0,
) -> tuple[npt.NDArray[np.int64], _F64_2D]: ...
def fit_sphere(
    points: _F64_2D,
    radius: float | None = None,
    reject: float | None = None,
    max_iterations: int = 100,
    min_coverage: float = 2.0,
) -> dict[str, Any]: ...
def fit_spheres(
    points: _F64_2D,
    bounds: npt.NDArray[np.int64],
    radius: float | None = None,
    reject: float | None = None,
    max_iterations: int = 100,
    min_coverage: float = 2.0,
) -> list[dict[str, Any] | Error]: ...
def fit_plane(points: _F64_2D, reject: float | None = None) -> dict[str, Any]: ...
