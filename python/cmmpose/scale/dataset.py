"""A folder of Parquet files (``u, v, D, E, F[, T]`` and any other columns) compensated into a folder of Parquet
files (``X, Y, Z`` and the other columns), one output per input, read and written row group by row group: memory
is bounded by the batch size, whatever the dataset's size.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomicfile import AtomicFile, check_outputs_free, ensure_folder
from ..errormap import ErrorMap, ErrorMapSet, warn_single_map
from ..errors import Error, InputError, quoting, warn_clamped
from ..temperature import TemperaturePolicy, as_policy
from ..kernel_report import KernelReport
from ..formats.pointformats.common import parquet_options
from ..point_uncertainty import UncertaintySources
from ..uncertainty_columns import StatedMaps, UncertaintyTally, budget_rows, columns_of, log_budget
from .._lazy import LazyModule
from .compensator import INPUT_COLUMNS, OUTPUT_COLUMNS, Compensator
from .scheduler import SCHEDULER_TIMEOUT, gather_results, scheduler_client

_log = logging.getLogger("cmmpose.scale")

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pq = LazyModule("pyarrow.parquet")

#: Rows read, compensated and written at a time by default (about 40 MB in flight per task;
#: batches that fit in the CPU caches' reach read faster than larger ones).
BATCH_ROWS = 1 << 18


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
                     topic: str | None, overwrite: bool = True) -> tuple[int, KernelReport, float,
                                                                    UncertaintyTally | None]:
    """One dataset file through the kernel, batch by batch, into ``dst``
    (written under a temporary name, renamed when whole; without
    ``overwrite`` created exclusively, so a file another writer made
    meanwhile is never replaced); with the kernel's ``uncertainty``, the u
    columns after X, Y, Z and their tally. Runs on a worker."""
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
        out = AtomicFile(dst_p, "wb", inputs=[src_p], overwrite=overwrite)  # renamed into place when whole
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
                       uncertainty_origins: dict | None = None, overwrite: bool = True) -> DatasetResult:
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
        whole; an existing one of the same name is replaced (see
        ``overwrite``).
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
    overwrite : bool
        False: an output file that exists already is refused before any
        work (``OutputError``), and each is created exclusively (of two
        writers of one name, one fails); ``cmmpose compensate`` without
        ``--overwrite``.

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
        _warn_single_map(error_map, dataset_dir, temperature, temperature_policy, temperature_tolerance)
    kernel = Compensator.make(error_map, pose, offset, temperature, out_of_range=out_of_range,
                              nan_policy=nan_policy, temperature_tolerance=temperature_tolerance,
                              temperature_policy=temperature_policy, uncertainty=uncertainty,
                              uncertainty_detail=uncertainty_detail)
    if not isinstance(batch_rows, (int, np.integer)) or batch_rows < 1:
        raise InputError(f"batch_rows: expected a positive integer, got {batch_rows!r}")
    files = dataset_files(dataset_dir)
    out = _output_folder(out_dir, dataset_dir)
    outputs = [out / f.name for f in files]
    if out.exists():  # before any work: none an input, none existing unless overwrite
        check_outputs_free(outputs, files, overwrite=overwrite)
    plans = [_plan_file(f, kernel.needs_temperature_column, kernel.columns) for f in files]
    total = sum(rows for rows, _ in plans)
    ensure_folder(out)
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
                                     int(batch_rows), topic, bool(overwrite),
                                     key=f"cmmpose-compensate-{f.name}-{topic[-8:]}", pure=False)
                       for f, o, (_, passthrough) in zip(files, outputs, plans)]
            results = gather_results(client, futures)
        finally:
            finished = True
            if progress is not None:
                client.unsubscribe_topic(topic)
    if progress is not None:
        progress(total, total)
    report = KernelReport.total(r for _, r, _, _ in results)
    warn_clamped(report)
    tally = _dataset_tally(kernel, error_map, uncertainty_origins, results, out)
    return DatasetResult(outputs, sum(n for n, *_ in results), report, sum(s for _, _, s, _ in results),
                         time.perf_counter() - t_start, tally)


def _warn_single_map(error_map: ErrorMap, dataset_dir, temperature, temperature_policy, temperature_tolerance) -> None:
    """One map holds at one temperature: said (a MapTemperatureWarning) when the given temperature, or the T
    columns' range from the files' statistics (no data read), is not the map's own."""
    given = temperature if temperature is not None else dataset_temperature_range(dataset_dir)
    if given is not None:
        policy = as_policy(temperature_policy, temperature_tolerance=temperature_tolerance)
        warn_single_map(error_map, given, policy.temperature_tolerance)


def _output_folder(out_dir, dataset_dir) -> Path:
    """The output folder: a folder or nothing yet, never the input folder."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.exists() and out.resolve() == Path(dataset_dir).resolve():
        raise InputError(f"{out}: the output folder is the input folder; the inputs would be replaced")
    return out


def _dataset_tally(kernel: Compensator, error_map, uncertainty_origins, results, out: Path) -> UncertaintyTally | None:
    """With uncertainty: the budget and the files' tallies merged into one, logged."""
    if kernel.uncertainty is None:
        return None
    stated = StatedMaps.of(kernel.uncertainty, error_map)
    tally = UncertaintyTally(budget=budget_rows(kernel.uncertainty, stated, uncertainty_origins))
    for *_, part in results:
        tally = tally.merge(part)
    log_budget(tally, str(out))
    return tally
