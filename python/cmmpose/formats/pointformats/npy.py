"""NPY point files: a structured array (one named field per column, any
integer or real type) or a plain 2-D real array whose columns are named by
its width (the caller's layout: ``u, v, D, E, F[, T]`` for
``cmmpose compensate``, ``X, Y, Z`` for a point cloud).

Read memory-mapped, chunk by chunk. Written as it goes, with a fixed-size
header whose row count is filled in at the end: a plain (N, 3) float64 array
when there are no extra columns, else a structured array with fields
``X, Y, Z`` (float64) and the extra columns in their own types. A plain
array cannot carry names, so extra columns always make a structured file."""

from __future__ import annotations

import tokenize
from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import NUMERIC_KINDS, ColumnWriter, check_file, require, release_pages

#: The first bytes of every .npy file.
MAGIC = b"\x93NUMPY"


def open_npy(path: Path, need) -> tuple[np.ndarray, list[str] | None]:
    """The memory-mapped array of ``path``, checked, and the names of a plain
    array's columns (None for a structured one)."""
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        kind = "a zip archive (an .npz?)" if head.startswith(b"PK") else "empty" if not head else "not NumPy data"
        raise InputError(f"{path}: not a .npy file ({kind})")
    try:
        # Memory-mapped: a header claiming more rows than the file holds
        # fails here, before anything is allocated.
        a = np.load(path, allow_pickle=False, mmap_mode="r")
    except (OSError, ValueError, EOFError, MemoryError, SyntaxError, tokenize.TokenError) as exc:
        # (a damaged header is parsed as a Python literal: it can fail as a syntax error)
        raise InputError(f"{path}: not a readable .npy file ({type(exc).__name__}: {exc})") from None
    if a.dtype.names:
        names = a.dtype.names
        require(path, names, need, "fields")
        if a.ndim != 1:
            raise InputError(f"{path}: expected a 1-D structured array, got shape {a.shape}")
        for name in names:
            dt = a.dtype.fields[name][0]
            if dt.kind not in NUMERIC_KINDS or dt.shape:
                raise InputError(f"{path}: field {name!r} holds {dt} values, expected real numbers")
        return a, None
    if a.dtype.kind not in NUMERIC_KINDS:
        raise InputError(f"{path}: holds {a.dtype} values, expected real numbers (float64)")
    if a.ndim != 2 or a.shape[1] not in need.plain:
        widths = " or ".join(f"(N, {k})" for k in need.plain)
        longest = need.plain[max(need.plain)] if need.plain else ()
        raise InputError(f"{path}: expected shape {widths} with columns {', '.join(longest)}, got {a.shape}")
    return a, list(need.plain[a.shape[1]])


def chunks(path: Path, chunk: int, need):
    """The columns of an NPY file in chunks of at most ``chunk`` rows: a
    plain array's as float64, a structured array's in their own types."""
    path = check_file(path)
    size = path.stat().st_size
    a, plain = open_npy(path, need)
    return size, _chunks(a, plain, chunk, size)


def _chunks(a, plain, chunk, size):
    n = len(a)
    for lo in range(0, max(n, 1), chunk):
        hi = min(lo + chunk, n)
        block = a[lo:hi]
        if plain is None:
            cols = {c: np.array(block[c], dtype=block.dtype.fields[c][0].newbyteorder("=")) for c in a.dtype.names}
        else:
            b = np.array(block, dtype=np.float64)
            cols = {c: np.ascontiguousarray(b[:, k]) for k, c in enumerate(plain)}
        release_pages(block)  # copied out: its pages of the file leave resident memory
        yield cols, int(size * hi / max(n, 1))


def header(descr, shape: tuple, size: int) -> bytes:
    """An NPY format 1.0 header (2.0 if it must be longer) for ``descr`` and
    ``shape`` in C order, padded with spaces to ``size`` bytes (a multiple of
    64, as the format asks)."""
    text = f"{{'descr': {descr!r}, 'fortran_order': False, 'shape': {shape!r}, }}".encode("latin1")
    if size < 65536:
        body = size - len(MAGIC) - 2 - 2
        return MAGIC + b"\x01\x00" + body.to_bytes(2, "little") + text.ljust(body - 1) + b"\n"
    body = size - len(MAGIC) - 2 - 4
    return MAGIC + b"\x02\x00" + body.to_bytes(4, "little") + text.ljust(body - 1) + b"\n"


#: Bytes of the header of a plain (N, 3) file: room for any 64-bit count.
PLAIN_HEADER_BYTES = 128


class Writer(ColumnWriter):
    """NPY written as it goes; the header's count is written in at the end."""

    def _start(self):
        if self.schema:
            self.dtype = np.dtype([("X", "<f8"), ("Y", "<f8"), ("Z", "<f8"),
                                   *[(n, dt.newbyteorder("<")) for n, dt in self.schema]])
            self.descr = np.lib.format.dtype_to_descr(self.dtype)
            text = len(f"{{'descr': {self.descr!r}, 'fortran_order': False, 'shape': ({2**63},), }}")
            self.size = -(-(12 + text + 1) // 64) * 64  # the widest count fits, in either version
            self.shape = lambda n: (n,)
        else:
            self.dtype, self.descr, self.size = None, "<f8", PLAIN_HEADER_BYTES
            self.shape = lambda n: (n, 3)
        self.f.write(header(self.descr, self.shape(0), self.size))

    def _write(self, xyz, extras):
        if self.dtype is None:
            self.f.write(np.ascontiguousarray(xyz, dtype="<f8").tobytes())
            return
        rec = np.empty(len(xyz), self.dtype)
        rec["X"], rec["Y"], rec["Z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        for n, v in extras.items():
            rec[n] = v
        self.f.write(rec.tobytes())

    def _finish(self):
        self.f.seek(0)
        self.f.write(header(self.descr, self.shape(self.rows), self.size))


register(PointFormat("npy", (".npy",), chunks, Writer,
                     description="NumPy .npy: a structured array, or a plain (N, k) real array"))
