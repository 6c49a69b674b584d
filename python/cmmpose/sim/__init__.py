"""Simulation of the thesis setup (DEA Iota 1102 + Hymarc Hyscan 45C): a truth
machine with exact rigid-body kinematics, extra physical effects, artefacts and
a line scanner sweeping over them. Data with a known truth, for testing
compensation, fitting, calibration and diagnosis."""

from typing import TYPE_CHECKING

from .._lazy import lazy_attributes
from .artefacts import BALL_RADIUS, Ballbar, Plane, Sphere, reference_sphere
from .effects import (
    Alignment,
    Incidence,
    Latency,
    MountOffset,
    Roll,
    Scale,
    Squareness,
    AxisTemperature,
    Effect,
    GraniteGradient,
    ScannerScale,
    available_effects,
    parse_effect,
)
from .machine import TruthMachine, temperature_series
from .scanner import ScanData, Scanner, Sweep, simulate_sweep
from .thermocouples import CHANNELS, OPEN_CIRCUIT_READING, Fault, thermocouple_log

# The interferometer simulator loads on first use: it imports the calibration
# solvers (about 30 ms), which a simulated ballbar run never needs. So do the
# run simulator and the calibration data (with the run format, about 20 ms),
# which the command line's machine file (the Scanner) does not need.
__getattr__, __dir__ = lazy_attributes(__name__, {
    **{name: ("interferometer", name)
       for name in ("interferometer_components", "simulate_interferometer_run", "simulate_interferometer_runs")},
    **{name: ("runs", name) for name in ("REALISTIC_JITTER", "simulate_ballbar_run", "simulate_reference_scan")},
    **{name: ("calibration_data", name) for name in ("VERNIER_NOISE", "plane_scan", "reference_sphere_scans",
                                                     "true_alignment_reading", "true_pose_and_offset",
                                                     "vernier_points")},
}, globals())

if TYPE_CHECKING:
    from .calibration_data import (VERNIER_NOISE, plane_scan, reference_sphere_scans, true_alignment_reading,
                                   true_pose_and_offset, vernier_points)
    from .runs import REALISTIC_JITTER, simulate_ballbar_run, simulate_reference_scan
    from .interferometer import interferometer_components, simulate_interferometer_run, simulate_interferometer_runs

__all__ = [
    "REALISTIC_JITTER",
    "TruthMachine",
    "temperature_series",
    "Scanner",
    "Sweep",
    "ScanData",
    "simulate_sweep",
    "simulate_ballbar_run",
    "simulate_reference_scan",
    "thermocouple_log",
    "Fault",
    "CHANNELS",
    "OPEN_CIRCUIT_READING",
    "Sphere",
    "Ballbar",
    "Plane",
    "reference_sphere",
    "BALL_RADIUS",
    "Effect",
    "AxisTemperature",
    "GraniteGradient",
    "ScannerScale",
    "Alignment",
    "Incidence",
    "Latency",
    "MountOffset",
    "Roll",
    "Scale",
    "Squareness",
    "available_effects",
    "vernier_points",
    "plane_scan",
    "reference_sphere_scans",
    "true_alignment_reading",
    "true_pose_and_offset",
    "VERNIER_NOISE",
    "simulate_interferometer_run",
    "simulate_interferometer_runs",
    "interferometer_components",
    "parse_effect",
]
