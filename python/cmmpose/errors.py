"""The exception hierarchy: every message names the file, line, row or
argument at fault, and every error carries the same facts as fields.

- ``Error``: base of everything cmmpose raises on bad input.
- ``MapError``: a malformed error map or map file.
- ``OutOfRangeError``: a scale reading or temperature the maps do not cover.
- ``InputError``: wrong shape, dtype, length, NaN, or a bad option value;
  ``InputTypeError`` when the value is of the wrong type; ``UserEffectError``
  when a user effect's own code fails (docs/user-effects.md).
- ``GeometryError``: degenerate geometry (zero normal, coplanar points, ...).
- ``RunError``: a malformed measurement run directory (``RunFileError``: a
  run.json its schema refuses, also an ``InputError``).
- ``CalibrationError``: data that cannot give a trustworthy calibration.
- ``AcquisitionError``: serial acquisition: a port, journal or run directory at fault.
- ``SchedulerError``: scaling out (cmmpose.scale): the dask extra missing, a bad
  scheduler spec, a scheduler that cannot be reached.
- ``OutputError``: an output that cannot be written (a full disk, a read-only
  file system, no permission); the earlier file is left whole
  (cmmpose.atomicfile).

The errors about bad input (map, range, input, geometry, run, calibration)
are also ``ValueError`` s, ``InputTypeError`` a ``TypeError``, as the
ecosystem expects. The classes live here (the Rust core raises them through
the bindings, rust/py/src/errors.rs), so they pickle and keep their class and
fields across processes (a Dask worker's error is caught on the client by
``except cmmpose.Error``).

Fields (each None when it does not apply): ``what`` (the quantity or
argument), ``value``, ``allowed`` ((lo, hi)), ``unit``, ``file``, ``row``,
``column``, ``option`` (the Python argument at fault), ``cli_option`` (the
command-line flag at fault), ``remedy`` (a key of :data:`REMEDIES`: what
the user can change) and ``after`` (text that follows the remedy, when a
larger message quotes an error and goes on). ``str(error)`` is the message
as the Python API says it; :meth:`Error.render` says it for the command
line, from the same fields; the command line never rewrites the text.
"""

from __future__ import annotations

import logging
import os
import stat
import warnings
from dataclasses import dataclass

__all__ = ["Error", "MapError", "InterferometerRunError", "OutOfRangeError", "InputError", "InputTypeError",
           "UserEffectError", "PositioningError", "GeometryError", "RunError", "RunFileError", "InterferometerWarning",
           "CalibrationError", "AcquisitionError", "SchedulerError", "OutputError", "ClampWarning",
           "ExtrapolationWarning", "IllConditionedFit", "ImplausibleFit", "MapTemperatureWarning", "Remedy", "REMEDIES",
           "split_remedy", "quoting", "warn_clamped",
           "read_lines", "read_input", "read_input_text", "MissingFileError", "MAX_DOCUMENT_BYTES"]

_log = logging.getLogger("cmmpose")


@dataclass(frozen=True)
class Remedy:
    """What a user can change about an error, in each interface's words.

    Attributes
    ----------
    python : str
        Appended to the message in the Python API (names the argument).
    cli : str
        Appended on the command line when the command has ``flag``.
    flag : str or None
        The command-line flag that does it (None: no command has one).
    missing : str
        Appended on the command line when the command lacks ``flag``.
    instead : tuple of (str, str)
        ``(flag, text)``: ``text`` follows ``missing`` when the command has
        that other flag (what it can do instead).
    lead : bool
        The remedy leads the message instead of following it: the message
        begins with ``python`` (the argument's name and a colon), said on the
        command line as ``cli`` (the flag) or ``missing`` (a command without
        it). A message that does not begin so (quoted inside another) is
        left as it is.
    template : bool
        The words name the error's fields (``{value}``, ``{value!r}``):
        filled from them (``str.format``).
    """

    python: str
    cli: str
    flag: str | None
    missing: str
    instead: tuple[tuple[str, str], ...] = ()
    lead: bool = False
    template: bool = False

    def words(self, interface: str = "python", flags=None, fields=None) -> str:
        """This remedy as ``interface`` ('python' or 'cli') says it; with 'cli',
        ``flags`` are the running command's (None: every flag counts);
        ``fields``: the error's, for a template."""
        if interface == "python":
            text = self.python
        elif self.flag is not None and (flags is None or self.flag in flags):
            text = self.cli
        else:
            text = self.missing + "".join(text for flag, text in self.instead if flags is None or flag in flags)
        return text.format(**(fields or {})) if self.template else text


#: The remedies an error may name (its ``remedy`` field), one home for their wording.
REMEDIES = {
    "temperature_out_of_range": Remedy(
        " (choices: out_of_range='clamp' holds it at the edge, 'extrapolate' extends the maps linearly, or a wider "
        "temperature_tolerance in K)",
        " (choices: --out-of-range clamp holds it at the edge, --out-of-range extrapolate extends the maps "
        "linearly, or a wider --temperature-tolerance K)",
        "--out-of-range", " (this command has no option to clamp or extrapolate the maps)"),
    "position_out_of_range": Remedy(
        " (choices: out_of_range='clamp' holds it at the table's end)",
        " (choices: --out-of-range clamp holds it at the table's end)",
        "--out-of-range", " (this command has no option to clamp it)"),
    "run_maps": Remedy(
        ": pass maps (names or files), a machine from a file, or maps=('none',) for uncompensated only",
        ": give --maps or --machine (or --maps none)", "--maps", ": give the maps"),
    "nan_policy": Remedy(
        " (pass nan_policy='propagate' to get NaN rows instead)",
        " (use --nan-policy propagate to get NaN rows instead)",
        "--nan-policy", " (this command has no option to let NaN rows through)"),
    "user_effects": Remedy(
        ": pass its UserEffect in user_effects=",
        ": give its file with --user-effect FILE.py", "--user-effect",
        ": this command takes no user effects (docs/user-effects.md)"),
    # the thermocouple log (cmmpose.temperature)
    "log_hold": Remedy(
        " (pass log_hold= (s) to hold the nearest reading that far, or give the temperature)",
        " (use --log-hold S to hold the nearest reading that far, or give the temperature)",
        "--log-hold", " (this command has no option to hold the log's readings, or give the temperature)"),
    "on_gap": Remedy(
        "; pass on_gap='interpolate' to interpolate across it",
        "; use --on-gap interpolate to interpolate across it",
        "--on-gap", "; the command line has no option to interpolate across it",
        instead=(("--temperature", " (give the machine temperature with --temperature instead)"),)),
    "on_gap_stretch": Remedy(
        "; pass on_gap='interpolate' to interpolate across the bad stretch",
        "; use --on-gap interpolate to interpolate across the bad stretch",
        "--on-gap", "; the command line has no option to interpolate across the bad stretch",
        instead=(("--temperature", " (give the machine temperature with --temperature instead)"),)),
    "broken_channels": Remedy(
        "; pass broken_channels='drop' to leave its bad samples out",
        "; use --broken-channels drop to leave its bad samples out",
        "--broken-channels", "; this command has no option to leave a broken thermocouple out"),
    "log_end_hold": Remedy(
        "; pass out_of_range='hold' to use the log's end values", "",
        None, "; the command line has no option to hold the log's end values this far"),
    "temperature": Remedy(
        ": pass temperature= (C)", ": give --temperature (C)", "--temperature",
        ": record a temperature log with the run"),
    "temperature_explicit": Remedy(
        ": pass temperature= explicitly", ": give --temperature (C)", "--temperature",
        ": record a temperature log with the run"),
    # the maps' temperature range (cmmpose.calibration.thermal)
    "clamp_temperature": Remedy(
        "; pass out_of_range='clamp' to clamp instead", "; use --out-of-range clamp to clamp instead",
        "--out-of-range", "; this command has no option to clamp it"),
    # a ballbar run's positions (cmmpose.evaluation.ballbar)
    "skip_incomplete": Remedy(
        " (fix the scans' position and ball labels, or pass skip_incomplete=True to evaluate the complete "
        "positions only and list the others)",
        " (fix the scans' position and ball labels, or use --skip-incomplete to evaluate the complete positions "
        "only and list the others)",
        "--skip-incomplete", " (fix the scans' position and ball labels, or complete or relabel the positions)"),
    # outputs that exist (cmmpose.atomicfile, cmmpose.run, the alignment library, the recorder)
    "overwrite": Remedy(
        " (pass overwrite=True to replace it)", " (use --overwrite to replace it)", "--overwrite",
        " (remove it first to replace it)"),
    "overwrite_run": Remedy(
        " (pass overwrite=True to replace the run in it)", " (use --overwrite to replace the run in it)",
        "--overwrite", " (remove it first to replace the run in it)"),
    "overwrite_recording": Remedy(
        " (pass overwrite=True / --overwrite to replace it)", " (use --overwrite to replace it)", "--overwrite",
        " (choose another folder)"),
    # a scheduler that does not answer (cmmpose.scale)
    "scheduler_timeout": Remedy(
        " (scheduler_timeout= sets the limit)", " (--scheduler-timeout SECONDS sets the limit)",
        "--scheduler-timeout", " (no option of this command sets the limit)"),
    "scheduler_handshake": Remedy(
        " (scheduler_timeout= sets the limit): is a Dask scheduler listening there (its port, usually 8786)?",
        " (--scheduler-timeout SECONDS sets the limit): is a Dask scheduler listening there (its port, usually "
        "8786)?",
        "--scheduler-timeout", " (no option of this command sets the limit): is a Dask scheduler listening there "
        "(its port, usually 8786)?"),
    # runs too few to estimate their noise from (cmmpose.diagnosis.plan)
    "sigma": Remedy(": give sigma_um", ": give --sigma UM (noise per ball-centre coordinate, um)", "--sigma",
                    ": give sigma_um"),
    # points whose span says they are in another unit (cmmpose.fitting: ``value`` is the unit); a command
    # without --units says the Python call, as it did
    "units": Remedy(
        " (read_point_cloud(path, units={value!r}))", " (give --units {value})", "--units",
        " (read_point_cloud(path, units={value!r}))", template=True),
    # arguments whose name leads the message, said as the command's flag
    "reproducibility_um": Remedy("reproducibility_um:", "--reproducibility:", "--reproducibility",
                                 "reproducibility:", lead=True),
    "repeat_scans": Remedy("repeat_scans:", "--repeat-scans:", "--repeat-scans", "repeat_scans:", lead=True),
}


def split_remedy(exc: BaseException) -> tuple[str, dict]:
    """An exception's message without its remedy, and the fields to raise it
    again with (its remedy included), for a message that quotes ``exc``
    inside a larger one: ``InputError(f"{where}: {text}", **fields)`` keeps
    the remedy a field, worded for each interface (not text to rewrite); a
    message that goes on after the quote adds it to ``fields['after']``
    (:func:`quoting`). An exception not of cmmpose: ``(str(exc), {})``."""
    if not isinstance(exc, Error):
        return str(exc), {}
    return exc.message, exc.fields


def quoting(exc: BaseException, before: str = "", after: str = "") -> tuple[str, dict]:
    """The message and fields of an error whose message is ``before``, the
    text of ``exc``, then ``after``: ``exc``'s remedy stays a field (worded
    for each interface where the quote ends), ``after`` follows it.
    ``message, fields = quoting(exc, f"{path}: ")``, then
    ``raise cls(message, **fields)``; the fields are ``exc``'s (file, row,
    option, ...)."""
    text, fields = split_remedy(exc)
    if not fields:
        return before + text + after, {}
    return before + text, {**fields, "after": (fields.get("after") or "") + after or None}

_FIELDS = ("what", "value", "allowed", "unit", "file", "row", "column", "option", "cli_option", "remedy", "after")


def _restore(cls, message, fields):
    """Unpickle an :class:`Error` (its class, message and fields)."""
    exc = cls.__new__(cls)
    Error.__init__(exc, message, **fields)
    return exc


class Error(Exception):
    """Base class of every cmmpose error.

    Parameters
    ----------
    message : str
        What is wrong, naming the file, row or argument at fault; without the
        remedy (added from ``remedy`` in each interface's words; a leading
        remedy, ``Remedy.lead``, begins it), and without ``after``.
    what, value, allowed, unit, file, row, column, option, cli_option, remedy, after
        The fields (see :mod:`cmmpose.errors`); keyword only.
    """

    def __init__(self, message: str = "", *, what=None, value=None, allowed=None, unit=None, file=None, row=None,
                 column=None, option=None, cli_option=None, remedy=None, after=None):
        if remedy is not None and remedy not in REMEDIES:
            raise KeyError(f"remedy: expected one of {', '.join(REMEDIES)}, got {remedy!r}")
        super().__init__(message)
        self.message = str(message)
        self.what, self.value, self.allowed, self.unit = what, value, allowed, unit
        self.file, self.row, self.column = file, row, column
        self.option, self.cli_option, self.remedy = option, cli_option, remedy
        self.after = after

    @property
    def fields(self) -> dict:
        """The fields as a dict (None where they do not apply)."""
        return {k: getattr(self, k) for k in _FIELDS}

    def render(self, interface: str = "python", flags=None) -> str:
        """The message as ``interface`` ('python' or 'cli') says it.

        Parameters
        ----------
        interface : {'python', 'cli'}
        flags : set of str, optional
            With 'cli': the flags of the command running; a remedy whose flag
            it lacks says the command has none. None: every flag counts.
        """
        if interface not in ("python", "cli"):
            raise KeyError(f"interface: expected 'python' or 'cli', got {interface!r}")
        remedy = REMEDIES.get(self.remedy)
        if remedy is None:
            return self.message + (self.after or "")
        if remedy.lead:
            if interface == "python" or not self.message.startswith(remedy.python):
                return self.message + (self.after or "")
            return remedy.words(interface, flags, self.fields) + self.message[len(remedy.python):] + (self.after or "")
        return self.message + remedy.words(interface, flags, self.fields) + (self.after or "")

    def __str__(self) -> str:
        return self.render("python")

    def __reduce__(self):
        return _restore, (type(self), self.message, self.fields), self.__dict__


class MapError(Error, ValueError):
    """A malformed error map or map file (names the file, carriage and row)."""


class InterferometerRunError(MapError):
    """A malformed interferometer run (file or in-memory), or runs that cannot
    make a map (:mod:`cmmpose.calibration.interferometer`). The message names
    the file and line (or the row, or the run)."""


class OutOfRangeError(Error, ValueError):
    """A scale reading or temperature outside what the maps cover (``value``,
    ``allowed`` and ``unit`` say by how much)."""


class InputError(Error, ValueError):
    """An input array or argument with the wrong shape, length or value."""


class PositioningError(InputError):
    """Positioning data that cannot give ISO 230-2 figures
    (:mod:`cmmpose.standards.iso230_2`): one cycle (no standard deviation),
    one target, a target approached from one direction only, a repeated
    cycle, a bad column. The message names the source (file) and the target
    or row at fault."""


class MissingFileError(InputError):
    """A file or folder the user named does not exist. The command line says
    it as a usage error (exit status 2), as it does an argument that names
    no file."""


class InputTypeError(InputError, TypeError):
    """An input of the wrong type (a string where a number belongs, ...)."""


class UserEffectError(InputError):
    """A user effect (docs/user-effects.md) whose own code failed: its
    function raised, or returned something other than a finite (N, 3) array
    in mm. An error in the user's code, not a verdict on the data, so a
    diagnosis stops on it instead of filing the effect as not observable.
    The message names the effect, its file (``file``), the line of the file
    where it failed (``row``, when known) and the user's exception."""


class GeometryError(Error, ValueError):
    """Degenerate geometry (zero normal, coplanar points, ...)."""


class RunError(Error, ValueError):
    """A malformed measurement run: a missing or unreadable file, a missing or
    badly typed column, a bad value, or tables that do not fit together. The
    message names the file (or table), the column and the first bad row."""


class RunFileError(RunError, InputError):
    """A run's ``run.json`` that its schema refuses (:mod:`cmmpose.schemas`):
    a ``RunError`` as every fault of a run, and an ``InputError`` as every
    document refused at the one door in. The message names the file and the
    key path."""


class CalibrationError(Error, ValueError):
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


class ImplausibleFit(UserWarning):
    """A sphere fit whose answer is implausible: an rms too large for the
    radius, or a fixed radius the points disagree with (a wrong radius, a
    diameter, a raw scan not segmented); docs/fitting.md, Sanity checks."""


class InterferometerWarning(UserWarning):
    """Map assembly from interferometer runs filled components with zeros,
    truncated a carriage's range, or mixed runs at different material
    temperatures (:mod:`cmmpose.calibration.interferometer`)."""


class MapTemperatureWarning(UserWarning):
    """A single map was used at temperatures other than its own."""


class ModelDomainWarning(UserWarning):
    """A found model applied outside the domain it was fitted on, or where
    its correction is not determined by that data (:mod:`cmmpose.model.domain`):
    the message names what is outside and by how much."""


class AliasedChoiceWarning(UserWarning):
    """A diagnosis model applied where an aliased choice matters: the effect
    its diagnosis chose and an alternative the data could not rule out
    predict these data differently (:mod:`cmmpose.model.alternatives`)."""


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


#: The largest input document (a model, machine, artefact or user-effect file) cmmpose reads whole (bytes).
MAX_DOCUMENT_BYTES = 256 << 20


def _kind(mode: int) -> str:
    return ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode)
            else "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a folder" if stat.S_ISDIR(mode) else "a special file")


def read_input(path, what: str = "file", *, limit: int = MAX_DOCUMENT_BYTES, error=None) -> bytes:
    """The bytes of the input file ``path`` through the one door in for documents: only a regular file is
    read (a FIFO, a device such as ``/dev/zero``, a socket or a folder is refused as what it is, without
    waiting for a writer: the file is opened non-blocking and checked by its descriptor), and no more than
    ``limit`` bytes.

    Raises
    ------
    MissingFileError
        Nothing at ``path`` ("no such ``what``").
    InputError (or ``error``)
        Not a regular file, larger than ``limit``, or unreadable; the message names the file.
    """
    error = error or InputError
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        raise MissingFileError(f"{path}: no such {what}", file=str(path)) from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, expected a {what}", file=str(path)) from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})", file=str(path)) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{path}: not a regular file but {_kind(st.st_mode)}; the {what} must be a regular file "
                        "(copy a stream to a file first)", file=str(path))
        if st.st_size > limit:
            raise error(f"{path}: {st.st_size:,} bytes, more than a {what} may hold ({limit:,})", file=str(path))
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while True:
            chunk = os.read(fd, min(1 << 20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
            if size > limit:
                raise error(f"{path}: more than a {what} may hold ({limit:,} bytes)", file=str(path))
        return b"".join(chunks)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})", file=str(path)) from None
    finally:
        os.close(fd)


def read_input_text(path, what: str = "file", **options) -> str:
    """:func:`read_input` decoded as UTF-8 (a bad byte: ``InputError`` naming the file and the byte's line)."""
    raw = read_input(path, what, **options)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise (options.get("error") or InputError)(
            f"{path}:{line}: the {what} is not UTF-8 text (byte {raw[exc.start]:#04x})", file=str(path)) from None


def read_lines(path, what: str = "text file") -> list[str]:
    """Lines of a UTF-8 text file (map files, positioning tables), read through the one door in
    (:func:`read_input`: a FIFO or a device is refused, never waited on or read for ever); an unreadable
    file or a bad byte raises ``MapError`` naming the file (and the line of the bad byte)."""
    try:
        raw = read_input(path, what, error=MapError)
    except MissingFileError:
        raise MapError(f"{path}: cannot read (No such file or directory)", file=str(path)) from None
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
