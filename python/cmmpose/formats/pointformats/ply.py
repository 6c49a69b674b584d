"""PLY point files (the ``plyfile`` package, extra ``[pointcloud]``).

Read: the ``vertex`` element, one column per scalar property under its own
name (coordinates are ``x, y, z``); other elements (faces) are ignored. A
binary file (either byte order) is memory-mapped and read chunk by chunk;
an ASCII file's rows are parsed a chunk of lines at a time (plyfile checks
its header), so memory stays bounded either way. Written: binary little endian
(``"ply"``), ASCII (``"ply-ascii"``) or binary big endian
(``"ply-big-endian"``), with properties ``x, y, z`` (double) and the extra
columns. PLY has no 64-bit integers: an int64 or uint64 column is written as
int32 or uint32 when its values fit, else refused. The header comes from
plyfile; the body is written chunk by chunk, and the vertex count, known only
at the end, is written into a fixed-width field of the header."""

from __future__ import annotations

import io
import re
import warnings
from itertools import islice
from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import ColumnWriter, arrow_table, check_file, require, release_pages
from ..._lazy import LazyModule

# Loaded on first use: `import cmmpose` does not pay for pyarrow (cmmpose._lazy).
pa_csv = LazyModule("pyarrow.csv")


def _plyfile():
    try:
        import plyfile
    except ImportError:
        raise InputError("PLY files need the plyfile package: pip install 'cmmpose[pointcloud]'") from None
    return plyfile


#: bytes: a body this much (beyond twice its size) shorter than its header declares is refused before reading.
_SHORT_BODY = 1 << 20
#: Bytes of each PLY scalar type (binary); list properties need at least their count's.
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_counts(path: Path) -> None:
    """``InputError`` when the header declares more rows than the file's size
    can hold (at least two bytes per ASCII value, the type's size per binary
    one): checked before anything is allocated for them (a header declaring
    1e12 vertices is an error, not a 22 TiB allocation; a body short by
    less than a factor 2 and 1 MiB is plyfile's "early end-of-file", naming
    the row). A header this
    cannot parse is left to plyfile, which names the line."""
    fmt, need, body = None, [], 0
    with path.open("rb") as f:
        for _ in range(10_000):
            line = f.readline()
            if not line:
                return
            words = line.decode("ascii", "replace").split()
            if words[:1] == ["format"] and len(words) > 1:
                fmt = words[1]
            elif words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
                need.append([words[1], int(words[2]), 0])
            elif words[:1] == ["property"] and need and len(words) >= 3:
                kind = words[2] if words[1] == "list" and len(words) >= 5 else words[1]
                if kind not in _PLY_SIZES:
                    return
                need[-1][2] += 2 if fmt == "ascii" else _PLY_SIZES[kind]
            elif line.strip() == b"end_header":
                body = path.stat().st_size - f.tell()
                break
        else:
            return
    total = 0
    for name, count, row in need:
        total += count * max(row, 1)
        # a modestly short body is left to plyfile, which names the row where it ends
        if total > 2 * body + _SHORT_BODY:
            raise InputError(f"{path}: the PLY header declares {count:,} {name!r} rows, which need at least "
                             f"{count * max(row, 1):,} bytes; the file holds {body:,} bytes after its header "
                             f"(the count is wrong or the file is cut)")


def read_ply(path: Path):
    """The ``PlyData`` of a binary PLY ``path`` (memory-mapped), or
    ``InputError`` naming the file, the header line or the element row at
    fault. (An ASCII file is read by :func:`_ascii_chunks`.)"""
    plyfile = _plyfile()
    _check_counts(path)
    try:
        # Opened here so that where the declared elements end can be compared with where the file ends.
        with path.open("rb") as f:
            data = plyfile.PlyData.read(f, mmap=True)
            _check_no_more_rows(path, f, data)
        return data
    except plyfile.PlyHeaderParseError as exc:
        raise InputError(f"{path}:{exc.line}: malformed PLY header: {exc.message}") from None
    except plyfile.PlyElementParseError as exc:
        where = f"element {exc.element.name!r}, row {exc.row}" if exc.element is not None else "data"
        if exc.prop is not None:
            where += f", property {exc.prop.name!r}"
        message = exc.message
        if message == "early end-of-file" and exc.element is not None and exc.row is not None:
            message += (f": the header declares {exc.element.count} {exc.element.name!r} rows, the file holds "
                        f"{exc.row}; the file is cut or its header is wrong")
        raise InputError(f"{path}: PLY {where}: {message}") from None
    except (ValueError, OSError, UnicodeDecodeError, IndexError, KeyError) as exc:
        raise InputError(f"{path}: not a readable PLY file ({type(exc).__name__}: {exc})") from None


def _check_no_more_rows(path: Path, f, data) -> None:
    """``InputError`` when the binary file ``f`` (just read by plyfile,
    positioned after the declared elements) holds more data than its header
    declares: plyfile reads the declared count and ignores the rest, which
    would silently drop points (fewer rows than declared is plyfile's own
    "early end-of-file")."""
    declared = ", ".join(f"{e.count} {e.name!r}" for e in data.elements) or "no elements"
    end = f.tell()
    size = f.seek(0, 2)
    if size > end:
        last = data.elements[-1] if data.elements else None
        rows = ""
        fixed = last is not None and not any(isinstance(q, _plyfile().PlyListProperty) for q in last.properties)
        if fixed and (size - end) % last.data.dtype.itemsize == 0:
            rows = f", {(size - end) // last.data.dtype.itemsize} more {last.name!r} rows"
        raise InputError(f"{path}: PLY body has {size - end} bytes beyond the header's count{rows} "
                         f"(it declares {declared} rows); the header disagrees with the body")


def _format_line(path: Path) -> str | None:
    with path.open("rb") as f:
        for line in f:
            words = line.split()
            if words[:1] == [b"format"] and len(words) > 1:
                return words[1].decode("ascii", "replace")
            if line.strip() == b"end_header":
                break
    return None


def chunks(path: Path, chunk: int, need):
    """The ``vertex`` element's scalar properties in chunks of at most ``chunk`` rows."""
    path = check_file(path)
    size = path.stat().st_size
    if _format_line(path) == "ascii":
        _check_counts(path)
        header, elements = _ascii_header(path)
        vertex = _vertex(path, [e for e, _ in elements])
        require(path, [q.name for q in vertex.properties], need, "vertex properties")
        return size, _ascii_chunks(path, header, elements, min(chunk, ASCII_CHUNK_LINES), size)
    data = read_ply(path)
    v = _vertex(path, data.elements).data
    require(path, v.dtype.names, need, "vertex properties")
    return size, _chunks(v, chunk, size)


def _vertex(path: Path, elements):
    """The ``vertex`` element of ``elements``, or ``InputError`` when there is
    none or one of its properties is a list."""
    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        raise InputError(f"{path}: no 'vertex' element (has {[e.name for e in elements]})")
    lists = [p.name for p in vertex.properties if isinstance(p, _plyfile().PlyListProperty)]
    if lists:
        raise InputError(f"{path}: vertex properties {lists} are lists; expected one number per property")
    return vertex


#: Lines of an ASCII PLY body parsed at a time (as XYZ files are read).
ASCII_CHUNK_LINES = 1_000_000
_ELEMENT_COUNT = re.compile(rb"^(\s*element\s+\S+\s+)(\d+)(\s*)$")


def _ascii_header(path: Path):
    """The header's bytes and its elements with their declared row counts.

    plyfile parses the header (naming the line of a malformed one) from a
    copy whose element counts are 0, so that it reads no body: the rows are
    then parsed here a chunk at a time."""
    plyfile = _plyfile()
    lines, counts = [], []
    with path.open("rb") as f:
        for line in islice(f, 10_000):
            m = _ELEMENT_COUNT.match(line)
            if m:
                counts.append(int(m.group(2)))
                line = m.group(1) + b"0" + m.group(3)
            lines.append(line)
            if line.strip() == b"end_header":
                break
    try:
        data = plyfile.PlyData.read(io.BytesIO(b"".join(lines)))
    except plyfile.PlyHeaderParseError as exc:
        raise InputError(f"{path}:{exc.line}: malformed PLY header: {exc.message}") from None
    except (plyfile.PlyParseError, ValueError) as exc:
        raise InputError(f"{path}: not a readable PLY file ({type(exc).__name__}: {exc})") from None
    return len(lines), list(zip(data.elements, counts))


def _ascii_chunks(path: Path, header: int, elements, chunk: int, size: int):
    """The vertex rows of an ASCII PLY as columns, ``chunk`` lines at a time
    (one row a line, as plyfile reads them), then the rest of the body
    counted: a body shorter or longer than its header declares is refused,
    as for a binary file."""
    line_no = header  # lines read so far
    with path.open("rb") as f:
        for _ in range(header):
            f.readline()
        for element, count in elements:
            if element.name != "vertex":
                got = sum(1 for _ in islice(f, count))
                if got < count:
                    raise InputError(f"{path}: PLY element {element.name!r}, row {got}: early end-of-file: the "
                                     f"header declares {count} {element.name!r} rows, the file holds {got}; the "
                                     "file is cut or its header is wrong")
                line_no += count
                continue
            dtype = np.dtype([(q.name, q.val_dtype) for q in element.properties])
            if count == 0:
                yield {c: np.zeros(0, dtype[c].newbyteorder("=")) for c in dtype.names}, f.tell()
            rows = 0
            while rows < count:
                raw = list(islice(f, min(chunk, count - rows)))
                if len(raw) < min(chunk, count - rows):
                    raise InputError(f"{path}: PLY element 'vertex', row {rows + len(raw)}: early end-of-file: the "
                                     f"header declares {count} 'vertex' rows, the file holds {rows + len(raw)}; "
                                     "the file is cut or its header is wrong")
                block = _ascii_rows(path, raw, dtype, rows, line_no)
                cols = {c: np.ascontiguousarray(block[c]).astype(dtype[c].newbyteorder("="), copy=False)
                        for c in dtype.names}
                rows += len(raw)
                line_no += len(raw)
                yield cols, f.tell()
        extra, first = 0, 0
        for line in f:
            line_no += 1
            if line.strip():
                extra += 1
                first = first or line_no
    if extra:
        declared = ", ".join(f"{count} {e.name!r}" for e, count in elements)
        raise InputError(f"{path}:{first}: PLY body has {extra} rows beyond the header's count "
                         f"(it declares {declared} rows); the header disagrees with the body")


def _ascii_rows(path: Path, raw: list[bytes], dtype: np.dtype, first_row: int, line_no: int) -> np.ndarray:
    """``raw`` lines as rows of ``dtype``; a line that is not one row names
    its row, property and line as plyfile would."""
    try:
        text = b"".join(raw).decode("ascii")
        with warnings.catch_warnings():
            warnings.simplefilter("error", UserWarning)  # loadtxt on an empty chunk
            block = np.loadtxt(io.StringIO(text), dtype=dtype, comments=None, ndmin=1)
        if len(block) == len(raw):  # loadtxt passes over blank lines; plyfile does not
            return block
    except (ValueError, UnicodeDecodeError, UserWarning):
        pass
    for k, line in enumerate(raw):
        tokens = line.split()
        where = f"{path}: PLY element 'vertex', row {first_row + k}"
        for j, name in enumerate(dtype.names):
            if j >= len(tokens):
                raise InputError(f"{where}, property {name!r} (line {line_no + k + 1}): early end-of-line")
            try:
                dtype[name].type(tokens[j].decode("ascii"))
            except (ValueError, OverflowError, UnicodeDecodeError):
                raise InputError(f"{where}, property {name!r} (line {line_no + k + 1}): malformed input") from None
        if len(tokens) > len(dtype.names):
            raise InputError(f"{where} (line {line_no + k + 1}): expected end-of-line")
    raise InputError(f"{path}: PLY element 'vertex', rows {first_row}-{first_row + len(raw) - 1}: not readable")


def _chunks(v, chunk, size):
    n = len(v)
    for lo in range(0, max(n, 1), chunk):
        hi = min(lo + chunk, n)
        block = v[lo:hi]
        cols = {c: np.array(block[c], dtype=v.dtype.fields[c][0].newbyteorder("=")) for c in v.dtype.names}
        release_pages(block)  # copied out: its pages of the file leave resident memory
        yield cols, int(size * hi / max(n, 1))


#: Digits the vertex count is padded to in a written header.
_COUNT_WIDTH = 20


def _ply_dtype(dt: np.dtype) -> np.dtype:
    """The PLY property type for a column of ``dt``: 64-bit integers narrowed
    to 32 bits (the writer refuses values that do not fit), float16 as float."""
    if dt.kind in "iu" and dt.itemsize == 8:
        return np.dtype(np.int32 if dt.kind == "i" else np.uint32)
    if dt.kind == "f" and dt.itemsize == 2:
        return np.dtype(np.float32)
    return dt


class Writer(ColumnWriter):
    """PLY, binary (either byte order) or ASCII."""

    encoding = "binary_little_endian"

    def _start(self):
        plyfile = _plyfile()
        order = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "="}[self.encoding]
        fields = [("x", "f8"), ("y", "f8"), ("z", "f8")] + [(n, _ply_dtype(dt))
                                                              for n, dt in self.schema]
        self.dtype = np.dtype([(n, np.dtype(t).newbyteorder(order if order != "=" else "<")) for n, t in fields])
        element = plyfile.PlyElement.describe(np.empty(0, self.dtype), "vertex")
        text = plyfile.PlyData([element], text=self.encoding == "ascii",
                               byte_order=order).header
        self.count_line = "element vertex 0"
        if self.count_line not in text:  # pragma: no cover - plyfile's header layout
            raise InputError(f"{self.path}: unexpected PLY header from plyfile")
        self.header = text
        self.f.write(self._header(0))

    def _header(self, rows: int) -> bytes:
        line = f"element vertex {rows}".ljust(len("element vertex ") + _COUNT_WIDTH)
        return (self.header.replace(self.count_line, line, 1) + "\n").encode("ascii")

    def _write(self, xyz, extras):
        for n, v in extras.items():
            narrow = self.dtype.fields[n][0]
            if narrow.kind in "iu" and len(v) and v.dtype.itemsize > narrow.itemsize:
                info = np.iinfo(narrow)
                if v.min() < info.min or v.max() > info.max:
                    raise InputError(f"{self.path}: column {n!r} holds values beyond PLY's {narrow.name} "
                                     f"({v.min()}..{v.max()})")
        if self.encoding == "ascii":
            if len(xyz):
                native = {n: v.astype(self.dtype.fields[n][0].newbyteorder("=")) for n, v in extras.items()}
                table = arrow_table({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], **native})
                pa_csv.write_csv(table, self.f, pa_csv.WriteOptions(include_header=False, delimiter=" ",
                                                                    quoting_style="none"))
            return
        rec = np.empty(len(xyz), self.dtype)
        rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        for n, v in extras.items():
            rec[n] = v
        self.f.write(rec.tobytes())

    def _finish(self):
        self.f.seek(0)
        self.f.write(self._header(self.rows))


class AsciiWriter(Writer):
    encoding = "ascii"


class BigEndianWriter(Writer):
    encoding = "binary_big_endian"


_DESC = "PLY vertex element (plyfile)"
register(PointFormat("ply", (".ply",), chunks, Writer, description=_DESC + "; written binary little endian"))
register(PointFormat("ply-ascii", (), chunks, AsciiWriter, description=_DESC + "; written as ASCII"))
register(PointFormat("ply-big-endian", (), chunks, BigEndianWriter, description=_DESC + "; written binary big endian"))
