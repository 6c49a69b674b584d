"""CSV point files: UTF-8, a header row naming the columns, one row per point.

Read in chunks by pyarrow's streaming reader (the required columns as
float64, every other column as pyarrow infers it: int64 for whole numbers,
else float64). A file the fast reader refuses is read whole by a strict
reader that names the line and column at fault; if the strict reader accepts
it after all, :class:`Reread` carries its columns. Written with a header row
``X,Y,Z[,extra...]``: coordinates rounded to 1 nm (6 decimals, mm; values
beyond 1e15 mm, whole numbers of nm already, as they are: never inf), extra
columns as they are (shortest form that reads back the same value)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import ColumnWriter, arrow_table, check_file, plain_text_names
from ..._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa = LazyModule("pyarrow")
pa_csv = LazyModule("pyarrow.csv")


#: Bytes the fast reader parses at a time. pyarrow reads up to 32 blocks ahead
#: of the caller: blocks of 64 MiB held 1.4 GB of a 1.1 GB file at its first
#: batch, blocks of 1 MiB hold 0.17 GB whatever the file's size, and parse it
#: no slower (benches/compensate_memory.py).
BLOCK_BYTES = 1 << 20

#: Beyond this magnitude (mm) a float64 is already a whole number of nm
#: (2**53 nm is 9.0e9 mm): rounding would change nothing, and x * 1e6 would
#: overflow to inf above about 1.8e302.
_ROUNDABLE_MM = 1e15


def round_nm(xyz: np.ndarray) -> np.ndarray:
    """Coordinates (mm) rounded to 1 nm (6 decimals) with -0.0 written as 0;
    values too large to have a fraction of a nm, and non-finite ones, are
    kept exactly (written in the shortest form that reads back the same)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    small = np.abs(xyz) < _ROUNDABLE_MM
    return np.where(small, np.round(np.where(small, xyz, 0.0), 6), xyz) + 0.0


class Reread(Exception):
    """The fast reader refused part of a file the strict one then read whole;
    ``columns`` holds the whole file."""

    def __init__(self, columns: dict[str, np.ndarray]):
        super().__init__("re-read")
        self.columns = columns


def _column_name(field: str) -> str:
    """A header field without blanks around it or the double quotes many
    writers put around names (pyarrow, spreadsheets)."""
    name = field.strip()
    if len(name) >= 2 and name[0] == name[-1] == '"':
        name = name[1:-1]
    return name


def _header_problem(header: list[str], need) -> str | None:
    """What keeps ``header`` from being read, or None."""
    missing = [c for c in need.names if c not in header]
    if missing:
        return f"header must name columns {need.what or ', '.join(need.names)}; missing {missing}"
    dup = sorted({h for h in header if h and header.count(h) > 1})
    if dup:
        return f"header names {dup} more than once"
    return None


def _fast_header(path: Path, need) -> list[str] | None:
    """The header's column names if the fast reader can take the file: UTF-8,
    the required columns present, no name empty or twice; else None (the
    strict reader then says what is wrong)."""
    with path.open("rb") as f:
        first = f.readline()
    if first.startswith(b"\xef\xbb\xbf"):
        first = first[3:]
    try:
        header = [_column_name(h) for h in first.decode("utf-8").rstrip("\r\n").split(",")]
    except UnicodeDecodeError:
        return None
    ok = _header_problem(header, need) is None and all(header)
    return header if ok else None


def read_strict(path: Path, need) -> dict[str, np.ndarray]:
    """The careful reader: every byte and field checked, the first fault named
    by line (used when the fast reader refuses a file, to say why). Columns
    required by ``need`` are float64; another column is int64 when every field
    of it is written as a whole number, else float64. Unnamed columns are
    dropped."""
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
        raise InputError(f"{path}:1: empty file; expected a header row {need.what or ', '.join(need.names)}")
    header = [_column_name(h) for h in lines[0].split(",")]
    problem = _header_problem(header, need)
    if problem:
        raise InputError(f"{path}:1: {problem}")
    width = len(header)
    for lineno, line in enumerate(lines[1:], start=2):
        if line.strip() and line.count(",") != width - 1:
            raise InputError(f"{path}:{lineno}: expected {width} fields like the header, got {line.count(',') + 1}")
    body = [ln for ln in lines[1:] if ln.strip()]
    if not body:
        a = np.zeros((0, width))
    else:
        try:
            a = np.loadtxt(body, delimiter=",", ndmin=2, dtype=np.float64)
        except ValueError:
            raise InputError(_first_bad_field(path, lines) or f"{path}: not numeric") from None
    typed = set(need.names) | set(need.optional)
    out = {}
    for k, name in enumerate(header):
        if not name:
            continue
        col = np.ascontiguousarray(a[:, k])
        if name not in typed and len(col) and _whole_numbers([ln.split(",")[k] for ln in body], col):
            col = col.astype(np.int64)
        out[name] = col
    return out


def _whole_numbers(fields: list[str], values: np.ndarray) -> bool:
    """True when every field is written as an integer that int64 holds."""
    if not np.all(np.isfinite(values)) or np.abs(values).max() >= 2.0**63:
        return False
    return not any(ch in f for f in fields for ch in ".eEnN")


def _first_bad_field(path: Path, lines: list[str]) -> str | None:
    """On the error path only: the first field that is not a plain number."""
    from ..._validate import DECIMAL_NUMBER

    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        for k, field in enumerate(line.split(",")):
            if not DECIMAL_NUMBER.fullmatch(field.strip()) and field.strip().lower() not in ("nan", "inf", "-inf", "+inf"):
                return f"{path}:{lineno}: value {field.strip()!r} in column {k + 1} is not a number"
    return None


def _batch_columns(batch, header: list[str]) -> dict[str, np.ndarray]:
    """A record batch as numeric arrays; ``ArrowInvalid`` for a null or a
    column pyarrow read as other than a number (the strict reader then names
    the line)."""
    out = {}
    for name in header:
        column = batch.column(name)
        if column.null_count or not (pa.types.is_integer(column.type) or pa.types.is_floating(column.type)):
            raise pa.ArrowInvalid(f"column {name!r} is not numeric")
        out[name] = column.to_numpy()
    return out


def _joined(parts: list[dict]) -> dict[str, np.ndarray]:
    """Batches' columns as one chunk (one batch's as they are)."""
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def chunks(path: Path, chunk: int, need):
    """The columns of a CSV file in chunks of at most ``chunk`` rows (see the
    module's description); :class:`Reread` when the fast reader gave up
    part way and the strict reader accepted the whole file."""
    path = check_file(path)
    size = path.stat().st_size
    return size, _chunks(path, chunk, need, size)


def _chunks(path: Path, chunk: int, need, size: int):
    header = _fast_header(path, need)
    if header is None:
        yield read_strict(path, need), size
        return
    typed = [c for c in header if c in need.names or c in need.optional]
    try:
        src = pa.OSFile(str(path))  # its position tells how far the reader got (progress)
        reader = pa_csv.open_csv(
            src,
            read_options=pa_csv.ReadOptions(column_names=header, skip_rows=1, block_size=BLOCK_BYTES),
            convert_options=pa_csv.ConvertOptions(
                column_types=dict.fromkeys(typed, pa.float64()), null_values=[],
                strings_can_be_null=False, quoted_strings_can_be_null=False),
        )
        empty = True
        parts, rows = [], 0  # small batches gathered into chunks of `chunk` rows
        for batch in reader:
            empty = False
            cols = _batch_columns(batch, header)
            done = min(src.tell(), size)
            lo = 0
            while lo < batch.num_rows:
                take = min(chunk - rows, batch.num_rows - lo)
                parts.append({k: v[lo:lo + take] for k, v in cols.items()})
                rows += take
                lo += take
                if rows == chunk:
                    yield _joined(parts), done
                    parts, rows = [], 0
        if parts:
            yield _joined(parts), size
        if empty:  # a header and no rows
            yield {c: np.zeros(0) for c in header}, size
    except (pa.ArrowException, OSError):
        # The strict reader says which line; if it accepts the file after
        # all, its values are what the fast reader would have given.
        raise Reread(read_strict(path, need)) from None


class Writer(ColumnWriter):
    """CSV: header ``X,Y,Z[,extra...]``, coordinates rounded to 1 nm."""

    SEEKS = False  # written front to back: a FIFO gets it as it is made

    def _start(self):
        names = [n for n, _ in self.schema]
        plain_text_names(self.path, names)
        self.f.write((",".join(["X", "Y", "Z", *names]) + "\n").encode())

    def _write(self, xyz, extras):
        if len(xyz):
            r = round_nm(xyz)
            table = arrow_table({"X": r[:, 0], "Y": r[:, 1], "Z": r[:, 2], **extras})
            pa_csv.write_csv(table, self.f, pa_csv.WriteOptions(include_header=False))


register(PointFormat("csv", (".csv",), chunks, Writer,
                     description="CSV with a header row (pyarrow); coordinates written to 1 nm"))
