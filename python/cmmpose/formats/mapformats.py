"""Registry of error-map file formats (docs/formats.md).

Each format module registers itself when it is imported: a name, a function
that recognises a file of that format, a reader and (optionally) a writer.
``ErrorMap.read`` and ``ErrorMap.write`` dispatch through this registry, so
:mod:`cmmpose.errormap` never imports the format modules; the package's
``__init__`` imports them (:mod:`cmmpose.formats.mapfiles`: ``'csv'``,
:mod:`cmmpose.formats.controller`: ``'controller'``).

This module imports nothing else from cmmpose but the exceptions.
"""

from __future__ import annotations

import importlib
import inspect
import threading
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Callable

from ..errors import InputError, MapError

__all__ = ["MapFormat", "register", "names", "get", "detect", "read", "write"]


@dataclass(frozen=True)
class MapFormat:
    """One error-map file format.

    Attributes
    ----------
    name : str
        The name given as ``format=`` to ``ErrorMap.read`` / ``ErrorMap.write``.
    sniff : callable
        ``sniff(path) -> bool``: True when the file looks like this format
        (cheap; never raises on an unreadable or foreign file).
    read : callable
        ``read(path, **options) -> ErrorMap``; raises ``MapError`` naming the
        file and line of malformed content.
    write : callable or None
        ``write(error_map, path)``, or None for a format that is read only.
    description : str
        One line for messages and listings.
    """

    name: str
    sniff: Callable[[Path], bool]
    read: Callable[..., Any]
    write: Callable[[Any, Path], None] | None = None
    description: str = ""


_FORMATS: dict[str, MapFormat] = {}

#: The formats cmmpose ships: module -> format name. Their modules register them the first time the registry is
#: used (``import cmmpose`` does not pay for them: issue 27, start-up); they come first, in this order, whichever
#: module was imported first, then any other format in the order registered.
BUILTIN = {"mapfiles": "csv", "controller": "controller", "iso230": "iso230-2"}
_builtin_state = {"loaded": False}
#: Held while the built-in modules load: threads reading maps at once (a Dask
#: scheduler's workers) must not see the registry before they have registered.
_builtin_lock = threading.RLock()


def _formats() -> dict[str, MapFormat]:
    """The registry, built-in formats loaded, in order."""
    if not _builtin_state["loaded"]:
        with _builtin_lock:
            if not _builtin_state["loaded"]:
                for module in BUILTIN:
                    importlib.import_module(f"{__package__}.{module}")
                _builtin_state["loaded"] = True
    first = [n for n in BUILTIN.values() if n in _FORMATS]
    return {n: _FORMATS[n] for n in [*first, *(n for n in _FORMATS if n not in first)]}


def register(name: str, *, sniff, read, write=None, description: str = "") -> MapFormat:
    """Register (or replace) the map file format ``name``; returns its entry."""
    fmt = MapFormat(name, sniff, read, write, description)
    _FORMATS[name] = fmt
    return fmt


def names() -> list[str]:
    """Names of the registered formats, in registration order."""
    return list(_formats())


def get(name: str) -> MapFormat:
    """The registered format ``name``; ``InputError`` naming it when unknown."""
    try:
        return _formats()[name]
    except (KeyError, TypeError):
        known = ", ".join(repr(n) for n in _FORMATS) or "none"
        raise InputError(f"format: unknown map file format {name!r} (known: {known})") from None


def detect(path: str | PathLike) -> str | None:
    """Name of the first registered format that recognises the file at ``path``, or None."""
    path = Path(path)
    for fmt in _formats().values():
        if fmt.sniff(path):
            return fmt.name
    return None


def read(path: str | PathLike, format: str = "csv", **options):
    """Read the map at ``path`` in ``format`` (``'auto'``: the format that
    recognises the file) with the reader's keyword ``options``."""
    if format == "auto":
        found = detect(path)
        if found is None:
            raise MapError(f"{path}: not an error-map file of a known format ({', '.join(_formats())})")
        format = found
    fmt = get(format)
    _check_options(fmt, options, path)
    return fmt.read(path, **options)


def _check_options(fmt: MapFormat, options: dict, path) -> None:
    """``InputError`` naming an option that the reader of ``fmt`` does not take
    (an option of another format: with ``format='auto'``, the file may be of a
    format other than the caller expected)."""
    try:
        params = inspect.signature(fmt.read).parameters
    except (TypeError, ValueError):
        return  # a reader whose signature cannot be inspected checks its own options
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    takes = [n for n, p in params.items()
             if p.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)][1:]
    unknown = [n for n in options if n not in takes]
    if unknown:
        took = ", ".join(takes) if takes else "none"
        raise InputError(f"{', '.join(unknown)}: not an option of the map file format {fmt.name!r}, which {path} "
                         f"is read as (its options: {took})")


def write(error_map, path: str | PathLike, format: str = "csv") -> None:
    """Write ``error_map`` at ``path`` in ``format``."""
    fmt = get(format)
    if fmt.write is None:
        raise InputError(f"format: map file format {format!r} can be read but not written")
    fmt.write(error_map, path)
