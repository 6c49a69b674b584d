"""Point files for the CLI: CSV with a header row (u, v, D, E, F and an
optional T), NPY ((N, 5) or (N, 6) in that column order, or a structured
array with those field names) or Parquet (columns with those names). Units:
mm and degrees C.

Reading is strict: a CSV must be UTF-8 with every row as wide as the header
(an extra field would shift the columns) and plain numbers; an NPY must be
a real-valued array whose header matches the file's size; a Parquet file
must hold real-valued columns without nulls. Every format is read and
written in chunks, so a file of any size takes bounded memory. Writing goes
to a temporary file renamed into place, so a failure leaves nothing behind."""

from __future__ import annotations

import os
import tempfile
import tokenize
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from .errors import InputError

REQUIRED = ("u", "v", "D", "E", "F")
#: The first bytes of every .npy file.
_NPY_MAGIC = b"\x93NUMPY"


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read ``uv`` (N, 2), ``scales`` (N, 3) and temperatures (N,) or None.

    Parameters
    ----------
    path : path-like
        A .npy or .parquet file, or a CSV file (any other suffix) with a
        header row.

    Raises
    ------
    InputError
        Naming the file, and the line and column where it can: a missing
        file, text that is not UTF-8, a header without u, v, D, E, F, a row
        of another width than the header, a field that is not a number, an
        NPY that is not a plain real array of the right shape.
    """
    _, chunks = point_chunks(path, chunk=2**62)  # one chunk: the whole file
    try:
        parts = [c[:3] for c in chunks]
    except RereadPoints as again:
        parts = [again.points]
    if len(parts) == 1:
        return parts[0]
    uv, scales, temps = zip(*parts)
    return (np.concatenate(uv), np.concatenate(scales), None if temps[0] is None else np.concatenate(temps))


def _read_npy(path: Path, lazy: bool = False) -> tuple[np.ndarray, bool]:
    """The (N, 5|6) points of an NPY file, checked; ``lazy``: a plain array
    stays memory-mapped (read chunk by chunk), a structured one is read."""
    with path.open("rb") as f:
        head = f.read(len(_NPY_MAGIC))
    if head != _NPY_MAGIC:
        kind = "a zip archive (an .npz?)" if head.startswith(b"PK") else "empty" if not head else "not NumPy data"
        raise InputError(f"{path}: not a .npy file ({kind})")
    try:
        # Memory-mapped first: a header claiming more rows than the file holds
        # fails here, before anything is allocated.
        a = np.load(path, allow_pickle=False, mmap_mode="r")
    except (OSError, ValueError, EOFError, MemoryError, SyntaxError, tokenize.TokenError) as exc:
        # (a damaged header is parsed as a Python literal: it can fail as a syntax error)
        raise InputError(f"{path}: not a readable .npy file ({type(exc).__name__}: {exc})") from None
    if a.dtype.names:
        names = a.dtype.names
        missing = [c for c in REQUIRED if c not in names]
        if missing:
            raise InputError(f"{path}: fields {missing} missing (have {list(names)})")
        cols = [np.asarray(a[c]) for c in REQUIRED] + ([np.asarray(a["T"])] if "T" in names else [])
        for c, name in zip(cols, [*REQUIRED, "T"]):
            if c.dtype.kind not in "iuf":
                raise InputError(f"{path}: field {name!r} holds {c.dtype} values, expected real numbers")
        return np.column_stack(cols).astype(np.float64), "T" in names
    if a.dtype.kind not in "iuf":
        raise InputError(f"{path}: holds {a.dtype} values, expected real numbers (float64)")
    if a.ndim != 2 or a.shape[1] not in (5, 6):
        raise InputError(f"{path}: expected shape (N, 5) or (N, 6) with columns u, v, D, E, F[, T], got {a.shape}")
    return (a if lazy else np.array(a, dtype=np.float64)), a.shape[1] == 6


def _read_csv_strict(path: Path) -> tuple[np.ndarray, bool]:
    """The careful reader: every byte and field checked, the first fault named
    by line (used when the fast reader refuses a file, to say why)."""
    raw = path.read_bytes()
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]  # a byte-order mark some spreadsheets write
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(f"{path}:{line}: not UTF-8 text (byte {raw[exc.start]:#04x}); save the file as UTF-8 "
                         f"CSV") from None
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(f"{path}:1: empty file; expected a header row u,v,D,E,F[,T]")
    header = [_column_name(h) for h in lines[0].split(",")]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise InputError(f"{path}:1: header must name columns u, v, D, E, F (and optionally T); missing {missing}")
    dup = sorted({h for h in header if h and header.count(h) > 1})
    if dup:
        raise InputError(f"{path}:1: header names {dup} more than once")
    width = len(header)
    for lineno, line in enumerate(lines[1:], start=2):
        if line.strip() and line.count(",") != width - 1:
            raise InputError(f"{path}:{lineno}: expected {width} fields like the header, got {line.count(',') + 1}")
    body = [ln for ln in lines[1:] if ln.strip()]
    if not body:
        return np.zeros((0, 6 if "T" in header else 5)), "T" in header
    try:
        a = np.loadtxt(body, delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError:
        raise InputError(_first_bad_field(path, lines) or f"{path}: not numeric") from None
    order = [header.index(c) for c in REQUIRED] + ([header.index("T")] if "T" in header else [])
    return a[:, order], "T" in header


def _column_name(field: str) -> str:
    """A header field without blanks around it or the double quotes many
    writers put around names (pyarrow, spreadsheets)."""
    name = field.strip()
    if len(name) >= 2 and name[0] == name[-1] == '"':
        name = name[1:-1]
    return name


def _csv_header(path: Path) -> list[str] | None:
    """The header's column names if the fast reader can take the file: UTF-8,
    u, v, D, E, F present, no name empty or twice; else None (the strict
    reader then says what is wrong)."""
    with path.open("rb") as f:
        first = f.readline()
    if first.startswith(b"\xef\xbb\xbf"):
        first = first[3:]
    try:
        header = [_column_name(h) for h in first.decode("utf-8").rstrip("\r\n").split(",")]
    except UnicodeDecodeError:
        return None
    ok = all(c in header for c in REQUIRED) and len(set(header)) == len(header) and all(header)
    return header if ok else None


def _first_bad_field(path: Path, lines: list[str]) -> str | None:
    """On the error path only: the first field that is not a plain number."""
    from ._validate import _NUMBER

    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        for k, field in enumerate(line.split(",")):
            if not _NUMBER.fullmatch(field.strip()) and field.strip().lower() not in ("nan", "inf", "-inf", "+inf"):
                return f"{path}:{lineno}: value {field.strip()!r} in column {k + 1} is not a number"
    return None


def check_writable(path: str | Path) -> Path:
    """The output ``path``, or ``InputError`` if its folder does not exist or is not one."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{path}: the folder {folder} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    return path


def write_points(path: str | Path, xyz: np.ndarray) -> None:
    """Write (N, 3) machine coordinates: CSV with header X,Y,Z (mm, rounded to
    1 nm, shortest form) or NPY (suffix .npy in any case, kept as given). The
    file appears whole or not at all."""
    writer = PointWriter(path)
    try:
        writer.write(xyz)
    except BaseException:
        writer.abort()
        raise
    writer.close()


#: Points per chunk when a file is streamed.
CHUNK_POINTS = 1_000_000


def point_chunks(path: str | Path, chunk: int | None = None):
    """The points of ``path`` in chunks of about ``chunk`` rows, so a file of
    any size is compensated in bounded memory.

    Returns
    -------
    size : int
        The file's size in bytes (for progress).
    chunks : iterator of (uv, scales, temps, bytes_done)
        As :func:`read_points` returns them, per chunk, with how far into the
        file (bytes) the chunk ends. A file the fast reader refuses is read
        whole by the strict one, which raises naming the line at fault.
    """
    path = Path(path)
    chunk = CHUNK_POINTS if chunk is None else int(chunk)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    size = path.stat().st_size
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return size, _npy_chunks(path, chunk, size)
    if suffix == ".parquet":
        return size, _parquet_chunks(path, chunk, size)
    return size, _csv_chunks(path, chunk, size)


def _split(a: np.ndarray, has_t: bool):
    return (np.ascontiguousarray(a[:, 0:2]), np.ascontiguousarray(a[:, 2:5]),
            np.ascontiguousarray(a[:, 5]) if has_t else None)


def _npy_chunks(path: Path, chunk: int, size: int):
    a, has_t = _read_npy(path, lazy=True)
    n = len(a)
    for lo in range(0, max(n, 1), chunk):
        hi = min(lo + chunk, n)
        block = np.array(a[lo:hi], dtype=np.float64)
        yield (*_split(block, has_t), int(size * hi / max(n, 1)))


def _parquet_chunks(path: Path, chunk: int, size: int):
    """Row groups read batch by batch; the columns checked first (names,
    real types), then each batch for nulls (the first null's row named)."""
    try:
        f = pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
    schema = f.schema_arrow
    missing = [c for c in REQUIRED if c not in schema.names]
    if missing:
        raise InputError(f"{path}: columns {missing} missing (have {schema.names})")
    cols = [*REQUIRED, *(["T"] if "T" in schema.names else [])]
    for c in cols:
        kind = schema.field(c).type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            raise InputError(f"{path}: column {c!r} holds {kind} values, expected real numbers")
    has_t, n, first = "T" in cols, max(f.metadata.num_rows, 1), 0
    try:
        for batch in f.iter_batches(batch_size=chunk, columns=cols):
            for c in cols:
                column = batch.column(c)
                if column.null_count:
                    row = first + int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
                    raise InputError(f"{path}: column {c!r}, row {row}: empty (null)")
            # Straight into the kernel's arrays: one copy per column, no (N, 6) in between.
            col = {c: batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64, copy=False) for c in cols}
            uv = np.column_stack([col["u"], col["v"]])
            scales = np.column_stack([col["D"], col["E"], col["F"]])
            temps = np.ascontiguousarray(col["T"]) if has_t else None
            first += batch.num_rows
            yield uv, scales, temps, int(size * first / n)
        if first == 0:
            yield (*_split(np.zeros((0, len(cols))), has_t), size)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None


def _csv_chunks(path: Path, chunk: int, size: int):
    header = _csv_header(path)
    if header is None:
        a, has_t = _read_csv_strict(path)
        yield (*_split(a, has_t), size)
        return
    cols = [*REQUIRED, *(["T"] if "T" in header else [])]
    has_t = "T" in header
    try:
        src = pa.OSFile(str(path))  # its position tells how far the reader got (progress)
        reader = pa_csv.open_csv(
            src,
            read_options=pa_csv.ReadOptions(column_names=header, skip_rows=1, block_size=64 << 20),
            convert_options=pa_csv.ConvertOptions(
                column_types=dict.fromkeys(cols, pa.float64()), include_columns=cols, null_values=[],
                strings_can_be_null=False, quoted_strings_can_be_null=False),
        )
        empty = True
        for batch in reader:
            empty = False
            if any(batch.column(c).null_count for c in cols):
                raise pa.ArrowInvalid("null")
            a = np.column_stack([batch.column(c).to_numpy() for c in cols]) if batch.num_rows else \
                np.zeros((0, len(cols)))
            done = min(src.tell(), size)
            for lo in range(0, len(a), chunk):
                yield (*_split(a[lo:lo + chunk], has_t), done)
        if empty:  # a header and no rows
            yield (*_split(np.zeros((0, len(cols))), has_t), size)
    except (pa.ArrowException, OSError):
        # The strict reader says which line; if it accepts the file after
        # all, its values are what the fast reader would have given.
        a, has_t = _read_csv_strict(path)
        raise RereadPoints(a, has_t) from None


class RereadPoints(Exception):
    """The fast reader refused part of a file the strict one then read whole."""

    def __init__(self, a, has_t):
        super().__init__("re-read")
        self.points = _split(a, has_t)


class PointWriter:
    """Machine coordinates (mm) written chunk by chunk to a temporary file
    renamed over ``path`` on success: CSV (header X,Y,Z, rounded to 1 nm),
    NPY (N, 3) float64 (suffix .npy) or Parquet columns X, Y, Z float64
    (suffix .parquet). Memory stays bounded by one chunk in every format."""

    def __init__(self, path: str | Path):
        self.path = check_writable(path)
        self.kind = {".npy": "npy", ".parquet": "parquet"}.get(self.path.suffix.lower(), "csv")
        self.rows = 0
        fd, self.tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent if str(self.path.parent) else ".")
        self.f = os.fdopen(fd, "wb")
        self._parquet: pq.ParquetWriter | None = None
        if self.kind == "csv":
            self.f.write(b"X,Y,Z\n")
        elif self.kind == "npy":
            self.f.write(_npy_header(0))  # the count is written in at the end

    def write(self, xyz: np.ndarray) -> None:
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        self.rows += len(xyz)
        if self.kind == "npy":
            self.f.write(np.ascontiguousarray(xyz).tobytes())
        elif self.kind == "parquet":
            table = pa.table({"X": xyz[:, 0], "Y": xyz[:, 1], "Z": xyz[:, 2]})
            if self._parquet is None:
                self._parquet = pq.ParquetWriter(self.f, table.schema)
            self._parquet.write_table(table)
        elif len(xyz):
            r = np.round(xyz, 6) + 0.0
            pa_csv.write_csv(pa.table({"X": r[:, 0], "Y": r[:, 1], "Z": r[:, 2]}), self.f,
                             pa_csv.WriteOptions(include_header=False))

    def close(self) -> None:
        if self.kind == "npy":
            self.f.seek(0)
            self.f.write(_npy_header(self.rows))
        elif self.kind == "parquet":
            if self._parquet is None:
                self._parquet = pq.ParquetWriter(self.f, pa.schema([(c, pa.float64()) for c in "XYZ"]))
            self._parquet.close()
        self.f.close()
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        self.f.close()
        Path(self.tmp).unlink(missing_ok=True)


#: Bytes of the NPY header PointWriter writes: fixed, so that the row count,
#: known only at the end, is written over the placeholder in place.
_NPY_HEADER_BYTES = 128


def _npy_header(rows: int) -> bytes:
    """An NPY format 1.0 header for (rows, 3) little-endian float64 in C
    order, padded with spaces to a fixed 128 bytes (a multiple of 64, as the
    format asks, and room for any 64-bit count)."""
    text = f"{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, 3), }}".encode("latin1")
    body = _NPY_HEADER_BYTES - len(_NPY_MAGIC) - 2 - 2
    return _NPY_MAGIC + b"\x01\x00" + body.to_bytes(2, "little") + text.ljust(body - 1) + b"\n"
