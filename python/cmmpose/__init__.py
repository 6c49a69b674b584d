"""cmmpose: geometric and quasi-static thermal error compensation of a laser
line scanner (digitizer) on a coordinate measuring machine.

Units throughout: mm for positions and results, um and arc-seconds in error
map tables, degrees for pose angles, degrees C for temperatures.
"""

from typing import TYPE_CHECKING

from ._threads import bound_thread_count

bound_thread_count()  # before the kernel's thread pool starts: RAYON_NUM_THREADS=100000 is not 100,000 threads

from ._core import __version__, thread_count  # noqa: E402
from ._lazy import lazy_attributes
from .compensation import compensate, uncompensated
from .errormap import CARRIAGES, TABLE_COLUMNS, ErrorMap, ErrorMapSet, data_path
from .errors import (AcquisitionError, AliasedChoiceWarning, CalibrationError, ClampWarning, Error,
                     ExtrapolationWarning, GeometryError, IllConditionedFit, ImplausibleFit, InputError, InputTypeError,
                     InterferometerRunError, InterferometerWarning, MapError, MissingFileError, ModelDomainWarning,
                     MapTemperatureWarning, OutOfRangeError, OutputError, PositioningError, RunError, RunFileError,
                     SchedulerError,
                     UserEffectError)
from .pose import MountOffset, Pose
from .kernel_report import KernelReport

# The acquisition, calibration, uncertainty and diagnosis modules load on
# first use: together about 70 ms of imports that `cmmpose simulate`,
# `compensate` or `evaluate` never need (the command line imports this
# package first). So do the run format and the evaluation (with pyarrow,
# which the run format reads through): `cmmpose fit` or `compensate` never
# needs them (tests/compensation/test_pipeline_and_import_footprint.py checks what `import cmmpose` loads).
__getattr__, __dir__ = lazy_attributes(__name__, {
    # What `cmmpose fit` or `compensate` need is loaded by those commands themselves (start-up, issue 27).
    **{name: ("filecompensation", name) for name in ("FileCompensation", "compensate_file")},
    **{name: ("evaluation.metrics", name) for name in ("b89_value", "improvement", "length_at_20c",
                                                       "rms_accuracy_error")},
    **{name: ("fitting", name) for name in ("E3125Result", "PlaneFit", "SphereFit", "SphereFits", "SphereSegmentation",
                                            "e3125", "fit_plane", "fit_sphere", "fit_spheres", "segment_sphere")},
    "layouts": ("layouts", None),
    **{name: ("layouts", name) for name in ("BallbarPosition", "b89_positions", "crossed_ballbar_positions",
                                            "digitizer_pose_for")},
    **{name: ("formats.pointclouds", name) for name in ("PointCloud", "read_point_cloud", "write_point_cloud")},
    "evaluation": ("evaluation", None),
    "evaluate": ("evaluation.ballbar", "evaluate"),
    "Evaluation": ("evaluation.ballbar", "Evaluation"),
    "BallbarResult": ("evaluation.ballbar", "BallbarResult"),
    "SphereResult": ("evaluation.ballbar", "SphereResult"),
    "run": ("run", None),
    "Run": ("run", "Run"),
    "load_truth": ("run", "load_truth"),
    "acquire": ("acquire", None),
    "Recorder": ("acquire", "Recorder"),
    "calibration": ("calibration", None),
    "uncertainty": ("evaluation.uncertainty", None),
    "formats": ("formats", None),
    "standards": ("standards", None),
    "evaluate_iso230_2": ("standards", "evaluate_iso230_2"),
    "Diagnosis": ("diagnosis", "Diagnosis"),
    "Model": ("model", "Model"),
    "MachineModel": ("model", "MachineModel"),
    "UserEffect": ("model", "UserEffect"),
    "diagnose": ("diagnosis", "diagnose"),
    "TemperaturePolicy": ("temperature", "TemperaturePolicy"),
}, globals())

if TYPE_CHECKING:
    from . import layouts
    from .evaluation.metrics import b89_value, improvement, length_at_20c, rms_accuracy_error
    from .filecompensation import FileCompensation, compensate_file
    from .fitting import (E3125Result, PlaneFit, SphereFit, SphereFits, SphereSegmentation, e3125, fit_plane,
                          fit_sphere, fit_spheres, segment_sphere)
    from .formats.pointclouds import PointCloud, read_point_cloud, write_point_cloud
    from .layouts import BallbarPosition, b89_positions, crossed_ballbar_positions, digitizer_pose_for
    from . import acquire, calibration, evaluation, formats, run, standards
    from .evaluation import uncertainty
    from .evaluation.ballbar import BallbarResult, Evaluation, SphereResult, evaluate
    from .run import Run, load_truth
    from .standards import evaluate_iso230_2
    from .acquire import Recorder
    from .diagnosis import Diagnosis, diagnose
    from .model import MachineModel, Model, UserEffect
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
    "MachineModel",
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
    "evaluation",
    "formats",
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
    "InterferometerRunError",
    "PositioningError",
    "OutOfRangeError",
    "InputError",
    "InputTypeError",
    "MissingFileError",
    "UserEffectError",
    "GeometryError",
    "RunError",
    "RunFileError",
    "OutputError",
    "CalibrationError",
    "AcquisitionError",
    "SchedulerError",
    "ClampWarning",
    "InterferometerWarning",
    "ExtrapolationWarning",
    "MapTemperatureWarning",
    "AliasedChoiceWarning",
    "IllConditionedFit",
    "ImplausibleFit",
]
