"""Scale out with Dask (extra ``dask``: ``pip install 'cmmpose[dask]'``).

The Rust kernel compensates a block of points with the GIL released; this
module hands blocks to a Dask scheduler so that datasets larger than memory,
and fleets of runs, are processed on every core of a machine or on a cluster
(docs/scale-out.md):

- :func:`compensate_dataset`: a folder of Parquet files (``u, v, D, E, F[,
  T]`` and any other columns) into a folder of Parquet files (``X, Y, Z`` and
  the other columns), one output per input, named after it, read and written
  row group by row group: memory is bounded by the batch size, whatever the
  dataset's size.
- :func:`compensate_array`, :func:`compensate_dataframe`: a Dask array or
  dataframe, lazily, partition by partition.
- :func:`map_runs`, :func:`evaluate_runs`, :func:`diagnose_runs`: per-run
  work over a fleet of run folders, one task per run; :func:`fleet_summary`
  tabulates the evaluations.

The maps (or model) travel to each worker once: broadcast with
``Client.scatter`` for the dataset and the fleets, one graph key that every
block's task depends on for the lazy collections. A task carries only a file
name, a run folder or a block of points. Results equal the in-process
kernel's bit for bit: every block goes through the same kernel call.

The scheduler is named by a spec: ``'threads'`` (default: this process, one
worker with a thread per core), ``'processes'`` (a local cluster of worker
processes, one per core), a scheduler address ``'tcp://host:port'`` (a running
cluster), or a ``distributed.Client`` (used as it is, not closed).

Dask is imported inside the functions that need it, so ``import cmmpose``
works without the extra; without it these functions raise
:class:`cmmpose.errors.SchedulerError` saying how to install it.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import socket
import struct
import time
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .compensation import compensate
from .atomicfile import AtomicFile, ensure_folder
from .errormap import ErrorMap, ErrorMapSet, warn_single_map
from .errors import Error, InputError, InputTypeError, SchedulerError, quoting, warn_clamped
from .temperature import TEMPERATURE_TOLERANCE, TemperaturePolicy, as_policy
from .pose import pose_tuple
from ._arrays import as_triple
from .kernel_report import KernelReport
from .formats.pointformats.common import parquet_options
from .point_uncertainty import UncertainPoints, UncertaintySources
from .uncertainty_columns import (UncertaintyTally, budget_rows, check_detail, columns_of, log_budget, require_stated,
                                  uncertainty_columns)
from ._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pq = LazyModule("pyarrow.parquet")

__all__ = ["SCHEDULERS", "SCHEDULER_TIMEOUT", "check_scheduler", "scheduler_client", "Compensator", "DatasetResult", "compensate_dataset", "dataset_files",
           "dataset_temperature_range",
           "compensate_array", "compensate_dataframe", "map_runs", "evaluate_runs", "diagnose_runs",
           "FleetRow", "fleet_summary", "INPUT_COLUMNS", "OUTPUT_COLUMNS"]

_log = logging.getLogger("cmmpose.scale")

#: The local scheduler specs; anything else must be an address ``tcp://host:port``.
SCHEDULERS = ("threads", "processes")
#: s: how long a scheduler at an address may take to accept the connection and
#: greet (``scheduler_timeout=``, ``--scheduler-timeout``; docs/scale-out.md).
SCHEDULER_TIMEOUT = 10.0
#: Address schemes a spec may have: ``tcp`` (probed, then connected) and
#: ``tls`` (Dask's TLS settings from its configuration).
_SCHEMES = ("tcp", "tls")
#: bytes: a Dask handshake's frames are a few hundred; a length beyond this is no Dask scheduler.
_MAX_GREETING = 1 << 20
#: Characters of a bad value echoed back in a message.
_ECHO = 40
#: Columns a dataset file must have (T: machine temperature, C, for a map set).
INPUT_COLUMNS = ("u", "v", "D", "E", "F")
#: Columns the compensation writes first; the input's other columns follow.
OUTPUT_COLUMNS = ("X", "Y", "Z")
#: Rows read, compensated and written at a time by default (about 40 MB in flight per task;
#: batches that fit in the CPU caches' reach read faster than larger ones).
BATCH_ROWS = 1 << 18


def _distributed():
    """The ``distributed`` module, or a clear error without the extra."""
    try:
        import dask  # noqa: F401
        import distributed
    except ImportError as exc:
        raise SchedulerError(f"scheduling needs the dask extra (missing module {exc.name!r}): "
                             f"pip install 'cmmpose[dask]'") from None
    return distributed


def check_scheduler(scheduler):
    """The scheduler spec if it is well formed, else ``SchedulerError`` saying
    what it must be (no connection is made).

    Parameters
    ----------
    scheduler : str or distributed.Client
        ``'threads'``, ``'processes'``, an address ``tcp://host:port`` (or
        ``tls://host:port``), or a Client.

    Returns
    -------
    str or distributed.Client
        ``scheduler``, unchanged.
    """
    if not isinstance(scheduler, str):
        if isinstance(scheduler, _distributed().Client):
            return scheduler
        raise SchedulerError(f"scheduler: expected 'threads', 'processes' or an address tcp://host:port, "
                             f"got {_echo(repr(scheduler))}")
    if scheduler in SCHEDULERS:
        return scheduler
    must = "'threads', 'processes' or an address tcp://host:port (a Dask scheduler's, usually port 8786)"
    if "://" not in scheduler:
        raise SchedulerError(f"scheduler: expected {must}, got {_echo(repr(scheduler))}")
    scheme, _, rest = scheduler.partition("://")
    if scheme.lower() not in _SCHEMES:
        web = " (an http:// address is a web page, such as the dashboard, not the scheduler)" \
            if scheme.lower() in ("http", "https") else ""
        raise SchedulerError(f"scheduler {_echo(scheduler)}: the address must be tcp://host:port{web}; "
                             f"the spec is {must}")
    host, _, port = rest.rstrip("/").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise SchedulerError(f"scheduler {_echo(scheduler)}: expected {scheme}://host:port with a port 1..65535 "
                             f"(a Dask scheduler's, usually 8786)")
    return scheduler


def _echo(text: str) -> str:
    """``text``, cut to its first characters when long (a bad value echoed back)."""
    return text if len(text) <= _ECHO else text[:_ECHO] + "..."


def _probe_scheduler(address: str, timeout: float) -> None:
    """Connect to ``address`` (``tcp://host:port``) and wait for a Dask
    scheduler's greeting: a scheduler sends its handshake first, a few
    hundred bytes after an 8-byte length. ``SchedulerError`` naming the
    address and what did not answer if nothing accepts the connection, the
    peer says nothing within ``timeout`` s, or what it says is not Dask's."""
    scheme, _, rest = address.partition("://")
    host, _, port = rest.rstrip("/").rpartition(":")
    host = host.strip("[]")  # an IPv6 literal
    limit = f"{timeout:g} s"
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout)
    except TimeoutError:
        raise SchedulerError(f"scheduler {address}: nothing accepted the connection within {limit}", value=timeout,
                             unit="s", option="scheduler_timeout", remedy="scheduler_timeout") from None
    except OSError as exc:
        raise SchedulerError(f"scheduler {address}: cannot connect ({exc.strerror or exc})") from None
    if scheme.lower() != "tcp":
        sock.close()  # a TLS server waits for the client's hello: Dask's own connect timeout bounds the rest
        return
    head = b""
    with sock:
        while len(head) < 8:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            sock.settimeout(left)
            try:
                chunk = sock.recv(8 - len(head))
            except TimeoutError:
                break
            except OSError as exc:
                raise SchedulerError(f"scheduler {address}: the connection failed before the Dask scheduler "
                                     f"greeted ({exc.strerror or exc})") from None
            if not chunk:
                raise SchedulerError(f"scheduler {address}: accepted the connection, then closed it without the "
                                     f"Dask handshake: is a Dask scheduler listening there?") from None
            head += chunk
    if len(head) < 8:
        raise SchedulerError(f"scheduler {address}: accepted the connection but sent no Dask handshake within "
                             f"{limit}", value=timeout, unit="s", option="scheduler_timeout",
                             remedy="scheduler_handshake")
    if min(struct.unpack("<Q", head)[0], struct.unpack(">Q", head)[0]) > _MAX_GREETING:
        said = head.split(b"\r")[0].decode("ascii", "replace")
        raise SchedulerError(f"scheduler {address}: answered, but not as a Dask scheduler (it began {said!r}; "
                             f"an HTTP server such as the dashboard?): the address must be the Dask scheduler's "
                             f"tcp://host:port (usually port 8786), or give 'threads' or 'processes'")


@contextlib.contextmanager
def scheduler_client(scheduler="threads", *, n_workers: int | None = None,
                     timeout: float = SCHEDULER_TIMEOUT):
    """A ``distributed.Client`` for a scheduler spec, closed on exit (with its
    local cluster) unless it was given.

    Parameters
    ----------
    scheduler : str or distributed.Client
        ``'threads'``: a worker in this process with one thread per core (no
        pickling of data); ``'processes'``: a local cluster of ``n_workers``
        single-threaded worker processes; ``'tcp://host:port'``: the running
        scheduler at that address; or a Client, yielded as it is.
    n_workers : int, optional
        Worker processes for ``'processes'`` (default: one per core).
    timeout : float
        s: at an address, the longest wait for the scheduler to accept the
        connection and for its greeting (the Dask handshake), and Dask's
        connect timeout (``distributed.comm.timeouts.connect``); default
        :data:`SCHEDULER_TIMEOUT`.

    Raises
    ------
    SchedulerError
        Without the dask extra, for a malformed spec (an ``http://`` address,
        a missing port), or when the scheduler at the address cannot be
        reached or does not answer within ``timeout`` (the message names the
        address and what did not answer).
    """
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout < math.inf:
        raise SchedulerError(f"scheduler_timeout: expected a positive number of seconds, got {_echo(repr(timeout))}")
    distributed = _distributed()
    if isinstance(scheduler, distributed.Client):
        yield scheduler
        return
    check_scheduler(scheduler)
    cores = os.cpu_count() or 1
    with contextlib.ExitStack() as stack:
        if scheduler == "threads":
            cluster = stack.enter_context(distributed.LocalCluster(
                processes=False, n_workers=1, threads_per_worker=cores, dashboard_address=":0"))
            address = cluster
        elif scheduler == "processes":
            # One kernel thread per worker process (Dask's nanny already sets OMP_NUM_THREADS=1,
            # which sizes Arrow's pool): the workers share the cores instead of oversubscribing them.
            cluster = stack.enter_context(distributed.LocalCluster(
                processes=True, n_workers=n_workers or cores, threads_per_worker=1, dashboard_address=":0",
                env={"RAYON_NUM_THREADS": "1"}))
            address = cluster
        else:
            # Dask bounds the TCP connect but not the wait for the scheduler's greeting (a port that accepts
            # and never answers hangs it; an HTTP server's answer is read as a 3 EiB message): probe first.
            _probe_scheduler(scheduler, float(timeout))
            address = scheduler
        import dask

        try:
            with dask.config.set({"distributed.comm.timeouts.connect": f"{float(timeout)}s"}):
                client = stack.enter_context(distributed.Client(address, timeout=f"{float(timeout)}s"))
        except (OSError, TimeoutError, ValueError, MemoryError) as exc:
            raise SchedulerError(f"scheduler {scheduler}: cannot connect within {float(timeout):g} s "
                                 f"({type(exc).__name__}: {exc})") from None
        _log.info("scheduler %s: %d workers", scheduler, len(client.scheduler_info().get("workers", {})))
        yield client


def _ask(client, futures, progress=None):
    """Results of ``futures`` in order; ``progress(done, total)`` after each.
    On an error the rest are cancelled and the first error is raised."""
    distributed = _distributed()
    index = {f.key: i for i, f in enumerate(futures)}
    out = [None] * len(futures)
    try:
        for done, fut in enumerate(distributed.as_completed(futures), start=1):
            out[index[fut.key]] = fut.result()
            if progress is not None:
                progress(done, len(futures))
    except BaseException:
        client.cancel(futures)
        raise
    return out


# -- the kernel a worker holds ----------------------------------------------------------------

@dataclass(frozen=True)
class Compensator:
    """What every block needs to be compensated: the maps, the pose and the
    options. Sent to each worker once; called per block.

    Parameters
    ----------
    error_map : ErrorMap or ErrorMapSet
        The machine's component errors (a set needs a temperature).
    pose : tuple of 3 float
        Euler 3-1-3 angles alpha, beta, gamma, degrees.
    offset : tuple of 3 float
        Mount offset l1 = (U1, V1, W1), mm.
    temperature : float, optional
        Machine temperature for every point, C; with a set and no value, each
        block's T column.
    out_of_range, nan_policy, temperature_tolerance
        As in :func:`cmmpose.compensate`.
    uncertainty : UncertaintySources, optional
        Also each point's uncertainty from these sources (:meth:`uncertain`).
    uncertainty_detail : {'standard', 'covariance', 'split'}
        What of it (:mod:`cmmpose.uncertainty_columns`).
    """

    error_map: ErrorMap | ErrorMapSet
    pose: tuple[float, float, float]
    offset: tuple[float, float, float]
    temperature: float | None = None
    out_of_range: str = "raise"
    nan_policy: str = "raise"
    temperature_tolerance: float = TEMPERATURE_TOLERANCE
    uncertainty: UncertaintySources | None = None
    uncertainty_detail: str = "standard"

    @classmethod
    def make(cls, error_map, pose, offset, temperature=None, *, out_of_range=None, nan_policy="raise",
             temperature_tolerance=None, temperature_policy: TemperaturePolicy | None = None,
             uncertainty: bool | UncertaintySources | None = None,
             uncertainty_detail: str = "standard") -> Compensator:
        """Checked arguments, as :func:`cmmpose.compensate` takes them (the
        keywords override ``temperature_policy``'s map side); with
        ``uncertainty`` (True: the maps' stated sources), a set of sources
        that states none is an ``InputError`` (every u would be 0)."""
        if not isinstance(error_map, (ErrorMap, ErrorMapSet)):
            raise InputTypeError(f"error_map: expected an ErrorMap or ErrorMapSet, got {type(error_map).__name__}")
        policy = as_policy(temperature_policy, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
        out_of_range, temperature_tolerance = policy.out_of_range, policy.temperature_tolerance
        if nan_policy not in ("raise", "propagate"):
            raise InputError(f"nan_policy: expected 'raise' or 'propagate', got {nan_policy!r}")
        if temperature is not None:
            try:
                temperature = float(temperature)
            except (TypeError, ValueError):
                raise InputError(f"temperature: expected a number (C), got {temperature!r}") from None
        if uncertainty is not None and uncertainty is not False:
            uncertainty = UncertaintySources() if uncertainty is True else uncertainty
            if not isinstance(uncertainty, UncertaintySources):
                raise InputTypeError(f"uncertainty: expected True or an UncertaintySources, "
                                     f"got {type(uncertainty).__name__}")
            require_stated(uncertainty, error_map)
        else:
            uncertainty = None
        return cls(error_map, pose_tuple(pose), as_triple("offset", offset), temperature, out_of_range, nan_policy,
                   float(temperature_tolerance), uncertainty, check_detail(uncertainty_detail))

    @property
    def needs_temperature_column(self) -> bool:
        """Whether each block must bring its own temperatures (a set, no fixed value)."""
        return isinstance(self.error_map, ErrorMapSet) and self.temperature is None

    @property
    def columns(self) -> tuple[str, ...]:
        """The uncertainty columns each block gains (none without ``uncertainty``)."""
        return () if self.uncertainty is None else uncertainty_columns(self.uncertainty_detail)

    def _temperature(self, temps):
        if not isinstance(self.error_map, ErrorMapSet):
            return None
        t = self.temperature if self.temperature is not None else temps
        if t is None:
            raise InputError("temperature: a map set needs a temperature or a T column")
        return t

    def __call__(self, uv: np.ndarray, scales: np.ndarray, temps: np.ndarray | None) -> tuple[np.ndarray, KernelReport]:
        """Compensated X, Y, Z (N, 3) mm of one block, and the kernel's report
        (no warnings: the caller sums the reports and warns once)."""
        t = self._temperature(temps)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return compensate(uv, scales, self.error_map, self.pose, self.offset, t, out_of_range=self.out_of_range,
                              nan_policy=self.nan_policy, temperature_tolerance=self.temperature_tolerance,
                              return_report=True)

    def uncertain(self, uv: np.ndarray, scales: np.ndarray,
                  temps: np.ndarray | None) -> tuple[UncertainPoints, KernelReport]:
        """With ``uncertainty``: one block's points and their uncertainty,
        the same kernel call as ``compensate(..., uncertainty=)``."""
        t = self._temperature(temps)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return compensate(uv, scales, self.error_map, self.pose, self.offset, t, out_of_range=self.out_of_range,
                              nan_policy=self.nan_policy, temperature_tolerance=self.temperature_tolerance,
                              return_report=True, uncertainty=self.uncertainty,
                              uncertainty_detail=self.uncertainty_detail)


# -- Parquet datasets -------------------------------------------------------------------------

@dataclass(frozen=True)
class DatasetResult:
    """What :func:`compensate_dataset` did.

    Attributes
    ----------
    outputs : list of Path
        The files written, in the order of the inputs.
    points : int
        Points compensated.
    report : KernelReport
        The kernel's counts summed over the dataset.
    kernel_seconds : float
        Time spent in the kernel, summed over the workers, s.
    elapsed : float
        Wall time, s (scheduler start-up included).
    uncertainty : UncertaintyTally or None
        With ``uncertainty=``: the budget and the rms and largest u per axis
        over the dataset (:class:`cmmpose.uncertainty_columns.UncertaintyTally`).
    """

    outputs: list[Path]
    points: int
    report: KernelReport
    kernel_seconds: float
    elapsed: float
    uncertainty: UncertaintyTally | None = None


#: Suffixes of a dataset's Parquet files, any case (those of the Parquet point format).
PARQUET_SUFFIXES = (".parquet", ".pq")


def dataset_files(dataset_dir) -> list[Path]:
    """The Parquet files of a dataset folder (``*.parquet`` or ``*.pq``, any
    case; sorted by name). Any other file is named in a warning (logged) as
    not compensated, except the metadata other tools leave in a dataset
    (names starting with ``.`` or ``_``, such as ``_SUCCESS``).

    Raises
    ------
    InputError
        The folder does not exist or holds no Parquet file (naming it).
    """
    folder = Path(dataset_dir)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    entries = sorted(folder.iterdir())
    files = [p for p in entries if p.suffix.lower() in PARQUET_SUFFIXES and p.is_file()]
    if not files:
        raise InputError(f"{folder}: no Parquet files (.parquet, .pq) in the folder")
    others = [p.name for p in entries if p not in files and not p.name.startswith((".", "_"))]
    if others:
        shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
        _log.warning("%s: %d entr%s not Parquet, not compensated: %s", folder, len(others),
                     "y is" if len(others) == 1 else "ies are", shown)
    return files


def dataset_temperature_range(dataset_dir) -> tuple[float, float] | None:
    """(lowest, highest) T (C) over a dataset, from the files' Parquet
    statistics alone (no data read); None when a file has no T column or
    no statistics for it."""
    lo, hi = math.inf, -math.inf
    for path in dataset_files(dataset_dir):
        try:
            meta = pq.read_metadata(path)
        except (OSError, pa.ArrowException) as exc:
            raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
        names = meta.schema.to_arrow_schema().names
        if "T" not in names:
            return None
        k = names.index("T")
        for g in range(meta.num_row_groups):
            stats = meta.row_group(g).column(k).statistics
            if stats is None or not stats.has_min_max:
                return None
            lo, hi = min(lo, float(stats.min)), max(hi, float(stats.max))
    return (lo, hi) if lo <= hi else None


def _plan_file(path: Path, needs_t: bool, written: tuple = ()) -> tuple[int, list[str]]:
    """Rows and pass-through columns of one dataset file, from its footer
    only; the file and the column are named when one is missing or not
    numeric, or would be written over (X, Y, Z and the ``written`` uncertainty columns)."""
    try:
        meta = pq.read_metadata(path)
        schema = meta.schema.to_arrow_schema()
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
    names = schema.names
    if len(set(names)) != len(names):  # before any lookup by name
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{path}: column {dup!r} appears twice")
    wanted = INPUT_COLUMNS + (("T",) if needs_t else ())
    for c in wanted:
        if c not in names:
            hint = " (a map set needs --temperature or a T column)" if c == "T" else ""
            raise InputError(f"{path}: missing column {c!r}{hint}")
        t = schema.field(c).type
        if not (pa.types.is_floating(t) or pa.types.is_integer(t)):
            raise InputError(f"{path}: column {c!r} has type {t}, expected numbers")
    for c in OUTPUT_COLUMNS + tuple(written):
        if c in names:
            raise InputError(f"{path}: has a column {c!r}, which the output would write over")
    passthrough = [c for c in names if c not in INPUT_COLUMNS + ("T",)]
    return meta.num_rows, passthrough


def _float_column(batch: pa.RecordBatch, name: str) -> np.ndarray:
    col = batch.column(batch.schema.get_field_index(name))
    return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)


def _compensate_file(kernel: Compensator, src: str, dst: str, passthrough: list[str], batch_rows: int,
                     topic: str | None) -> tuple[int, KernelReport, float, UncertaintyTally | None]:
    """One dataset file through the kernel, batch by batch, into ``dst``
    (written under a temporary name, renamed when whole); with the kernel's
    ``uncertainty``, the u columns after X, Y, Z and their tally. Runs on a worker."""
    worker = None
    if topic is not None:
        try:
            from distributed import get_worker

            worker = get_worker()
        except (ImportError, ValueError):
            worker = None
    src_p, dst_p = Path(src), Path(dst)
    reports, kernel_s, n = [], 0.0, 0
    tally = UncertaintyTally() if kernel.uncertainty is not None else None
    writer = out = None
    try:
        out = AtomicFile(dst_p, "wb", inputs=[src_p])  # cmmpose.atomicfile: renamed into place when whole
        pf = pq.ParquetFile(src_p)
        in_schema = pf.schema_arrow
        out_schema = pa.schema([pa.field(c, pa.float64()) for c in OUTPUT_COLUMNS + kernel.columns]
                               + [in_schema.field(c) for c in passthrough], metadata=in_schema.metadata)
        # X, Y, Z never repeat: no dictionary for them (it only costs time); parquet_options
        writer = pq.ParquetWriter(out.f, out_schema, **parquet_options(out_schema))
        use_t = kernel.needs_temperature_column
        for batch in pf.iter_batches(batch_size=batch_rows):
            m = batch.num_rows
            uv = np.empty((m, 2))
            scales = np.empty((m, 3))
            for k, c in enumerate(("u", "v")):
                uv[:, k] = _float_column(batch, c)
            for k, c in enumerate(("D", "E", "F")):
                scales[:, k] = _float_column(batch, c)
            temps = _float_column(batch, "T") if use_t else None
            t0 = time.perf_counter()
            try:
                if tally is None:
                    xyz, rep = kernel(uv, scales, temps)
                    u_cols = {}
                else:
                    points, rep = kernel.uncertain(uv, scales, temps)
                    xyz, u_cols = points.xyz, columns_of(points)
                    tally.add(points.u)
            except Error as exc:
                message, fields = quoting(exc, f"{src_p}: rows {n}..{n + m - 1} (from 0): ")
                raise type(exc)(message, **fields) from None
            kernel_s += time.perf_counter() - t0
            cols = [pa.array(xyz[:, k]) for k in range(3)]
            cols += [pa.array(np.ascontiguousarray(v)) for v in u_cols.values()]
            cols += [batch.column(batch.schema.get_field_index(c)) for c in passthrough]
            writer.write_table(pa.Table.from_arrays(cols, schema=out_schema))
            reports.append(rep)
            n += m
            if worker is not None:
                worker.log_event(topic, m)
        writer.close()
        writer = None
        out.commit()
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{src_p}: cannot be compensated into {dst_p} ({exc})") from None
    finally:
        if writer is not None:
            with contextlib.suppress(OSError, pa.ArrowException):
                writer.close()
        if out is not None:
            out.abort()  # nothing once committed
    return n, KernelReport.total(reports), kernel_s, tally


def compensate_dataset(dataset_dir, out_dir, error_map: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                       out_of_range: str | None = None, nan_policy: str = "raise",
                       temperature_tolerance: float | None = None, scheduler="threads",
                       batch_rows: int = BATCH_ROWS, progress=None,
                       scheduler_timeout: float = SCHEDULER_TIMEOUT,
                       temperature_policy: TemperaturePolicy | None = None,
                       uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard",
                       uncertainty_origins: dict | None = None) -> DatasetResult:
    """Compensate a folder of Parquet scans into a folder of Parquet files.

    Each input ``NAME.parquet`` (columns ``u, v`` mm, ``D, E, F`` mm, ``T`` C
    when a map set takes its temperatures from the file, and any others)
    becomes ``out_dir/NAME.parquet`` with ``X, Y, Z`` (mm, machine frame,
    float64) followed by the input's other columns (all but ``u, v, D, E, F,
    T``), unchanged, row for row. One task per file, which streams it in
    batches of ``batch_rows``: memory stays bounded whatever the dataset's
    size. The results equal :func:`cmmpose.compensate` on the same points
    bit for bit.

    Parameters
    ----------
    dataset_dir, out_dir : path-like
        The input folder and the output folder (made if missing; must differ).
        An output file is written under a temporary name and renamed when
        whole; an existing one of the same name is replaced.
    error_map, pose, offset, temperature, out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As in :func:`cmmpose.compensate` (``temperature`` a float, C, or None).
    scheduler : str or distributed.Client
        Where the work runs (see :func:`scheduler_client`); a cluster's workers
        must see both folders (a shared file system).
    batch_rows : int
        Rows read, compensated and written at a time per task.
    progress : callable, optional
        ``progress(points_done, points_total)``, called in this process as
        batches finish.
    scheduler_timeout : float
        s: the longest wait for a scheduler at an address to connect and
        greet (:func:`scheduler_client`'s ``timeout``).
    uncertainty, uncertainty_detail, uncertainty_origins
        As :func:`cmmpose.compensate_file` takes them: the u columns (and
        covariance) after X, Y, Z, each batch by the same kernel call.

    Returns
    -------
    DatasetResult

    Raises
    ------
    InputError
        Naming the file (and column) at fault: no Parquet file, a missing or
        non-numeric column, an unreadable file, a bad row (the file and its
        row span). Files already written stay; the one in progress does not.
    SchedulerError
        Without the dask extra, a malformed spec, or a scheduler that cannot
        be reached or does not answer within ``scheduler_timeout``.
    """
    t_start = time.perf_counter()
    if isinstance(error_map, ErrorMap):
        # One map holds at one temperature: said (a MapTemperatureWarning) when the given temperature, or the T
        # columns' range from the files' statistics (no data read), is not the map's own.
        given = temperature if temperature is not None else dataset_temperature_range(dataset_dir)
        if given is not None:
            policy = as_policy(temperature_policy, temperature_tolerance=temperature_tolerance)
            warn_single_map(error_map, given, policy.temperature_tolerance)
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    if not isinstance(batch_rows, (int, np.integer)) or batch_rows < 1:
        raise InputError(f"batch_rows: expected a positive integer, got {batch_rows!r}")
    files = dataset_files(dataset_dir)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.exists() and out.resolve() == Path(dataset_dir).resolve():
        raise InputError(f"{out}: the output folder is the input folder; the inputs would be replaced")
    plans = [_plan_file(f, kernel.needs_temperature_column, kernel.columns) for f in files]
    total = sum(rows for rows, _ in plans)
    ensure_folder(out)
    outputs = [out / f.name for f in files]
    topic = f"cmmpose-progress-{uuid.uuid4().hex}"
    done, finished = 0, False

    def on_event(event):
        """A worker finished a batch (called on the client's event loop)."""
        nonlocal done
        done += int(event[1])
        if not finished:
            progress(min(done, total), total)

    with scheduler_client(scheduler, timeout=scheduler_timeout) as client:
        shared = client.scatter(kernel, broadcast=True, hash=False)
        if progress is not None:
            client.subscribe_topic(topic, on_event)
        try:
            # absolute paths: a cluster's workers do not share this process's working folder
            futures = [client.submit(_compensate_file, shared, str(f.absolute()), str(o.absolute()), passthrough,
                                     int(batch_rows), topic,
                                     key=f"cmmpose-compensate-{f.name}-{topic[-8:]}", pure=False)
                       for f, o, (_, passthrough) in zip(files, outputs, plans)]
            results = _ask(client, futures)
        finally:
            finished = True
            if progress is not None:
                client.unsubscribe_topic(topic)
    if progress is not None:
        progress(total, total)
    report = KernelReport.total(r for _, r, _, _ in results)
    warn_clamped(report)
    tally = None
    if kernel.uncertainty is not None:
        tally = UncertaintyTally(budget=budget_rows(kernel.uncertainty, error_map, uncertainty_origins))
        for *_, part in results:
            tally = tally.merge(part)
        log_budget(tally, str(out))
    return DatasetResult(outputs, sum(n for n, *_ in results), report, sum(s for _, _, s, _ in results),
                         time.perf_counter() - t_start, tally)


# -- lazy collections -------------------------------------------------------------------------

def _block(points: np.ndarray, kernel: Compensator) -> np.ndarray:
    """One (n, 5 or 6) block of u, v, D, E, F[, T] -> (n, 3) X, Y, Z mm
    (with uncertainty: and the uncertainty columns, mm and mm^2)."""
    uv = np.ascontiguousarray(points[:, 0:2], dtype=np.float64)
    scales = np.ascontiguousarray(points[:, 2:5], dtype=np.float64)
    temps = np.ascontiguousarray(points[:, 5], dtype=np.float64) if points.shape[1] == 6 else None
    if kernel.uncertainty is None:
        return kernel(uv, scales, temps)[0]
    p = kernel.uncertain(uv, scales, temps)[0]
    return np.column_stack([p.xyz, *columns_of(p).values()])


def compensate_array(points, error_map: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                     out_of_range: str | None = None, nan_policy: str = "raise",
                     temperature_tolerance: float | None = None, temperature_policy: TemperaturePolicy | None = None,
                     uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard"):
    """Compensate a Dask array of points, lazily, block by block.

    Parameters
    ----------
    points : dask.array.Array, shape (N, 5) or (N, 6)
        Columns u, v (mm), D, E, F (mm)[, T (C)], chunked along rows (the
        columns are made one chunk).
    error_map, pose, offset, temperature, out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As in :func:`cmmpose.compensate` (``temperature`` a float, C; with a
        set and none, column T).
    uncertainty, uncertainty_detail
        As in :func:`cmmpose.compensate`: each block's uncertainty by the
        same kernel call.

    Returns
    -------
    dask.array.Array, shape (N, 3) or (N, 3 + k)
        X, Y, Z in mm, float64, chunked as ``points`` along rows; computing it
        calls the kernel once per block. With ``uncertainty``, k more columns
        in the order of :func:`cmmpose.uncertainty_columns.uncertainty_columns`
        (u_x, u_y, u_z mm; the covariance and its common part, mm^2: k = 3,
        9 or 15). The maps are one key of the graph,
        sent to each worker once. Kernel warnings are not raised per block;
        ``out_of_range='raise'`` still raises.
    """
    _distributed()
    import dask
    import dask.array as da

    if not isinstance(points, da.Array) or points.ndim != 2 or points.shape[1] not in (5, 6):
        raise InputError(f"points: expected a dask array of shape (N, 5) or (N, 6) (u, v, D, E, F[, T]), "
                         f"got {type(points).__name__} {getattr(points, 'shape', '')}")
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    if kernel.needs_temperature_column and points.shape[1] != 6:
        raise InputError("points: a map set without a temperature needs a sixth column T (C)")
    points = points.rechunk({1: -1})
    shared = dask.delayed(kernel, pure=True, traverse=False)
    width = 3 + len(kernel.columns)
    return da.map_blocks(_block, points, shared, dtype=np.float64, chunks=(points.chunks[0], (width,)),
                         meta=np.empty((0, width), dtype=np.float64))


def _partition(frame, kernel: Compensator, passthrough: list[str]):
    """One pandas partition -> X, Y, Z and the pass-through columns."""
    import pandas as pd

    uv = np.column_stack([frame[c].to_numpy(dtype=np.float64) for c in ("u", "v")]) if len(frame) else np.empty((0, 2))
    scales = np.column_stack([frame[c].to_numpy(dtype=np.float64) for c in ("D", "E", "F")]) if len(frame) \
        else np.empty((0, 3))
    temps = frame["T"].to_numpy(dtype=np.float64) if kernel.needs_temperature_column else None
    u_cols = {}
    if not len(frame):
        xyz = np.empty((0, 3))
        u_cols = {c: np.empty(0) for c in kernel.columns}
    elif kernel.uncertainty is None:
        xyz = kernel(uv, scales, temps)[0]
    else:
        p = kernel.uncertain(uv, scales, temps)[0]
        xyz, u_cols = p.xyz, columns_of(p)
    out = pd.DataFrame({**{c: xyz[:, k] for k, c in enumerate(OUTPUT_COLUMNS)}, **u_cols}, index=frame.index)
    for c in passthrough:
        out[c] = frame[c]
    return out


def compensate_dataframe(frame, error_map: ErrorMap | ErrorMapSet, pose, offset, temperature=None, *,
                         out_of_range: str | None = None, nan_policy: str = "raise",
                         temperature_tolerance: float | None = None, temperature_policy: TemperaturePolicy | None = None,
                         uncertainty: bool | UncertaintySources | None = None, uncertainty_detail: str = "standard"):
    """Compensate a Dask dataframe, lazily, partition by partition.

    Parameters
    ----------
    frame : dask.dataframe.DataFrame
        Columns u, v, D, E, F (mm)[, T (C)] and any others.
    error_map, pose, offset, temperature, out_of_range, nan_policy, temperature_tolerance, temperature_policy
        As in :func:`compensate_array`.
    uncertainty, uncertainty_detail
        As in :func:`compensate_array`: the uncertainty columns
        (``u_x_mm`` ..., :mod:`cmmpose.uncertainty_columns`) after X, Y, Z.

    Returns
    -------
    dask.dataframe.DataFrame
        X, Y, Z (mm, float64), the uncertainty columns when asked, and the
        other columns of ``frame`` (all but u, v, D, E, F, T), partitioned as
        ``frame``; e.g. ``.to_parquet(folder)`` writes it partition by partition.
    """
    _distributed()
    import dask

    if not hasattr(frame, "map_partitions") or not hasattr(frame, "columns"):
        raise InputTypeError(f"frame: expected a dask dataframe, got {type(frame).__name__}")
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    names = list(frame.columns)
    for c in INPUT_COLUMNS + (("T",) if kernel.needs_temperature_column else ()):
        if c not in names:
            raise InputError(f"frame: missing column {c!r}")
    for c in OUTPUT_COLUMNS + kernel.columns:
        if c in names:
            raise InputError(f"frame: has a column {c!r}, which the output would write over")
    passthrough = [c for c in names if c not in INPUT_COLUMNS + ("T",)]
    meta = _partition(frame._meta, kernel, passthrough)
    shared = dask.delayed(kernel, pure=True, traverse=False)
    return frame.map_partitions(_partition, shared, passthrough, meta=meta)


# -- fleets of runs ---------------------------------------------------------------------------

def _on_run(func, run_dir: str, args: tuple, kwargs: dict):
    """``func(Run.load(run_dir), *args, **kwargs)`` on a worker; an error names the run."""
    from .run import Run

    try:
        return func(Run.load(run_dir), *args, **kwargs)
    except Error as exc:
        if run_dir in str(exc):
            raise
        message, fields = quoting(exc, f"{run_dir}: ")
        raise type(exc)(message, **fields) from None


def map_runs(func, run_dirs, *shared, scheduler="threads", progress=None, scheduler_timeout: float = SCHEDULER_TIMEOUT,
             **kwargs) -> list:
    """``func(run, *shared, **kwargs)`` for every run folder, one task per
    run on the scheduler; the run is loaded on the worker.

    Parameters
    ----------
    func : callable
        Takes a :class:`cmmpose.Run` first; must pickle for worker processes
        (a module-level function).
    run_dirs : sequence of path-like
        Run folders (a cluster's workers must see them).
    *shared
        Arguments every call takes (maps, a model): sent to each worker once.
    scheduler : str or distributed.Client
        See :func:`scheduler_client`.
    progress : callable, optional
        ``progress(runs_done, runs_total)`` in this process.
    scheduler_timeout : float
        s: see :func:`scheduler_client`'s ``timeout``.
    **kwargs
        Small keyword arguments, sent with each task.

    Returns
    -------
    list
        ``func``'s results, in the order of ``run_dirs``.

    Raises
    ------
    RunError, Error
        The first run's error, its message naming the run folder.
    """
    run_dirs = [str(Path(r).absolute()) for r in run_dirs]  # a cluster's workers have another working folder
    if not run_dirs:
        raise InputError("run_dirs: no run folders given")
    with scheduler_client(scheduler, timeout=scheduler_timeout) as client:
        args = tuple(client.scatter(a, broadcast=True, hash=False) for a in shared)
        token = uuid.uuid4().hex[:8]
        futures = [client.submit(_on_run, func, r, args, kwargs, key=f"cmmpose-run-{i}-{Path(r).name}-{token}",
                                 pure=False)
                   for i, r in enumerate(run_dirs)]
        return _ask(client, futures, progress)


def _maps_named_by(run):
    """The maps run.json names (the bundled thesis set), or RunError."""
    from .errors import RunError

    if run.maps.get("kind") == "bundled" and run.maps.get("name") == "thesis":
        return ErrorMapSet.thesis().with_kinematics(run.maps.get("kinematics", "thesis"))
    raise RunError("run.json names no bundled maps: give the maps")


def _evaluate_run(run, maps, **kwargs):
    from .evaluation.artefact import evaluate_artefact
    from .evaluation.artefact_balls import is_artefact_run
    from .evaluation.ballbar import evaluate

    if isinstance(maps, str) and maps == "run":
        maps = _maps_named_by(run)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if is_artefact_run(run):  # a plate or step gauge: deviations and length errors, not ballbar lengths
            options = {k: v for k, v in kwargs.items() if k in ("temperature", "reject", "out_of_range",
                                                                "temperature_tolerance", "log_hold")}
            ev = evaluate_artefact(run, maps, **options)
        else:
            ev = evaluate(run, maps, **kwargs)
    ev.provenance.setdefault("run", {})["created"] = run.created  # for the fleet's trend
    return ev


def evaluate_runs(run_dirs, maps="run", *, scheduler="threads", progress=None,
                  scheduler_timeout: float = SCHEDULER_TIMEOUT, **kwargs) -> list:
    """:func:`cmmpose.evaluate` of every run, one task per run.

    Parameters
    ----------
    run_dirs : sequence of path-like
        Run folders.
    maps : ErrorMap, ErrorMapSet, None or 'run'
        The compensation maps for every run (sent to each worker once), None
        for uncompensated only, or ``'run'``: the bundled maps each run.json
        names.
    scheduler, progress, scheduler_timeout
        As in :func:`map_runs`.
    **kwargs
        :func:`cmmpose.evaluate`'s options (temperature, reject, expansion,
        out_of_range, temperature_tolerance, log_hold).

    Returns
    -------
    list of Evaluation
        In the order of ``run_dirs``; warnings are in each one's
        ``provenance['notes']``.
    """
    return map_runs(_evaluate_run, run_dirs, maps, scheduler=scheduler, progress=progress,
                    scheduler_timeout=scheduler_timeout, **kwargs)


def _diagnose_run(run, model, temperature=None, **kwargs):
    import dataclasses

    from .diagnosis import diagnose
    from .model import Model

    if model is None or (isinstance(model, str) and model == "run"):
        model = Model(_maps_named_by(run), temperature=temperature)
    elif temperature is not None:
        model = dataclasses.replace(Model(model) if not isinstance(model, Model) else model,
                                    temperature=float(temperature))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return diagnose(run, model, **kwargs)


def diagnose_runs(run_dirs, model=None, *, scheduler="threads", progress=None,
                  scheduler_timeout: float = SCHEDULER_TIMEOUT, **kwargs) -> list:
    """:func:`cmmpose.diagnose` of every run, one task per run.

    Parameters
    ----------
    run_dirs : sequence of path-like
        Run folders.
    model : Model, ErrorMap, ErrorMapSet, None or 'run'
        The starting model for every run (sent to each worker once); None or
        ``'run'``: the bundled maps each run.json names (with their
        configuration).
    scheduler, progress, scheduler_timeout
        As in :func:`map_runs`.
    **kwargs
        :func:`cmmpose.diagnose`'s options (add, auto, max_effects,
        out_of_range, temperature_tolerance, log_hold, ...), and
        ``temperature`` (C) for the model instead of the runs' logs.

    Returns
    -------
    list of Diagnosis
        In the order of ``run_dirs``.
    """
    return map_runs(_diagnose_run, run_dirs, model, scheduler=scheduler, progress=progress,
                    scheduler_timeout=scheduler_timeout, **kwargs)


@dataclass(frozen=True)
class FleetRow:
    """One run of a fleet summary.

    Attributes
    ----------
    run : str
        The run folder.
    created : str
        When the run was made (ISO-8601 UTC, from its provenance), or ''.
    temperature : float
        Mean machine temperature over the run, C (NaN if unknown).
    rms_uncompensated, b89_uncompensated : float
        rms accuracy error and B89 value of the uncompensated lengths, mm;
        of an artefact run (``kind`` not 'ballbar'): the rms ball deviation
        and the largest |length error| (E) over all placements.
    rms_compensated, b89_compensated : float
        The same compensated, mm (NaN without maps).
    kind : str
        'ballbar', or the artefact's kind ('ball-plate', 'step-gauge', ...).
    """

    run: str
    created: str
    temperature: float
    rms_uncompensated: float
    b89_uncompensated: float
    rms_compensated: float
    b89_compensated: float
    kind: str = "ballbar"


def fleet_summary(run_dirs, evaluations) -> list[FleetRow]:
    """One :class:`FleetRow` per run from :func:`evaluate_runs`' results."""
    from .evaluation.artefact import ArtefactEvaluation

    def artefact_figures(result):  # rms deviation and largest |E| of an artefact run, mm
        if result is None:
            return math.nan, math.nan
        worst = result.largest_length_error
        return result.rms, math.nan if worst is None else abs(worst.error)

    rows = []
    for r, ev in zip(run_dirs, evaluations):
        t = ev.provenance.get("temperature", {}).get("mean_C", math.nan)
        created = str(ev.provenance.get("run", {}).get("created", ""))
        if isinstance(ev, ArtefactEvaluation):
            rows.append(FleetRow(str(r), created, float(t), *artefact_figures(ev.uncompensated),
                                 *artefact_figures(ev.compensated), kind=ev.artefact.kind))
            continue
        c = ev.compensated
        rows.append(FleetRow(str(r), created, float(t),
                             ev.uncompensated.rms_accuracy_error, ev.uncompensated.b89,
                             math.nan if c is None else c.rms_accuracy_error, math.nan if c is None else c.b89))
    return rows
