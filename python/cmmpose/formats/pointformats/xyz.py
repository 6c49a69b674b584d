"""ASCII XYZ and PTS point files: one point per line, numbers separated by
blanks or tabs (or commas), read chunk by chunk with NumPy's text reader.

XYZ (``.xyz``): ``x y z`` and any further columns. Column names come from a
header line if there is one: a first line ``//X Y Z intensity`` or ``# X Y Z
...`` (the form CloudCompare writes), or a first line of names without a
marker. Without a header the columns are ``X, Y, Z``, then by their count:
4 ``intensity``; 6 ``red, green, blue``; 7 ``intensity, red, green, blue``;
otherwise ``column4``, ``column5``, ... Later lines starting with ``#`` or
``//`` are comments. Written with a ``//X Y Z ...`` header line.

PTS (``.pts``, Leica): a first line with the number of points, then ``x y z``
and optionally ``intensity``, ``red green blue`` or ``intensity red green
blue`` (named by their count as above). A file of several clouds (a count
line before each) is not read. Written with the count first (padded with
blanks, filled in at the end); only those layouts can be written.

Text has no types: every column is float64 except ``scan_id``, ``red``,
``green``, ``blue``, ``row``, ``column`` and names ending in ``_id``, which
are int64 and must hold whole numbers."""

from __future__ import annotations

import io
import warnings
from itertools import islice
from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import ColumnWriter, arrow_table, check_file, plain_text_names, require
from ..._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa_csv = LazyModule("pyarrow.csv")

#: Names of extra columns by how many there are (after x, y, z), for files without a header.
_BY_COUNT = {0: (), 1: ("intensity",), 3: ("red", "green", "blue"), 4: ("intensity", "red", "green", "blue")}
_INTEGER_NAMES = {"scan_id", "red", "green", "blue", "row", "column"}


def _is_integer_name(name: str) -> bool:
    return name in _INTEGER_NAMES or name.endswith("_id")


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _tokens(line: str, delimiter: str | None) -> list[str]:
    return [t.strip() for t in line.split(delimiter)] if delimiter else line.split()


def _decode(path: Path, raw: bytes, first_line: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = first_line + raw[: exc.start].count(b"\n")
        raise InputError(f"{path}:{line}: not UTF-8 text (byte {raw[exc.start]:#04x})") from None


def _default_names(width: int) -> list[str]:
    extra = width - 3
    return ["X", "Y", "Z", *(_BY_COUNT.get(extra) or [f"column{k}" for k in range(4, width + 1)])]


class _Layout:
    """What the first lines of a file say: where the data start, the
    separator, the column names, the PTS count."""

    def __init__(self, path: Path, pts: bool):
        self.path, self.pts, self.count = path, pts, None
        self.skip = 0  # lines before the data
        names = None
        with path.open("rb") as f:
            head = list(islice(f, 64))
        lines = _decode(path, b"".join(head), 1).splitlines()
        k = 0
        while k < len(lines) and not lines[k].strip():
            k += 1
        if pts:
            if k == len(lines) or not lines[k].strip().isdigit():
                got = lines[k].strip()[:40] if k < len(lines) else "nothing"
                raise InputError(f"{path}:{k + 1}: expected the number of points (a PTS file's first line), "
                                 f"got {got!r}")
            self.count = int(lines[k])
            k += 1
        elif k < len(lines):
            line = lines[k].strip()
            marked = line.startswith(("//", "#"))
            words = _tokens(line.lstrip("/#"), "," if "," in line else None)
            if words and not any(_is_number(w) for w in words):
                names = words
                k += 1
            elif marked:
                k += 1  # a comment
        while k < len(lines) and (not lines[k].strip() or lines[k].lstrip().startswith(("#", "//"))):
            k += 1
        self.skip = k
        first = lines[k] if k < len(lines) else ""
        self.delimiter = "," if "," in first else None
        width = len(_tokens(first, self.delimiter)) if first.strip() else (len(names) if names else 3)
        if names is not None and len(names) != width:
            raise InputError(f"{path}:{k + 1}: {width} numbers, but the header names {len(names)} columns {names}")
        if width < 3:
            raise InputError(f"{path}:{k + 1}: expected at least x y z, got {width} numbers")
        if pts and width - 3 not in _BY_COUNT:
            raise InputError(f"{path}:{k + 1}: a PTS line holds x y z [intensity] [r g b], got {width} numbers")
        self.names = names or _default_names(width)
        if len(set(self.names)) != len(self.names):
            raise InputError(f"{path}:{k}: the header names a column more than once: {self.names}")


def _line_of_row(lines: list[str], row: int) -> int:
    """On the error path only: the index in ``lines`` of data row ``row``."""
    seen = -1
    for k, line in enumerate(lines):
        s = line.strip()
        if s and not s.startswith(("#", "//")):
            seen += 1
            if seen == row:
                return k
    return 0


def _bad_line(path: Path, lines: list[str], first_line: int, width: int, delimiter) -> str:
    """On the error path only: the first line that is not ``width`` numbers."""
    for k, line in enumerate(lines):
        s = line.strip()
        if not s or s.startswith(("#", "//")):
            continue
        words = _tokens(s, delimiter)
        if len(words) != width:
            return f"{path}:{first_line + k}: expected {width} numbers, got {len(words)}"
        for j, w in enumerate(words):
            if not _is_number(w):
                return f"{path}:{first_line + k}: value {w!r} in column {j + 1} is not a number"
    return f"{path}:{first_line}: not numeric"


def _make_chunks(pts: bool):
    def chunks(path: Path, chunk: int, need):
        """Columns of the text file in chunks of at most ``chunk`` lines."""
        path = check_file(path)
        size = path.stat().st_size
        layout = _Layout(path, pts)
        require(path, layout.names, need)
        return size, _chunks(path, layout, chunk, size)
    return chunks


def _chunks(path: Path, layout: _Layout, chunk: int, size: int):
    width, names, rows = len(layout.names), layout.names, 0
    line_no = layout.skip + 1  # the file's line number of the chunk's first line
    with path.open("rb") as f:
        for _ in range(layout.skip):
            f.readline()
        while True:
            raw = list(islice(f, chunk))
            if not raw:
                break
            text = _decode(path, b"".join(raw), line_no)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # a chunk of comments only: no data
                    a = np.loadtxt(io.StringIO(text), dtype=np.float64, comments=("#", "//"),
                                   delimiter=layout.delimiter, ndmin=2)
            except ValueError:  # the lines are split only to name the one at fault
                raise InputError(_bad_line(path, text.splitlines(), line_no, width, layout.delimiter)) from None
            if a.size and a.shape[1] != width:
                raise InputError(_bad_line(path, text.splitlines(), line_no, width, layout.delimiter))
            a = a.reshape(-1, width)
            cols = {}
            for j, name in enumerate(names):
                col = np.ascontiguousarray(a[:, j])
                if _is_integer_name(name):
                    whole = np.isfinite(col) & (col == np.round(col))
                    if not whole.all():
                        bad = int(np.flatnonzero(~whole)[0])
                        raise InputError(f"{path}:{line_no + _line_of_row(text.splitlines(), bad)}: column {name!r} must hold "
                                         f"whole numbers, got {col[bad]!r}")
                    col = col.astype(np.int64)
                cols[name] = col
            rows += len(a)
            line_no += len(raw)
            yield cols, f.tell()
    if rows == 0:
        yield {n: np.zeros(0, np.int64 if _is_integer_name(n) else np.float64) for n in names}, size
    if layout.count is not None and layout.count != rows:
        raise InputError(f"{path}:{layout.skip}: the count line says {layout.count} points, the file holds {rows}")


class XyzWriter(ColumnWriter):
    """XYZ: a ``//X Y Z ...`` header line, then blank-separated numbers."""

    SEEKS = False  # written front to back: a FIFO gets it as it is made

    def _start(self):
        names = [n for n, _ in self.schema]
        plain_text_names(self.path, names)
        self.f.write(("//" + " ".join(["X", "Y", "Z", *names]) + "\n").encode())

    def _write(self, xyz, extras):
        if len(xyz):
            table = arrow_table({"X": xyz[:, 0], "Y": xyz[:, 1], "Z": xyz[:, 2], **extras})
            pa_csv.write_csv(table, self.f, pa_csv.WriteOptions(include_header=False, delimiter=" ",
                                                                quoting_style="none"))


_PTS_COUNT_WIDTH = 20


class PtsWriter(XyzWriter):
    """PTS: the count (filled in at the end), then ``x y z [intensity] [r g b]``."""

    SEEKS = True  # the count is filled in at the end

    def _start(self):
        names = tuple(n for n, _ in self.schema)
        if names not in _BY_COUNT.values():
            raise InputError(f"{self.path}: a PTS file holds x y z and optionally intensity, red green blue in that "
                             f"order; cannot write columns {list(names)} (use .xyz, .csv, .ply or .parquet)")
        self.f.write(b" " * _PTS_COUNT_WIDTH + b"\n")

    def _finish(self):
        self.f.seek(0)
        self.f.write(str(self.rows).ljust(_PTS_COUNT_WIDTH).encode())


register(PointFormat("xyz", (".xyz",), _make_chunks(False), XyzWriter,
                     description="ASCII x y z [more columns], blank or tab separated, optional //header"))
register(PointFormat("pts", (".pts",), _make_chunks(True), PtsWriter,
                     description="Leica PTS: a count line, then x y z [intensity] [r g b]", named_columns=False))
