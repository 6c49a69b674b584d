"""The ``Run``: one measurement run's tables and run.json fields, checked once when made; loaded from and saved
to a run folder (docs/formats.md, "Measurement run").
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from functools import cached_property
from operator import index as _as_index
from pathlib import Path

import numpy as np

from .._lazy import LazyModule
from ..atomicfile import staged_folder
from ..errors import RunError
from ..schemas.run import SCHEMA, SCHEMA_VERSION, TABLES
from ..formats.pointformats.common import parquet_options
from ._files import (RUN_FILES, TRUTH_ARRAYS, TRUTH_DIR, TRUTH_INFO, arrow_column, check_artefact_numbers,
                     check_channels, check_created, check_json_value, check_row_counts, check_run_target, check_truth,
                     read_run_json, read_table_file, table_path)
from ._tables import (FIXED_COLUMNS, POINTS_COLUMNS, POSES_COLUMNS, SCANS_COLUMNS, Labels, Where, as_table,
                      check_points, check_scans, check_temperature_times, stack_columns, tables_equal, utc_now)

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pq = LazyModule("pyarrow.parquet")


@dataclass(frozen=True, eq=False, repr=False)
class Run:
    """One measurement run: points, scans, poses, temperatures and what they
    were measured on.

    Every table is a dict of column name -> 1-D numpy array; the constructor
    checks and converts them (the same checks as :meth:`load`, messages naming
    the table, column and row) and stores read-only copies, so the inputs are
    never modified nor shared.

    Parameters
    ----------
    points : dict of str -> array_like, each shape (N,)
        ``scan_id`` (int32), ``t`` (float64, s, non-decreasing within each
        scan), ``u``, ``v`` (float64, mm, scan plane), ``D``, ``E``, ``F``
        (float64, mm, scale readings). One row per point.
    scans : dict of str -> array_like, each shape (S,)
        ``scan_id`` (int32, unique), ``pose_id`` (int32, in poses),
        ``feature`` (str, e.g. "ball"), ``position`` (int32, e.g. B89
        position, -1 if none), ``ball`` (int32, 1 or 2, -1 if none),
        ``sweep_axis`` (str, "X", "Y" or "Z"), ``sweep_direction`` (int8, +1
        or -1), ``sweep_speed`` (float64, mm/s).
    poses : dict of str -> array_like, each shape (P,)
        ``pose_id`` (int32, unique), ``alpha``, ``beta``, ``gamma`` (float64,
        degrees, Euler 3-1-3), ``U1``, ``V1``, ``W1`` (float64, mm, mount
        offset).
    temperatures : dict of str -> array_like, each shape (M,), or None
        ``t`` (float64, s, strictly increasing) and one float64 column per
        channel of ``temperature_channels`` (degrees C). None only when there
        are no channels.
    temperature_channels : list of dict
        ``{"name": str, "role": str}`` per channel (other keys are kept);
        roles are those of ``CHANNEL_ROLES``.
    artefact, maps, metadata : dict
        Free JSON data: the artefact (e.g. ``{"kind": "ballbar", "radius_mm":
        38.125, "length_mm": 404.2}``), which error maps apply (e.g.
        ``{"kind": "bundled", "name": "thesis"}``), anything else. Must come
        back equal from JSON (lists not tuples, str keys, finite numbers).
    created : str
        ISO-8601 UTC time the run was made, e.g. "2025-01-31T12:00:00Z";
        default now.
    """

    points: dict[str, np.ndarray]
    scans: dict[str, np.ndarray]
    poses: dict[str, np.ndarray]
    temperatures: dict[str, np.ndarray] | None = None
    temperature_channels: list[dict] = field(default_factory=list)
    artefact: dict = field(default_factory=dict)
    maps: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    created: str = field(default_factory=utc_now)

    def __post_init__(self):
        self._validate(Labels.in_memory(), copy=True)

    # -- validation, shared by the constructor and load -----------------------------
    def _validate(self, labels: Labels, copy: bool) -> None:
        set_ = object.__setattr__
        j = labels.json
        for name in ("artefact", "maps", "metadata"):
            value = getattr(self, name)
            if not isinstance(value, dict):
                raise RunError(f"{j}{name}: expected a dict (JSON object), got {type(value).__name__}")
            set_(self, name, check_json_value(value, f"{j}{name}"))
        check_artefact_numbers(self.artefact, f"{j}artefact")
        set_(self, "created", check_created(self.created, f"{j}created"))
        channels = check_channels(self.temperature_channels, j)
        set_(self, "temperature_channels", channels)

        tw = labels.tables
        points = as_table(self.points, POINTS_COLUMNS, tw["points"], copy)
        scans = as_table(self.scans, SCANS_COLUMNS, tw["scans"], copy)
        poses = as_table(self.poses, POSES_COLUMNS, tw["poses"], copy)
        names = [ch["name"] for ch in channels]
        if self.temperatures is None:
            if names:
                raise RunError(f"{tw['temperatures']}: missing, but {j}temperature_channels lists {len(names)} channels ({', '.join(names)})")
            temps = None
        else:
            w = tw["temperatures"]
            if isinstance(self.temperatures, Mapping):
                absent = [n for n in names if n not in self.temperatures]
                if absent:
                    raise RunError(f"{w}: missing column {absent[0]!r} (a channel listed in {j}temperature_channels)")
            temps = as_table(self.temperatures, {"t": "float64", **{n: "float64" for n in names}}, w, copy)

        check_scans(scans, poses, tw)
        order = check_points(points, scans, tw)
        if temps is not None:
            check_temperature_times(temps, tw["temperatures"])

        set_(self, "points", points)
        set_(self, "scans", scans)
        set_(self, "poses", poses)
        set_(self, "temperatures", temps)
        order.flags.writeable = False
        set_(self, "_point_order", order)

    # -- files -------------------------------------------------------------------------
    @classmethod
    def load(cls, run_dir) -> Run:
        """Read and check a run directory; ``truth/`` is never opened.

        Parameters
        ----------
        run_dir : str or path-like
            The run directory (run.json and the tables, docs/formats.md).

        Returns
        -------
        Run

        Raises
        ------
        RunError
            Naming the file, column and first bad row of any problem.
        """
        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise RunError(f"{run_dir}: no such run directory" if not run_dir.exists() else f"{run_dir}: not a directory")
        doc = read_run_json(run_dir / "run.json")
        where = {}
        tables = {}
        for name in TABLES:
            path = table_path(run_dir, name, required=name != "temperatures" or bool(doc["temperature_channels"]))
            if path is None:
                tables[name] = None
                where[name] = Where(str(run_dir / f"{name}.parquet"))
                continue
            where[name] = Where(str(path), csv=path.suffix == ".csv")
            spec = FIXED_COLUMNS.get(name) or {"t": "float64", **{ch["name"]: "float64" for ch in doc["temperature_channels"]}}
            tables[name] = read_table_file(path, spec, where[name])
        check_row_counts(run_dir / "run.json", doc.get("rows"), tables, where)
        run = cls.__new__(cls)
        for name in TABLES:
            object.__setattr__(run, name, tables[name])
        for name in ("temperature_channels", "artefact", "maps", "metadata", "created"):
            object.__setattr__(run, name, doc[name])
        run._validate(Labels(where, f"{run_dir / 'run.json'}: "), copy=False)
        object.__setattr__(run, "_source", str(run_dir))  # for messages (Run.source); not part of the run's data
        return run

    @property
    def source(self) -> str | None:
        """The directory the run was loaded from, for messages (None: a run
        made in memory, or passed to another process)."""
        return self.__dict__.get("_source")

    def save(self, run_dir, truth=None, *, overwrite: bool = False) -> None:
        """Write the run as a directory (run.json and Parquet tables).

        Parameters
        ----------
        run_dir : str or path-like
            Directory to write; created with its parents if missing.
        truth : tuple (dict of str -> ndarray, dict), optional
            What a simulator knows and analysis must never read: arrays (any
            shape, numeric/bool/str dtype, units up to the simulator) written to
            ``truth/truth.npz`` and free JSON data written to
            ``truth/truth.json``. Read back only by :func:`load_truth`.
        overwrite : bool
            Write into a non-empty directory, replacing the run files there
            (run.json, the tables as .parquet or .csv, truth/); other files are
            left alone. Without it a non-empty directory raises ``RunError``
            (:func:`check_run_target` makes the same check before any work),
            and the run is created exclusively: of two writers of one folder
            one fails, and the folder holds one whole run, never a mix.

        The new run is written into a temporary folder beside ``run_dir`` and
        swapped in only when complete (:func:`cmmpose.atomicfile.staged_folder`):
        a failure (a full disk, Ctrl-C, SIGTERM) leaves the old run whole.
        """
        final = run_dir = Path(run_dir)
        arrays, info = check_truth(truth) if truth is not None else (None, None)
        check_run_target(run_dir, overwrite=overwrite)
        # without overwrite: created exclusively (of two writers of one folder, one fails; nothing mixed)
        with staged_folder(final, RUN_FILES, error=RunError, exclusive=not overwrite) as run_dir:
            self._write_files(run_dir, final, arrays, info)

    def _write_files(self, run_dir: Path, final: Path, arrays, info) -> None:
        """Write the run's files into the empty folder ``run_dir`` (messages name ``final``)."""
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            doc = {
                "schema": SCHEMA,
                "schema_version": SCHEMA_VERSION,
                "created": self.created,
                "artefact": self.artefact,
                "maps": self.maps,
                "temperature_channels": self.temperature_channels,
                "metadata": self.metadata,
                # Each table's row count, checked on load: a table cut short (or grown) is an error.
                "rows": {name: len(next(iter(getattr(self, name).values())))
                         for name in TABLES if getattr(self, name) is not None},
            }
            (run_dir / "run.json").write_text(json.dumps(doc, indent=2, allow_nan=False, ensure_ascii=False) + "\n", encoding="utf-8")
            for name in TABLES:
                cols = getattr(self, name)
                if cols is None:
                    continue
                spec = FIXED_COLUMNS.get(name) or dict.fromkeys(cols, "float64")
                table = pa.Table.from_arrays([arrow_column(cols[c], dt) for c, dt in spec.items()], names=list(spec))
                # Page checksums (CRC32), verified on load: a flipped bit
                # names the damaged file instead of loading changed values.
                pq.write_table(table, run_dir / f"{name}.parquet", write_page_checksum=True,
                               **parquet_options(table.schema))
            if arrays is not None:
                tdir = run_dir / TRUTH_DIR
                tdir.mkdir(exist_ok=True)
                with zipfile.ZipFile(tdir / TRUTH_ARRAYS, "w", zipfile.ZIP_STORED) as zf:
                    for key, a in arrays.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                            np.lib.format.write_array(fh, a, allow_pickle=False)
                (tdir / TRUTH_INFO).write_text(json.dumps(info, indent=2, allow_nan=False, ensure_ascii=False) + "\n", encoding="utf-8")
        except OSError as exc:
            raise RunError(f"{final}: cannot write ({exc.strerror or exc})") from None

    # -- convenience ------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        """Number of points N."""
        return len(self.points["scan_id"])

    @cached_property
    def uv(self) -> np.ndarray:
        """Scan-plane coordinates u, v of every point, (N, 2) float64 mm, C-contiguous, read-only."""
        return stack_columns(self.points, ("u", "v"))

    @cached_property
    def scales(self) -> np.ndarray:
        """Scale readings D, E, F of every point, (N, 3) float64 mm, C-contiguous, read-only."""
        return stack_columns(self.points, ("D", "E", "F"))

    @cached_property
    def _scan_index(self):
        """(sorted scan ids, start, stop, columns): rows start:stop of
        ``columns`` are one scan's points in file order. ``columns`` are the
        points themselves when every scan's points are contiguous, else copies
        sorted (stably) by scan_id, made once."""
        order = self._point_order
        s = self.points["scan_id"][order]
        ids = np.sort(self.scans["scan_id"])
        lo = np.searchsorted(s, ids, side="left")
        hi = np.searchsorted(s, ids, side="right")
        used = hi > lo
        contiguous = bool(np.all(order[hi[used] - 1] - order[lo[used]] == (hi - lo)[used] - 1))
        if contiguous:
            start = np.zeros_like(lo)
            start[used] = order[lo[used]]
            return ids, start, start + (hi - lo), self.points
        cols = {}
        for c, a in self.points.items():
            cols[c] = a[order]
            cols[c].flags.writeable = False
        return ids, lo, hi, cols

    def scan_points(self, scan_id: int) -> dict[str, np.ndarray]:
        """The points of one scan, in file order.

        Parameters
        ----------
        scan_id : int
            A scan id of ``scans``.

        Returns
        -------
        dict of str -> ndarray
            The columns of ``points`` for that scan (units as in ``points``),
            read-only views; empty arrays if the scan has no points.
        """
        ids, start, stop, cols = self._scan_index
        sid = _as_index(scan_id)
        k = int(np.searchsorted(ids, sid))
        if k == len(ids) or ids[k] != sid:
            raise RunError(f"scan {sid} is not in scans")
        a, b = int(start[k]), int(stop[k])
        return {c: v[a:b] for c, v in cols.items()}

    @cached_property
    def _pose_index(self):
        order = np.argsort(self.poses["pose_id"])
        return self.poses["pose_id"][order], order

    def points_by_pose(self):
        """The points pose by pose: ``(rows, (alpha, beta, gamma), (U1, V1, W1))``
        for each pose that took points (rows: indices into the points; angles
        in degrees, offset in mm), in pose-id order."""
        ids = self.scans["scan_id"]
        order = np.argsort(ids)
        sid = self.points["scan_id"]
        # Run validation guarantees every point's scan exists.
        pose_of_point = self.scans["pose_id"][order][np.searchsorted(ids[order], sid)] if len(sid) else sid
        for pose_id in np.unique(pose_of_point):
            yield (np.flatnonzero(pose_of_point == pose_id), *self.pose(int(pose_id)))

    def pose(self, pose_id: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Pose angles and mount offset of one pose.

        Parameters
        ----------
        pose_id : int
            A pose id of ``poses``.

        Returns
        -------
        (alpha, beta, gamma) : tuple of float
            Euler 3-1-3 angles, degrees.
        (U1, V1, W1) : tuple of float
            Mount offset, mm.
        """
        ids, order = self._pose_index
        pid = _as_index(pose_id)
        k = int(np.searchsorted(ids, pid))
        if k == len(ids) or ids[k] != pid:
            raise RunError(f"pose {pid} is not in poses")
        r = order[k]
        p = self.poses
        return (
            (float(p["alpha"][r]), float(p["beta"][r]), float(p["gamma"][r])),
            (float(p["U1"][r]), float(p["V1"][r]), float(p["W1"][r])),
        )

    # -- pickling (sent to a worker process: cmmpose.scale) -------------------------------
    def __getstate__(self) -> dict:
        """The checked tables and records, without the cached stacks (``uv``,
        ``scales``, scan index), which a worker rebuilds when it needs them."""
        return {f.name: getattr(self, f.name) for f in fields(self)} | {"_point_order": self._point_order}

    def __setstate__(self, state: dict) -> None:
        """Restore a pickled run as it was checked: every column read-only again
        (unpickled arrays come back writeable)."""
        for name, value in state.items():
            if isinstance(value, dict) and name in TABLES:
                for col in value.values():
                    col.flags.writeable = False
            elif isinstance(value, np.ndarray):
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    # -- comparison -------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        """Exact equality: equal dicts and bitwise-equal columns of equal dtype."""
        if not isinstance(other, Run):
            return NotImplemented
        if (self.temperature_channels, self.artefact, self.maps, self.metadata, self.created) != (
            other.temperature_channels,
            other.artefact,
            other.maps,
            other.metadata,
            other.created,
        ):
            return False
        return all(tables_equal(getattr(self, t), getattr(other, t)) for t in TABLES)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        nt = 0 if self.temperatures is None else len(self.temperatures["t"])
        return (
            f"Run({self.n_points} points, {len(self.scans['scan_id'])} scans, {len(self.poses['pose_id'])} poses, "
            f"{len(self.temperature_channels)} temperature channels x {nt} readings, "
            f"artefact={self.artefact!r}, maps={self.maps!r}, created={self.created!r})"
        )
