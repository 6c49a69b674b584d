"""E57 point files (ASTM E2807; the ``pye57`` package and the libE57Format
library it wraps, extra ``[pointcloud]``). Coordinates in metres, the
standard's unit.

Read: every scan of ``/data3D`` in turn, chunk by chunk, as ``X, Y, Z`` in
the file's coordinate system (each scan's pose applied); points flagged
invalid (``cartesianInvalidState`` not 0) are dropped. Scans stored in
spherical coordinates only are converted. Further fields become columns:
``intensity``; ``colorRed``, ``colorGreen``, ``colorBlue`` as ``red, green,
blue``; ``rowIndex``, ``columnIndex`` as ``row, column``; cmmpose's own
extension fields ``cmmpose:NAME`` as ``NAME``; any other numeric field under
its E57 name. A file of several scans gets a ``scan_id`` column (the scan's
index) unless it carries one.

Written: one scan whose points have ``cartesianX/Y/Z`` as 64-bit floats
(``pye57``'s own writer stores single precision, too coarse for a CMM), and
the extra columns: ``intensity`` (float), ``red, green, blue`` as the
standard's colour fields (whole numbers 0-255), ``row, column`` as
``rowIndex, columnIndex``, every other column as an extension field
``cmmpose:NAME`` (64-bit integer or float). Written chunk by chunk."""

from __future__ import annotations

import logging
import os
import uuid
from pathlib import Path

import numpy as np

from ...errors import InputError
from . import PointFormat, register
from .common import ColumnWriter, check_file

_log = logging.getLogger("cmmpose")

#: The namespace of cmmpose's extension fields.
NAMESPACE = ("cmmpose", "urn:cmmpose:e57:1")  # an identifier (a URI, as E57 asks), not a web address
#: Standard E57 fields and the column names they are read and written under.
_STANDARD = {"intensity": "intensity", "colorRed": "red", "colorGreen": "green", "colorBlue": "blue",
             "rowIndex": "row", "columnIndex": "column"}
_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
#: Records moved per call of the library's reader and writer.
_BLOCK = 1 << 16
#: libE57Format's Python binding takes NumPy's "q" (long long) as 64-bit; "l" is read as 32-bit.
_INT64 = np.dtype("q")


def _pye57():
    try:
        import pye57
    except ImportError:
        raise InputError("E57 files need the pye57 package: pip install 'cmmpose[pointcloud]'") from None
    return pye57


def _column_name(field: str) -> str:
    if field in _STANDARD:
        return _STANDARD[field]
    if field.startswith(NAMESPACE[0] + ":"):
        return field.split(":", 1)[1]
    return field


def chunks(path: Path, chunk: int, need):
    """The points of every scan, in chunks of at most ``chunk`` rows."""
    path = check_file(path)
    size = path.stat().st_size
    pye57 = _pye57()
    try:
        e57 = pye57.E57(str(path), mode="r")
        headers = [e57.get_header(k) for k in range(e57.scan_count)]
    except Exception as exc:  # libE57Format raises its own exception types and RuntimeError
        raise InputError(f"{path}: not a readable E57 file ({type(exc).__name__}: {exc})") from None
    if not headers:
        raise InputError(f"{path}: no scans (the E57 file's /data3D is empty)")
    plans = [_plan(path, k, h, pye57.libe57) for k, h in enumerate(headers)]
    first = {n for n, _ in plans[0][1]}
    for k, (_, fields, _) in enumerate(plans[1:], start=1):
        if {n for n, _ in fields} != first:
            raise InputError(f"{path}: scan {k} has fields {sorted(n for n, _ in fields)}, scan 0 has "
                             f"{sorted(first)}; every scan must carry the same ones")
    add_scan_id = len(headers) > 1 and "scan_id" not in {_column_name(f) for f, _ in plans[0][1]}
    return size, _chunks(path, e57, headers, plans, chunk, size, add_scan_id)


def _plan(path, k, header, libe57):
    """The fields of scan ``k`` to read, with the NumPy type of each, and
    whether its coordinates are spherical."""
    fields = header.point_fields
    spherical = not all(f in fields for f in _CARTESIAN)
    if spherical and not all(f in fields for f in _SPHERICAL):
        raise InputError(f"{path}: scan {k} has no cartesianX/Y/Z (nor spherical) fields; it has {fields}")
    proto = libe57.StructureNode(header.points.prototype())
    plan = []
    for f in fields:
        kind = proto.get(f).type()
        if kind in (libe57.NodeType.E57_FLOAT, libe57.NodeType.E57_SCALED_INTEGER):
            plan.append((f, np.dtype(np.float64)))
        elif kind == libe57.NodeType.E57_INTEGER:
            plan.append((f, _INT64))
        else:
            _log.info("%s: scan %d: field %r (%s) is not a number; not read", path, k, f, kind)
    return spherical, plan, header.point_count


def _chunks(path, e57, headers, plans, chunk, size, add_scan_id):
    libe57 = _pye57().libe57
    from pye57.utils import convert_spherical_to_cartesian

    total = max(sum(p[2] for p in plans), 1)
    done = 0
    try:
        for k, (header, (spherical, plan, count)) in enumerate(zip(headers, plans)):
            if count == 0:
                continue  # libE57Format cannot read an empty compressed vector
            cap = max(min(chunk, count), 1)
            arrays = {f: np.empty(cap, dt) for f, dt in plan}
            buffers = libe57.VectorSourceDestBuffer()
            for f, a in arrays.items():
                buffers.append(libe57.SourceDestBuffer(e57.image_file, f, a, cap, True, True))
            reader = header.points.reader(buffers)
            rotation = header.rotation_matrix if header.has_pose() else None
            translation = header.translation if header.has_pose() else None
            try:
                while True:
                    n = reader.read()
                    if n == 0:
                        break
                    got = {f: a[:n].copy() for f, a in arrays.items()}
                    state = "sphericalInvalidState" if spherical else "cartesianInvalidState"
                    keep = got.pop(state) == 0 if state in got else None
                    got.pop("cartesianInvalidState" if spherical else "sphericalInvalidState", None)
                    if spherical:
                        xyz = convert_spherical_to_cartesian(np.column_stack([got.pop(f) for f in _SPHERICAL]))
                        for f in _CARTESIAN:
                            got.pop(f, None)
                    else:
                        xyz = np.column_stack([got.pop(f) for f in _CARTESIAN])
                    if rotation is not None:
                        xyz = xyz @ np.asarray(rotation).T + np.asarray(translation)
                    cols = {"X": xyz[:, 0], "Y": xyz[:, 1], "Z": xyz[:, 2]}
                    for f, v in got.items():
                        cols[_column_name(f)] = v.astype(np.int64) if v.dtype == _INT64 else v
                    if add_scan_id:
                        cols["scan_id"] = np.full(n, k, dtype=np.int64)
                    if keep is not None and not keep.all():
                        _log.info("%s: scan %d: %d points flagged invalid dropped", path, k, int((~keep).sum()))
                        cols = {c: v[keep] for c, v in cols.items()}
                    done += n
                    yield cols, int(size * done / total)
            finally:
                reader.close()
        if done == 0:
            names = ["X", "Y", "Z"] + [_column_name(f) for f, _ in plans[0][1]
                                       if f not in _CARTESIAN + _SPHERICAL and not f.endswith("InvalidState")]
            yield {c: np.zeros(0) for c in names + (["scan_id"] if add_scan_id else [])}, size
    except InputError:
        raise
    except Exception as exc:  # a damaged compressed vector
        raise InputError(f"{path}: not a readable E57 file: {type(exc).__name__}: {exc}") from None
    finally:
        e57.close()


def _e57_name(path, name: str) -> str:
    """The E57 field a column is written as."""
    for field, column in _STANDARD.items():
        if name == column:
            return field
    if not (name[:1].isalpha() or name[:1] == "_") or not all(ch.isalnum() or ch in "_-." for ch in name):
        raise InputError(f"{path}: column name {name!r} cannot be an E57 field name (letters, digits, _ - . "
                         f"and not starting with a digit)")
    return f"{NAMESPACE[0]}:{name}"


class Writer(ColumnWriter):
    """E57: one scan, written chunk by chunk through libE57Format."""

    def __init__(self, path):
        super().__init__(path)
        self.f.close()  # libE57Format opens the temporary file itself
        os.unlink(self.tmp)
        self.e57 = None

    def _start(self):
        pye57 = _pye57()
        lib = pye57.libe57
        try:
            self.e57 = pye57.E57(self.tmp, mode="w")
        except Exception as exc:
            raise InputError(f"{self.path}: cannot write an E57 file ({exc})") from None
        imf = self.e57.image_file
        fields = [(f, np.dtype(np.float64)) for f in _CARTESIAN]
        extra = {}
        ns = NAMESPACE[0] + ":"
        for name, dt in self.schema:
            field = _e57_name(self.path, name)
            if field in ("colorRed", "colorGreen", "colorBlue", "rowIndex", "columnIndex") and dt.kind == "f":
                raise InputError(f"{self.path}: column {name!r} must hold whole numbers for E57's {field}")
            if field.startswith(ns) and not any(f.startswith(ns) for f in extra.values()):
                imf.extensionsAdd(*NAMESPACE)
            extra[name] = field
            fields.append((field, _INT64 if dt.kind in "iu" else np.dtype(np.float64)))
        self.columns = extra
        proto = lib.StructureNode(imf)
        for field, dt in fields:
            if field in ("colorRed", "colorGreen", "colorBlue"):
                proto.set(field, lib.IntegerNode(imf, 0, 0, 255))
            elif dt == _INT64:
                proto.set(field, lib.IntegerNode(imf, 0, lib.E57_INT64_MIN, lib.E57_INT64_MAX))
            else:
                proto.set(field, lib.FloatNode(imf, 0.0, lib.E57_DOUBLE))
        scan = lib.StructureNode(imf)
        scan.set("guid", lib.StringNode(imf, "{%s}" % uuid.uuid4()))
        scan.set("name", lib.StringNode(imf, self.path.stem))
        points = lib.CompressedVectorNode(imf, proto, lib.VectorNode(imf, True))
        scan.set("points", points)
        self.e57.data3d.append(scan)
        self.arrays = {f: np.zeros(_BLOCK, dt) for f, dt in fields}
        buffers = lib.VectorSourceDestBuffer()
        for f, a in self.arrays.items():
            buffers.append(lib.SourceDestBuffer(imf, f, a, _BLOCK, True, True))
        self.writer = points.writer(buffers)

    def _write(self, xyz, extras):
        for name in ("red", "green", "blue"):
            v = extras.get(name)
            if v is not None and len(v) and (v.min() < 0 or v.max() > 255):
                raise InputError(f"{self.path}: column {name!r} holds values beyond 0..255 ({v.min()}..{v.max()})")
        for lo in range(0, len(xyz), _BLOCK):
            n = min(_BLOCK, len(xyz) - lo)
            for j, f in enumerate(_CARTESIAN):
                self.arrays[f][:n] = xyz[lo:lo + n, j]
            for name, field in self.columns.items():
                self.arrays[field][:n] = extras[name][lo:lo + n]
            self.writer.write(n)

    def _finish(self):
        self.writer.close()
        self.e57.close()

    def abort(self):
        try:
            if self.e57 is not None:
                self.e57.close()
        except Exception:  # the file is being thrown away
            pass
        Path(self.tmp).unlink(missing_ok=True)


register(PointFormat("e57", (".e57",), chunks, Writer, units="m",
                     description="ASTM E57 (pye57 / libE57Format); metres"))
