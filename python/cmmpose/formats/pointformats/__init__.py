"""Registry of point-file formats (docs/formats.md, "Point files").

Each format lives in one public module of this package and registers itself
when the package is imported (every public module is, in name order; a
second format of a name already taken is refused): a name, the file suffixes
it is found by, a chunked reader of named columns and a chunked writer. :mod:`cmmpose.formats.pointfiles`
(``cmmpose compensate``) and :mod:`cmmpose.formats.pointclouds`
(:func:`~cmmpose.read_point_cloud`) dispatch through it and never import a
format module themselves.

Registered: ``"csv"``, ``"npy"``, ``"parquet"``, ``"ply"`` (binary little
endian when written; ``"ply-ascii"`` and ``"ply-big-endian"`` write the
other two encodings), ``"xyz"``, ``"pts"`` and ``"e57"``.

A reader is ``chunks(path, chunk, need) -> (size, iterator)``: ``size`` is
the file's size in bytes and each item of the iterator is ``(columns,
bytes_done)``, ``columns`` a dict of 1-D numeric arrays of equal length (at
most ``chunk`` rows; names as stored) and ``bytes_done`` how far into the
file the chunk ends (for progress). ``need`` (:class:`Need`) names the
columns the caller requires, so that a reader can refuse a file early and
name the columns of an unnamed layout (a plain NPY array).

A writer is ``writer(path) -> ColumnWriter``: ``write(xyz, extras)`` takes
(n, 3) coordinates in the format's ``units`` and a dict of extra columns
(the first call fixes their names and types), ``close()`` renames the
temporary file into place, ``abort()`` removes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..._registry import Registry, import_modules
from ...errors import InputError

__all__ = ["PointFormat", "Need", "REGISTRY", "register", "names", "get", "for_path", "read_all", "Reread"]


@dataclass(frozen=True)
class Need:
    """The columns a caller requires of a point file.

    Attributes
    ----------
    names : tuple of str
        Columns that must be present (e.g. ``u, v, D, E, F``); read as float64.
    optional : tuple of str
        Columns read as float64 when present (e.g. ``T``).
    plain : dict of int to tuple of str
        Column names for an unnamed layout by its width (a plain NPY array):
        ``{5: (u, v, D, E, F), 6: (u, v, D, E, F, T)}``.
    what : str
        How messages describe the required columns.
    """

    names: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()
    plain: dict[int, tuple[str, ...]] = field(default_factory=dict)
    what: str = ""


@dataclass(frozen=True)
class PointFormat:
    """One point-file format.

    Attributes
    ----------
    name : str
        The name given as ``format=``.
    suffixes : tuple of str
        Lower-case file suffixes (with the dot) that select this format.
    chunks : callable
        ``chunks(path, chunk, need) -> (size, iterator of (columns, bytes_done))``.
    writer : callable
        ``writer(path) -> ColumnWriter``.
    units : str
        The unit the format stores coordinates in by convention: ``"m"`` for
        E57 (the standard's), ``"mm"`` for every other.
    description : str
        One line for messages and listings.
    named_columns : bool
        Whether the writer carries any named extra column (PTS carries only
        intensity and colour): the uncertainty columns need it.
    """

    name: str
    suffixes: tuple[str, ...]
    chunks: Callable[..., Any]
    writer: Callable[..., Any]
    units: str = "mm"
    description: str = ""
    named_columns: bool = True


#: The point-file formats by name, in registration order (each module registers its own).
REGISTRY: Registry[PointFormat] = Registry(
    "point-file format",
    unknown=lambda name, known: InputError(f"unknown point-file format {name!r}; known: {', '.join(known)}"))


def register(fmt: PointFormat) -> PointFormat:
    """Register ``fmt`` under its name; returns it. ``ValueError`` when
    another format holds the name already (a format never replaces another)."""
    return REGISTRY.register(fmt.name, fmt)


def names() -> list[str]:
    """The registered format names."""
    return REGISTRY.names()


def get(name: str) -> PointFormat:
    """The format called ``name``; ``InputError`` listing the known names otherwise."""
    return REGISTRY.get(name)


#: Suffixes of compressed files, refused by name rather than read or written as CSV.
COMPRESSED = (".gz", ".bz2", ".xz", ".zst", ".zip", ".7z", ".lz4", ".z")


def for_path(path: str | Path, format: str | None = None, default: str | None = None) -> PointFormat:
    """The format for ``path``: ``format`` by name if given, else by the
    file's suffix (any case), else ``default``.

    Raises
    ------
    InputError
        Naming the file and the known suffixes when the suffix is unknown and
        there is no default; naming the file when its suffix says it is
        compressed (``.gz``, ``.zip``, ...), whatever the default.
    """
    if format is not None:
        return get(format)
    suffix = Path(path).suffix.lower()
    if suffix in COMPRESSED:
        # Read as text, such a file is garbage; written as CSV, a file named .gz is not gzip.
        raise InputError(f"{path}: compressed point files ({suffix!r}) are neither read nor written: decompress "
                         f"the input first, and name an output without {suffix!r} (compress it afterwards)")
    for fmt in REGISTRY.values():
        if suffix in fmt.suffixes:
            return fmt
    if default is not None:
        return get(default)
    known = sorted({s for f in REGISTRY.values() for s in f.suffixes})
    raise InputError(f"{path}: unknown point-file suffix {suffix or '(none)'!r}; known: {', '.join(known)} "
                     f"(or give the format by name: {', '.join(REGISTRY.names())})")


# Each public module registers its format(s) when imported (``common`` holds what they share); in name order.
import_modules(__name__, __path__)
from . import csv  # noqa: E402

#: The strict CSV reader's whole file, raised when the fast reader gave up on
#: a line the strict one accepts (see :mod:`.csv`).
Reread = csv.Reread


def read_all(fmt: PointFormat, path: str | Path, need: Need) -> dict:
    """Every column of a file, whole: its chunks joined (or the strict CSV
    reader's columns when the fast one gave up)."""
    _, chunks = fmt.chunks(Path(path), 1 << 62, need)
    try:
        parts = [c for c, _ in chunks]
    except Reread as again:
        return again.columns
    if len(parts) == 1:
        return parts[0]
    return {n: np.concatenate([p[n] for p in parts]) for n in parts[0]}
