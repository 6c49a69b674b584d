"""Registry of error-map file formats (docs/formats.md).

Each format module registers itself when it is imported: a name, a function
that recognises a file of that format, a reader and (optionally) a writer.
``ErrorMap.read`` and ``ErrorMap.write`` dispatch through this registry, so
:mod:`cmmpose.errormap` never imports the format modules; the package's
``__init__`` imports them (:mod:`cmmpose.formats.mapfiles`: ``'csv'``,
:mod:`cmmpose.formats.controller`: ``'controller'``, :mod:`cmmpose.formats.iso230`:
``'iso230-2'``, :mod:`cmmpose.formats.linuxcnc`: ``'linuxcnc'``).

A format stored as one file per axis (LinuxCNC's compensation tables) declares
the name of each axis's file (``per_axis``): it is read from a mapping axis ->
file (or a folder holding the files by those names) and written into a folder,
one file per axis. ``cmmpose map import/export`` dispatch on that declaration.

This module imports nothing else from cmmpose but the exceptions and the
registry mechanism.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Callable

from .._registry import Registry
from ..errors import InputError, MapError

__all__ = ["MapFormat", "REGISTRY", "AXES", "register", "names", "get", "detect", "read", "write"]

#: The axes a per-axis format holds a file for, in order.
AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class MapFormat:
    """One error-map file format.

    Attributes
    ----------
    name : str
        The name given as ``format=`` to ``ErrorMap.read`` / ``ErrorMap.write``.
    sniff : callable or None
        ``sniff(path) -> bool``: True when the file looks like this format
        (cheap; never raises on an unreadable or foreign file); None for a
        format never recognised by its content (``format='auto'`` skips it).
    read : callable
        ``read(path, **options) -> ErrorMap``; raises ``MapError`` naming the
        file and line of malformed content. A per-axis format's reader takes
        a mapping axis -> file.
    write : callable or None
        ``write(error_map, path, **options)``, or None for a format that is
        read only. A per-axis format's writer takes a mapping axis -> file.
    description : str
        One line for messages and listings.
    per_axis : str
        Empty for a format of one file; else the name of each axis's file,
        ``{axis}`` standing for its letter in lower case (``"{axis}.comp"``).
    """

    name: str
    sniff: Callable[[Path], bool] | None
    read: Callable[..., Any]
    write: Callable[..., None] | None = None
    description: str = ""
    per_axis: str = ""

    def files(self, folder: str | PathLike, existing: bool = False) -> dict[str, Path]:
        """A per-axis format's file of each axis in ``folder`` (with ``existing``,
        only the files there); ``InputError`` for a format of one file."""
        if not self.per_axis:
            raise InputError(f"format: map file format {self.name!r} is one file, not one file per axis")
        found = {a: Path(folder) / self.per_axis.format(axis=a.lower()) for a in AXES}
        return {a: p for a, p in found.items() if p.is_file()} if existing else found

    def read_options(self) -> list[str]:
        """The keyword options the reader takes (all of them: ``["*"]`` when it takes any)."""
        return _options(self.read)

    def write_options(self) -> list[str]:
        """The keyword options the writer takes (``[]`` for a read-only format; ``["*"]`` when it takes any)."""
        return [] if self.write is None else _options(self.write)


def _options(function) -> list[str]:
    try:
        params = inspect.signature(function).parameters
    except (TypeError, ValueError):
        return ["*"]  # a function whose signature cannot be inspected checks its own options
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return ["*"]
    return [n for n, p in params.items()
            if p.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)][1:]


#: The formats cmmpose ships: module -> format name. Their modules register them the first time the registry is
#: used (``import cmmpose`` does not pay for them: issue 27, start-up); they come first, in this order, whichever
#: module was imported first, then any other format in the order registered.
BUILTIN = {"mapfiles": "csv", "controller": "controller", "iso230": "iso230-2", "linuxcnc": "linuxcnc"}
_BUILTIN_ORDER = list(BUILTIN.values())


def _load_builtin() -> None:
    for module in BUILTIN:
        importlib.import_module(f"{__package__}.{module}")


#: The map file formats by name: built-in first (in ``BUILTIN``'s order), then in registration order. The
#: built-in modules load on the first read, under the registry's lock (threads reading maps at once, a Dask
#: scheduler's workers, must not see the registry before they have registered).
REGISTRY: Registry[MapFormat] = Registry(
    "map file format", load=_load_builtin,
    order=lambda n: _BUILTIN_ORDER.index(n) if n in _BUILTIN_ORDER else len(_BUILTIN_ORDER),
    unknown=lambda name, known: InputError(
        f"format: unknown map file format {name!r} (known: {', '.join(repr(n) for n in known) or 'none'})"))


def register(name: str, *, sniff=None, read, write=None, description: str = "", per_axis: str = "") -> MapFormat:
    """Register the map file format ``name``; returns its entry. ``ValueError``
    when another format holds the name already (a format never replaces another)."""
    return REGISTRY.register(name, MapFormat(name, sniff, read, write, description, per_axis))


def names() -> list[str]:
    """Names of the registered formats: the built-in ones first, then in registration order."""
    return REGISTRY.names()


def get(name: str) -> MapFormat:
    """The registered format ``name``; ``InputError`` naming it when unknown."""
    return REGISTRY.get(name)


def detect(path: str | PathLike) -> str | None:
    """Name of the first registered format that recognises the file at ``path``, or None."""
    path = Path(path)
    for fmt in REGISTRY.values():
        if fmt.sniff is not None and fmt.sniff(path):
            return fmt.name
    return None


def read(path, format: str = "csv", **options):
    """Read the map at ``path`` in ``format`` (``'auto'``: the format that
    recognises the file) with the reader's keyword ``options``. A per-axis
    format reads a mapping axis -> file, or the files of a folder."""
    if format == "auto":
        found = detect(path)
        if found is None:
            raise MapError(f"{path}: not an error-map file of a known format ({', '.join(names())})")
        format = found
    fmt = get(format)
    _check_options(fmt, options, path)
    given = path
    if fmt.per_axis and not isinstance(path, Mapping):
        files = fmt.files(path, existing=True)
        if not files:
            raise MapError(f"{path}: no file of the map file format {fmt.name!r} (one per axis: "
                           f"{', '.join(str(p.name) for p in fmt.files(path).values())})")
        path = files
    try:
        return fmt.read(path, **options)
    except MapError as exc:
        # The core checks a map's values (finite, within a machine's bounds) and names the table and row;
        # the file is the reader's to name.
        if exc.file is not None or str(exc).startswith(str(given)):
            raise
        raise MapError(f"{given}: {exc}", what=exc.what, file=str(given)) from None


def _check_options(fmt: MapFormat, options: dict, path) -> None:
    """``InputError`` naming an option that the reader of ``fmt`` does not take
    (an option of another format: with ``format='auto'``, the file may be of a
    format other than the caller expected)."""
    takes = fmt.read_options()
    if takes == ["*"]:
        return
    unknown = [n for n in options if n not in takes]
    if unknown:
        took = ", ".join(takes) if takes else "none"
        raise InputError(f"{', '.join(unknown)}: not an option of the map file format {fmt.name!r}, which {path} "
                         f"is read as (its options: {took})")


def write(error_map, path, format: str = "csv", **options) -> None:
    """Write ``error_map`` at ``path`` in ``format`` with the writer's keyword
    ``options``. A per-axis format writes into the folder ``path`` (made if
    missing), one file per axis, or to a mapping axis -> file."""
    fmt = get(format)
    if fmt.write is None:
        raise InputError(f"format: map file format {format!r} can be read but not written")
    takes = fmt.write_options()
    unknown = [n for n in options if n not in takes] if takes != ["*"] else []
    if unknown:
        raise InputError(f"{', '.join(unknown)}: not an option of the map file format {fmt.name!r} when written "
                         f"(its options: {', '.join(takes) or 'none'})")
    if fmt.per_axis and not isinstance(path, Mapping):
        Path(path).mkdir(parents=True, exist_ok=True)
        path = fmt.files(path)
    fmt.write(error_map, path, **options)
