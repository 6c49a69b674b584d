"""Compensating a point file into another in bounded memory
(``cmmpose compensate IN OUT``; :func:`compensate_file`).

Reading, compensating and writing run at once in a pipeline: a reader
thread parses chunks of :data:`~cmmpose.formats.pointfiles.CHUNK_POINTS` rows into
a queue of at most :data:`QUEUE_CHUNKS` chunks, the calling thread runs the
kernel on them (the Rust kernel releases the GIL) into a second queue of the
same bound, and a writer thread writes them. A reader that runs ahead of a
slow writer waits for it, so memory stays flat in the file's size (about
:data:`QUEUE_CHUNKS` * 2 + 3 chunks in flight; benches/compensate_memory.py
measures it), and reading overlaps writing.
"""

from __future__ import annotations

import logging
import queue
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._arrays import as_triple
from .errormap import ErrorMap, ErrorMapSet, warn_single_map
from .errors import Error, InputError, InputTypeError, warn_clamped
from .formats.pointfiles import PointWriter, RereadPoints, check_writable, output_format, point_chunks
from .atomicfile import check_not_input
from .kernel_report import KernelReport
from .model import MachineModel
from .point_uncertainty import UncertaintySources
from .pose import MountOffset, Pose
from .temperature import TemperaturePolicy, as_policy
from .uncertainty_columns import (UncertaintyTally, budget_rows, check_detail, check_no_collision, columns_of,
                                  log_budget, require_stated, uncertainty_columns)

__all__ = ["compensate_file", "FileCompensation", "QUEUE_CHUNKS"]

_log = logging.getLogger("cmmpose.filecompensation")

#: Chunks each queue of the pipeline holds at most (reader -> kernel, kernel -> writer).
QUEUE_CHUNKS = 1
#: s: how often a thread waiting on a queue looks whether the other side failed or stopped.
_POLL = 0.2
#: s: how long, after a failure or Ctrl-C, the reader and writer threads are waited for.
_JOIN_TIMEOUT = 30.0
_END = object()
_STOPPED = object()


@dataclass(frozen=True)
class FileCompensation:
    """What :func:`compensate_file` did.

    Attributes
    ----------
    points_in, points_out : Path
        The files read and written.
    points : int
        Points compensated.
    report : KernelReport
        The kernel's counts over the whole file (clamped, held, extrapolated).
    kernel_seconds : float
        s: time spent in the kernel (reading and writing overlap it).
    temperature : str or None
        How the temperature was given: ``"per point (T column)"``, ``"21.5 C"``,
        or None (a single map without one).
    uncertainty : UncertaintyTally or None
        With ``uncertainty=``: the budget (each source on or off, its value
        and where it comes from) and the rms and largest u per axis over the
        points (:class:`cmmpose.uncertainty_columns.UncertaintyTally`).
    """

    points_in: Path
    points_out: Path
    points: int
    report: KernelReport
    kernel_seconds: float
    temperature: str | None
    uncertainty: UncertaintyTally | None = None


class _Failed:
    """An exception raised in a pipeline thread, carried to the calling thread."""

    def __init__(self, exc: BaseException):
        self.exc = exc


def compensate_file(points_in, points_out, maps: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                    out_of_range: str | None = None, nan_policy: str = "raise",
                    temperature_tolerance: float | None = None, progress=None,
                    chunk: int | None = None, temperature_policy: TemperaturePolicy | None = None,
                    uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard",
                    uncertainty_origins: dict | None = None) -> FileCompensation:
    """Compensate the scanner points of a file into machine coordinates in
    another, in bounded memory, reading, compensating and writing at once.

    Parameters
    ----------
    points_in : path-like
        A point file with columns u, v, D, E, F (mm) and optionally T
        (degrees C), in any registered format (:mod:`cmmpose.formats.pointfiles`).
        Its other columns (scan_id, intensity, ...) are written to
        ``points_out`` unchanged.
    points_out : path-like
        The output, in the format of its suffix (an unknown one is refused,
        listing the known ones; a stream such as /dev/null is CSV):
        X, Y, Z in mm (E57 in metres). Written through a temporary file
        renamed into place when whole; never one of the inputs.
    maps : ErrorMap, ErrorMapSet or Model
        The machine's component errors; a set needs ``temperature`` or a T column.
        Or a model a diagnosis found (``cmmpose.Model.load``): its effects
        read their inputs from the file's columns (``cmmpose.model.point_inputs``;
        a missing one is an ``InputError`` naming the effect and the column);
        a model with latency is compensated sweep by sweep (``scan_id``).
    pose, offset
        Euler 3-1-3 angles in degrees and the mount offset in mm (as
        :func:`cmmpose.compensate` takes them).
    temperature : float, optional
        degrees C for every point; default the T column when there is one.
        A single map held at another temperature gives a ``MapTemperatureWarning``.
    out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As :func:`cmmpose.compensate` takes them (K for the tolerance; the
        keywords override the policy's map side, cmmpose.temperature).
    progress : callable, optional
        ``progress(bytes_done, size)``: how far into the input (bytes) the
        written points reach, called in the calling thread.
    chunk : int, optional
        Rows per chunk (default :data:`cmmpose.formats.pointfiles.CHUNK_POINTS`).
    uncertainty : bool or UncertaintySources, optional
        Also write each point's standard uncertainty (k = 1), computed per
        chunk by the same kernel call as :func:`cmmpose.compensate` with
        ``uncertainty=`` (True: the sources the maps or model state):
        columns ``u_x_mm, u_y_mm, u_z_mm`` (mm) after X, Y, Z, before the
        input's other columns (:mod:`cmmpose.uncertainty_columns`). A format
        that cannot carry named columns (PTS) is refused, and so is a set of
        sources that states none (every u would be 0).
    uncertainty_detail : {'standard', 'covariance', 'split'}
        Also the six covariance columns ``cov_xx_mm2`` ... (mm^2); also the
        six of its common part ``cov_common_xx_mm2`` ....
    uncertainty_origins : dict of str -> str, optional
        Where each source's value comes from, by source name, for the budget
        (e.g. ``{"scanner_noise": "machine.toml: scanner.noise_um"}``).

    Returns
    -------
    FileCompensation

    Raises
    ------
    InputError
        A bad input (the file, row and column named), an output that is an
        input, a map set without a temperature; with ``uncertainty``: an
        output format without named columns, an input column named as an
        uncertainty column, no stated source.
    OutputError
        The output cannot be written (a full disk): nothing is left behind.
    """
    policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
    points_in, points_out = Path(points_in), Path(points_out)
    check_writable(points_out)  # before any work: a missing folder is found now, not after
    check_not_input(points_out, [points_in], "OUT")
    size, chunks = point_chunks(points_in, chunk, extras=True)
    if not isinstance(maps, MachineModel):
        raise InputTypeError(f"maps: expected an ErrorMap, ErrorMapSet or Model, got {type(maps).__name__}")
    if maps.reads_sweeps:  # a model with latency: each sweep whole in one chunk
        chunks = whole_scans(chunks)
    pose = pose.as_tuple() if isinstance(pose, Pose) else as_triple("pose", pose)
    offset = tuple(offset) if isinstance(offset, MountOffset) else as_triple("offset", offset)
    kernel = _FileKernel(maps, points_in, pose, offset, temperature, policy, nan_policy, uncertainty_detail)
    kernel.sources, kernel.tally = _uncertainty_plan(points_out, maps, uncertainty, uncertainty_detail,
                                                     uncertainty_origins)
    report = _write_points(chunks, kernel, points_in, points_out, size, progress)
    _log.info("compensated %d points of %s into %s", report.points, points_in, points_out)
    if kernel.tally is not None:
        log_budget(kernel.tally, str(points_out))
    return FileCompensation(points_in, points_out, report.points, report, kernel.seconds, kernel.temperature_used,
                            kernel.tally)


class _FileKernel:
    """The chunks of one point file through the kernel: each chunk's coordinates, report and extra columns (the
    uncertainty columns after X, Y, Z); an error naming a row of the chunk names the file and the file's row. Counts
    the rows read, the kernel's time and the temperature used; a model's checks warn once per file, not per chunk."""

    def __init__(self, maps, points_in: Path, pose, offset, temperature, policy: TemperaturePolicy, nan_policy: str,
                 detail: str):
        self.maps, self.points_in, self.pose, self.offset = maps, points_in, pose, offset
        self.temperature, self.policy, self.nan_policy = temperature, policy, nan_policy
        self.detail = detail
        # With uncertainty (set from the plan, checked before any work): the sources and the running tally.
        self.sources: UncertaintySources | None = None
        self.tally: UncertaintyTally | None = None
        self.once: set = set()  # a model's checks of this file: each warning once, not once per chunk
        self.temperature_used = None
        self.warned = False
        self.seconds = 0.0
        self.rows = 0

    def restart(self) -> None:
        """Before the file is read again whole: the counts and the tally from zero (warnings given stay given)."""
        self.seconds, self.rows = 0.0, 0
        if self.tally is not None:
            self.tally = UncertaintyTally(budget=self.tally.budget)

    def __call__(self, uv, scales, temps, extras=None):
        first = self.rows
        self.rows += len(uv)
        try:
            return self._chunk(uv, scales, temps, extras)
        except Error as exc:
            raise _in_file(exc, self.points_in, first) from None

    def _temperatures(self, temps):
        """The temperature the kernel takes for a chunk: the given one, else the T column; None for one map (it
        holds at its own temperature: a warning once when the points' differs)."""
        maps, temperature = self.maps, self.temperature
        t = temperature if temperature is not None else temps
        if isinstance(maps, ErrorMapSet) and t is None:
            raise InputError(f"{self.points_in}: a map set needs a temperature (--temperature, temperature=) "
                             f"or a T column in the input")
        if isinstance(maps, ErrorMap):  # one map holds at its own temperature
            if t is not None and not self.warned:
                warn_single_map(maps, t, self.policy.temperature_tolerance)
                self.warned = True
            return None
        if t is not None:
            self.temperature_used = "per point (T column)" if temperature is None else f"{temperature:g} C"
            if temperature is None:
                t = np.ascontiguousarray(t, dtype=float)
        return t

    def _chunk(self, uv, scales, temps, extras):
        t = self._temperatures(temps)
        where, maps = str(self.points_in), self.maps
        t0 = time.perf_counter()
        if self.sources is None:
            xyz, raw = maps.compensate_points(uv, scales, self.pose, self.offset, t, policy=self.policy,
                                              nan_policy=self.nan_policy, columns=extras, where=where, once=self.once)
        else:
            check_no_collision(self.points_in, extras, self.detail)
            points, raw = maps.compensate_points_uncertainty(
                uv, scales, self.pose, self.offset, t, sources=self.sources, detail=self.detail, policy=self.policy,
                nan_policy=self.nan_policy, columns=extras, where=where, once=self.once)
            xyz, extras = points.xyz, {**columns_of(points), **extras}  # u columns after X, Y, Z
            self.tally.add(points.u)
        self.seconds += time.perf_counter() - t0
        report = KernelReport(**raw)
        warn_clamped(report)
        return xyz, report, extras


def _write_points(chunks, kernel: _FileKernel, points_in: Path, points_out: Path, size: int,
                  progress) -> KernelReport:
    """The chunks compensated into ``points_out`` (nothing left behind on an error): the kernel's reports summed.
    When the fast reader refuses a line the strict one accepts, the whole file is read again by the strict one."""
    reports: list[KernelReport] = []
    writer = PointWriter(points_out, inputs=[points_in])
    try:
        try:
            _pipeline(chunks, kernel, writer, reports, size, progress)
        except RereadPoints as again:  # the fast reader refused a line the strict one accepts: the whole file
            writer.abort()
            writer = PointWriter(points_out, inputs=[points_in])
            reports.clear()
            kernel.restart()
            _pipeline(iter([(*again.points, again.extras, size)]), kernel, writer, reports, size, progress)
    except BaseException:
        writer.abort()
        raise
    writer.close()
    return KernelReport.total(reports)


def _uncertainty_plan(points_out, maps, uncertainty, detail: str, origins):
    """The sources and an empty tally with their budget (None, None without
    ``uncertainty``); checked before any work: the output format carries
    named columns, some source is stated."""
    if uncertainty is None or uncertainty is False:
        return None, None
    sources = UncertaintySources() if uncertainty is True else uncertainty
    if not isinstance(sources, UncertaintySources):
        raise InputTypeError(f"uncertainty: expected True or an UncertaintySources, got {type(sources).__name__}")
    check_detail(detail)
    fmt = output_format(points_out)
    if not fmt.named_columns:
        raise InputError(f"{points_out}: the {fmt.name.upper()} format cannot carry the uncertainty columns "
                         f"({', '.join(uncertainty_columns(detail))}) that uncertainty= (--uncertainty) writes; "
                         f"write .csv, .parquet, .npy, .ply, .xyz or .e57, or leave out the uncertainty")
    stated = require_stated(sources, maps, str(points_out))
    return sources, UncertaintyTally(budget=budget_rows(sources, stated, origins))


def whole_scans(chunks):
    """Re-chunk a point file's chunks ``(uv, scales, temps, extras, done)``
    so that no sweep is split between two chunks (the rows of the last
    ``scan_id`` of a chunk wait for the next one); memory grows by one
    sweep at most."""
    held = None
    for uv, scales, temps, extras, done in chunks:
        if held is not None:
            huv, hsc, hte, hex_ = held
            uv, scales = np.concatenate([huv, uv]), np.concatenate([hsc, scales])
            temps = None if temps is None else np.concatenate([hte, temps])
            extras = {k: np.concatenate([hex_[k], v]) for k, v in extras.items()}
            held = None
        sid = extras.get("scan_id")
        if sid is not None and len(sid):
            last = sid[-1]
            start = len(sid) - int(np.argmax(sid[::-1] != last)) if np.any(sid != last) else 0
            if start > 0:
                held = (uv[start:], scales[start:], None if temps is None else temps[start:],
                        {k: v[start:] for k, v in extras.items()})
                uv, scales = uv[:start], scales[:start]
                temps = None if temps is None else temps[:start]
                extras = {k: v[:start] for k, v in extras.items()}
        if len(uv):
            yield uv, scales, temps, extras, done
    if held is not None:
        yield (*held, done)


#: The kernel's argument names and the columns of a point file they are read from.
_COLUMNS = {"uv": "columns u, v", "scales": "columns D, E, F", "temperature": "column T"}


def _in_file(exc: Error, path, first: int) -> Error:
    """``exc``, raised for a chunk whose first row is the file's row
    ``first``, as the same error naming ``path`` and the file's row (data
    rows counted from 0, as the arrays the Python API takes)."""
    if exc.row is None or exc.file is not None:
        return exc
    row = exc.row + first
    message = re.sub(r"\brow \d+\b", f"row {row}", exc.message, count=1)
    for argument, columns in _COLUMNS.items():
        if message.startswith(argument + ":"):
            message = columns + message[len(argument):]
    again = type(exc)(f"{path}: {message}", **{**exc.fields, "file": str(path), "row": row})
    return again


def _put(q: queue.Queue, item, stop: threading.Event) -> bool:
    """Put ``item`` on ``q``, waiting while it is full; False once stopped."""
    while not stop.is_set():
        try:
            q.put(item, timeout=_POLL)
            return True
        except queue.Full:
            continue
    return False


def _get(q: queue.Queue, thread: threading.Thread, stop: threading.Event):
    """The next item of ``q``; a failure if its producer died without one."""
    while True:
        try:
            return q.get(timeout=_POLL)
        except queue.Empty:
            if not thread.is_alive():
                try:
                    return q.get_nowait()
                except queue.Empty:
                    if stop.is_set():  # the writer failed and stopped the reader
                        return _STOPPED
                    return _Failed(RuntimeError(f"the {thread.name} thread ended without a result"))


def _pipeline(chunks, kernel, writer: PointWriter, reports: list, size: int, progress) -> None:
    """Read ``chunks`` in a thread, compensate here, write in a thread; the
    first exception of any of them is raised here, after the threads stop."""
    stop = threading.Event()
    read_q: queue.Queue = queue.Queue(QUEUE_CHUNKS)
    write_q: queue.Queue = queue.Queue(QUEUE_CHUNKS)
    written = queue.SimpleQueue()  # bytes_done of each chunk written, or a failure

    def read() -> None:
        try:
            for item in chunks:
                if not _put(read_q, item, stop):
                    return
            _put(read_q, _END, stop)
        except BaseException as exc:  # carried to the calling thread
            _put(read_q, _Failed(exc), stop)

    def write() -> None:
        while not stop.is_set():
            try:
                item = write_q.get(timeout=_POLL)
            except queue.Empty:
                continue
            if item is _END:
                written.put(_END)
                return
            xyz, extras, done = item
            try:
                writer.write(xyz, extras)  # scan_id, intensity, ... unchanged
            except BaseException as exc:
                stop.set()
                written.put(_Failed(exc))
                return
            written.put(done)

    def report_progress(block: bool) -> BaseException | None:
        """Pass on what the writer finished; its failure, if any."""
        while True:
            try:
                done = written.get(timeout=_POLL) if block else written.get_nowait()
            except queue.Empty:
                if block and writer_thread.is_alive():
                    continue
                return None
            if isinstance(done, _Failed):
                return done.exc
            if done is _END:
                return None
            if progress is not None:
                progress(done, size)

    reader_thread = threading.Thread(target=read, name="cmmpose point reader", daemon=True)
    writer_thread = threading.Thread(target=write, name="cmmpose point writer", daemon=True)
    reader_thread.start()
    writer_thread.start()
    try:
        while True:
            item = _get(read_q, reader_thread, stop)
            if isinstance(item, _Failed):
                raise item.exc
            if item is _END:
                break
            if item is _STOPPED:
                raise report_progress(block=True) or RuntimeError("the point writer stopped without a result")
            uv, scales, temps, extras, done = item
            xyz, rep, extras = kernel(uv, scales, temps, extras)
            reports.append(rep)
            del uv, scales, temps, item
            if not _put(write_q, (xyz, extras, done), stop):
                break
            del xyz, extras
            failure = report_progress(block=False)
            if failure is not None:
                raise failure
        _put(write_q, _END, stop)  # False when the writer stopped on a failure, reported next
        failure = report_progress(block=True)
        if failure is not None:
            raise failure
    finally:
        stop.set()  # after a failure or Ctrl-C: the threads leave their queues
        reader_thread.join(_JOIN_TIMEOUT)
        writer_thread.join(_JOIN_TIMEOUT)
        if writer_thread.is_alive():
            _log.warning("the point writer did not stop within %g s", _JOIN_TIMEOUT)
