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

from .compensator import INPUT_COLUMNS, OUTPUT_COLUMNS, Compensator
from .dataset import BATCH_ROWS, DatasetResult, compensate_dataset, dataset_files, dataset_temperature_range
from .fleet import FleetRow, diagnose_runs, evaluate_runs, fleet_summary, map_runs
from .lazy import compensate_array, compensate_dataframe
from .scheduler import SCHEDULER_TIMEOUT, SCHEDULERS, check_scheduler, scheduler_client

__all__ = ["SCHEDULERS", "SCHEDULER_TIMEOUT", "check_scheduler", "scheduler_client", "Compensator", "DatasetResult",
           "compensate_dataset", "dataset_files", "dataset_temperature_range", "BATCH_ROWS",
           "compensate_array", "compensate_dataframe", "map_runs", "evaluate_runs", "diagnose_runs",
           "FleetRow", "fleet_summary", "INPUT_COLUMNS", "OUTPUT_COLUMNS"]
