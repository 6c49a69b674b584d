"""Parquet point files (pyarrow): one column per quantity, integer or real,
without nulls. Read row group by row group in batches; written one row
group per chunk with columns ``X, Y, Z`` (float64) and the extra columns in
their own types, each column encoded for what it holds (``common.parquet_options``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import ColumnWriter, arrow_table, check_file, parquet_options, require
from ..._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pq = LazyModule("pyarrow.parquet")


#: Bytes read at a time from a column chunk. Without a buffer pyarrow reads
#: whole column chunks and the reading process grew with the file (0.44 GB
#: at 5e6 rows, 0.63 GB at 2e7); with one it stays at about 0.33 GB, no slower
#: (benches/compensate_memory.py).
READ_BUFFER_BYTES = 1 << 20


def chunks(path: Path, chunk: int, need):
    """Batches of at most ``chunk`` rows; the columns checked first (names,
    real types), then each batch for nulls (the first null's row named)."""
    path = check_file(path)
    size = path.stat().st_size
    try:
        f = pq.ParquetFile(path, buffer_size=READ_BUFFER_BYTES, pre_buffer=False)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
    schema = f.schema_arrow
    repeated = [c for c in schema.names if schema.names.count(c) > 1]
    if repeated:  # which of them would be the data?
        raise InputError(f"{path}: column {repeated[0]!r} appears {schema.names.count(repeated[0])} times; "
                         f"each column must have its own name")
    require(path, schema.names, need)
    for c in schema.names:
        kind = schema.field(c).type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            raise InputError(f"{path}: column {c!r} holds {kind} values, expected real numbers")
    return size, _chunks(f, path, chunk, size, schema)


def _chunks(f, path, chunk, size, schema):
    n, first = max(f.metadata.num_rows, 1), 0
    try:
        for batch in f.iter_batches(batch_size=chunk):
            cols = {}
            for c in schema.names:
                column = batch.column(c)
                if column.null_count:
                    row = first + int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
                    raise InputError(f"{path}: column {c!r}, row {row}: empty (null)")
                cols[c] = column.to_numpy(zero_copy_only=False)
            first += batch.num_rows
            yield cols, int(size * first / n)
        if first == 0:
            yield {c: np.zeros(0, schema.field(c).type.to_pandas_dtype()) for c in schema.names}, size
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None


class Writer(ColumnWriter):
    """Parquet: one row group per chunk written."""

    def _start(self):
        self.arrow_schema = pa.schema([(c, pa.float64()) for c in "XYZ"]
                                      + [(n, pa.from_numpy_dtype(dt)) for n, dt in self.schema])
        self.pq = pq.ParquetWriter(self.f, self.arrow_schema, **parquet_options(self.arrow_schema))

    def _write(self, xyz, extras):
        table = arrow_table({"X": xyz[:, 0], "Y": xyz[:, 1], "Z": xyz[:, 2], **extras}, schema=self.arrow_schema)
        self.pq.write_table(table)

    def _finish(self):
        self.pq.close()

    def abort(self):
        if getattr(self, "pq", None) is not None:
            try:
                self.pq.close()
            except (pa.ArrowException, OSError):
                pass
        super().abort()


register(PointFormat("parquet", (".parquet", ".pq"), chunks, Writer,
                     description="Apache Parquet columns (pyarrow)"))
