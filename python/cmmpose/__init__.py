"""cmmpose: geometric and quasi-static thermal error compensation of a laser
line scanner (digitizer) on a coordinate measuring machine.

Units throughout: mm for positions and results, um and arc-seconds in error
map tables, degrees for pose angles, degrees C for temperatures.
"""

from typing import TYPE_CHECKING

from . import mapfiles, controller, iso230  # noqa: F401  (each registers its map file format, cmmpose.mapformats)
from . import linuxcnc  # noqa: F401  (LinuxCNC compensation tables: one file per axis, not a registered format)
from . import layouts
from ._core import __version__, thread_count
from ._lazy import lazy_attributes
from .compensation import compensate, uncompensated
from .filecompensation import FileCompensation, compensate_file
from .metrics import b89_value, improvement, length_at_20c, rms_accuracy_error
from .fitting import E3125Result, PlaneFit, SphereFit, SphereFits, SphereSegmentation, e3125, fit_plane, fit_sphere, fit_spheres, segment_sphere
from .errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap, ErrorMapSet, data_path
from .errors import (AcquisitionError, CalibrationError, ClampWarning, Error, ExtrapolationWarning, GeometryError,
                     IllConditionedFit, InputError, InputTypeError, MapError, MapTemperatureWarning, OutOfRangeError,
                     OutputError, RunError, SchedulerError)
from .layouts import BallbarPosition, b89_positions, crossed_ballbar_positions, digitizer_pose_for
from .pointclouds import PointCloud, read_point_cloud, write_point_cloud
from .pose import MountOffset, Pose
from .report import KernelReport

# The acquisition, calibration, uncertainty and diagnosis modules load on
# first use: together about 70 ms of imports that `cmmpose simulate`,
# `compensate` or `evaluate` never need (the command line imports this
# package first). So do the run format and the evaluation (with pyarrow,
# which the run format reads through): `cmmpose fit` or `compensate` never
# needs them (tests/test_speed_footprint.py checks what `import cmmpose` loads).
__getattr__, __dir__ = lazy_attributes(__name__, {
    "evaluation": ("evaluation", None),
    "evaluate": ("evaluation", "evaluate"),
    "Evaluation": ("evaluation", "Evaluation"),
    "BallbarResult": ("evaluation", "BallbarResult"),
    "SphereResult": ("evaluation", "SphereResult"),
    "run": ("run", None),
    "Run": ("run", "Run"),
    "load_truth": ("run", "load_truth"),
    "acquire": ("acquire", None),
    "Recorder": ("acquire", "Recorder"),
    "calibration": ("calibration", None),
    "uncertainty": ("uncertainty", None),
    "standards": ("standards", None),
    "evaluate_iso230_2": ("standards", "evaluate_iso230_2"),
    "Diagnosis": ("diagnosis", "Diagnosis"),
    "Model": ("diagnosis", "Model"),
    "UserEffect": ("diagnosis", "UserEffect"),
    "diagnose": ("diagnosis", "diagnose"),
    "TemperaturePolicy": ("temperature", "TemperaturePolicy"),
}, globals())

if TYPE_CHECKING:
    from . import acquire, calibration, evaluation, run, standards, uncertainty
    from .evaluation import BallbarResult, Evaluation, SphereResult, evaluate
    from .run import Run, load_truth
    from .standards import evaluate_iso230_2
    from .acquire import Recorder
    from .diagnosis import Diagnosis, Model, UserEffect, diagnose
    from .temperature import TemperaturePolicy

del TYPE_CHECKING, lazy_attributes  # not part of the package's face (dir(cmmpose))

__all__ = [
    "__version__",
    "PointCloud",
    "read_point_cloud",
    "write_point_cloud",
    "compensate",
    "uncompensated",
    "compensate_file",
    "FileCompensation",
    "evaluate",
    "diagnose",
    "TemperaturePolicy",
    "Diagnosis",
    "Model",
    "UserEffect",
    "Evaluation",
    "BallbarResult",
    "SphereResult",
    "rms_accuracy_error",
    "b89_value",
    "improvement",
    "length_at_20c",
    "fit_sphere",
    "fit_spheres",
    "fit_plane",
    "segment_sphere",
    "e3125",
    "SphereFit",
    "SphereFits",
    "SphereSegmentation",
    "E3125Result",
    "PlaneFit",
    "calibration",
    "acquire",
    "Recorder",
    "layouts",
    "uncertainty",
    "standards",
    "evaluate_iso230_2",
    "BallbarPosition",
    "b89_positions",
    "crossed_ballbar_positions",
    "digitizer_pose_for",
    "ErrorMap",
    "ErrorMapSet",
    "Pose",
    "MountOffset",
    "KernelReport",
    "Run",
    "load_truth",
    "CARRIAGES",
    "TABLE_COLUMNS",
    "data_path",
    "thread_count",
    "Error",
    "MapError",
    "OutOfRangeError",
    "InputError",
    "InputTypeError",
    "GeometryError",
    "RunError",
    "OutputError",
    "CalibrationError",
    "AcquisitionError",
    "SchedulerError",
    "ClampWarning",
    "ExtrapolationWarning",
    "MapTemperatureWarning",
    "IllConditionedFit",
]
