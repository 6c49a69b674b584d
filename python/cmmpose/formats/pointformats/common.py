"""What the point-format modules share: the temporary-file writer every
format writes through, and the checks of column names and types."""

from __future__ import annotations

import logging
import mmap
import stat
from pathlib import Path

import numpy as np

from ...atomicfile import AtomicFile
from ...atomicfile import check_output as check_writable  # noqa: F401 - the format modules' name for it
from ...errors import InputError, MissingFileError
from ..._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")

_log = logging.getLogger("cmmpose")

#: Kinds of NumPy dtype a column may hold: signed and unsigned integers, reals.
NUMERIC_KINDS = "iuf"


def check_file(path: str | Path) -> Path:
    """``path`` as a Path, or ``InputError`` if it is not an existing regular
    file: missing, a folder, or a special file (a FIFO, a device such as
    ``/dev/zero``, a socket: read whole, one could wait forever or never end),
    each said as such."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise MissingFileError(f"{path}: no such file", file=str(path)) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a folder, expected a file")
    if not stat.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode)
                else "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "a special file")
        raise InputError(f"{path}: not a regular file but {kind}; give a point file (copy the stream to a file first)")
    return path


def numeric_column(path, name: str, values, where: str = "column") -> np.ndarray:
    """``values`` as a 1-D array of integers or reals (native byte order), or
    ``InputError`` naming the file and the column."""
    a = np.asarray(values)
    if a.dtype.kind not in NUMERIC_KINDS or a.ndim != 1:
        raise InputError(f"{path}: {where} {name!r} holds {a.dtype} values, expected real numbers")
    return a.astype(a.dtype.newbyteorder("="), copy=False)


def require(path, names, need, what: str = "columns") -> None:
    """``InputError`` naming the file when a column ``need`` requires is not
    among ``names`` (``what`` says what the format calls them)."""
    missing = [c for c in need.names if c not in names]
    if missing:
        raise InputError(f"{path}: {what} {missing} missing (have {list(names)})")


class ColumnWriter:
    """Base of the format writers, writing through :class:`~cmmpose.atomicfile.AtomicFile`:
    a temporary file beside ``path``, renamed over it by :meth:`close` (the
    file appears whole or not at all) and removed by :meth:`abort`; a special
    file (``/dev/null``, a FIFO) is written as a stream. The first
    :meth:`write` fixes the extra columns' names and types (:attr:`schema`);
    later chunks must carry the same names. Subclasses implement ``_start()``
    (after the schema is known), ``_write(xyz, extras)`` and ``_finish()``;
    one that seeks back (a count in its header) or opens the file by name
    keeps ``SEEKS = True`` and a stream is then spooled through a temporary
    file. An ``OSError`` while writing (a full disk) raises ``OutputError``
    naming ``path``, the temporary file removed."""

    #: The writer seeks back or reopens :attr:`tmp` by name.
    SEEKS = True

    def __init__(self, path: str | Path, *, inputs=()):
        self.path = Path(path)
        self.rows = 0
        self.schema: list[tuple[str, np.dtype]] | None = None
        self.out = AtomicFile(self.path, "wb", inputs=inputs, spool=self.SEEKS)
        self.f = self.out.f
        self.tmp = self.out.name

    def write(self, xyz: np.ndarray, extras: dict[str, np.ndarray] | None = None) -> None:
        """Append ``xyz`` (n, 3) and the extra columns (each of length n)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        extras = dict(extras or {})
        for name, values in extras.items():
            if name.lower() in ("x", "y", "z"):
                raise InputError(f"{self.path}: an extra column named {name!r} would collide with the coordinates")
            if len(values) != len(xyz):
                raise InputError(f"{self.path}: column {name!r} has {len(values)} values for {len(xyz)} points")
        try:
            if self.schema is None:
                self.schema = [(name, numeric_column(self.path, name, v).dtype) for name, v in extras.items()]
                self._start()
            elif list(extras) != [n for n, _ in self.schema]:
                raise InputError(f"{self.path}: columns {list(extras)} differ from the first chunk's "
                                 f"{[n for n, _ in self.schema]}")
            cast = {n: np.asarray(extras[n]).astype(dt, copy=False) for n, dt in self.schema}
            self._write(xyz, cast)
        except OSError as exc:
            raise self._failed(exc) from None
        self.rows += len(xyz)

    def close(self) -> None:
        """Finish the file and rename it into place (``OutputError`` if that fails)."""
        try:
            if self.schema is None:
                self.schema = []
                self._start()
            self._finish()
        except OSError as exc:
            raise self._failed(exc) from None
        self.out.commit()
        _log.debug("wrote %d points to %s", self.rows, self.path)

    def abort(self) -> None:
        """Drop the temporary file; ``path`` is left as it was."""
        self.out.abort()

    def _failed(self, exc: OSError):
        """The error to raise for ``exc``, after :meth:`abort`."""
        self.abort()
        return self.out.fail(exc)

    # -- for subclasses
    def _start(self) -> None:
        """Write what comes before the points (a header), once the schema is known."""

    def _write(self, xyz: np.ndarray, extras: dict[str, np.ndarray]) -> None:
        """Append one chunk (extras already in the schema's types)."""
        raise NotImplementedError(f"{type(self).__name__} writes no points")

    def _finish(self) -> None:
        """Complete the file (a count in its header) before it is renamed."""


def plain_text_names(path, names) -> None:
    """``InputError`` for a column name a text header cannot carry (blank,
    a separator, a quote or a line break in it)."""
    for n in names:
        if not n or any(ch in n for ch in ',"\n\r\t ') or n.startswith(("#", "//")):
            raise InputError(f"{path}: column name {n!r} cannot be written in a text header "
                             f"(no blanks, commas, quotes or line breaks)")


def arrow_table(columns: dict, schema=None) -> pa.Table:
    """Named numeric columns as an Arrow table, each built from its buffer
    (zero-copy for a contiguous column): ``pa.table`` or ``pa.array`` on an
    ndarray imports pandas to ask whether it was given a pandas object,
    about 0.15 s on every write command (the same reason as ``run._arrow_column``)."""
    arrays = []
    for name, values in columns.items():
        a = np.ascontiguousarray(values)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        arrays.append(pa.Array.from_buffers(pa.from_numpy_dtype(a.dtype), len(a), [None, pa.py_buffer(a)]))
    if schema is not None:
        return pa.Table.from_arrays(arrays, schema=schema)
    return pa.Table.from_arrays(arrays, names=list(columns))


#: zstd level of the Parquet files written (1: the fastest; higher levels
#: shrink profile coordinates by a few per cent more at two to four times the time).
PARQUET_ZSTD_LEVEL = 1


def parquet_options(schema) -> dict:
    """Keyword arguments of ``pyarrow.parquet.ParquetWriter`` (or
    ``write_table``) for a table of ``schema``: an encoding for what each
    column is (docs/formats.md, "Parquet encodings").

    Real columns (coordinates, temperatures, times) are almost all distinct:
    a dictionary only costs time before Parquet falls back to plain pages,
    so they are written without one, in BYTE_STREAM_SPLIT (the bytes of
    each value split into streams, which compress where neighbouring points
    share exponents and leading digits). Integer and text columns (scan and
    ball numbers, labels: few distinct values) keep a dictionary. Every
    column is compressed with zstd at :data:`PARQUET_ZSTD_LEVEL`.

    Parameters
    ----------
    schema : pyarrow.Schema
        The table's schema.

    Returns
    -------
    dict
        ``use_dictionary``, ``column_encoding``, ``compression`` and
        ``compression_level``.
    """
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    return {"use_dictionary": [f.name for f in schema if f.name not in floats],
            "column_encoding": dict.fromkeys(floats, "BYTE_STREAM_SPLIT"),
            "compression": "zstd", "compression_level": PARQUET_ZSTD_LEVEL}


def release_pages(block: np.ndarray) -> None:
    """Tell the kernel a memory-mapped ``block`` (rows already copied out)
    is no longer needed, so the pages of a file read chunk by chunk through
    a memory map (NPY, binary PLY) leave the process's resident memory as it
    goes instead of adding up to the whole file. A block that is not in a
    memory map, or a system without ``madvise``, is left alone."""
    owner = block
    while owner is not None and not isinstance(owner, mmap.mmap):
        owner = getattr(owner, "base", None)
    if owner is None or not hasattr(owner, "madvise") or not hasattr(mmap, "MADV_DONTNEED") or block.nbytes == 0:
        return
    start = block.ctypes.data - np.frombuffer(owner, dtype=np.uint8).ctypes.data
    lo = start - start % mmap.PAGESIZE
    hi = start + block.nbytes
    hi -= hi % mmap.PAGESIZE  # whole pages only: the next block may share the last one
    if hi > lo >= 0:
        owner.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
