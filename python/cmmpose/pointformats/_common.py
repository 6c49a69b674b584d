"""What the point-format modules share: the temporary-file writer every
format writes through, and the checks of column names and types."""

from __future__ import annotations

import logging
import os
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa

from ..errors import InputError

_log = logging.getLogger("cmmpose")

#: Kinds of NumPy dtype a column may hold: signed and unsigned integers, reals.
NUMERIC_KINDS = "iuf"


def check_writable(path: str | Path) -> Path:
    """The output ``path``, or ``InputError`` if its folder does not exist or is not one."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{path}: the folder {folder} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    return path


def check_file(path: str | Path) -> Path:
    """``path`` as a Path, or ``InputError`` if it is not an existing file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
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
    """Base of the format writers: a temporary file beside ``path``, renamed
    over it by :meth:`close` (the file appears whole or not at all) and
    removed by :meth:`abort`. The first :meth:`write` fixes the extra columns'
    names and types (:attr:`schema`); later chunks must carry the same names.
    Subclasses implement ``_start()`` (after the schema is known),
    ``_write(xyz, extras)`` and ``_finish()``."""

    def __init__(self, path: str | Path):
        self.path = check_writable(path)
        self.rows = 0
        self.schema: list[tuple[str, np.dtype]] | None = None
        fd, self.tmp = tempfile.mkstemp(prefix=f".{self.path.name}.",
                                        dir=self.path.parent if str(self.path.parent) else ".")
        self.f = os.fdopen(fd, "wb")

    def write(self, xyz: np.ndarray, extras: dict[str, np.ndarray] | None = None) -> None:
        """Append ``xyz`` (n, 3) and the extra columns (each of length n)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        extras = dict(extras or {})
        for name, values in extras.items():
            if name.lower() in ("x", "y", "z"):
                raise InputError(f"{self.path}: an extra column named {name!r} would collide with the coordinates")
            if len(values) != len(xyz):
                raise InputError(f"{self.path}: column {name!r} has {len(values)} values for {len(xyz)} points")
        if self.schema is None:
            self.schema = [(name, numeric_column(self.path, name, v).dtype) for name, v in extras.items()]
            self._start()
        elif list(extras) != [n for n, _ in self.schema]:
            raise InputError(f"{self.path}: columns {list(extras)} differ from the first chunk's "
                             f"{[n for n, _ in self.schema]}")
        cast = {n: np.asarray(extras[n]).astype(dt, copy=False) for n, dt in self.schema}
        self._write(xyz, cast)
        self.rows += len(xyz)

    def close(self) -> None:
        """Finish the file and rename it into place."""
        if self.schema is None:
            self.schema = []
            self._start()
        self._finish()
        if not self.f.closed:
            self.f.close()
        os.replace(self.tmp, self.path)
        _log.debug("wrote %d points to %s", self.rows, self.path)

    def abort(self) -> None:
        """Drop the temporary file; ``path`` is left as it was."""
        if not self.f.closed:
            self.f.close()
        Path(self.tmp).unlink(missing_ok=True)

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
