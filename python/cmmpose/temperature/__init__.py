"""Temperatures: one policy, and the functions that turn a thermocouple log
into temperatures (docs/conventions.md, "Temperatures outside the maps and
the log"; docs/thermal.md). One module per concern:

- :mod:`~cmmpose.temperature.policy`: :class:`TemperaturePolicy`, the one
  frozen object that says how readings become temperatures and what happens
  at the edges (map range and tolerance, the log's ends, gaps, broken
  channels, which sensor each role reads), its defaults and checks. Every
  library function that turns readings into temperatures accepts
  ``temperature_policy=`` (compensate, evaluate, diagnose, the standards,
  scale-out, calibration) with the same default, ``TemperaturePolicy()``;
  the command line builds its flags from the policy's fields
  (:mod:`cmmpose.cli.temperature_options`).
- :mod:`~cmmpose.temperature.log`: :func:`check_log` finds what is wrong
  with a log (gaps in time, stuck channels, open-circuit or implausible
  readings, NaN) and gives a clean mask per channel and sample;
  :func:`check_log_coverage` refuses points beyond the hold at its ends.
- :mod:`~cmmpose.temperature.interpolation`: :func:`temperatures_at`
  interpolates the clean samples in time at the points' time stamps and
  applies a combination (``'machine_mean'``, ``'per_axis'``,
  ``'role:ROLE'``, ``'channel:NAME'``); :func:`per_scan_temperature` gives
  one temperature per scan.
- :mod:`~cmmpose.temperature.runs`: :func:`run_temperatures` and
  :func:`run_sensor_temperatures` do it for a run under a
  :class:`TemperaturePolicy`, with the provenance (:func:`log_provenance`,
  :func:`log_notes`).

Why a package at the root: the policy is read by the map code
(``errormap``, ``compensation``, ``scale``) as much as by calibration,
evaluation, diagnosis and the standards, so it sits below all of them. It
imports only ``errors`` (``run`` loads on first use), so any layer imports it
without a circle and ``import cmmpose`` stays light.

Units: times in s, temperatures in degrees C, temperature differences in K.
Rows in messages are counted from 0.
"""

from __future__ import annotations

from .interpolation import (AXIS_ROLES, POLICIES, ScanTemperatures, ThermalSummary, per_scan_temperature,
                            temperatures_at)
from .log import (GAP_FACTOR, PLAUSIBLE, STUCK_AFTER, STUCK_TOLERANCE, LogProblem, LogReport, check_log,
                  check_log_coverage)
from .policy import (BROKEN_CHANNELS, DEFAULT_POLICY, LOG_HOLD, ON_GAP, OUT_OF_RANGE, TEMPERATURE_TOLERANCE,
                     TemperaturePolicy, as_policy, check_policy)
from .runs import (GRADIENT_WINDOW, SensorTemperatures, log_notes, log_provenance, run_sensor_temperatures,
                   run_temperatures)

__all__ = [
    "TemperaturePolicy",
    "DEFAULT_POLICY",
    "as_policy",
    "TEMPERATURE_TOLERANCE",
    "LOG_HOLD",
    "OUT_OF_RANGE",
    "ON_GAP",
    "BROKEN_CHANNELS",
    "check_policy",
    "check_log_coverage",
    "LogProblem",
    "LogReport",
    "ThermalSummary",
    "ScanTemperatures",
    "check_log",
    "temperatures_at",
    "per_scan_temperature",
    "run_temperatures",
    "run_sensor_temperatures",
    "SensorTemperatures",
    "log_provenance",
    "log_notes",
    "PLAUSIBLE",
    "STUCK_AFTER",
    "STUCK_TOLERANCE",
    "GAP_FACTOR",
    "POLICIES",
    "AXIS_ROLES",
    "GRADIENT_WINDOW",
]
