"""The exception hierarchy. Defined in the Rust extension so the core can raise
them; every message names the file, line, row or argument at fault.

- ``Error``: base of everything cmmpose raises on bad input.
- ``MapError``: a malformed error map or map file.
- ``OutOfRangeError``: a scale reading or temperature the maps do not cover.
- ``InputError``: wrong shape, dtype, length, NaN, or a bad option value.
- ``GeometryError``: degenerate geometry (zero normal, coplanar points, ...).
- ``RunError``: a malformed measurement run directory (Python-side only).
- ``CalibrationError``: data that cannot give a trustworthy calibration.
- ``AcquisitionError``: serial acquisition: a port, journal or run directory at fault.
- ``SchedulerError``: scaling out (cmmpose.scale): the dask extra missing, a bad
  scheduler spec, a scheduler that cannot be reached.
- ``OutputError``: an output that cannot be written (a full disk, a read-only
  file system, no permission); the earlier file is left whole
  (cmmpose.atomicfile).
"""

import logging
import warnings

from ._core import Error, GeometryError, InputError, MapError, OutOfRangeError

__all__ = ["Error", "MapError", "OutOfRangeError", "InputError", "GeometryError", "RunError", "CalibrationError", "AcquisitionError", "SchedulerError", "OutputError", "ClampWarning", "ExtrapolationWarning", "IllConditionedFit", "MapTemperatureWarning", "warn_clamped", "read_lines"]

_log = logging.getLogger("cmmpose")


class RunError(Error):
    """A malformed measurement run: a missing or unreadable file, a missing or
    badly typed column, a bad value, or tables that do not fit together. The
    message names the file (or table), the column and the first bad row."""


class CalibrationError(Error):
    """A calibration that cannot give a trustworthy result: data that do not
    determine the quantity (no motion, a single sweep over a plane of unknown
    orientation), alignments that disagree beyond the tolerance, a pose that
    was never aligned, a malformed alignment library."""


class ClampWarning(UserWarning):
    """Points were clamped into the maps because ``out_of_range='clamp'``."""


class ExtrapolationWarning(UserWarning):
    """Temperatures beyond the maps were extrapolated (``out_of_range='extrapolate'``)."""


class IllConditionedFit(UserWarning):
    """A free-radius sphere fit whose centre is ill-determined: the centre and
    the radius are so correlated (a small cap) that the centre moves with the
    radius; fix the radius at its calibrated value (docs/fitting.md)."""


class MapTemperatureWarning(UserWarning):
    """A single map was used at temperatures other than its own."""


def warn_clamped(report) -> None:
    """Warn once per call when a report says anything was clamped or
    extrapolated; log the points held at the edge within the tolerance."""
    held = report.held_temperature
    if held:
        _log.info("%d of %d temperatures within the tolerance outside the maps were held at the edge",
                  held, report.points)
    ext = report.extrapolated_temperature
    if ext:
        warnings.warn(f"{ext} of {report.points} temperatures extrapolated beyond the maps, up to "
                      f"{report.max_extrapolation:.2f} K", ExtrapolationWarning, stacklevel=3)
    x, y, z = report.clamped_position
    if x or y or z or report.clamped_temperature:
        warnings.warn(
            f"clamped into the maps: {x} X, {y} Y, {z} Z scale readings and "
            f"{report.clamped_temperature} temperatures (of {report.points} points)",
            ClampWarning,
            stacklevel=3,
        )


def read_lines(path) -> list[str]:
    """Lines of a UTF-8 text file; an unreadable file or a bad byte raises
    ``MapError`` naming the file (and the line of the bad byte)."""
    try:
        raw = open(path, "rb").read()
    except OSError as exc:
        raise MapError(f"{path}: cannot read ({exc.strerror or exc})") from None
    lines = []
    for lineno, chunk in enumerate(raw.splitlines(), start=1):
        try:
            lines.append(chunk.decode("utf-8"))
        except UnicodeDecodeError as exc:
            raise MapError(f"{path}:{lineno}: not UTF-8 text (byte {chunk[exc.start]:#04x} at column {exc.start + 1})") from None
    return lines


class AcquisitionError(Error):
    """Serial acquisition failed: a port that cannot be opened, a journal that
    cannot be written or read, a run directory already in use. The message
    names the port, file or record at fault."""


class SchedulerError(Error):
    """Scaling out failed before any work: the ``dask`` extra is not installed
    (``pip install 'cmmpose[dask]'``), the scheduler spec is not one of
    'threads', 'processes' or an address, or the scheduler at the address
    cannot be reached. The message names the spec or the address."""


class OutputError(Error):
    """An output cannot be written: no space left, a read-only file system,
    no permission, a FIFO nobody reads. The message names the file and the
    reason; the earlier file at that name is unchanged and no temporary file
    is left (:mod:`cmmpose.atomicfile`)."""
