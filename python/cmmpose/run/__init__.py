"""The measurement run format: one directory per run, simulated or recorded by
acquisition (docs/formats.md, "Measurement run").

A run directory holds ``run.json`` (schema, artefact, which maps apply, the
temperature channels, free metadata) and four tables: ``points``, ``scans``,
``poses`` and, when there are temperature channels, ``temperatures``. Tables
are Parquet files; a table whose ``.parquet`` file is missing is read from a
``.csv`` file of the same name with a header row of the same column names.
An optional ``truth/`` folder holds what a simulator knows and analysis must
never read: :meth:`Run.load` never opens it, :func:`load_truth` does.

Units: t in s, u, v, D, E, F, U1, V1, W1 in mm, alpha, beta, gamma in degrees
(Euler 3-1-3), sweep speed in mm/s, temperatures in degrees C. Rows in error
messages are counted from 0 (the first data row); CSV messages also give the
line of the file.
"""

from ..schemas.run import CHANNEL_ROLES, SCHEMA, SCHEMA_VERSION, SUPPORTED_SCHEMA_VERSIONS
from ..errors import RunError
from ._files import RUN_FILES, check_run_target, load_truth
from ._tables import POINTS_COLUMNS, POSES_COLUMNS, SCANS_COLUMNS
from .run import Run

__all__ = [
    "Run",
    "check_run_target",
    "RunError",
    "load_truth",
    "SCHEMA",
    "SCHEMA_VERSION",
    "SUPPORTED_SCHEMA_VERSIONS",
    "CHANNEL_ROLES",
    "POINTS_COLUMNS",
    "SCANS_COLUMNS",
    "POSES_COLUMNS",
    "RUN_FILES",
]
